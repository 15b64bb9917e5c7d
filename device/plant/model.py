"""The plant: on/off valves, chambers, cylinders with friction, rigid platform and foot.

One call of :func:`plant_tick` advances the physics by one controller tick (1/7000 s) in
``substeps`` semi-implicit Euler steps. The pieces, each in its own function:

- valve: the armature moves only after the coil has been on (or off) for ``valve_delay``,
  then travels for ``valve_travel``; the open area follows it linearly. A pulse shorter than
  the delay passes nothing, a gap shorter than it never closes the valve: the paper's dead band.
- flow: ISO 6358 (sonic conductance C, critical ratio b) with the ISO 6358-3 laminar branch
  near equal pressures, in either direction.
- chamber: Richer & Hurmuzlu (2000) energy equation with dead volume; gauge force balance.
- friction: LuGre (Canudas de Wit et al. 1995) per piston: sticks below breakaway, Stribeck.
- platform: Newton-Euler of platform + foot about the ankle centre, leg masses reflected
  through the Jacobian, end stops at both ends of each stroke.
- patient: spring-damper of the strapped leg and passive ankle, the shank's preload and a
  scripted active torque (relaxed, resisting, pushing).

- faults (``device.plant.faults``): a fixed table of rows (kind, t0, channel, value in SI,
  t_end, held reading) acting while t0 <= t < t_end. Physical faults (supply, stuck valves,
  leaks) act in :func:`plant_tick`; sensor faults only change what :func:`read_sensors`
  reports, never the physics. An empty table costs one comparison per tick.

Chamber ``2 i`` is the cap (lower) side of leg ``i`` and ``2 i + 1`` its rod (upper) side;
valve ``2 c`` is the intake and ``2 c + 1`` the exhaust of chamber ``c``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from device._jit import njit, njit_inline
from device.kinematics import (
    Vec3,
    leg_vector,
    leg_vectors,
    m3,
    m3_rotate_inertia,
    m3_rotation,
    m3_rotation_sincos,
    m3_t_vec,
    m3_vec,
    row3,
    solve6,
    solve6_augmented,
    twist_jacobian,
    v3,
    v3_add,
    v3_cross,
    v3_scale,
    v3_sub,
)
from device.plant.faults import FAULT_COLUMNS, MAX_FAULTS, FaultKind
from device.plant.params import SENSOR_RING, TUBE_RING, PlantParams


class PlantState(NamedTuple):
    """Mutable state of the plant (arrays changed in place)."""

    time: NDArray[np.float64]  # (1,) s
    pose: NDArray[np.float64]  # (6,) task pose (m, rad)
    twist: NDArray[np.float64]  # (6,) v (m/s) and w (rad/s), base frame
    accel: NDArray[np.float64]  # (6,) last acceleration, for the sensor's inertial term
    pressure: NDArray[np.float64]  # (12,) Pa abs
    valve_cmd: NDArray[np.float64]  # (24,) 1 energised, 0 not
    valve_timer: NDArray[np.float64]  # (24,) s since the command last changed
    valve_open: NDArray[np.float64]  # (24,) open area fraction 0..1
    bristle: NDArray[np.float64]  # (6,) LuGre z (m)
    leg_force: NDArray[np.float64]  # (6,) net pneumatic force on each piston (N)
    script: NDArray[np.float64]  # (6, 4) patient force/torque script per axis: kind, t0, a, b
    scratch: NDArray[np.float64]  # (2, 6, 7) working memory of plant_tick (and of true_readings
    # between ticks), not state (see there)
    supply: NDArray[np.float64]  # (4,) manifold, regulator output (Pa abs), its set point
    # (Pa abs, sagging only under a SUPPLY_DROOP fault), flow in the supply line (kg/s)
    faults: NDArray[np.float64]  # (MAX_FAULTS, FAULT_COLUMNS) fault table, filled from row 0
    fault_now: NDArray[np.float64]  # (2, 24) per tick: valve armature override (-1 none), leak
    valve_delay_now: NDArray[np.float64]  # (24,) s: delay of each valve's current switching
    valve_switches: NDArray[np.float64]  # (24,) times each coil was energised
    air: NDArray[np.float64]  # (2,) kg: through the supply line, into the chambers
    tube: NDArray[np.float64]  # (TUBE_RING, 12) valve flow on its way down each tube (kg/s)
    in_flight: NDArray[np.float64]  # (12,) that flow's sum over the tube's delay (kg)
    sensor_history: NDArray[np.float64]  # (SENSOR_RING, 26) time and true value per read
    sensor_filter: NDArray[np.float64]  # (25,) each channel's filter output
    rings: NDArray[np.int64]  # (3,) tube head, sensor-history head, reads so far


SCRIPT_NONE = 0
SCRIPT_CONSTANT = 1  # a after t0
SCRIPT_RAMP = 2  # a * (t - t0) after t0, limited to |b|
SCRIPT_SINE = 3  # a * sin(2 pi b (t - t0)) after t0

# Fault kinds as plain integers: compile-time constants for numba.
F_SUPPLY_LOSS = int(FaultKind.SUPPLY_LOSS)
F_SUPPLY_DROOP = int(FaultKind.SUPPLY_DROOP)
F_PRESSURE_OPEN = int(FaultKind.PRESSURE_OPEN)
F_PRESSURE_SHORT = int(FaultKind.PRESSURE_SHORT)
F_PRESSURE_STUCK = int(FaultKind.PRESSURE_STUCK)
F_PRESSURE_OFFSET = int(FaultKind.PRESSURE_OFFSET)
F_LEG_STUCK = int(FaultKind.LEG_STUCK)
F_LEG_OFFSET = int(FaultKind.LEG_OFFSET)
F_LEG_NOISE = int(FaultKind.LEG_NOISE)
F_FT_DEAD = int(FaultKind.FT_DEAD)
F_FT_SATURATED = int(FaultKind.FT_SATURATED)
F_FT_OFFSET = int(FaultKind.FT_OFFSET)
F_VALVE_STUCK_OPEN = int(FaultKind.VALVE_STUCK_OPEN)
F_VALVE_STUCK_CLOSED = int(FaultKind.VALVE_STUCK_CLOSED)
F_CHAMBER_LEAK = int(FaultKind.CHAMBER_LEAK)


def new_state(params: PlantParams) -> PlantState:
    """Platform at rest at home, chambers balanced so the legs carry the platform's weight."""
    s = PlantState(
        time=np.zeros(1),
        pose=params.rest_pose.copy(),
        twist=np.zeros(6),
        accel=np.zeros(6),
        pressure=np.full(12, params.p_atm),
        valve_cmd=np.zeros(24),
        valve_timer=np.full(24, 1.0),
        valve_open=np.zeros(24),
        bristle=np.zeros(6),
        leg_force=np.zeros(6),
        script=np.zeros((6, 4)),
        scratch=np.zeros((2, 6, 7)),
        supply=np.array([params.p_supply, params.p_supply, params.p_supply, 0.0]),
        faults=np.zeros((MAX_FAULTS, FAULT_COLUMNS)),
        fault_now=np.zeros((2, 24)),
        valve_delay_now=params.valve_close_delay.copy(),
        valve_switches=np.zeros(24),
        air=np.zeros(2),
        tube=np.zeros((TUBE_RING, 12)),
        in_flight=np.zeros(12),
        sensor_history=np.zeros((SENSOR_RING, 26)),
        sensor_filter=np.zeros(25),
        rings=np.zeros(3, dtype=np.int64),
    )
    static_pressures(s, params)
    return s


