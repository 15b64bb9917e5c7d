"""Start-up identification: what the controller may not assume about this unit.

A device built to the drawing still differs from it: each leg sensor's zero moves with its
mounting, each pressure transducer's zero is off by a fraction of a percent of its range,
and the force sensor's zero drifts between uses. The controller's model cannot know these;
the unit can measure them, with nobody on the plate, before it is armed:

1. **Down to the stops.** Each leg's rod side fills and its cap side vents, in short pulses
   first (the controller's release pattern, so the platform comes down slowly and level),
   then fully: every piston is pulled onto its lower end stop, where its displacement is
   zero. Gravity alone is not enough: on a build with stiff seals the legs' breakaway
   friction together exceeds the platform's weight, and a platform left to sink stops
   tilted and twisted with some legs in mid-stroke.
2. **Vent.** Every exhaust opens, every intake stays shut: the chambers fall to the
   atmosphere, and the end stops' bumpers relax until friction holds them (microns).
3. **Read at rest.** The average of :data:`READS` readings of every channel: each leg
   sensor's reading at its end stop is its zero; each chamber transducer's reading less
   the atmosphere is its zero; the force sensor's reading with nothing on the plate is
   its zero.

The result is a :class:`~device.calibration.Calibration`: saved as JSON, loaded by the device
(``ankle device --calibration FILE``), applied by the controller to every reading
(``ControllerConfig.calibration``) and reported in ``DeviceHello``. It runs through the
:class:`~device.hardware.Hardware` interface only (sensors in, valves out), so it is the
same routine on the simulation and on an I/O board.

4. **Pulse every valve** (:func:`identify_valves`): how much air each valve passes per
   pulse, against the air observer's model, so that the observer (device.supervision)
   judges a held chamber against this build's valves rather than the type's range; and
   what each chamber loses between the pulses with every valve shut (a leak,
   :func:`check_leaks`).

5. **Heave slowly** (:func:`identify_friction`): the controller, with the zeros just
   found, moves every leg up and down its mid-stroke at two slow, steady speeds. A leg's
   chambers push with the load plus its seals' friction going up and the load less it
   going down, so the difference is twice the friction: what the position loop feeds
   forward along the leg's moving target (``ControllerConfig.friction_compensation``).
   The faster passes sway a little as they go, which weighs what the legs move
   (:func:`moving_mass`): the position loop's derivative gain grows with it
   (``ControllerConfig.moving_mass_reference``). What each leg pushes beyond the load the
   controller figures, friction fitted out, is its load bias (:func:`load_bias`): the
   plate's true weight against the model's and the transducers' spans at the working
   pressures, which the force checks take out of the legs' residual.

6. **Listen to the transducers** (:func:`pressure_still_reads`), the chambers vented
   again: how often each reading changes code with its noise says how long a live one's
   reading may stand still; the force sensor's six channels too, the plate empty.

What it does not identify (yet): the platform's centre of mass (the outer loop's integral
takes up its static part), the sensors' span errors one by one (only what they leave in
each leg's force at mid-stroke).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace
from datetime import UTC, datetime

import numpy as np
from numpy.typing import NDArray

from device import pwm, signals, supervision
from device.calibration import (
    FT_CHANNELS,
    LEG_ZERO_MAX,
    PRESSURE_ZERO_MAX,
    STILL_READS_RANGE,
    Calibration,
    IdentificationError,
)
from device.controller import CONTROL_PERIOD, ControllerConfig, Mode, build_params
from device.geometry import DEFAULT_GEOMETRY, Geometry
from device.hardware import Hardware, SimulatedHardware
from device.kinematics import Kinematics
from device.plant.params import TICK_HZ, PlantConfig
from device.rig import Rig
from device.signals import chamber
from device.trips import Trip, event_text

READS = 200
"""Readings averaged at rest (0.2 s at 1 kHz): the noise of the mean is 1/14 of one
reading's (5 um on a leg, 7 Pa on a chamber)."""
NOISE_READS = 1000
"""Readings at rest (1 s), every chamber vented again at the end, counted code by code for
each transducer's noise (:func:`pressure_still_reads`): from 200 a transducer of 100 Pa read
75-117 Pa, from 1,000 96-105 Pa."""
SENSOR_PERIOD_TICKS = 7
READ_HZ = TICK_HZ / SENSOR_PERIOD_TICKS
DOWN_PULSE_S = 2.5
"""Pull down in pulses first: each rod-side intake and cap-side exhaust open in the
controller's release pattern (``ControllerConfig.vent_pulse_slots`` of 28 slots, once every
``vent_every_periods`` PWM periods): the legs come down slowly."""
DOWN_OPEN_S = 0.5
"""Then fully open: every piston pressed onto its stop."""
VENT_OPEN_S = 1.0
"""Then every exhaust open: the chambers reach the atmosphere."""
SETTLED_SPEED = 2.0e-3
"""The legs count as resting on their stops when none moved faster than this (m/s) over
the last 0.1 s of the vent; otherwise the identification fails."""
NOISY_STEP = 0.1e-3
"""A leg sensor whose steps from read to read scatter by more than this (m, their standard
deviation) over the last 0.1 s of the vent is noisy: a healthy one (5-15 um of noise on
24 um counts) steps by one count at most, and a leg that moves steps evenly."""
FILLED_READS = 20
"""Reads at the end of the open pull-down (the rod sides open to the supply for
``DOWN_OPEN_S``) over which the supply transducer is judged against them."""
SUPPLY_GAP_MAX = 0.3e5
"""The supply transducer may read this far (Pa) from the rod sides, the median of six, once
their intakes have stood open to it for ``DOWN_OPEN_S``. Over the nominal unit and drawn
builds 0-99 the median stood -0.18 to +0.20 bar from it, a single rod side -0.23 to +0.24
(the supply transducer's zero, up to 0.1 bar, is never vented; both transducers' span
errors, up to 2 % of 7 bar; what still flows). Beyond, the supply transducer is off: the
supply's low and loss marks and the valves' flow model would be judged on a wrong
pressure. The limit a chamber's zero has (``device.calibration.PRESSURE_ZERO_MAX``)."""


