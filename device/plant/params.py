"""Every physical parameter of the plant simulation, with its reasoning, in one table.

The paper fixes the valves (Matrix, about 1 ms response, 300 Hz, about 100 NL/min) and the
PWM (250 Hz); everything else is unpublished and chosen here to be physically plausible for
a foot-sized pneumatic Stewart platform with low-friction (glass/graphite) cylinders, the
kind haptic devices use. Nothing here is tuned to flatter the controller: a value changes
only with a better source, and the reason column says where each one comes from.

``ankle sim params`` prints this table; ``docs/plant.md`` is generated from it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from device.geometry import DEFAULT_GEOMETRY, Geometry


@dataclass(frozen=True)
class Param:
    """One row of the parameter table."""

    name: str
    value: float
    unit: str
    reason: str
    low: float | None = None
    """Plausible range of a real build (``low``..``high``): what ``ankle bench control
    --ensemble`` draws from. None: not varied (a constant of physics, a design choice, or a
    setting of the experiment)."""
    high: float | None = None

    @property
    def varies(self) -> bool:
        return self.low is not None and self.high is not None


_ROWS: tuple[Param, ...] = (
    # Air supply
    Param(
        "supply_pressure",
        7.0e5,
        "Pa abs",
        "6 bar gauge: a common compressor/regulator setting, as DESIGN assumes; a regulator set by hand at home lands within about 0.3 bar of it",
        6.7e5,
        7.3e5,
    ),
    Param("atmosphere", 1.01325e5, "Pa abs", "standard atmosphere"),
    Param(
        "supply_volume",
        50.0e-6,
        "m3",
        "supply side behind the regulator: manifold of the 12 intake valves (about 20 cm3) plus 1 m of 6 mm bore hose (28 cm3)",
        30.0e-6,
        100.0e-6,
    ),
    Param(
        "supply_line_conductance",
        2.0,
        "dm3/(s bar)",
        "ISO 6358 C of 1 m of 6 mm hose with a 1/4 in quick coupling (about 2; same b as the valves): several intakes open at once draw the manifold down through it. With supply_volume: choked blowdown time constant V/(C rho0 R T) = 25 ms when the hose comes off",
        1.0,
        4.0,
    ),
    Param(
        "regulator_droop",
        0.1,
        "bar per 100 NL/min",
        "a regulator's output falls with the flow it delivers (its flow curve): about 0.1 bar at 100 NL/min for a precision regulator, up to 0.4 for a general-purpose one",
        0.0,
        0.4,
    ),
    Param(
        "regulator_response",
        20.0e-3,
        "s",
        "time constant with which a diaphragm regulator's output follows a change of flow (10-50 ms for small regulators)",
        10.0e-3,
        50.0e-3,
    ),
    Param(
        "supply_droop_time_constant",
        0.5,
        "s",
        "a regulator sagging to a lower output (compressor tank drawn below its set point; fault injection only) changes over seconds; 0.5 s is the fast end, a harsher test",
    ),
    Param(
        "temperature",
        293.15,
        "K",
        "supply air at room temperature; chambers exchange heat with the walls",
    ),
    Param("gas_constant", 287.05, "J/(kg K)", "dry air"),
    Param(
        "speed_of_sound",
        343.0,
        "m/s",
        "in air at 20 C: how fast a pressure change runs down a tube",
    ),
    Param("alpha_in", 1.4, "-", "polytropic index of charging: adiabatic (Richer & Hurmuzlu 2000)"),
    Param("alpha_out", 1.0, "-", "discharge close to isothermal (Richer & Hurmuzlu 2000)"),
    Param("alpha_work", 1.2, "-", "volume-change term between the two (Richer & Hurmuzlu 2000)"),
    # Valves
    Param(
        "valve_conductance",
        0.30,
        "dm3/(s bar)",
        "ISO 6358 sonic conductance C. 100 NL/min is 0.24 if rated choked at 7 bar abs and 0.37 if rated 6->5 bar gauge with b = 0.4: the middle of that range",
        0.24,
        0.37,
    ),
    Param(
        "valve_conductance_spread",
        0.05,
        "-",
        "each valve's C differs from the type's by up to this fraction (uniform, drawn per valve from the unit's seed): orifice and seat tolerances",
        0.0,
        0.10,
    ),
    Param(
        "valve_critical_ratio",
        0.40,
        "-",
        "ISO 6358 b for a small poppet solenoid valve (typical 0.3-0.5)",
        0.30,
        0.50,
    ),
    Param(
        "valve_laminar_ratio",
        0.999,
        "-",
        "ISO 6358-3 laminar branch above this pressure ratio: finite, linear flow near equal pressures",
    ),
    Param(
        "valve_open_delay",
        0.75e-3,
        "s",
        "the armature does not move until the coil has been energised this long (current rise to pull-in); with the travel, about the paper's 1 ms response",
        0.55e-3,
        1.05e-3,
    ),
    Param(
        "valve_close_delay",
        0.85e-3,
        "s",
        "after the coil is released the armature waits for the current and the residual flux to decay: as a rule slower than pull-in",
        0.60e-3,
        1.20e-3,
    ),
    Param(
        "valve_delay_spread",
        0.05,
        "-",
        "each valve's delays differ from the type's by up to this fraction (uniform, per valve and per direction, drawn from the unit's seed): spring preload and coil tolerances",
        0.0,
        0.15,
    ),
    Param(
        "valve_jitter",
        0.03e-3,
        "s",
        "rms of each switching's delay about the valve's own (supply voltage ripple, temperature, the previous switching's residual field)",
        0.0,
        0.10e-3,
    ),
    Param(
        "valve_travel",
        0.2e-3,
        "s",
        "armature travel from closed to open (and back)",
        0.15e-3,
        0.30e-3,
    ),
    Param(
        "valve_seat_leak",
        0.01,
        "NL/min",
        "a closed valve still passes a little air, laminar (flow ~ p1^2 - p2^2); this much from 6 bar gauge to atmosphere: 10 cm3/min, a new elastomer-seated poppet; a worn seat leaks many times that",
        0.0,
        0.5,
    ),
    # Tubes and cylinders (double-acting, low friction)
    Param(
        "tube_length",
        0.5,
        "m",
        "from the valve block in the control box to each cylinder port. A pressure change at the valve reaches the piston tube_length / speed_of_sound later (Richer & Hurmuzlu 2000's line model; its attenuation is not modelled), and the tube adds to the dead volume",
        0.3,
        1.0,
    ),
    Param("tube_bore", 4.0e-3, "m", "inner diameter of the 6 mm polyurethane tubes"),
    Param(
        "port_volume",
        1.0e-6,
        "m3",
        "per chamber: cylinder end and fittings, beside the tube's volume; chamber dead volume = this + the tube (7.3 cm3 nominal)",
        0.5e-6,
        2.0e-6,
    ),
    Param(
        "bore",
        25.0e-3,
        "m",
        "25 mm: about 290 N per leg at 6 bar, ample for ankle torques near 50 N m on a 0.1 m platform",
    ),
    Param("rod", 8.0e-3, "m", "8 mm rod of a 25 mm glass/graphite cylinder; area ratio r = 0.90"),
    Param(
        "piston_leak",
        0.5,
        "NL/min",
        "a glass/graphite piston seals by a clearance and leaks across by design, laminar (flow ~ p1^2 - p2^2); this much from 6 bar gauge to atmosphere. Assumed: a 25 mm, 10 mm long piston in a 4.5 um gap by Poiseuille; 3-7 um gives the range",
        0.1,
        2.0,
    ),
    Param(
        "leg_mass",
        0.25,
        "kg",
        "piston, rod and rod-end joint moving with each leg",
        0.20,
        0.35,
    ),
    Param(
        "friction_coulomb",
        1.0,
        "N",
        "glass/graphite piston: Coulomb about 1 N (haptic-grade cylinders); light elastomer seals reach about 5 N",
        0.5,
        5.0,
    ),
    Param(
        "friction_breakaway_ratio",
        1.5,
        "-",
        "breakaway (static) friction over Coulomb friction",
        1.2,
        2.0,
    ),
    Param(
        "friction_stribeck_velocity",
        5.0e-3,
        "m/s",
        "Stribeck velocity of lubricated glass/graphite",
        2.0e-3,
        10.0e-3,
    ),
    Param(
        "friction_viscous",
        5.0,
        "N s/m",
        "viscous friction of the piston and rod seal",
        2.0,
        20.0,
    ),
    Param(
        "bristle_stiffness",
        1.0e5,
        "N/m",
        "LuGre sigma0: 15 um pre-sliding displacement at breakaway",
    ),
    Param(
        "bristle_damping",
        300.0,
        "N s/m",
        "LuGre sigma1: about half critical damping of the bristles with ~1 kg on the leg",
    ),
    Param("end_stop_stiffness", 2.0e6, "N/m", "rubber bumper at either end of the stroke"),
    Param("end_stop_damping", 2.0e3, "N s/m", "bumper damping"),
    # Platform and foot
    Param(
        "platform_mass",
        2.5,
        "kg",
        "aluminium plate (1.2 kg), force/torque sensor (0.3 kg), foot plate and straps (1.0 kg); a build with a heavier plate or straps differs by a kilogram",
        2.0,
        3.5,
    ),
    Param(
        "platform_com_below_ankle",
        0.09,
        "m",
        "platform centre of mass 1 cm above the joint plane",
        0.07,
        0.11,
    ),
    Param(
        "platform_com_forward",
        0.0,
        "m",
        "platform centre of mass ahead of the ankle axis: zero as drawn, a centimetre either way as built (straps, cable, sensor mounting)",
        -0.01,
        0.01,
    ),
    Param(
        "platform_com_left",
        0.0,
        "m",
        "platform centre of mass to the side of the ankle: zero as drawn",
        -0.01,
        0.01,
    ),
    Param(
        "platform_radius_of_gyration",
        0.07,
        "m",
        "disc of 0.12 m radius about a diameter (r/2 = 0.06) plus the sensor and straps",
        0.06,
        0.08,
    ),
    Param(
        "foot_mass",
        1.1,
        "kg",
        "foot of a 75 kg adult: 1.45 % of body mass (de Leva 1996); 55-100 kg adults",
        0.8,
        1.45,
    ),
    Param("foot_com_forward", 0.05, "m", "foot centre of mass ahead of the ankle axis"),
    Param("foot_com_below", 0.04, "m", "foot centre of mass below the ankle axis"),
    Param(
        "foot_inertia_pitch",
        0.004,
        "kg m2",
        "foot about its centre of mass, sagittal axis (de Leva 1996)",
    ),
    Param("foot_inertia_roll", 0.001, "kg m2", "foot about its centre of mass, long axis"),
    Param("foot_inertia_yaw", 0.004, "kg m2", "foot about its centre of mass, vertical axis"),
    # Patient (seated, foot strapped to the plate)
    Param(
        "shank_preload",
        30.0,
        "N",
        "part of the shank's weight that rests on the foot of a seated patient",
        15.0,
        60.0,
    ),
    Param(
        "patient_translation_stiffness",
        5.0e3,
        "N/m",
        "knee and hip compliance of a seated, strapped leg against translation of the ankle",
    ),
    Param("patient_translation_damping", 100.0, "N s/m", "soft-tissue damping of that restraint"),
    Param(
        "ankle_stiffness_pitch",
        15.0,
        "N m/rad",
        "passive ankle stiffness of a relaxed adult near neutral, sagittal plane",
        8.0,
        30.0,
    ),
    Param(
        "ankle_stiffness_roll",
        20.0,
        "N m/rad",
        "passive ankle stiffness, frontal plane",
        10.0,
        40.0,
    ),
    Param("ankle_stiffness_yaw", 10.0, "N m/rad", "passive stiffness about the shank axis"),
    Param("ankle_damping", 0.3, "N m s/rad", "passive ankle damping, relaxed"),
    Param(
        "resist_factor",
        4.0,
        "-",
        "co-contraction of a patient who resists multiplies ankle stiffness about fourfold",
    ),
    # Sensors
    Param(
        "pressure_sensors_at_valves",
        1.0,
        "1 or 0",
        "1: each chamber's transducer sits in the control box at the valve end of its tube, beside the valves and the amplifiers the paper's box holds; 0: at the cylinder port, where it sees the tube's delay",
    ),
    Param("pressure_range", 1.0e6, "Pa", "0-10 bar absolute transducers, 12-bit ADC"),
    Param("pressure_noise", 100.0, "Pa", "1 mbar rms electrical noise", 50.0, 300.0),
    Param(
        "pressure_delay",
        0.2e-3,
        "s",
        "from the chamber to the number the controller reads: transducer electronics and the board's conversion",
        0.0,
        0.5e-3,
    ),
    Param(
        "pressure_bandwidth",
        1000.0,
        "Hz",
        "first-order: the transducer's response (about 0.5 ms for a piezoresistive one) with the board's anti-alias filter before the 1 kHz sampling",
        500.0,
        2000.0,
    ),
    Param(
        "pressure_offset",
        5.0e3,
        "Pa",
        "each transducer's zero is off by up to this (uniform, per channel, from the unit's seed): 0.5 % of full scale, a typical total error band",
        0.0,
        10.0e3,
    ),
    Param(
        "pressure_gain_error",
        0.005,
        "-",
        "each transducer's span is off by up to this fraction (per channel)",
        0.0,
        0.02,
    ),
    Param("leg_sensor_bits", 12.0, "bit", "12-bit ADC over the stroke: 0.024 mm per count"),
    Param(
        "leg_sensor_margin",
        2.0e-3,
        "m",
        "the sensor's measuring range reaches this far past either end of the stroke, so a zero error either way still reads at the end stops",
    ),
    Param(
        "leg_noise",
        5.0e-6,
        "m",
        "rms noise of the linear position sensor",
        2.0e-6,
        15.0e-6,
    ),
    Param(
        "leg_delay",
        0.3e-3,
        "s",
        "from the piston to the number read: a magnetostrictive sensor's measuring cycle or a potentiometer's filter, and the conversion",
        0.0,
        1.0e-3,
    ),
    Param(
        "leg_bandwidth",
        1000.0,
        "Hz",
        "first-order: the position sensor's output filter with the anti-alias filter",
        300.0,
        2000.0,
    ),
    Param(
        "leg_offset",
        0.2e-3,
        "m",
        "each leg sensor's zero is off by up to this (per channel): mounting and temperature since the factory's calibration",
        0.0,
        1.0e-3,
    ),
    Param(
        "leg_gain_error",
        0.001,
        "-",
        "each leg sensor's span is off by up to this fraction (per channel): a ratiometric sensor after the factory's two-point calibration of each leg",
        0.0,
        0.003,
    ),
    Param(
        "force_resolution",
        1.0 / 4.0,
        "N",
        "6-axis sensor of the ATI Mini85 class (SI-1900-80): a range that covers the device's 60 N m torque limit and a resisting patient (the Mini45's 5 N m does not)",
    ),
    Param("force_noise", 0.2, "N", "rms force noise, about one count"),
    Param(
        "force_range_xy",
        1900.0,
        "N",
        "full scale of Fx, Fy (Mini85 SI-1900-80); a healthy reading never comes near it (the device trips at 400 N)",
    ),
    Param("force_range_z", 3800.0, "N", "full scale of Fz (Mini85 SI-1900-80)"),
    Param("torque_resolution", 1.0 / 80.0, "N m", "6-axis sensor of the Mini85 class"),
    Param("torque_noise", 0.01, "N m", "rms torque noise, about one count"),
    Param(
        "torque_range",
        80.0,
        "N m",
        "full scale of Tx, Ty, Tz (Mini85 SI-1900-80): above the device's 60 N m torque limit",
    ),
    Param(
        "ft_delay",
        0.5e-3,
        "s",
        "from the foot to the number read: the sensor's strain-gauge electronics and its data acquisition",
        0.2e-3,
        1.0e-3,
    ),
    Param(
        "ft_bandwidth",
        500.0,
        "Hz",
        "first-order: the force sensor's low-pass filter as commonly configured",
        200.0,
        1000.0,
    ),
    Param(
        "ft_force_offset",
        1.0,
        "N",
        "each force channel's zero drifts by up to this between tares (per channel)",
        0.0,
        3.0,
    ),
    Param(
        "ft_torque_offset",
        0.05,
        "N m",
        "each torque channel's zero drifts by up to this between tares (per channel)",
        0.0,
        0.2,
    ),
    Param(
        "ft_gain_error",
        0.01,
        "-",
        "each force/torque channel's span is off by up to this fraction (1 % of reading, a calibrated sensor's accuracy)",
        0.0,
        0.02,
    ),
    Param(
        "sensor_below_ankle",
        0.08,
        "m",
        "force/torque sensor origin above the platform centre, under the foot plate",
    ),
    Param("gravity", 9.81, "m/s2", "standard gravity"),
)
PARAMETERS: dict[str, Param] = {p.name: p for p in _ROWS}


def parameter_table_markdown() -> str:
    """The parameter table as Markdown (the source of docs/plant.md)."""
    lines = ["| parameter | nominal | range | unit | why |", "|---|---|---|---|---|"]
    lines += [f"| `{p.name}` | {p.value:g} | {_range(p)} | {p.unit} | {p.reason} |" for p in _ROWS]
    return "\n".join(lines)


def _range(p: Param) -> str:
    return f"{p.low:g} .. {p.high:g}" if p.varies else "fixed"


def parameter_lines() -> list[str]:
    """One line per parameter, ``name nominal range unit`` (what ``ankle sim params`` lists)."""
    width = max(len(p.name) for p in _ROWS)
    return [f"{p.name:<{width}}  {p.value:<10g}  {_range(p):<22}  {p.unit}" for p in _ROWS]


class PlantParams(NamedTuple):
    """Parameters in SI units as the compiled plant step reads them."""

    p_supply: float
    p_atm: float
    supply_volume: float  # m3, the supply side behind the regulator
    supply_line_fraction: float  # supply line's ISO 6358 C / a valve's C
    supply_droop_tau: float  # s, a SUPPLY_DROOP fault's sag
    regulator_droop: float  # Pa of output lost per kg/s delivered
    regulator_decay: float  # exp(-tick / regulator response): its output's step per tick
    droop_decay: float  # exp(-tick / supply droop time constant)
    temperature: float
    gas_r: float
    alpha_in: float
    alpha_out: float
    alpha_work: float
    conductance: float  # m3/(s Pa), ISO 6358 C
    critical_ratio: float
    laminar_ratio: float
    rho_anr: float  # kg/m3, density at ISO 8778 reference conditions
    t_anr: float
    valve_open_delay: NDArray[np.float64]  # (24,) s, each valve's own
    valve_close_delay: NDArray[np.float64]  # (24,) s
    valve_jitter: float  # s rms per switching
    valve_travel: float
    valve_scale: NDArray[np.float64]  # (24,) each valve's C over the type's
    seat_leak: float  # kg/(s Pa2): laminar leak of a closed valve, k (p1^2 - p2^2)
    piston_leak: float  # kg/(s Pa2): across each piston, cap to rod side
    tube_steps: int  # transport delay of the tubes in substeps
    area_cap: float
    area_annulus: float
    dead_volume: float
    stroke: float
    min_length: float
    leg_mass: float
    f_coulomb: float
    f_static: float
    v_stribeck: float
    f_viscous: float
    bristle_k: float
    bristle_c: float
    stop_k: float
    stop_c: float
    body_mass: float
    body_com: NDArray[np.float64]  # (3,) task frame
    body_inertia: NDArray[np.float64]  # (3,3) about the task origin, task frame
    foot_mass: float
    foot_com: NDArray[np.float64]
    foot_inertia: NDArray[np.float64]  # (3,3) about the foot centre of mass
    patient_k: NDArray[np.float64]  # (6,)
    patient_b: NDArray[np.float64]  # (6,)
    shank_preload: float
    rest_pose: NDArray[np.float64]  # (6,)
    base: NDArray[np.float64]  # (6,3)
    plat: NDArray[np.float64]  # (6,3)
    sensor_origin: NDArray[np.float64]  # (3,) task frame
    sensor_at_valves: bool  # chamber transducers at the valve end of the tubes
    sensor_delay: NDArray[np.float64]  # (25,) s, per channel of device.signals
    sensor_tau: NDArray[np.float64]  # (25,) s, first-order filter per channel
    sensor_offset: NDArray[np.float64]  # (25,) SI, zero error per channel
    sensor_gain: NDArray[np.float64]  # (25,) span per channel (1: exact)
    pressure_lsb: float
    pressure_top: float  # Pa, the ADC's top code: what a shorted transducer reads
    pressure_noise: float
    leg_lsb: float
    leg_low: float  # m, lowest and highest reading of a leg sensor
    leg_high: float
    leg_noise: float
    force_lsb: float
    force_noise: float
    torque_lsb: float
    torque_noise: float
    ft_range: NDArray[np.float64]  # (6,) full scale of Fx Fy Fz Tx Ty Tz (faults only)
    gravity: float
    dt: float  # one tick (s)
    substeps: int


TICK_HZ = 7000
"""Interrupt rate of the controller (paper, section 3: 4 ms / 28)."""


HARDWARE_KINDS = ("sim", "board")
"""What the controller reads and drives (``open_hardware``): this simulation or the real I/O
board. Named here, in a module without compiled code, so command lines load fast."""

PATIENTS = ("relaxed", "resisting", "absent")
"""The simulated patient: a relaxed foot, one that co-contracts, or no foot at all."""


@dataclass(frozen=True)
class PlantConfig:
    """What a user may vary per experiment; physics comes from the table."""

    geometry: Geometry = DEFAULT_GEOMETRY
    substeps: int = 2
    """Integration substeps per tick (1/7000 s). Two agree with eight to within the sensor
    resolution (tests/device/test_plant.py); that is the cheapest honest setting."""
    patient: str = "relaxed"
    """``relaxed``, ``resisting`` (co-contraction: stiffer ankle) or ``absent`` (no foot)."""
    overrides: tuple[tuple[str, float], ...] = ()
    """Parameter table entries to replace, e.g. ``(("friction_coulomb", 8.0),)``."""
    unit: int = 0
    """Which unit of the build: the seed of everything drawn per channel (each valve's
    delays and conductance, each sensor's offset and span error). Unit 0 is the nominal
    unit; another number is another device built to the same table."""

    def with_overrides(self, **values: float) -> PlantConfig:
        return replace(self, overrides=(*self.overrides, *values.items()))

    def changed(self, changes: tuple[tuple[str, float], ...]) -> PlantConfig:
        """This plant with ``changes`` on top: parameter ``(name, value)`` pairs, and
        ``("unit", n)`` for another unit of the build."""
        out = self
        for name, value in changes:
            if name == "unit":
                if value != int(value) or value < 0:
                    raise ValueError(f"unit must be a whole number >= 0, not {value:g}")
                out = replace(out, unit=int(value))
            else:
                check_override(name, value)
                out = replace(out, overrides=(*out.overrides, (name, float(value))))
        return out

    def describe(self) -> str:
        """The changes from the nominal plant, e.g. ``unit 3, friction_coulomb=4.2``."""
        parts = [f"unit {self.unit}"] if self.unit else []
        parts += [f"{k}={v:.4g}" for k, v in self.overrides]
        return ", ".join(parts) or "nominal"


TUBE_RING = 128
"""Substeps of valve flow a tube can hold in flight (device.plant.model): 9 ms at the
default two substeps, enough for 3 m of tube."""
SENSOR_RING = 8
"""Past readings kept for the sensors' latency (one per read, 1 ms apart): 7 ms of delay."""
SENSOR_DELAY_MAX = 5.0e-3
"""Largest sensor latency the plant accepts (s)."""


def draw_plant(seed: int, patient: str = "relaxed", base: PlantConfig | None = None) -> PlantConfig:
    """One plausible build: every parameter with a range drawn uniformly from it, and the
    per-channel spreads drawn for unit ``seed``. The same seed gives the same plant."""
    rng = np.random.default_rng(np.random.SeedSequence([0x414E4B4C, seed]))
    overrides = tuple(
        (p.name, float(rng.uniform(p.low, p.high)))
        for p in _ROWS
        if p.low is not None and p.high is not None
    )
    start = base if base is not None else PlantConfig(patient=patient)
    return replace(start, overrides=(*start.overrides, *overrides), unit=seed)


def check_override(name: str, value: float) -> None:
    """Refuse a value no build could have (ValueError): not finite, or negative where the
    parameter cannot be. ``name`` ``unit`` is a whole unit number."""
    if name == "unit":
        if not (math.isfinite(value) and value >= 0 and value == int(value)):
            raise ValueError(f"unit must be a whole number >= 0, not {value!r}")
        return
    if name not in PARAMETERS:
        raise ValueError(f"unknown plant parameter {name!r}")
    p = PARAMETERS[name]
    if not math.isfinite(value):
        raise ValueError(f"plant parameter {name} must be a finite number, not {value!r}")
    if value < 0.0 and not (p.low is not None and p.low < 0.0):
        raise ValueError(f"plant parameter {name} cannot be negative ({value:g} {p.unit})")


def _value(config: PlantConfig, name: str) -> float:
    for k, v in reversed(config.overrides):
        if k == name:
            return float(v)
    return PARAMETERS[name].value


def build_params(config: PlantConfig = PlantConfig()) -> PlantParams:
    """Turn the table (and a config's overrides) into :class:`PlantParams`."""
    unknown = [k for k, _ in config.overrides if k not in PARAMETERS]
    if unknown:
        raise ValueError(f"unknown plant parameter(s): {', '.join(unknown)}")
    if config.patient not in PATIENTS:
        raise ValueError(f"patient must be relaxed, resisting or absent, not {config.patient!r}")
    if not 1 <= config.substeps <= 64:
        raise ValueError("substeps must be 1..64")
    for name, value in config.overrides:
        check_override(name, value)

    def v(name: str) -> float:
        return _value(config, name)

    def positive(*names: str) -> None:
        for name in names:
            if v(name) <= 0.0:
                raise ValueError(f"plant parameter {name} must be above zero")

    positive(
        "supply_pressure", "valve_conductance", "valve_travel", "tube_bore", "bore",
        "leg_mass", "platform_mass", "pressure_bandwidth", "leg_bandwidth", "ft_bandwidth",
        "regulator_response", "speed_of_sound", "supply_volume", "supply_line_conductance",
    )  # fmt: skip
    if v("rod") >= v("bore"):
        raise ValueError("plant parameter rod must be thinner than the bore")
    for name in ("pressure_delay", "leg_delay", "ft_delay"):
        if v(name) > SENSOR_DELAY_MAX:
            raise ValueError(f"plant parameter {name} above {SENSOR_DELAY_MAX * 1e3:g} ms")
    dt_sub = 1.0 / TICK_HZ / config.substeps
    tube_steps = round(v("tube_length") / v("speed_of_sound") / dt_sub)
    if tube_steps >= TUBE_RING:
        raise ValueError(f"plant parameter tube_length too long (at most {TUBE_RING - 1} substeps)")
    unit = np.random.default_rng(np.random.SeedSequence([0x554E4954, config.unit]))

    def spread(fraction: float, n: int) -> NDArray[np.float64]:
        values: NDArray[np.float64] = 1.0 + fraction * unit.uniform(-1.0, 1.0, n)
        return values

    g = config.geometry
    bore, rod = v("bore"), v("rod")
    area_cap = math.pi * bore**2 / 4.0
    area_annulus = area_cap - math.pi * rod**2 / 4.0

    # Platform and foot as one rigid body about the task origin (the ankle centre).
    m_p = v("platform_mass")
    c_p = np.array(
        [v("platform_com_forward"), v("platform_com_left"), -v("platform_com_below_ankle")]
    )
    k_p = v("platform_radius_of_gyration")
    I_p = m_p * np.diag([k_p**2, k_p**2, 2.0 * k_p**2])
    absent = config.patient == "absent"
    m_f = 0.0 if absent else v("foot_mass")
    c_f = np.array([v("foot_com_forward"), 0.0, -v("foot_com_below")])
    I_f: NDArray[np.float64] = np.diag(
        [v("foot_inertia_roll"), v("foot_inertia_pitch"), v("foot_inertia_yaw")]
    )
    if absent:
        I_f = np.zeros((3, 3))

    def about_origin(
        m: float, c: NDArray[np.float64], I: NDArray[np.float64]
    ) -> NDArray[np.float64]:
        return I + m * (float(c @ c) * np.eye(3) - np.outer(c, c))  # parallel axis theorem

    body_mass = m_p + m_f
    body_com = (m_p * c_p + m_f * c_f) / body_mass
    body_inertia = about_origin(m_p, c_p, I_p) + about_origin(m_f, c_f, I_f)

    factor = v("resist_factor") if config.patient == "resisting" else 1.0
    kt, bt = v("patient_translation_stiffness"), v("patient_translation_damping")
    patient_k: NDArray[np.float64] = np.array(
        [
            kt,
            kt,
            kt,
            factor * v("ankle_stiffness_roll"),
            factor * v("ankle_stiffness_pitch"),
            factor * v("ankle_stiffness_yaw"),
        ]
    )
    patient_b: NDArray[np.float64] = np.array([bt, bt, bt] + [factor * v("ankle_damping")] * 3)
    if absent:
        patient_k[:] = 0.0
        patient_b[:] = 0.0

    p_atm, t = v("atmosphere"), v("temperature")
    rho_anr = 1.185  # kg/m3 at ISO 8778 reference conditions (20 C, 1 bar, 65 % humidity)
    p_ref = v("supply_pressure")

    def laminar(nl_per_min: float) -> float:  # NL/min from the supply to atmosphere -> k
        return nl_per_min * 1e-3 / 60.0 * rho_anr / (p_ref**2 - p_atm**2)

    # Per channel, in this order, so a unit's draws do not depend on which are used.
    open_delay = v("valve_open_delay") * spread(v("valve_delay_spread"), 24)
    close_delay = v("valve_close_delay") * spread(v("valve_delay_spread"), 24)
    valve_scale = spread(v("valve_conductance_spread"), 24)
    p_off = v("pressure_offset") * unit.uniform(-1.0, 1.0, 13)
    p_gain = spread(v("pressure_gain_error"), 13)
    l_off = v("leg_offset") * unit.uniform(-1.0, 1.0, 6)
    l_gain = spread(v("leg_gain_error"), 6)
    f_off = np.concatenate(
        [
            v("ft_force_offset") * unit.uniform(-1.0, 1.0, 3),
            v("ft_torque_offset") * unit.uniform(-1.0, 1.0, 3),
        ]
    )
    f_gain = spread(v("ft_gain_error"), 6)
    groups = (13, 6, 6)  # pressures (12 chambers, supply), legs, force/torque

    def per_group(a: float, b: float, c: float) -> NDArray[np.float64]:
        return np.concatenate([np.full(n, x) for n, x in zip(groups, (a, b, c), strict=True)])

    bandwidths = per_group(v("pressure_bandwidth"), v("leg_bandwidth"), v("ft_bandwidth"))
    tube_volume = math.pi * v("tube_bore") ** 2 / 4.0 * v("tube_length")
    return PlantParams(
        p_supply=v("supply_pressure"),
        p_atm=p_atm,
        supply_volume=v("supply_volume"),
        supply_line_fraction=v("supply_line_conductance") / v("valve_conductance"),
        supply_droop_tau=v("supply_droop_time_constant"),
        # bar per 100 NL/min -> Pa per kg/s
        regulator_droop=v("regulator_droop") * 1e5 / (100.0e-3 / 60.0 * rho_anr),
        regulator_decay=math.exp(-1.0 / TICK_HZ / v("regulator_response")),
        droop_decay=math.exp(-1.0 / TICK_HZ / v("supply_droop_time_constant")),
        temperature=t,
        gas_r=v("gas_constant"),
        alpha_in=v("alpha_in"),
        alpha_out=v("alpha_out"),
        alpha_work=v("alpha_work"),
        conductance=v("valve_conductance") * 1e-3 / 1e5,
        critical_ratio=v("valve_critical_ratio"),
        laminar_ratio=v("valve_laminar_ratio"),
        rho_anr=rho_anr,
        t_anr=293.15,
        valve_open_delay=open_delay,
        valve_close_delay=close_delay,
        valve_jitter=v("valve_jitter"),
        valve_travel=v("valve_travel"),
        valve_scale=valve_scale,
        seat_leak=laminar(v("valve_seat_leak")),
        piston_leak=laminar(v("piston_leak")),
        tube_steps=tube_steps,
        area_cap=area_cap,
        area_annulus=area_annulus,
        dead_volume=v("port_volume") + tube_volume,
        stroke=g.stroke,
        min_length=g.min_length,
        leg_mass=v("leg_mass"),
        f_coulomb=v("friction_coulomb"),
        f_static=v("friction_coulomb") * max(1.0, v("friction_breakaway_ratio")),
        v_stribeck=v("friction_stribeck_velocity"),
        f_viscous=v("friction_viscous"),
        bristle_k=v("bristle_stiffness"),
        bristle_c=v("bristle_damping"),
        stop_k=v("end_stop_stiffness"),
        stop_c=v("end_stop_damping"),
        body_mass=body_mass,
        body_com=body_com,
        body_inertia=body_inertia,
        foot_mass=m_f,
        foot_com=c_f,
        foot_inertia=I_f,
        patient_k=patient_k,
        patient_b=patient_b,
        shank_preload=0.0 if absent else v("shank_preload"),
        rest_pose=g.home_pose.copy(),
        base=np.ascontiguousarray(g.base_joints),
        plat=np.ascontiguousarray(g.platform_joints),
        sensor_origin=np.array([0.0, 0.0, -v("sensor_below_ankle")]),
        sensor_at_valves=v("pressure_sensors_at_valves") >= 0.5,
        sensor_delay=per_group(v("pressure_delay"), v("leg_delay"), v("ft_delay")),
        sensor_tau=1.0 / (2.0 * math.pi * bandwidths),
        sensor_offset=np.concatenate([p_off, l_off, f_off]),
        sensor_gain=np.concatenate([p_gain, l_gain, f_gain]),
        pressure_lsb=v("pressure_range") / 4096.0,
        pressure_top=v("pressure_range") / 4096.0 * 4095.0,
        pressure_noise=v("pressure_noise"),
        leg_lsb=g.stroke / 2.0 ** v("leg_sensor_bits"),
        leg_low=-v("leg_sensor_margin"),
        leg_high=g.stroke + v("leg_sensor_margin"),
        leg_noise=v("leg_noise"),
        force_lsb=v("force_resolution"),
        force_noise=v("force_noise"),
        torque_lsb=v("torque_resolution"),
        torque_noise=v("torque_noise"),
        ft_range=np.array(
            [v("force_range_xy")] * 2 + [v("force_range_z")] + [v("torque_range")] * 3
        ),
        gravity=v("gravity"),
        dt=1.0 / TICK_HZ,
        substeps=config.substeps,
    )


def nominal_dead_volume() -> float:
    """Chamber volume at the end of its stroke as designed (m3): port and tube."""
    p = PARAMETERS
    tube = math.pi * p["tube_bore"].value ** 2 / 4.0 * p["tube_length"].value
    return p["port_volume"].value + tube


def param_names() -> list[str]:
    """Names accepted in :attr:`PlantConfig.overrides`."""
    return list(PARAMETERS)