def static_pressures(s: PlantState, p: PlantParams) -> None:
    """Set chamber pressures that hold the current pose still (half supply on the rod side)."""
    L, U, A, J = np.empty(6), np.empty((6, 3)), np.empty((6, 3)), np.empty((6, 6))
    leg_vectors(s.pose, p.base, p.plat, L, U, A)
    twist_jacobian(U, A, J)
    W = np.zeros(6)
    gravity_and_patient_wrench(s, p, W)
    f = np.empty(6)
    JT = np.ascontiguousarray(J.T)
    # Legs must supply -W (their wrench balances gravity and the foot), plus their own weight.
    if not solve6(JT, -W, f):
        return
    for i in range(6):
        f[i] += p.leg_mass * p.gravity * U[i, 2]
        p_rod = 0.5 * (p.p_supply + p.p_atm)
        s.pressure[2 * i + 1] = p_rod
        s.pressure[2 * i] = p.p_atm + (f[i] + (p_rod - p.p_atm) * p.area_annulus) / p.area_cap


@njit_inline
def iso6358_mass_flow(p_up: float, p_down: float, open_fraction: float, p: PlantParams) -> float:
    """Mass flow (kg/s) from ``p_up`` to ``p_down`` through a valve; negative if reversed."""
    if open_fraction <= 0.0 or p_up == p_down:
        return 0.0
    sign = 1.0
    if p_down > p_up:
        p_up, p_down = p_down, p_up
        sign = -1.0
    ratio = p_down / p_up
    b = p.critical_ratio
    if ratio <= b:
        phi = 1.0
    elif ratio < p.laminar_ratio:
        x = (ratio - b) / (1.0 - b)
        phi = math.sqrt(1.0 - x * x)
    else:
        x = (p.laminar_ratio - b) / (1.0 - b)
        phi = math.sqrt(1.0 - x * x) * (1.0 - ratio) / (1.0 - p.laminar_ratio)
    return (
        sign
        * open_fraction
        * p.conductance
        * p.rho_anr
        * p_up
        * math.sqrt(p.t_anr / p.temperature)
        * phi
    )