def identify(
    hardware: Hardware,
    atmosphere: float = 1.01325e5,
    progress: Callable[[str], None] | None = None,
) -> Calibration:
    """Vent the unit and read its zeros (see the module docstring). Nobody may stand on
    the plate: the platform sinks to its stops. Leaves every valve closed."""
    sensors = np.zeros(signals.N_SENSORS)
    history: list[NDArray[np.float64]] = []
    tick = 0

    def step(pattern: NDArray[np.uint8]) -> None:
        nonlocal tick
        if tick % SENSOR_PERIOD_TICKS == 0:
            hardware.read_sensors(sensors)
            history.append(sensors.copy())
        hardware.write_valves(pattern)
        hardware.wait_tick()
        tick += 1

    if progress:
        progress("identification: legs down to their end stops")
    filled: list[int] = []
    try:
        valves = _down_and_vent(step, lambda: filled.append(len(history)))
        down = np.array(history)
        check_settled(down[-101:, signals.SENSOR_LEG : signals.SENSOR_LEG + 6])
        if progress:
            progress("identification: reading the zeros")
        history.clear()
        while len(history) < READS:
            step(valves)
    finally:
        hardware.write_valves(np.zeros(signals.N_VALVES, dtype=np.uint8))
    mean = np.mean(np.array(history), axis=0)
    pressure_zero = mean[:12] - atmosphere
    check_came_down(down, mean, atmosphere)
    check_supply(down[filled[0] - FILLED_READS : filled[0]], pressure_zero)
    if progress:
        progress("identification: test pulses through every valve")
    gains, extras, dead, shut, opens, lost = identify_valves(hardware, pressure_zero, atmosphere)
    check_leaks(lost)
    cal = Calibration(
        leg_zero=tuple(float(v) for v in mean[signals.SENSOR_LEG : signals.SENSOR_LEG + 6]),
        pressure_zero=tuple(float(v) for v in pressure_zero),
        ft_zero=tuple(float(v) for v in mean[signals.SENSOR_FORCE : signals.SENSOR_FORCE + 6]),
        identified_at=datetime.now(UTC).isoformat(timespec="seconds"),
    )
    cal.check()  # zeros no healthy unit has: refused, the unit needs looking at
    identified = replace(
        cal,
        valve_gain=gains,
        valve_extra=extras,
        dead_volume=dead,
        pulse_shut=shut,
        pulse_opens=opens,
    )
    try:
        identified.check_valves()
    except IdentificationError as exc:
        # The pulse test is an estimate (its flow falls during a pulse): figures outside a
        # healthy valve's range are not used, and the air observer keeps the whole type's
        # tolerance, rather than a healthy unit being refused or judged on a wrong figure.
        identified = replace(cal, notes=(f"valve identification not used: {exc}",))
    if progress:
        progress("identification: a slow heave up and down for the legs' friction")
    friction, mass, bias = identify_friction(hardware, identified, atmosphere)
    with_friction = replace(identified, leg_friction=friction, moving_mass=mass, load_bias=bias)
    with_friction.check_friction()  # a leg no healthy unit has: refused, look at it
    with_friction.check_mass()
    with_friction.check_load_bias()
    if progress:
        progress("identification: the transducers' noise, vented")
    history.clear()
    try:
        while len(history) < NOISE_READS:
            step(valves)  # every exhaust open: the chambers stay at the atmosphere
    finally:
        hardware.write_valves(np.zeros(signals.N_VALVES, dtype=np.uint8))
    rest = np.array(history)
    check_live_channels(rest[:, signals.SENSOR_FORCE : signals.SENSOR_FORCE + 6])
    still = pressure_still_reads(rest[:, :13])
    force = pressure_still_reads(rest[:, signals.SENSOR_FORCE : signals.SENSOR_FORCE + 3])
    torque = pressure_still_reads(rest[:, signals.SENSOR_TORQUE : signals.SENSOR_TORQUE + 3])
    return replace(with_friction, pressure_still_reads=still, ft_still_reads=force + torque)


# -- how long a live transducer's reading may stand still (the last reads at rest) --------

STILL_RISK = 1e-12
"""The chance, at the worst place within a count, that a healthy transducer's noise leaves
its reading the same for as many reads in a row as the rule waits, at the noise assumed
(:data:`STILL_NOISE_SHARE`): once in a million million stretches. A live 100 Pa reading
starts a few hundred stretches a second, so with thirteen channels that is about once in
ten years of running without a stop; at the noise measured, far rarer (3e-18 at 100 Pa)."""
STILL_NOISE_SHARE = 0.85
"""The noise the rule assumes, as a share of what the reads at rest showed
(:data:`NOISE_READS` quantised reads estimate it to within about 5 %): assumed quieter, it
waits longer."""


def identify_simulated(config: PlantConfig) -> Calibration:
    """The calibration a simulated unit's maintenance made: :func:`identify` on a twin of
    its plant with nobody on the plate, as a technician identifies a real unit before its
    first patient. The zeros, valves and seals are the unit's, the same on the twin; its
    patient and faults are not (a fault comes after the calibration). Seeds the plant's
    random generator: open the unit's own simulation after this, not before."""
    twin = SimulatedHardware(replace(config, patient="absent"), seed=0)
    try:
        return identify(twin)
    finally:
        twin.close()


def count_size(readings: NDArray[np.float64]) -> float:
    """The transducers' count (the smallest step between two different readings of any
    channel, columns of ``readings``); 0 if no channel's reading changed."""
    steps = [np.diff(np.unique(readings[:, c])) for c in range(readings.shape[1])]
    found = np.concatenate(steps) if steps else np.zeros(0)
    found = found[found > 0.0]
    return float(found.min()) if found.size else 0.0