@njit_inline
def laminar_leak(p_up: float, p_down: float, k: float) -> float:
    """Mass flow (kg/s) through a leak path that is laminar: ``k (p_up^2 - p_down^2)``."""
    return k * (p_up * p_up - p_down * p_down)


@njit
def valve_opening(
    opening: float, energised: float, timer: float, delay: float, rate: float
) -> float:
    """Open fraction after a substep in which the armature may travel ``rate``."""
    if timer < delay:
        return opening
    if energised > 0.5:
        return min(1.0, opening + rate)
    return max(0.0, opening - rate)


@njit_inline
def write_valves(s: PlantState, p: PlantParams, command: NDArray[np.uint8]) -> None:
    """Energise (1) or release (0) the 24 coils; open-open is refused (both released).

    Each switching waits its valve's own delay for that direction, plus jitter drawn then.
    """
    for c in range(12):
        intake = 1.0 if command[2 * c] else 0.0
        exhaust = 1.0 if command[2 * c + 1] else 0.0
        if intake > 0.5 and exhaust > 0.5:
            intake = 0.0
            exhaust = 0.0
        for v, new in ((2 * c, intake), (2 * c + 1, exhaust)):
            if new != s.valve_cmd[v]:
                s.valve_cmd[v] = new
                s.valve_timer[v] = 0.0
                delay = p.valve_open_delay[v] if new > 0.5 else p.valve_close_delay[v]
                if new > 0.5:
                    s.valve_switches[v] += 1.0
                if p.valve_jitter > 0.0:
                    delay += p.valve_jitter * np.random.normal()
                s.valve_delay_now[v] = max(0.0, delay)


@njit_inline
def lugre_substep(s: PlantState, p: PlantParams, i: int, v: float, dt: float) -> float:
    """Advance leg ``i``'s bristle state by dt at piston velocity v; return friction (N)."""
    e = v / p.v_stribeck
    g = p.f_coulomb + (p.f_static - p.f_coulomb) * math.exp(-e * e)
    z: float = s.bristle[i]
    av = abs(v)
    if av > 0.0:
        z_ss = g / p.bristle_k * (1.0 if v > 0.0 else -1.0)
        # Exact solution of dz/dt = v - k |v| z / g for constant v: stable at any dt.
        z_new = z_ss + (z - z_ss) * math.exp(-p.bristle_k * av / g * dt)
    else:
        z_new = z
    z_dot = (z_new - z) / dt
    s.bristle[i] = z_new
    return p.bristle_k * z_new + p.bristle_c * z_dot + p.f_viscous * v


@njit_inline
def scripted_torque(script: NDArray[np.float64], axis: int, t: float) -> float:
    kind = int(script[axis, 0])
    t0: float = script[axis, 1]
    a: float = script[axis, 2]
    b: float = script[axis, 3]
    if kind == SCRIPT_NONE or t < t0:
        return 0.0
    if kind == SCRIPT_CONSTANT:
        return a
    if kind == SCRIPT_RAMP:
        x = a * (t - t0)
        return max(-abs(b), min(abs(b), x))
    if kind == SCRIPT_SINE:
        return a * math.sin(2.0 * math.pi * b * (t - t0))
    return 0.0


@njit_inline
def patient_wrench(s: PlantState, p: PlantParams, W: NDArray[np.float64]) -> None:
    """Wrench the patient's leg exerts on the foot plate, about the ankle (base frame)."""
    for k in range(6):
        W[k] = -p.patient_k[k] * (s.pose[k] - p.rest_pose[k]) - p.patient_b[k] * s.twist[k]
    W[2] -= p.shank_preload
    for k in range(6):  # the patient's active push (x, y, z) and torque (roll, pitch, yaw)
        W[k] += scripted_torque(s.script, k, s.time[0])


@njit
def gravity_and_patient_wrench(s: PlantState, p: PlantParams, W: NDArray[np.float64]) -> None:
    """Gravity on platform and foot plus the patient's wrench, about the ankle (base frame)."""
    patient_wrench(s, p, W)
    R = m3_rotation(s.pose[3], s.pose[4], s.pose[5])
    add_weight(W, m3_vec(R, p.body_com), p.body_mass, p.gravity)


@njit_inline
def add_weight(W: NDArray[np.float64], r: Vec3, mass: float, gravity: float) -> None:
    """Add to ``W`` the wrench about the ankle of a weight whose centre is at ``r``."""
    fz = -mass * gravity
    W[2] += fz
    W[3] += r[1] * fz
    W[4] -= r[0] * fz


@njit_inline
def plant_tick(s: PlantState, p: PlantParams) -> None:
    """Advance the plant by one tick with the valve commands already written.

    Written as one loop for speed: each ``np.empty`` is a heap allocation, and each call
    that numba does not inline costs reference-count updates for the arrays it is passed
    (22 for a state and its parameters); per substep these used to cost more than the
    physics. So nothing here allocates (the working arrays live in ``s.scratch``), the
    helpers called per substep take and return numbers and tuples and get inlined, and only
    the linear solve is a call with arrays (and, only while the fault table holds a fault or
    the supply is recovering from one, the fault helpers). The arithmetic is that of the plain
    version operation for operation, so the results are bit-identical to it; with no fault
    they are bit-identical to the plant before faults existed (tests/device/test_plant_faults).
    """
    n = p.substeps
    dt = p.dt / n
    rt = p.gas_r * p.temperature
    inv_rt = 1.0 / rt
    valve_rate = dt / p.valve_travel
    body_inertia = m3(p.body_inertia)
    J = s.scratch[0, :, :6]  # twist Jacobian
    f = s.scratch[0, :, 6]  # net force on each leg
    MW = s.scratch[1]  # [M | W]: mass matrix and generalised forces, solved in place
    W = MW[:, 6]
    # Faults: with an empty table this is the whole cost.
    faulty = s.faults[0, 0] != 0.0
    supply_lost = False
    set_point = p.p_supply
    if faulty:
        supply_lost, set_point = physical_faults(s, p)
    regulator_tick(s, p, set_point)
    tick_draw = 0.0  # the intakes' draw summed over the substeps (kg/s)
    for _ in range(n):
        for v in range(24):  # the valves' armatures, spelled out to keep s and p out of a call
            s.valve_timer[v] += dt
            s.valve_open[v] = valve_opening(
                s.valve_open[v], s.valve_cmd[v], s.valve_timer[v], s.valve_delay_now[v], valve_rate
            )
        if faulty:
            for v in range(24):  # a stuck armature, whatever the coil
                if s.fault_now[0, v] >= 0.0:
                    s.valve_open[v] = s.fault_now[0, v]
        supply_draw = 0.0  # kg/s into the chambers through their intakes
        p_valves = s.supply[0]  # what the intakes see; changes once a tick
        # Valve flow enters a tube now and reaches its cylinder tube_steps substeps later.
        tube_head = s.rings[0]
        tube_tail = (tube_head - p.tube_steps) % TUBE_RING
        s.rings[0] = (tube_head + 1) % TUBE_RING
        # The pose does not change until the integration at the end, so its rotation (and
        # the sines and cosines the integration needs) are computed once.
        cr, sr = math.cos(s.pose[3]), math.sin(s.pose[3])
        cp, sp = math.cos(s.pose[4]), math.sin(s.pose[4])
        cy, sy = math.cos(s.pose[5]), math.sin(s.pose[5])
        R = m3_rotation_sincos(cr, sr, cp, sp, cy, sy)
        position = v3(s.pose, 0)
        for i in range(6):
            length, u, arm = leg_vector(position, R, row3(p.base, i), row3(p.plat, i))
            moment_arm = v3_cross(arm, u)  # row i of the twist Jacobian is (u, arm x u)
            for k in range(3):
                J[i, k] = u[k]
                J[i, 3 + k] = moment_arm[k]
            x = length - p.min_length
            xd = 0.0
            for k in range(6):
                xd += J[i, k] * s.twist[k]
            # Across the piston, cap side to rod side, from the pressures before this substep.
            m_piston = laminar_leak(s.pressure[2 * i], s.pressure[2 * i + 1], p.piston_leak)
            # Chambers: cap side grows with x, rod side shrinks.
            for side in range(2):
                c = 2 * i + side
                if side == 0:
                    area = p.area_cap
                    vol = p.dead_volume + area * x
                    dvol = area * xd
                    m_leak = m_piston  # out of this chamber
                else:
                    area = p.area_annulus
                    vol = p.dead_volume + area * (p.stroke - x)
                    dvol = -area * xd
                    m_leak = -m_piston
                vol = max(vol, 0.2 * p.dead_volume)  # a bottomed piston still leaves its port
                pc = s.pressure[c]
                # The valves see the pressure at their end of the tube: the cylinder's plus
                # what has passed them and is still on its way.
                rt_v = rt / vol  # one division, used three times
                pv = pc + rt_v * s.in_flight[c]
                a_in = s.valve_open[2 * c] * p.valve_scale[2 * c]
                a_out = s.valve_open[2 * c + 1] * p.valve_scale[2 * c + 1]
                if a_in > 0.0:
                    m_in = iso6358_mass_flow(p_valves, pv, a_in, p)
                else:  # a closed seat still passes a little
                    m_in = laminar_leak(p_valves, pv, p.seat_leak)
                if a_out > 0.0:
                    m_out = iso6358_mass_flow(pv, p.p_atm, a_out, p)
                else:
                    m_out = laminar_leak(pv, p.p_atm, p.seat_leak)
                supply_draw += m_in
                inflow = (p.alpha_in if m_in > 0.0 else p.alpha_out) * m_in
                outflow = (p.alpha_out if m_out > 0.0 else p.alpha_in) * m_out
                s.tube[tube_head, c] = inflow - outflow
                valve_term = s.tube[tube_tail, c]
                s.in_flight[c] += (inflow - outflow - valve_term) * dt
                if faulty and s.fault_now[1, c] > 0.0:  # a leak: an orifice to atmosphere
                    m_leak += iso6358_mass_flow(pc, p.p_atm, s.fault_now[1, c], p)
                leak_term = (p.alpha_out if m_leak > 0.0 else p.alpha_in) * m_leak
                dp = rt_v * (valve_term - leak_term - p.alpha_work * pc * dvol * inv_rt)
                s.pressure[c] = max(1000.0, pc + dp * dt)
            force = (s.pressure[2 * i] - p.p_atm) * p.area_cap - (
                s.pressure[2 * i + 1] - p.p_atm
            ) * p.area_annulus
            s.leg_force[i] = force
            force -= lugre_substep(s, p, i, xd, dt)
            force -= p.leg_mass * p.gravity * u[2]
            if x < 0.0:
                force -= p.stop_k * x + p.stop_c * min(xd, 0.0)
            elif x > p.stroke:
                force -= p.stop_k * (x - p.stroke) + p.stop_c * max(xd, 0.0)
            f[i] = force
        tick_draw += supply_draw
        # Generalised forces on the platform (base frame, about the ankle).
        r = m3_vec(R, p.body_com)
        patient_wrench(s, p, W)
        add_weight(W, r, p.body_mass, p.gravity)
        for k in range(6):
            for i in range(6):
                W[k] += J[i, k] * f[i]
        # Mass matrix of the rigid body about the ankle plus reflected leg masses.
        Io = m3_rotate_inertia(R, body_inertia)
        m = p.body_mass
        for a in range(6):
            for b in range(6):
                MW[a, b] = 0.0
        for a in range(3):
            MW[a, a] = m
            for b in range(3):
                MW[3 + a, 3 + b] = Io[a][b]
        # m [r]x in the lower-left block, its transpose upper-right.
        MW[3, 1] = -m * r[2]
        MW[3, 2] = m * r[1]
        MW[4, 0] = m * r[2]
        MW[4, 2] = -m * r[0]
        MW[5, 0] = -m * r[1]
        MW[5, 1] = m * r[0]
        for a in range(3):
            for b in range(3):
                MW[a, 3 + b] = MW[3 + b, a]
        # J^T J is symmetric: each sum is formed once and added to both of its entries.
        for a in range(6):
            for b in range(a, 6):
                s_ab = 0.0
                for i in range(6):
                    s_ab += J[i, a] * J[i, b]
                MW[a, b] += p.leg_mass * s_ab
                if b != a:
                    MW[b, a] += p.leg_mass * s_ab
        w = v3(s.twist, 3)
        wwr = v3_cross(w, v3_cross(w, r))
        wIw = v3_cross(w, m3_vec(Io, w))
        for k in range(3):
            W[k] -= m * wwr[k]
            W[3 + k] -= wIw[k]
        acc = s.accel  # solved straight into the state
        if not solve6_augmented(MW, acc):
            acc[:] = 0.0
        for k in range(6):
            s.twist[k] += acc[k] * dt
        s.pose[0] += s.twist[0] * dt
        s.pose[1] += s.twist[1] * dt
        s.pose[2] += s.twist[2] * dt
        wx, wy, wz = s.twist[3], s.twist[4], s.twist[5]
        roll_rate = (cy * wx + sy * wy) / cp
        s.pose[3] += roll_rate * dt
        s.pose[4] += (-sy * wx + cy * wy) * dt
        s.pose[5] += (wz + sp * roll_rate) * dt
        s.time[0] += dt
    # The supply side changes with time constants of tens of milliseconds: once a tick,
    # with the intakes' mean draw over it, is as good as once a substep and half the cost.
    supply_substep(s, p, supply_lost, tick_draw / n, p.dt)