def flicker_noise(codes: NDArray[np.int64]) -> float:
    """The rms noise (counts) of a steady reading quantised to ``codes``: the most likely
    Gaussian noise and place within a count to give how often each code came; 0 if only
    one code came (too quiet to tell)."""
    values, counts = np.unique(codes - int(np.median(codes)), return_counts=True)
    if len(values) < 2:
        return 0.0
    place, noise = np.meshgrid(np.linspace(-0.5, 0.5, 21), np.geomspace(0.05, 4.0, 160))
    erf = np.vectorize(math.erf)
    likelihood = np.zeros_like(place)
    for value, count in zip(values, counts, strict=True):
        top = erf((value + 0.5 - place) / (noise * math.sqrt(2.0)))
        bottom = erf((value - 0.5 - place) / (noise * math.sqrt(2.0)))
        likelihood += count * np.log(np.maximum(0.5 * (top - bottom), 1e-300))
    best = np.unravel_index(int(np.argmax(likelihood)), likelihood.shape)
    return float(noise[best])


def still_reads(noise: float) -> int:
    """How many reads in a row a reading with ``noise`` (rms, counts) may stay the same with
    the chance :data:`STILL_RISK`, taking it :data:`STILL_NOISE_SHARE` as loud, at the middle
    of a count (where it stays longest); 0 if that is beyond
    ``calibration.STILL_READS_RANGE`` (too quiet to tell a frozen transducer by)."""
    low, high = STILL_READS_RANGE
    if noise <= 0.0:
        return 0
    stay = math.erf(0.5 / (STILL_NOISE_SHARE * noise * math.sqrt(2.0)))
    if stay >= 1.0:
        return 0
    reads = max(low, math.ceil(math.log(STILL_RISK) / math.log(stay)))
    return reads if reads <= high else 0


def check_live_channels(readings: NDArray[np.float64]) -> None:
    """Refuse a force/torque channel that read exactly 0 at every one of ``readings`` (reads
    x 6, at rest, the plate empty): a live one's zero is off by some counts and its noise
    flickers it (about a count), so a channel of only zeros is dead alone (its wire or
    amplifier), which the whole sensor's dead rule (all six zero) does not see, and whose
    flicker the identification cannot count (``ft_still_reads`` would not judge it)."""
    for k in range(readings.shape[1]):
        if not np.any(readings[:, k]):
            raise IdentificationError(
                f"force/torque channel {FT_CHANNELS[k]} read exactly 0 through the "
                f"{len(readings)} reads at rest, where a live one shows its zero and its "
                "noise: check that channel's cable and amplifier"
            )


def pressure_still_reads(readings: NDArray[np.float64]) -> tuple[int, ...]:
    """Per pressure channel (columns of ``readings``, each steady: vented chambers, the
    supply with every intake shut), :func:`still_reads` of the noise its reading showed.
    Likewise for channels of one count size, each steady: the force sensor's three force
    channels, its three torque channels, with nobody on the plate."""
    count = count_size(readings)
    if count <= 0.0:
        return (0,) * int(readings.shape[1])
    out: list[int] = []
    for c in range(readings.shape[1]):
        codes = np.round(readings[:, c] / count).astype(np.int64)
        out.append(still_reads(flicker_noise(codes)))
    return tuple(out)


# -- each valve's air per pulse (start-up, after the zeros) ------------------------------

PULSE_TICKS = (12, 24)
"""Test pulse lengths (ticks of 1/7 ms): 1.7 and 3.4 ms, both longer than the slowest
valve a build may have takes to open fully (1.21 ms of delay and 0.3 ms of travel)."""
PULSE_CYCLES = 6
"""Intake-then-exhaust cycles per pulse length and chamber."""
SWEEP_TICKS = tuple(range(3, 12))
"""Shorter test pulses (0.43-1.57 ms), past the fastest valve's opening delay (0.47 ms) and
the slowest's with three times the largest jitter (1.21 + 0.3 ms): which of them opens each
valve (``Calibration.pulse_shut``, ``pulse_opens``). A valve either stays shut or opens for
at least its closing delay (0.5-1.2 ms), so each pulse's answer is plain."""
SWEEP_CYCLES = 3
"""Cycles per short pulse length: the jitter decides near the opening delay, and three tries
at each length show the band where it does."""
OPENED = 0.15e-3
"""A test pulse whose air took at least this long at the model's flow (s) opened its valve:
an opened valve passes its closing delay's worth less half its travel (at least 0.35 ms), a
shut one only its seat's leak (microseconds' worth)."""
PULSE_WAIT_READS = 15
"""Reads (1 ms) after each pulse before its air is read: the valve has closed (at most
1.5 ms after its coil) and the air in the tube has settled."""
DRIFT_READS = 20
"""Reads (1 ms) with every valve shut before each cycle's pulses, through which a straight
line gives each chamber's drift and where it stands (the noise of that figure 22 ms later:
about 0.02 ms of a pulse's air in a rod side, the largest chamber)."""
PULSE_READS = 5
"""Readings averaged before and after each pulse (the noise of the mean: 0.1 % of a pulse)."""
FILL_INDEX = 1.4
DISCHARGE_INDEX = 1.0
"""Polytropic indices of a fast fill (adiabatic) and of a discharge (nearly isothermal),
Richer and Hurmuzlu 2000: what separates a chamber's volume from its valves' flow."""
BASE_BAND = 0.1e5
"""Each cycle starts within this (Pa) of its base pressure..."""
BASE_TICKS_MAX = 3500
"""...reached by opening the intake or the exhaust for at most this many ticks (0.5 s)."""
HOLD_READS = 300
"""Reads (1 ms) the rod sides fill before the cap sides are pulsed: they reach the supply."""
PULSE_BASE = (3.0e5, 3.5e5)
"""Absolute pressure (Pa) each cap (rod) chamber is brought to before its pulses: an
exhaust from there chokes (the atmosphere is below b = 0.3 of it), an intake from a 7 bar
supply passes at least 90 % of choked flow, and a cap side pulsed from 3 bar lifts its leg
less than the rod side, held at the supply, presses it down."""


Figures = tuple[float, ...]

OPEN_TIME_POINTS = 17
"""Pressures at which :func:`open_time` samples the model's flow across a pulse."""