@njit
def physical_faults(s: PlantState, p: PlantParams) -> tuple[bool, float]:
    """Fill ``s.fault_now`` for this tick; return (supply hose off, regulator's set point).

    Row 0 of ``fault_now``: the armature position a stuck valve is held at (-1: free).
    Row 1: each chamber's leak to atmosphere as a fraction of one valve's conductance.
    """
    t = s.time[0]
    for v in range(24):
        s.fault_now[0, v] = -1.0
        s.fault_now[1, v] = 0.0
    lost = False
    target = p.p_supply
    for r in range(s.faults.shape[0]):
        kind = int(s.faults[r, 0])
        if kind == 0:
            break
        if t < s.faults[r, 1] or t >= s.faults[r, 4]:
            continue
        ch = int(s.faults[r, 2])
        value = s.faults[r, 3]
        if kind == F_SUPPLY_LOSS:
            lost = True
        elif kind == F_SUPPLY_DROOP:
            target = min(target, p.p_atm + value)
        elif kind == F_VALVE_STUCK_OPEN:
            s.fault_now[0, ch] = 1.0
        elif kind == F_VALVE_STUCK_CLOSED:
            s.fault_now[0, ch] = 0.0
        elif kind == F_CHAMBER_LEAK:
            s.fault_now[1, ch] += value
    return lost, target


@njit_inline
def regulator_tick(s: PlantState, p: PlantParams, set_point: float) -> None:
    """Once a tick: the regulator's set point (which sags only under a SUPPLY_DROOP fault,
    and recovers, with the droop time constant) and its output, which follows the set point
    less its droop under the flow it delivers, with the regulator's response time."""
    if s.supply[2] != set_point:
        s.supply[2] = set_point + (s.supply[2] - set_point) * p.droop_decay
        if abs(s.supply[2] - set_point) < 1.0:
            s.supply[2] = set_point
    target = s.supply[2] - p.regulator_droop * max(s.supply[3], 0.0)
    s.supply[1] = target + (s.supply[1] - target) * p.regulator_decay


@njit_inline
def supply_substep(s: PlantState, p: PlantParams, lost: bool, draw: float, dt: float) -> None:
    """The valve manifold (``supply_volume``) fills from the regulator's output through the
    supply line (an ISO 6358 orifice) and feeds the intakes (``draw``, kg/s; negative when
    chambers blow back) over ``dt``. With the hose off the line's far end is the
    atmosphere."""
    upstream = p.p_atm if lost else s.supply[1]
    ps = s.supply[0]
    m_line = iso6358_mass_flow(upstream, ps, p.supply_line_fraction, p)
    s.supply[3] = m_line
    s.air[0] += m_line * dt
    s.air[1] += draw * dt
    net = m_line - draw
    alpha = p.alpha_in if net > 0.0 else p.alpha_out
    ps += alpha * p.gas_r * p.temperature / p.supply_volume * net * dt
    s.supply[0] = max(1000.0, ps)