def open_time(
    before: float,
    after: float,
    volume: float,
    supply: float,
    intake: bool,
    q: supervision.SupervisionParams,
) -> float:
    """The time (s) a valve at the air observer's ISO 6358 flow would have been open to take
    a chamber of ``volume`` (m3) from ``before`` to ``after`` (Pa abs; ``supply`` Pa abs for
    an intake, else an exhaust to the atmosphere): the air each pressure step took (``V dp``
    over the polytropic index) divided by the flow at that pressure, summed over the pulse.
    A pulse into a small chamber moves its pressure far (a cap side at its stop, 3 to 4.5
    bar in 3.4 ms), and the flow falls as it does: figured at the pulse's mean pressure,
    that fall was read as the valve's own, a longer pulse passing less than its share.
    Signed: negative when the chamber moved against the valve."""
    pressures = np.linspace(before, after, OPEN_TIME_POINTS)
    if intake:
        flows = np.array([supervision.valve_flow(supply, p, q) for p in pressures])
    else:
        flows = np.array([supervision.valve_flow(p, q.atm, q) for p in pressures])
    inverse = 1.0 / np.maximum(flows, 1e-9)
    took = float(np.trapezoid(inverse, pressures)) * volume / q.obs_k
    return took if intake else -took


def identify_valves(
    hardware: Hardware,
    pressure_zero: NDArray[np.float64],
    atmosphere: float = 1.01325e5,
    config: ControllerConfig | None = None,
    geometry: Geometry = DEFAULT_GEOMETRY,
) -> tuple[Figures, Figures, Figures, Figures, Figures, Figures]:
    """Each valve's air per pulse, with every leg on its lower end stop (the chambers'
    volumes known): test pulses of two lengths into and out of each chamber, the air each
    passed measured as the air observer measures it (change of p V over its polytropic
    index) and divided by the flow the observer's ISO 6358 model gives. A straight line
    through the pulse lengths gives each valve's gain (air it passes against the model's)
    and its extra time (s: closing delay less opening delay, what a pulse passes beyond
    its length). The gains of a chamber's two valves also give its volume (see below).
    Shorter pulses (:data:`SWEEP_TICKS`) then find where each valve starts to open
    (:func:`pulse_edges`). Returns (gains, extra times), 24 each, valve ``2c`` the intake
    of chamber ``c``, each chamber's dead volume (m3, 12), and each valve's longest pulse
    that left it shut and shortest that opened it every time (s, 24 each), and the air each
    chamber lost with every valve shut (NL/min, 12; negative: it gained, across its
    piston from the side held at the supply). Leaves every chamber vented and every valve
    closed."""
    cfg = config if config is not None else ControllerConfig()
    # The air observer's model and the cylinder's areas, as the controller builds them.
    q = supervision.build(cfg.supervision, atmosphere, CONTROL_PERIOD / TICK_HZ)
    params, _ = build_params(cfg, geometry)
    area_ann = params.area_annulus
    volume = np.empty(12)
    volume[0::2] = cfg.dead_volume
    volume[1::2] = cfg.dead_volume + area_ann * geometry.stroke
    sensors = np.zeros(signals.N_SENSORS)
    valves = np.zeros(signals.N_VALVES, dtype=np.uint8)

    def read(pattern: NDArray[np.uint8], ticks: int = SENSOR_PERIOD_TICKS) -> NDArray[np.float64]:
        for _ in range(ticks):
            hardware.write_valves(pattern)
            hardware.wait_tick()
        hardware.read_sensors(sensors)
        out = sensors.copy()
        out[:12] -= pressure_zero
        return out

    def mean(pattern: NDArray[np.uint8]) -> NDArray[np.float64]:
        average: NDArray[np.float64] = np.mean([read(pattern) for _ in range(PULSE_READS)], axis=0)
        return average

    def to_base(pattern: NDArray[np.uint8], chambers: list[int], base: float) -> None:
        """Every cycle starts from the same pressure: a small chamber's pulses would
        otherwise ratchet it towards the supply, where the flow is least like the model."""
        reading = read(pattern)
        for _ in range(BASE_TICKS_MAX):
            done = True
            for c in chambers:
                off = reading[c] - base
                pattern[2 * c] = 1 if off < -BASE_BAND else 0
                pattern[2 * c + 1] = 1 if off > BASE_BAND else 0
                done = done and abs(off) <= BASE_BAND
            if done:
                break
            reading = read(pattern, 1)
        for c in chambers:
            pattern[2 * c] = pattern[2 * c + 1] = 0
        for _ in range(PULSE_WAIT_READS):
            read(pattern)

    samples: dict[int, list[tuple[float, float]]] = {v: [] for v in range(24)}
    drifts: list[list[float]] = [[] for _ in range(12)]  # Pa a read, every valve shut
    try:
        for side in (0, 1):
            chambers = list(range(side, 12, 2))
            valves[:] = 0
            if side == 0:  # the rod sides at the supply hold each leg down
                valves[2::4] = 1
            for _ in range(HOLD_READS):
                read(valves)
            widths = list(PULSE_TICKS) * PULSE_CYCLES + list(SWEEP_TICKS) * SWEEP_CYCLES
            for width in widths:
                to_base(valves, chambers, PULSE_BASE[side])
                # The chambers drift between two reads with every valve shut: air past the
                # piston from the other side, held at the supply (a cap side at its stop holds
                # 7 cm3, and a healthy piston's 0.5 NL/min moves it by about a bar a second).
                # Measured just before the pulses and taken out of what each pulse moved: left
                # in, it read as air a shut valve passed (a cap's exhaust "opened" by a 0.4 ms
                # pulse) and shifted the extra times by 0.3-0.9 ms.
                quiet = np.array([read(valves) for _ in range(DRIFT_READS)])
                drift, before = np.polyfit(np.arange(1 - DRIFT_READS, 1), quiet, 1)  # per read
                for c in chambers:
                    drifts[c].append(float(drift[c]))
                for intake in (True, False):
                    pulse = valves.copy()
                    for c in chambers:
                        pulse[2 * c + (0 if intake else 1)] = 1
                    read(pulse, width)
                    for _ in range(PULSE_WAIT_READS):
                        read(valves)
                    after = mean(valves)
                    # From the last read before to the middle of those after.
                    elapsed = width / SENSOR_PERIOD_TICKS + PULSE_WAIT_READS + (PULSE_READS + 1) / 2
                    moved = after - drift * elapsed
                    for c in chambers:
                        samples[2 * c + (0 if intake else 1)].append(
                            (
                                width / TICK_HZ,
                                open_time(before[c], moved[c], volume[c], before[12], intake, q),
                            )
                        )
                    before = after
            valves[:] = 0
            valves[1::2] = 1
            for _ in range(int(VENT_OPEN_S * TICK_HZ / SENSOR_PERIOD_TICKS)):
                read(valves)
    finally:
        hardware.write_valves(np.zeros(signals.N_VALVES, dtype=np.uint8))
    slope, extras = np.zeros(24), np.zeros(24)
    shut, opens = np.zeros(24), np.zeros(24)
    fitted = np.array(PULSE_TICKS) / TICK_HZ
    for v in range(24):
        width, passed = np.array(samples[v]).T
        on_line = np.isin(width, fitted)
        slope[v], offset = np.polyfit(width[on_line], passed[on_line], 1)
        extras[v] = offset / slope[v]
        shut[v], opens[v] = pulse_edges(width, passed)
    # The slopes carry each chamber's true volume against the design's (its tube): what a
    # fill and a discharge of the same air do to p V differs only by their polytropic
    # indices, so a chamber's two slopes against those give its volume, and what is left
    # of each slope is the valve's own conductance. The cap side, empty at its stop, tells
    # its leg's dead volume best (a rod side's is a seventh of its volume there): both
    # sides of a leg have the same tube and port.
    with np.errstate(invalid="ignore"):  # a valve that passed nothing: NaN, refused below
        ratio = np.sqrt(slope[0::2] * slope[1::2] / (FILL_INDEX * DISCHARGE_INDEX)) * q.obs_k
    dead = np.repeat(volume[0::2] / ratio[0::2], 2)
    true_volume = dead + volume - cfg.dead_volume
    gains = slope * np.repeat(true_volume / volume, 2)
    # What each chamber lost with every valve shut, as normal litres a minute: the median
    # drift over its cycles (a big fill's first read of the air cooling is one of 39).
    held = np.where(np.isfinite(true_volume), true_volume, volume)
    lost = -np.median(np.array(drifts), axis=1) * READ_HZ * held / atmosphere * 60e3
    return (
        tuple(float(g) for g in gains),
        tuple(float(e) for e in extras),
        tuple(float(d) for d in dead),
        tuple(float(t) for t in shut),
        tuple(float(t) for t in opens),
        tuple(float(n) for n in lost),
    )