@njit
def _quantise(value: float, lsb: float) -> float:
    return lsb * math.floor(value / lsb + 0.5)


@njit_inline
def true_readings(s: PlantState, p: PlantParams, out: NDArray[np.float64]) -> None:
    """What every sensor would read if it were perfect, now, into ``out``."""
    out[12] = s.supply[0]
    R = m3_rotation(s.pose[3], s.pose[4], s.pose[5])
    rt = p.gas_r * p.temperature
    for i in range(6):
        x = leg_vector(v3(s.pose, 0), R, row3(p.base, i), row3(p.plat, i))[0] - p.min_length
        out[13 + i] = x
        for side in range(2):
            c = 2 * i + side
            out[c] = s.pressure[c]
            if p.sensor_at_valves:  # what is on its way down the tube is already here
                vol = p.dead_volume + (
                    p.area_cap * x if side == 0 else p.area_annulus * (p.stroke - x)
                )
                out[c] += rt / max(vol, 0.2 * p.dead_volume) * s.in_flight[c]
    # The force plate carries the foot: the patient's wrench, the foot's weight and the
    # foot's inertia, moved from the ankle to the sensor origin and into the sensor's frame.
    W = s.scratch[1, :, 6]  # plant_tick's working memory: free between ticks, no allocation
    patient_wrench(s, p, W)
    rf = m3_vec(R, p.foot_com)
    w, alpha = v3(s.twist, 3), v3(s.accel, 3)
    a_com = v3_add(v3_add(v3(s.accel, 0), v3_cross(alpha, rf)), v3_cross(w, v3_cross(w, rf)))
    F0, F1, F2 = v3_sub(v3(W, 0), v3_scale(p.foot_mass, a_com))
    F: Vec3 = (F0, F1, F2 - p.foot_mass * p.gravity)
    If = m3_rotate_inertia(R, m3(p.foot_inertia))
    Mo = v3_sub(
        v3_sub(v3_add(v3(W, 3), v3_cross(rf, v3_sub(F, v3(W, 0)))), m3_vec(If, alpha)),
        v3_cross(w, m3_vec(If, w)),
    )
    rs = m3_vec(R, p.sensor_origin)
    Ms = v3_sub(Mo, v3_cross(rs, F))
    Fb = m3_t_vec(R, F)
    Mb = m3_t_vec(R, Ms)
    for k in range(3):
        out[19 + k] = Fb[k]
        out[22 + k] = Mb[k]


@njit_inline
def bracket(history: NDArray[np.float64], head: int, n: int, t: float) -> tuple[int, int, float]:
    """(older row, newer row, fraction) of the reads in ``history`` (rows: time, then the
    25 channels; ``head`` the newest of ``n`` rows) that time ``t`` lies between; a time
    after the newest read gives the newest, one before the oldest kept the oldest."""
    if t >= history[head, 0]:
        return head, head, 0.0
    rows = history.shape[0]
    newer = head
    for j in range(1, n):
        older = (head - j) % rows
        t_old = history[older, 0]
        if t_old <= t:
            span = history[newer, 0] - t_old
            return older, newer, (t - t_old) / span if span > 0.0 else 1.0
        newer = older
    return newer, newer, 0.0