def pulse_edges(width: NDArray[np.float64], passed: NDArray[np.float64]) -> tuple[float, float]:
    """From one valve's test pulses (lengths, s; each one's open time, s): the longest
    length at and below which no pulse opened it, and the shortest from which on every one
    did (:data:`OPENED`). 0 if even the shortest opened it; twice the longest length tried
    if some pulse of that length failed (a valve that does not open: the calibration then
    refuses the valve figures, and the observer keeps the type's range)."""
    lengths = np.unique(width)
    failed = np.array([bool((passed[width == w] < OPENED).any()) for w in lengths])
    opened = np.array([bool((passed[width == w] >= OPENED).any()) for w in lengths])
    shut = 0.0
    for w, any_open in zip(lengths, opened, strict=True):
        if any_open:
            break
        shut = float(w)
    opens = float(lengths[-1])
    for w, any_failed in zip(lengths[::-1], failed[::-1], strict=True):
        if any_failed:
            break
        opens = float(w)
    if failed[-1]:
        opens = float(lengths[-1]) * 2.0
    return shut, opens


# -- each leg's seal friction (start-up, last) -------------------------------------------

FRICTION_SPEEDS = (8.0e-3, 20.0e-3)
"""Steady leg speeds of the heave (m/s): about the seals' Stribeck speed (2-10 mm/s) and
above it, near the legs' speeds when a foot turns the plate at an exercise's pace."""
FRICTION_SPAN = (0.4, 0.6)
"""Share of the stroke each leg travels between, up and down, at each speed."""
FRICTION_SKIP = 0.2
"""Share of each travel left out at either end: the legs speed up and slow down there."""
FRICTION_PASSES = 2
"""Up-and-down passes at each speed."""
SETTLE_S = 1.5
"""Time (s) the legs are given to reach the span's lower end before the heave."""


def identify_friction(
    hardware: Hardware,
    calibration: Calibration,
    atmosphere: float = 1.01325e5,
    config: ControllerConfig | None = None,
    geometry: Geometry = DEFAULT_GEOMETRY,
) -> tuple[tuple[float, ...], float, tuple[float, ...]]:
    """Each leg's seal friction (N, 6), the mass the legs move (kg) and each leg's load
    bias (N, 6; :func:`load_bias`). The controller,
    calibrated with ``calibration``, moves every leg together up and down
    :data:`FRICTION_SPAN` of the stroke at each of :data:`FRICTION_SPEEDS` (the empty
    platform heaving), and each leg's chamber force
    (cap side times its area less rod side times the annulus) is fitted by least squares as
    ``a + b x + f d``, ``d`` the direction commanded (+1 up, -1 down): the load and its slope
    with the pose, and ``f`` what the seals hold back, the mean over both speeds (the
    direction, not the measured rate: a 24 um sensor differentiated at 1 kHz is too noisy
    to split Coulomb from viscous friction at these speeds). ``f`` is floored at 0. The
    faster passes also sway, which weighs what the legs move (:func:`moving_mass`).
    Nobody may stand on the plate. Leaves every leg on its stop and every chamber vented
    (IdentificationError if the controller tripped)."""
    cfg = replace(config if config is not None else ControllerConfig(), calibration=calibration)
    rig = Rig(hardware, cfg, geometry)
    params = rig.params
    dt = params.dt_control
    low, high = (share * geometry.stroke for share in FRICTION_SPAN)
    rows: list[NDArray[np.float64]] = []
    try:
        _lift_off_stops(hardware, calibration, LIFT_TO * geometry.stroke, atmosphere)
        rig.run(dt, log_hz=0)  # at rest, valves closed: the controller reads where it is
        start = rig.state.leg_x.copy()
        # Like homing: every leg at a steady speed from where it rests to the span's end.
        periods = math.ceil(float(np.max(np.abs(low - start))) / (FRICTION_SPEEDS[0] * dt))
        for k in range(1, periods + 1):
            share = k / periods
            rate = (low - start) / (periods * dt)
            rig.apply_leg_targets(start + share * (low - start), rate)
            rig.run(dt, log_hz=0)
            _check(rig)
        rig.apply_leg_targets(np.full(6, low))
        rig.run(SETTLE_S, log_hz=0)
        _check(rig)
        x = low
        passes = 0
        omega = 2.0 * math.pi * SWAY_HZ
        for speed in FRICTION_SPEEDS:
            sway = SWAY_SHARE * speed / omega if speed == FRICTION_SPEEDS[-1] else 0.0
            for _ in range(FRICTION_PASSES):
                for direction in (1.0, -1.0):
                    periods = round((high - low) / (speed * dt))
                    skip = round(FRICTION_SKIP * periods)
                    passes += 1
                    for k in range(periods):
                        x += direction * speed * dt
                        t = (k + 1) * dt
                        rig.apply_leg_targets(
                            np.full(6, x + sway * math.sin(omega * t)),
                            np.full(6, direction * speed + sway * omega * math.cos(omega * t)),
                        )
                        rig.run(dt, log_hz=0)
                        _check(rig)
                        if skip <= k < periods - skip:
                            s = rig.state
                            force = (
                                s.pressure[0::2] * params.area_cap
                                - s.pressure[1::2] * params.area_annulus
                            )
                            swaying = passes if sway else 0
                            held = s.monitor[supervision.M_LOAD_HELD : supervision.M_LOAD_HELD + 6]
                            rows.append(
                                np.concatenate((s.leg_x, force, [direction, swaying, t], held))
                            )
                    x = high if direction > 0 else low
    finally:
        rig.close_valves_now()
        lower_and_vent(hardware)
    data = np.array(rows)
    friction = [max(0.0, float(heave_fit(data, leg, data[:, 6 + leg])[2])) for leg in range(6)]
    bias = load_bias(data, 0.5 * (low + high))
    return tuple(float(f) for f in friction), moving_mass(data, geometry), bias


def load_bias(data: NDArray[np.float64], x: float) -> tuple[float, ...]:
    """Each leg's load bias (N) at displacement ``x`` (m), from the rows of
    :func:`identify_friction` (leg displacements, chamber forces, direction, pass, time, and
    the force the controller figured each leg holds): what its chambers push beyond that
    force, its seals' friction fitted out as in the friction's own fit (``a + b x + f d``,
    the bias ``a + b x``).

    The controller figures the load from its model of the platform (2.5 kg, its centre of
    mass where the drawing puts it) and the force sensor; a build's plate weighs 2.0-3.5 kg
    (up to 10 N on the six legs together), and each transducer's span, which the zeros do not
    find, is off by up to 2 % of a chamber's working pressure (about 4 N on a leg). Both
    stay with the unit: the force checks (device.supervision) take the bias out of each
    leg's residual, so that what is left is what a sensor or a leg gets wrong now."""
    out = []
    for leg in range(6):
        coef = heave_fit(data, leg, data[:, 6 + leg] - data[:, 15 + leg])
        out.append(float(coef[0] + coef[1] * x))
    return tuple(out)


def heave_fit(
    data: NDArray[np.float64], leg: int, force: NDArray[np.float64]
) -> NDArray[np.float64]:
    """``force`` (N, one per row of :func:`identify_friction`'s data) fitted by least squares
    as ``a + b x + f d`` on ``leg``'s displacement ``x`` and the direction commanded ``d``:
    ``(a, b, f)``."""
    x = data[:, leg]
    design = np.column_stack((np.ones_like(x), x, data[:, 12]))
    coef, *_ = np.linalg.lstsq(design, force, rcond=None)
    return np.asarray(coef, dtype=np.float64)


SWAY_HZ = 15.0
"""Frequency (Hz) of a small sway added to each leg's target in the heave's faster passes,
which weighs what the legs move (:func:`moving_mass`)."""
SWAY_SHARE = 0.6
"""The sway's peak speed as a share of the pass's: the legs never stop or turn within a
pass, so their seals slide one way throughout (about 8-32 mm/s at the faster speed). A sway
that turned them weighed their seals too: the breakaway at each turn comes where the
acceleration peaks; measured so (a 6-8 Hz shake about mid-stroke), the stiff-sealed builds
weighed 1-1.5 kg more than the rest."""


def moving_mass(data: NDArray[np.float64], geometry: Geometry = DEFAULT_GEOMETRY) -> float:
    """The mass (kg) the legs move in a heave of the empty platform, from the rows of
    :func:`identify_friction` (leg displacements, chamber forces, direction, pass, time):
    the legs' vertical force in phase with the sway's acceleration, per unit of it, the
    mean over the swaying passes.

    Per pass, both the heave (from the mean leg displacement) and the legs' vertical force
    are fitted by a slow quadratic plus a sine at :data:`SWAY_HZ`. The seals' friction,
    one way all pass, and their viscous part and the air's damping, in phase with the
    speed, are not in phase with the acceleration; nor are the platform's weight and what
    the transducers' spans get wrong of the large chamber pressures, both slow. (The static
    load alone is off by up to half a kilogram: a 2 % span error of a 4 bar chamber is 4 N,
    as much as a leg's share of the platform.) What is weighed is the platform and each
    piston along its leg (``platform_mass + leg_mass * sum(u_z**2)``), and 0.04-1.09 kg
    more over fifty drawn builds (median 0.25; the light ones most); the controller
    compares it with the same figure weighed on the unit its gains were tuned on
    (``ControllerConfig.moving_mass_reference``)."""
    omega = 2.0 * math.pi * SWAY_HZ
    kinematics = Kinematics(geometry)
    pose = kinematics.forward(geometry.min_length + np.mean(data[:, :6], axis=0))
    up = kinematics.jacobian(pose)[:, 2]  # each leg's unit vector, vertical part
    masses = []
    for index in sorted(set(data[:, 13].tolist()) - {0.0}):
        rows = data[data[:, 13] == index]
        t = rows[:, 14]
        basis = np.column_stack((np.ones_like(t), t, t * t, np.sin(omega * t), np.cos(omega * t)))
        vertical = rows[:, 6:12] @ up  # the legs' vertical force on the platform (N)
        heave = rows[:, :6] @ (1.0 / up) / 6.0  # (m)
        fz, *_ = np.linalg.lstsq(basis, vertical, rcond=None)
        hz, *_ = np.linalg.lstsq(basis, heave, rcond=None)
        # The acceleration is -omega^2 times the heave's sine: the force's share along it.
        amplitude2 = hz[3] ** 2 + hz[4] ** 2
        masses.append(-(fz[3] * hz[3] + fz[4] * hz[4]) / (omega**2 * amplitude2))
    return float(np.mean(masses))