@njit_inline
def read_sensors(s: PlantState, p: PlantParams, out: NDArray[np.float64]) -> None:
    """Sample every sensor into ``out`` (see device.signals).

    Each channel is the true value ``sensor_delay`` ago (linear between reads), through a
    first-order filter (``sensor_tau``, advanced by the time since the last read), with its
    unit's span and zero errors, noise and quantisation, clipped to its range. The filter
    acts on the reads, so it is exact for signals slow beside the read rate (1 kHz). Delay
    and filter are the same within each group of channels (pressures, legs, force/torque):
    one search and one exponential per group.

    Inlined into the simulated loop, as :func:`true_readings` is: called, each passed the
    plant's state and parameter tuples, whose every array's reference count numba raises
    and lowers again with an atomic instruction per array. Profiled with ``perf``, those
    instructions were 21 % of the loop's time (numba's ``NRT_incref``/``NRT_decref``).
    """
    true_readings(s, p, out)
    t = s.time[0]
    history = s.sensor_history
    rows = history.shape[0]
    head = s.rings[1]
    reads = s.rings[2]
    previous_t = history[(head - 1) % rows, 0]
    history[head, 0] = t
    for k in range(25):
        history[head, 1 + k] = out[k]
    n = min(reads + 1, rows)
    older, newer, f = 0, 0, 0.0
    a = 1.0
    for k in range(25):
        if k == 0 or k == 13 or k == 19:  # the first channel of a group
            older, newer, f = bracket(history, head, n, t - p.sensor_delay[k])
            a = 1.0
            if reads > 0 and t > previous_t:
                a = 1.0 - math.exp(-(t - previous_t) / p.sensor_tau[k])
        value = history[older, 1 + k] + f * (history[newer, 1 + k] - history[older, 1 + k])
        if reads == 0:
            s.sensor_filter[k] = value
        else:
            s.sensor_filter[k] += a * (value - s.sensor_filter[k])
        y = s.sensor_filter[k] * p.sensor_gain[k] + p.sensor_offset[k]
        if k < 13:
            y = _quantise(y + np.random.normal(0.0, p.pressure_noise), p.pressure_lsb)
            out[k] = min(max(y, 0.0), p.pressure_top)
        elif k < 19:
            y = _quantise(y + np.random.normal(0.0, p.leg_noise), p.leg_lsb)
            out[k] = min(max(y, p.leg_low), p.leg_high)
        elif k < 22:
            out[k] = _quantise(y + np.random.normal(0.0, p.force_noise), p.force_lsb)
        else:
            out[k] = _quantise(y + np.random.normal(0.0, p.torque_noise), p.torque_lsb)
    s.rings[1] = (head + 1) % rows
    s.rings[2] = reads + 1
    if s.faults[0, 0] != 0.0:
        sensor_faults(s, p, out)


@njit
def sensor_faults(s: PlantState, p: PlantParams, out: NDArray[np.float64]) -> None:
    """Replace healthy readings in ``out`` by what the faulty sensors report.

    A stuck sensor keeps the first reading it gave from t0 on (in the row's last column,
    NaN until then). An offset is added before the ADC: the result is quantised and clipped
    to the sensor's range, as a real one would be. Healthy channels are untouched, and the
    random numbers of their noise are the same with or without faults elsewhere (except
    after a LEG_NOISE burst, which draws its own numbers from the same generator).
    """
    t = s.time[0]
    for r in range(s.faults.shape[0]):
        kind = int(s.faults[r, 0])
        if kind == 0:
            break
        if t < s.faults[r, 1] or t >= s.faults[r, 4]:
            continue
        ch = int(s.faults[r, 2])
        value = s.faults[r, 3]
        if kind == F_PRESSURE_OPEN:
            out[ch] = 0.0
        elif kind == F_PRESSURE_SHORT:
            out[ch] = p.pressure_top
        elif kind == F_PRESSURE_OFFSET:
            out[ch] = min(max(_quantise(out[ch] + value, p.pressure_lsb), 0.0), p.pressure_top)
        elif kind == F_PRESSURE_STUCK:
            out[ch] = _held(s.faults, r, out[ch])
        elif kind == F_LEG_STUCK:
            out[13 + ch] = _held(s.faults, r, out[13 + ch])
        elif kind == F_LEG_OFFSET:
            out[13 + ch] = min(
                max(_quantise(out[13 + ch] + value, p.leg_lsb), p.leg_low), p.leg_high
            )
        elif kind == F_LEG_NOISE:
            x = out[13 + ch] + np.random.normal(0.0, value)
            out[13 + ch] = min(max(_quantise(x, p.leg_lsb), p.leg_low), p.leg_high)
        elif kind == F_FT_DEAD or kind == F_FT_SATURATED or kind == F_FT_OFFSET:  # noqa: SIM109
            lo, hi = (0, 6) if ch < 0 else (ch, ch + 1)
            for k in range(lo, hi):
                if kind == F_FT_DEAD:
                    out[19 + k] = 0.0
                elif kind == F_FT_SATURATED:
                    out[19 + k] = p.ft_range[k]
                else:
                    lsb = p.force_lsb if k < 3 else p.torque_lsb
                    out[19 + k] = _quantise(out[19 + k] + value, lsb)


@njit
def _held(table: NDArray[np.float64], row: int, reading: float) -> float:
    """A stuck sensor's reading: the first one it gave while stuck, kept in the row."""
    if math.isnan(table[row, 5]):
        table[row, 5] = reading
    return float(table[row, 5])


@njit
def seed(value: int) -> None:
    """Seed the compiled code's random generator (sensor noise)."""
    np.random.seed(value)