LIFT_TO = 0.38
"""Each leg is lifted open loop off its lower stop to this share of its stroke before the
controller takes it: on the stops the platform is below its range of motion and within the
stroke margin (device.limits), where the controller trips."""
LIFT_TIMEOUT_S = 5.0
LIFT_ROD_PRESSURE = 2.5e5
"""Gauge pressure (Pa) each rod side is filled to before its leg is lifted."""
LIFT_SETTLE_S = 0.5
"""Time (s) the lifted platform is left with every valve closed before the controller
takes it: it bobs on its trapped air, and a controller taking a moving platform rang."""


def _lift_off_stops(
    hardware: Hardware, calibration: Calibration, lift: float, atmosphere: float
) -> None:
    """Fill each rod side to :data:`LIFT_ROD_PRESSURE` (the legs held on their stops), then
    pulse each cap-side intake in the release pattern until its leg's reading passes
    ``lift`` (m), and close every valve: each leg comes up against the air of its rod side
    and stops on its own, and the controller then takes chambers near the pressures it
    holds a leg with."""
    zero = np.array(calibration.leg_zero)
    pressure_zero = np.array(calibration.pressure_zero)
    sensors = np.zeros(signals.N_SENSORS)
    pattern = np.zeros(signals.N_VALVES, dtype=np.uint8)
    closed = np.zeros(signals.N_VALVES, dtype=np.uint8)
    filling = np.ones(6, dtype=bool)
    up = np.ones(6, dtype=bool)
    try:
        for tick in range(int(LIFT_TIMEOUT_S * TICK_HZ)):
            if tick % SENSOR_PERIOD_TICKS == 0:
                hardware.read_sensors(sensors)
                rod = sensors[1:12:2] - pressure_zero[1::2] - atmosphere
                filling &= rod < LIFT_ROD_PRESSURE
                if not filling.any():
                    legs = sensors[signals.SENSOR_LEG : signals.SENSOR_LEG + 6] - zero
                    up &= legs < lift
                if not up.any():
                    hardware.write_valves(closed)
                    for _ in range(int(LIFT_SETTLE_S * TICK_HZ)):  # it rests on its air
                        hardware.wait_tick()
                    return
            pattern[2::4] = filling  # rod intake
            pattern[0::4] = up & ~filling.any() & _release_pulse(tick)  # cap intake
            hardware.write_valves(pattern)
            hardware.wait_tick()
        if filling.any():  # the legs are lifted once every rod side is filled
            empty = [chamber(2 * i + 1) for i in range(6) if filling[i]]
            raise IdentificationError(
                f"{', '.join(empty)} did not fill to {LIFT_ROD_PRESSURE / 1e5:g} bar in "
                f"{LIFT_TIMEOUT_S:g} s: check the supply and the rod-side intakes"
            )
        stuck = [i + 1 for i in range(6) if up[i]]
        raise IdentificationError(
            f"leg(s) {stuck} did not lift {lift * 1e3:.0f} mm off the stop in "
            f"{LIFT_TIMEOUT_S:g} s: check the supply and the cap-side valves"
        )
    finally:
        hardware.write_valves(closed)


LOAD_TRIPS = frozenset(
    {
        Trip.FOLLOWING,
        Trip.WRENCH_LIMIT,
        Trip.RANGE_OF_MOTION,
        Trip.LEG_SPEED,
        Trip.STROKE_END,
        Trip.HOMING,
    }
)
"""Trips that something on the plate, or a hand holding it, can cause on a healthy unit; the
others name a part, and the identification's refusal names it alone."""


def _check(rig: Rig) -> None:
    if rig.mode == Mode.FAULT:
        text = event_text(rig.trip, rig.trip_channel, limit=1000)
        plate = "; or is something on the plate?" if rig.trip in LOAD_TRIPS else ""
        raise IdentificationError(
            f"the controller tripped while the empty platform heaved slowly: {text}{plate}"
        )


def _release_pulse(tick: int) -> bool:
    """Whether the release pattern (``ControllerConfig.vent_pulse_slots`` of each PWM
    period, once every ``vent_every_periods``) has its valves open at ``tick``."""
    slot, period = tick % pwm.PWM_SLOTS, tick // pwm.PWM_SLOTS
    every = ControllerConfig.vent_every_periods
    return slot < ControllerConfig.vent_pulse_slots and period % every == 0


def _down_and_vent(
    step: Callable[[NDArray[np.uint8]], None], filled: Callable[[], None] | None = None
) -> NDArray[np.uint8]:
    """Bring the legs down onto their stops (each cap side's exhaust and rod side's intake,
    in the release pattern first, then open), then vent every chamber, ``step`` writing one
    tick's valve pattern; ``filled`` is called when the rod sides have stood open to the
    supply for ``DOWN_OPEN_S``, before the vent. Returns the vent pattern (every exhaust
    open) it ends on."""
    closed = np.zeros(signals.N_VALVES, dtype=np.uint8)
    down = closed.copy()
    down[1::4] = 1  # each cap side's exhaust (chamber 2i: valves 4i, 4i + 1)
    down[2::4] = 1  # each rod side's intake (chamber 2i + 1: valves 4i + 2, 4i + 3)
    vent = closed.copy()
    vent[1::2] = 1
    for tick in range(int(DOWN_PULSE_S * TICK_HZ)):
        step(down if _release_pulse(tick) else closed)
    for _ in range(int(DOWN_OPEN_S * TICK_HZ)):
        step(down)
    if filled is not None:
        filled()
    for _ in range(int(VENT_OPEN_S * TICK_HZ)):
        step(vent)
    return vent


def check_settled(legs: NDArray[np.float64]) -> None:
    """Refuse a unit whose legs, over the last 0.1 s of the vent (``legs``: reads x 6, m),
    are not at rest on their stops: a sensor that steps from read to read more than
    :data:`NOISY_STEP` is named as noisy; a leg that moved on faster than
    :data:`SETTLED_SPEED`, as held or loaded."""
    steps = np.std(np.diff(legs, axis=0), axis=0)  # a steady motion steps evenly
    if np.any(steps > NOISY_STEP):
        worst = int(np.argmax(steps))
        raise IdentificationError(
            f"leg {worst + 1} sensor's reading scatters {steps[worst] * 1e3:.2f} mm from read "
            "to read with its leg at rest on the stop: a noisy sensor or a loose contact, "
            "check the sensor and its cable"
        )
    speed = np.abs(legs[-1] - legs[0]) / ((len(legs) - 1) / READ_HZ)
    if np.any(speed > SETTLED_SPEED):
        worst = int(np.argmax(speed))
        raise IdentificationError(
            f"leg {worst + 1} still moves at {speed[worst] * 1e3:.1f} mm/s after venting: "
            "is something on the plate or holding the platform?"
        )


def check_came_down(
    down: NDArray[np.float64], rest: NDArray[np.float64], atmosphere: float
) -> None:
    """Before a leg zero beyond ``LEG_ZERO_MAX`` is refused as a slipped sensor
    (``Calibration.check``), see whether the leg came down at all: ``down`` is every read of
    the pull-down and the vent, ``rest`` the mean read at rest after it. A chamber of that
    leg still holding air with its exhaust open says a valve kept it up; a reading the same
    bit for bit through the whole pull-down, a stuck sensor."""
    for leg in range(6):
        reading = rest[signals.SENSOR_LEG + leg]
        if abs(reading) <= LEG_ZERO_MAX:
            continue
        for c in (2 * leg, 2 * leg + 1):
            gauge = rest[signals.SENSOR_PRESSURE + c] - atmosphere
            if abs(gauge) > PRESSURE_ZERO_MAX:
                raise IdentificationError(
                    f"leg {leg + 1} did not come down onto its end stop (its sensor reads "
                    f"{reading * 1e3:+.2f} mm) and {chamber(c)} still reads {gauge / 1e5:+.2f} "
                    "bar with its exhaust open: check that chamber's valves (an intake stuck "
                    "open or an exhaust stuck shut) and its transducer"
                )
        column = down[:, signals.SENSOR_LEG + leg]
        if np.all(column == column[0]):
            raise IdentificationError(
                f"leg {leg + 1} sensor read {reading * 1e3:+.2f} mm bit for bit the same all "
                "the while the legs were pulled down onto their stops: the sensor is stuck "
                "or its cable is off (or the leg is jammed)"
            )


LOST_MAX = 1.0
"""NL/min a chamber may lose with every valve shut in the valve test (a cap side at 3 bar
absolute with its rod side at the supply, a rod side at 3.5 with its cap side vented): what
its piston passes across by design (up to 2 NL/min from 6 bar gauge to atmosphere, laminar:
at most 0.5 out of a rod side at 3.5 bar) and its exhaust's seat (up to 0.5 from 6 bar
gauge: 0.1 there), against what its intake's seat brings in. Measured (the median of each
chamber's 39 cycles): the nominal unit's rod sides lose 0.04-0.11, its cap sides gain 0.6
across the piston; drawn builds 0-99 lose at most 0.39 (a rod side), and their cap sides
gain 0.26-3.1. A leak to atmosphere of a hundredth of a valve's conductance loses 0.6 at
3.5 bar, a fiftieth 1.3 (a cap side's piston inflow hides up to 1.7 of it). Real chambers
also cool after a fill, which reads as air lost for a second or so: each cycle starts
within 0.1 bar of its base, so that is a small fill, and the median of 39 cycles leaves out
the first, large one."""


def check_leaks(lost: Figures) -> None:
    """Refuse a chamber that lost more than :data:`LOST_MAX` with every valve shut
    (``lost``: NL/min per chamber, :func:`identify_valves`): a leak. Left in, the valve
    figures take it up as the chamber's own valves' air, and the air observer then judges
    that chamber's leak as healthy."""
    worst = int(np.argmax(lost))
    if lost[worst] > LOST_MAX:
        raise IdentificationError(
            f"{chamber(worst)} lost {lost[worst]:.1f} NL/min with every valve shut (a healthy "
            f"piston and valve seats: under {LOST_MAX:g}): a leak in its tube, fitting or "
            "seal, or a valve that does not close"
        )


def check_supply(filled: NDArray[np.float64], pressure_zero: NDArray[np.float64]) -> None:
    """Refuse a supply transducer that reads more than :data:`SUPPLY_GAP_MAX` from the rod
    sides (the median of the six, each less its zero) at the end of the open pull-down
    (``filled``: those reads x sensors, Pa abs), when their intakes have stood open to it."""
    rod = filled[:, signals.SENSOR_PRESSURE + 1 : 12 : 2] - pressure_zero[1::2]
    gap = float(np.mean(filled[:, signals.SENSOR_SUPPLY]) - np.median(np.mean(rod, axis=0)))
    if abs(gap) > SUPPLY_GAP_MAX:
        raise IdentificationError(
            f"the supply transducer reads {gap / 1e5:+.2f} bar from the rod sides its open "
            f"intakes filled (more than {SUPPLY_GAP_MAX / 1e5:g} bar): check the supply "
            "transducer and its cable"
        )


def lower_and_vent(hardware: Hardware) -> None:
    """Where the identification leaves a unit: every leg down on its stop, every chamber
    vented, every valve closed."""

    def step(pattern: NDArray[np.uint8]) -> None:
        hardware.write_valves(pattern)
        hardware.wait_tick()

    try:
        _down_and_vent(step)
    finally:
        hardware.write_valves(np.zeros(signals.N_VALVES, dtype=np.uint8))
