"""The controller distrusts its own sensors and its air: plausibility and cross-checks.

Run inside the interrupt handler, beside the limit checks of :mod:`device.safety`. Each check
returns a trip code and the channel at fault (0 and -1 when all is well); the controller
latches the trip (all valves closed) and the mode machine reports it with the sentence from
:mod:`device.trips`. Every threshold is a field of :class:`SupervisionConfig` with the reason
for its value; the README's fault table is built from the same numbers.

What is watched, and how:

- each pressure transducer (12 chambers and the supply) against what air can do: a reading
  near 0 bar absolute is an open wire (a chamber never falls far below the atmosphere it
  exhausts to), one at the top of the transducer's range a short;
- the supply: below a low mark the mode machine holds the exercise (and refuses new motion
  until it recovers); below a loss mark, or above a high mark, a moving device trips. An
  intake valve is never opened into a chamber whose pressure is above the supply's, which
  would vent the chamber backwards into a failing supply line;
- the force/torque sensor: any channel at its full scale (saturated), all six channels
  reading exactly zero (dead: a live sensor always shows noise), or all six unchanged bit for
  bit (frozen); on a calibrated unit, one channel unchanged bit for bit for longer than the
  noise it showed at start-up lets a live one (dead or frozen alone);
- each leg length sensor: a jump between two reads that no leg can make (unplugged, noisy
  wiper), or a reading that stays bit for bit constant while the leg is driven hard toward a
  target that ran millimetres away from it (stuck);
- each chamber against its valves: an intake held open for most of several PWM periods
  must raise the chamber's pressure, an exhaust lower it (a stuck valve, a stuck pressure
  reading, a large leak or a blocked port fails this);
- each leg's force balance: the pneumatic force its two pressures make must match, averaged
  over tens of milliseconds, the force that holds the platform's weight and the foot's
  measured wrench (a wrong pressure or force reading, a leak, a valve that does not do what
  it is told);
- the force/torque sensor against the six legs together: the legs' residuals, summed as a
  wrench at the ankle, are what the sensor says differently from what the legs carry. A
  sensor offset on any channel spreads over all six legs, each share too small for the
  per-leg check, but adds up in the sum, where the legs' own errors (friction, each
  transducer's zero) largely cancel;
- sideways, the same sum less the platform's own inertial force and the seals' identified
  friction: what is left is the force sensor's error alone, so a phantom sideways load is
  caught within milliseconds, before the loop has carried the platform far;
- about the ankle, the same sum's moment, against an allowance for what the seals may hold
  beyond their identified friction, leg by leg as each slides or sticks: a phantom torque
  that sets the platform turning is caught as soon as the legs slide under it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from device._jit import njit, njit_inline
from device.trips import Trip

# Slots of ControllerState.monitor (floats) and .counters (ints).
M_FT_PREV = 0  # 6: last force/torque reading
M_LEG_PREV = 6  # 6: last leg reading
M_P_START = 12  # 12: chamber air (p V, Pa abs m3) at the start of its valve window
M_RESIDUAL = 24  # 6: filtered force-balance residual per leg (N)
M_P_LAST = 30  # 12: chamber reading at the previous control period (Pa abs)
M_P_READ = 42  # 13: pressure readings of the previous read (Pa abs)
M_AIR_START = 56  # 12: chamber air (p V) at the start of its balance window
M_AIR_EXPECT = 68  # 12: air its intake was told to bring in the window (Pa m3)
M_AIR_OUT = 80  # 12: air its exhaust was told to let out in the window (Pa m3)
M_VALVE_IN = 92  # 12: intake slots commanded in the valve window
M_VALVE_OUT = 104  # 12: exhaust slots commanded in the valve window
M_PUSH = 116  # 6: force (N) the position loop last commanded beyond the load, per leg
M_WRENCH = 122  # 6: filtered force-balance residual as a wrench at the ankle (N, N m)
M_WRENCH_PEAK = 128  # 2: largest filtered force and torque residual since the last reset
M_OBS_PV = 130  # 12: chamber air (p V, Pa abs m3) at the previous control period
M_OBS_V = 142  # 12: chamber volume (m3) at the previous control period
M_OBS_R = 154  # 12: filtered air residual: measured minus expected inflow (Pa m3/s)
M_OBS_T = 166  # 12: filtered tolerance of that residual (Pa m3/s)
M_OBS_PEAK = 178  # 1: largest |residual| / tolerance seen since the last reset
M_LEG_TARGET_SEEN = 179  # 6: a leg's target when its reading last changed (calibrated, m)
M_FOLLOW_SPEED = 185  # 6: commanded speed per axis, held and decaying with the loop's lag
M_FOLLOW_TURN = 191  # 3: commanded rotation rates, low-passed with the loop's lag (rad/s)
M_FOLLOW_SWERVE = 194  # 1: how far the rotation rates left that, held and decaying (rad/s)
M_P_MOVED = 195  # 12: 1 if a chamber's raw reading changed between two reads since the last
# control period (a live transducer's noise flickers it; a frozen one never changes)
M_AIR_SHARE = 207  # 12: last ended air window: the share of the air its valves were told to
# move that the chamber's measured air followed (1 all of it)
M_AIR_WAY = 219  # 12: ...which way they were told to move it (+1 in, -1 out; 0 both ways)
M_AIR_JUDGED = 231  # 12: ...1 if that window was judged (where the rough figure holds)
M_TWIST_PREV = 243  # 6: the task origin's twist [v, w] at the previous pose period
M_SIDE = 249  # 2: filtered sideways (x, y) residual less the platform's inertial force (N)
M_SIDE_PEAK = 251  # 1: largest magnitude of that since the last reset
M_LEG_PREV2 = 252  # 6: the leg reading before the last
M_LEG_LAG = 258  # 6: each leg's residual less its seals' friction (N), through the pose
# rate's own low-pass (so it lags as the measured acceleration does)
M_SIDE_ALLOW = 264  # 1: filtered allowance for the model's inertia errors (N), check_side
M_LOAD_SIDE = 265  # 2: the sideways load (x, y; N, base frame) the compensation last took
M_LOAD_HELD = 267  # 6: each leg's force (N) that holds the load as measured, pistons' weight in
M_BLIND_SEEN = 273  # 6: the load compensation (N) a leg was given while its reading last moved
M_BLIND = 279  # 6: what the compensation gives a still leg beyond its load (N; - withheld)
M_TURN = 285  # 3: filtered moment residual at the ankle less the platform's inertia (N m)
M_TURN_ALLOW = 288  # 3: filtered allowance for what the legs' friction and the model leave there
M_TURN_PEAK = 291  # 1: largest share of its allowance the moment residual took since the reset
M_LOAD_TURN = 292  # 3: the moment (roll, pitch, yaw; N m) the compensation last took
M_AIR_IN_MOST = 295  # 12: the most air its intake may have brought in the window (Pa m3)
M_AIR_OUT_MOST = 307  # 12: ...and its exhaust let out (pulses near a valve's opening delay)
M_LIFT = 319  # 1: filtered vertical residual force at the ankle less the platform's inertia (N)
M_LIFT_ALLOW = 320  # 1: filtered allowance for what the legs' friction and the model leave there
M_LIFT_PEAK = 321  # 1: largest share of its allowance the vertical residual took since the reset
M_ANSWER = 322  # 12 x ANSWER_SUMS: each chamber's decaying sums of what its valves answered
ANSWER_CAME = 0  # air that came in (Pa m3, + in)
ANSWER_IN = 1  # air its intake's pulses surely brought, as this build's valve passes one
ANSWER_IN_TOL = 2  # ...how far that may be off (Pa m3)
ANSWER_OUT = 3  # air its exhaust's pulses surely let out (Pa m3, negative)
ANSWER_OUT_TOL = 4  # ...how far that may be off (Pa m3)
ANSWER_VOLUME_TOL = 5  # what the volume term and the floor leave unknown (Pa m3)
ANSWER_SUMS = 6
M_ANSWER_PEAK = M_ANSWER + 12 * ANSWER_SUMS
"""1: how near a chamber's valves came to not answering since the last reset: the answer
rule's share over the lowest answer share judged (1 asks for service; 0 while none was)."""
M_RELEASE = M_ANSWER_PEAK + 1
"""5 x 12, while the platform is released (vented): per chamber, its air at the release's
start (0 before the first read), the least air since, the least gauge pressure since, its
gauge pressure at the start, and its air's trailing average over about the last
``release_window`` reads (device.controller.watch_release)."""
M_SHUT = M_RELEASE + 60
"""2 x 12, 1 and 2 x 12, while every valve is shut (IDLE, not released): per chamber, its
air and its gauge pressure at the window's start, then the reads since the valves shut
(device.controller.watch_shut; 0: not yet), then per chamber its air's and its gauge
pressure's trailing averages over about ``shut_slow_reads`` reads."""
M_LEG_AIR = M_SHUT + 49
"""3 x 12, 6, 1 and 2 x 6, while every valve is shut (:func:`judge_leg_air`): per chamber
its air's trailing average over about ``shut_leg_reads`` reads (``p^(1/k) V``, pressure in
atmospheres, this build's dead volume), and what its valves' seats and its piston's
clearance would have moved by the model (:func:`leak_terms`) less its trailing average;
then per leg what cooling after the fills before the shut may still take of its air (a
share, decaying); the largest share of ``shut_leg_air`` a leg's loss beyond the model took
since the shut; then per leg how far the seats' and the pistons' terms may be off from
what the transducers' spans and zeros leave unknown, less its trailing average."""
M_FILLED = M_LEG_AIR + 55
"""12, in every mode: each chamber's gauge pressure's low envelope, which rises back to the
reading over about ``shut_thermal_time`` (:func:`track_fills`): the reading above it is
what the valves filled lately, whose heat a real chamber's walls take back."""
M_PUSH_SEEN = M_FILLED + 12
"""6: the push (``M_PUSH``, N) the position loop gave a leg while its reading last changed."""
M_STEADY_PEAK = M_PUSH_SEEN + 6
"""1: the largest share of its floor (``balance_steady_floor`` plus twice its seals'
friction) the residual of a leg that carried it alone took since the last reset."""
N_MONITOR = M_STEADY_PEAK + 1

# Rows of the valves' figures the air checks take (``valves``, 4 x 24; valve ``2c`` is the
# intake, ``2c + 1`` the exhaust of chamber ``c``), from the calibration
# (device.calibration.Calibration.valve_figures).
V_GAIN = 0  # the air a pulse passes against the model (1: not identified)
V_EXTRA = 1  # s a pulse passes beyond its length (0: not identified)
V_SHUT = 2  # s the longest test pulse that left it shut (0: not identified)
V_OPENS = 3  # s the shortest that opened it every time (0: not identified)

C_FT_SAME = 0
C_FT_ZERO = 1
C_FT_SAT = 2
C_LEG_SAME = 3  # 6
C_WINDOW = 9  # 12: PWM periods in the current valve window
C_RESIDUAL = 21  # 6: control periods with the residual above its threshold
C_SUPPLY_LOW = 27
C_SUPPLY_LOSS = 28
C_SUPPLY_HIGH = 29
C_SUPPLY_OK = 30
C_LOW_FLAG = 31
"""1 while the supply is below its low mark (the mode machine holds and refuses motion)."""
C_READS = 32
C_P_SAME = 33  # 12: driven control periods a chamber's reading stayed the same
C_AIR = 45  # 12: control periods in the current air-balance window
C_WRENCH = 58
"""Control periods in a row with the wrench residual over its limit."""
C_OBS_OVER = 59  # 12: control periods in a row a chamber's air residual was over tolerance
C_OBS = 71  # 12: control periods a chamber's air has been observed since motion started
C_FOLLOW = 83
"""Pose periods in a row the platform was further from its commanded pose than allowed."""
C_FOLLOW_ARMED = 84
"""Pose periods in a row the platform has been within the following bound since motion
(re)started; the check is armed at FOLLOW_ARM_PERIODS. A segment resumed after a hold
starts wherever the foot left the platform, and the loop first brings it back to its
command; a leg stepping to a new target slows as it arrives (drawn build 34's 10 mm step
came within 1.8 mm at 60 ms, then crept at 2.1 mm for 8 ms before it settled: armed at
its first period within the bound, that tripped a healthy step)."""
FOLLOW_ARM_PERIODS = 10
"""40 ms within the bound before the check counts: the arrival above is over by then, and a
fault that strikes a platform already on command is judged at once."""
C_SERVICE = 57
"""Chamber + 1 whose air did not add up (0: none): the device needs service. Not a trip:
closing every valve would let a leaking chamber, or one whose intake is stuck open, move
its leg with nothing to stop it, while the loop holds it. So the running segment finishes
under control and nothing new starts until a technician re-arms (device.modes)."""
C_SERVICE_LEGS = 85
"""Bits of the legs (1 << leg) a chamber of which did not add up since the last re-arm."""
C_WOKE = 86  # 6: control periods left in which a leg that woke by drifting is watched closer
C_SIDE = 92
"""Control periods in a row with the sideways residual (``M_SIDE``) over its limit."""
C_SIDE_ARMED = 93
"""Pose periods since start-up or the last new command (a segment, a resume), counted up
to ``SIDE_ARM_PERIODS``: the pose's rate starts from nothing and its first difference is a
jump, not a motion; and a new command sets the legs chasing a new target, which the model
of the sideways check (no velocity products, a rigid loop) follows least well."""
SIDE_ARM_PERIODS = 10
"""40 ms. Measured in the safety benchmark's boundary run (a new segment every 5-10 ms, at
and around every published bound, through the service): the sideways residual reached
7-17 N within 10 ms of a segment's start (one run of eight over the limit, a false
FORCE_SENSOR trip, on a loaded machine where segments arrive bunched), under 3 N between;
this waits four times that. The pose rate's low-pass (30 Hz, 0.47 of it left each period)
keeps 5e-4 of its start-up jump by then, and the device cannot move that soon after start:
it homes first. At 0.1 s (25 periods) the checks this gates were blind for the first
0.1 s of every move: 30 N on any force channel or 3 N m on any torque channel 50 ms into
the move that starts every session was named at 52-56 ms; at 40 ms, in 16-28 ms, with no
other row of the safety benchmark changed and no false trip over its healthy runs, its
boundary run, its K-B grid or the control benchmark's fifty builds."""
C_POSE_ROUGH = 94
"""Reads left in which the measured pose is no acceleration: a leg reading moved in a way
no leg can (``side_leg_rough``) within the last ``side_rough_reads``."""
C_LEG_STILL = 95  # 6: reads in a row, in motion, a leg's reading stayed bit for bit the same
C_TURN = 101
"""Control periods in a row with the moment residual (``M_TURN``) over its allowance."""
C_FT_STEPPED = 102
"""1 from a torque reading's step (``ft_torque_step``) until the load compensation of the
held rotational axes has caught up with the readings (``ControllerConfig.load_turn_slew``)."""
C_LIFT = 103
"""Control periods in a row with the vertical residual (``M_LIFT``) over its allowance."""
C_P_STILL = 104  # 13: reads in a row a pressure channel's raw reading stayed bit for bit the same
C_ANSWER = 117  # 12: control periods in a row a chamber's valve did not answer its pulses
C_SUPPLY_DRAWN = 129
"""Reads since the supply's raw reading last changed in which an intake drew from it."""
C_STEADY = 130  # 6: control periods in a row a leg alone carried a residual over its floor
C_FT_STILL = 136  # 6: reads in a row a force/torque channel stayed bit for bit the same
C_SIDE_JUDGED = 142
"""Pose periods the cross-checks have judged since they last armed, counted up to
``SIDE_ARM_PERIODS``: a new command makes them wait only once they have judged as long as
they last waited (``settle_side``)."""
N_COUNTERS = 143


@dataclass(frozen=True)
class SupervisionConfig:
    """Thresholds of the sensor and supply supervision, SI units (pressures Pa)."""

    pressure_full_scale: float = 1.0e6
    """The transducers' range (Pa absolute): 0-10 bar, as the device's are specified."""
    pressure_open_below: float = 0.3e5
    """Below this (Pa absolute) a reading is an open wire: a chamber exhausts to 1 bar
    absolute and, even when the piston pulls a closed chamber, stays above about 0.6 bar; the
    supply is above the atmosphere whenever there is air. 0.3 bar leaves room for both."""
    pressure_jump: float = 0.8e5
    """A reading that changes more than this between two reads (1 ms) is a sensor fault
    (Pa): a fully open valve moves a chamber at most about 0.1 bar per millisecond at mid
    stroke and 0.4 bar at the end of its stroke, where the chamber is smallest."""
    pressure_short_above: float = 0.97e6
    """At or above this (Pa absolute) a reading is a short to the supply rail: 97 % of full
    scale, above the supply's high mark and anything a chamber reaches (at most the supply
    plus what the 400 N force limit adds on one piston, about 8 bar)."""
    supply_low: float = 4.5e5
    """Gauge supply below which an exercise is held (Pa): 1.5 bar under the nominal 6 bar, far
    below a regulator's droop under flow (0.2-0.5 bar), and above the chambers' working
    pressures (about 5 bar), so the platform still holds its load on trapped air."""
    supply_resume: float = 5.0e5
    """...and above which it counts as recovered (Pa, hysteresis)."""
    supply_loss: float = 3.5e5
    """Gauge supply below which a moving device trips SUPPLY_LOSS (Pa): below the chambers'
    working pressure, so intakes can no longer fill them."""
    supply_high: float = 8.0e5
    """Gauge supply above which a moving device trips SUPPLY_HIGH (Pa): the regulator failed;
    the valves and cylinders are rated 10 bar."""
    supply_low_reads: int = 20
    """Reads (1 kHz) below the low mark before the hold: 20 ms, longer than a flow transient."""
    supply_resume_reads: int = 200
    """Reads above the resume mark before motion is allowed again (0.2 s)."""
    supply_trip_reads: int = 3
    """Reads past the loss or high mark before the trip: 3 ms, against a single bad sample."""
    intake_margin: float = 0.05e5
    """An intake opens only while the supply is this much above the chamber (Pa): 20
    transducer counts, well above their noise; below it an intake passes next to nothing
    anyway, and with a falling supply it would let the chamber's air out backwards."""
    ft_force_full_scale: float = 1500.0
    """The force/torque sensor's force range (N), per channel."""
    ft_torque_full_scale: float = 80.0
    """...and torque range (N m) per channel."""
    ft_saturated_fraction: float = 0.99
    ft_saturated_reads: int = 1
    """One read at full scale is enough: the device trips on force long before a healthy
    reading could get there."""
    ft_zero_reads: int = 5
    """All six channels exactly 0 for this many reads is a dead sensor: with about one count
    of noise on each channel, six zeros at once happen about once in a thousand reads, five
    times in a row practically never."""
    ft_frozen_reads: int = 20
    """All six channels unchanged bit for bit for this many reads (20 ms) is a frozen sensor."""
    ft_force_jump: float = 40.0
    """A force channel that changes more than this between two reads (1 ms) is a sensor
    fault (N): 40 000 N/s, ten times the fastest a foot develops force at the ankle (2-5 N
    per ms) and nine times the largest step between two reads in the healthy runs of every
    library exercise on the nominal unit and drawn builds 0, 4 and 11 (4.5 N). A bias that
    jumps (a connector, a bridge) would otherwise reach the legs whole through the load
    compensation: 80 N on Fx moved a held platform 13 mm before the wrench cross-check
    tripped at 66 ms. A bias that creeps stays the cross-check's. Judged only while the
    platform moves (when the compensation acts): a foot set down on a resting plate may
    land harder."""
    ft_torque_jump: float = 4.0
    """...and a torque channel (N m): eight times the healthy runs' largest step (0.53)."""
    ft_torque_step: float = 1.5
    """A torque channel that changes more than this between two reads (N m), under the jump
    rule, is a step no foot twists (0.2-0.5 N m a millisecond: the 2-5 N/ms of
    ``ft_force_jump`` at the ankle's 0.1 m; three times the healthy runs' largest step) but
    not yet a fault: what it brings enters the held axes' load compensation slowly
    (``ControllerConfig.load_turn_slew``) while the moment cross-check judges it."""
    leg_jump: float = 1.0e-3
    """A leg reading that moves more than this between two reads (1 ms) is a sensor fault:
    1 m/s, 2.5 times the leg speed limit, 40 sensor counts."""
    leg_stuck_force: float = 15.0
    """A leg the position loop pushes this hard (N) beyond its load, or..."""
    leg_stuck_floor: float = 5.0
    """...on a unit whose seals' friction was identified (``Calibration.leg_friction``),
    this (N) plus ``leg_stuck_seals`` times the leg's own, if less: what a healthy leg
    sticks against is its breakaway friction (1.2-2 times its Coulomb friction), and 15 N
    is half as much again as the largest breakaway of a plausible build (5 N seals). The
    floor covers what the load model leaves to each leg (a plate a kilogram off its model:
    about 1.6 N a leg). Measured on the calibrated nominal unit (seals of 1.1-1.3 N, so
    8.3-8.9 N): leg sensors 3 and 4 frozen as the legs settle at mid stroke were named in
    308-380 ms, the platform 2.8-3.2 mm off, where 15 N took 596-724 ms and 4.1-4.7 mm.
    The library on drawn builds 0-39, relaxed and resisting, never met it; with a floor of
    3 N it tripped four healthy runs on build 32 (seals of 1.1-1.2 N identified, so 6.4 N),
    with 4 N none (2.9 mm in 276 ms at 3 N: the margin was kept instead)."""
    leg_stuck_seals: float = 3.0
    """See ``leg_stuck_floor``: 1.5 times a breakaway of twice the Coulomb friction."""
    leg_stuck_error: float = 0.7e-3
    """...whose reading is this far (m) from its target, ... The smaller, the sooner a
    target that runs away from a frozen reading is seen: over the fault matrix's frozen leg
    sensors, 1 mm caught them in 127-235 ms with the platform up to 5.4 mm off, 0.7 mm in
    55-199 ms and 3.5 mm (and legs 0 and 1 mid-exercise, before missed, in 435-459 ms).
    What bounds it is a healthy leg that sticks while its target moves on: over the
    start-up identification of drawn builds 0-49 (a slow heave of the empty plate, where
    stiff seals stick longest), the longest such stretch was 40 reads past 0.5 mm (draw 1,
    which 0.5 mm tripped), 28 past 0.6, 21 past 0.7 and 0.8 (draw 2) and 15 past 1 mm
    (draw 27)."""
    leg_stuck_target_move: float = 0.3e-3
    """The error rule counts only once the target has moved this far (m) since the reading
    last changed: a leg whose target runs away from a frozen reading, not one that rests
    short of a target that stands still. While an axis renders a low stiffness against a
    resisting foot, stiff seals hold a leg 1.0-1.1 mm short of its target for longer than
    the rule's 33 reads while its target creeps by 0.05-0.1 mm (draw 2 of the plant
    ensemble tripped there); a healthy leg whose target moves 0.3 mm (12 counts) away
    breaks free and changes its reading."""
    leg_stuck_reads: int = 33
    """...and whose reading stays bit for bit the same for this many reads (33 ms) is
    stuck. 15 N is half as much again as the largest breakaway friction of a plausible
    cylinder (5 N Coulomb, breakaway ratio 2; device/plant/params.py): a healthy leg pushed
    that hard moves by more than a sensor count (24 um) within a few milliseconds. The push
    is the loop's own command (proportional, derivative and integral terms). The error rule
    is the faster one when the target runs away from a frozen reading. A stiff-sealed leg
    held by stick-slip friction at the reversal of a slow sine sits 1 mm from its target
    for up to about 30 ms: 25 reads (the wave-1 rule) tripped two of twelve drawn plants in
    a 2 deg pitch sweep, 33 none; each read more lets a frozen reading move the platform
    further before the trip (lab/safety.py measures how far)."""
    leg_stuck_blame_reads: int = 10
    """A trip of the force/torque sensor found by the legs' force balance (the wrench, the
    sideways force, the moment or the lift the legs and the sensor disagree on) is named as a
    leg's length sensor instead while that leg's reading has stayed bit for bit the same
    through this many reads of the rule above (driven, 10 ms): the pose the model puts the
    platform in comes from that frozen reading, so the platform's true motion shows as a
    force the sensor reads and the model does not. A sensor frozen while the platform
    rested, then a 10 mm step of its leg: the sideways check tripped 18 ms into the step,
    with the leg 18 reads into the rule, and sent the technician to the force plate.
    Healthy legs stayed within 3 such reads in pitch, roll and heave sines with a relaxed,
    a resisting and an absent foot; the trip itself is the same, only the part it names."""
    leg_blind_reads: int = 33
    """A leg whose reading has stayed bit for bit the same for this many reads (33 ms, as
    long as the stuck rule counts) in motion is blind: the load compensation (eq. 15's G_p)
    it is given may then move at most ``leg_blind_band`` from what it was given while its
    reading last moved, until it moves again. The compensation follows the load the force
    sensor measures, through the pose the legs measure; a leg whose sensor froze has no
    position feedback left, and its pressure loop holds whatever force it is given, so it
    goes where that force takes it. A foot resists the tilt this makes, the sensor measures
    that as load, the compensation hands it to the frozen leg and the leg yields further:
    with the patient pushing a compliant pitch (K = 50), a frozen leg 0 or 1 was pulled from
    +22 to -94 N and ran 25-27 mm in 2 s (6.2-6.7 deg; the following bound tripped at 1 s).
    Bounded, it moves 2.0-2.2 mm (0.66-0.76 deg) and stops. A healthy leg that stands still
    while its load changes moves a count once the withheld force overcomes its seals, and
    is followed again. After 10 reads instead the bound also caught healthy legs that rest
    at the reversals of the lab's 0.3 mm heave sine as the foot settled on them (one
    period, 0.6 N), and the sine's gain near 2 Hz, which the friction fed forward then
    made as sensitive to any such nudge as to the noise seed (2.0-3.8 dB absolute on seeds
    1-5 without the bound; see ControllerConfig.friction_compensation_lead), moved by
    1.5 dB; at 33 reads the lab's sweeps of z, x and pitch were unchanged but z at 1 Hz
    (+0.2 dB)."""
    leg_blind_band: float = 5.0
    """...(N). What the compensation withholds beyond it counts with the loop's push toward
    ``leg_stuck_force``: a leg left 15 N out of balance that does not move a count is
    stuck; so is one the loop pushes 15 N beyond the load it is given, as before, though
    what is withheld may balance that push (a leg frozen a few counts short of its target
    as the legs settle at mid stroke, pushed on by the integral and the foot's growing
    reaction: before the bound it ran 21-30 mm before a VALVE or LEG_SENSOR trip at
    247-370 ms, with the bound and the push alone it stops 5-6 mm off, named in
    223-471 ms). At 10 N the frozen legs above moved 3.1-3.4 mm."""
    pressure_frozen_periods: int = 10
    """A chamber reading unchanged bit for bit over this many control periods in a row in
    each of which a valve of it was open at least the valve's response time (d_dead of
    eq. 1) is frozen (40 ms). Such a pulse moves a chamber by about 0.06 bar or 25
    transducer counts; a shorter one may pass no air at all (without dead-band compensation
    most pulses at rest are that short). Counting only the air a pulse surely moved past
    its valve's opening edge (as ``supply_draw_air`` does) was tried and not kept: the
    loop's pulses in motion surely move a chamber only 1,000-2,000 Pa a period, the rule
    then named a frozen chamber reading mid-exercise in up to 175 ms (41 ms), the platform
    3.4 mm off, and on a unit without its calibration hardly at all; no healthy run of the
    library on drawn builds 0-99 had a chamber reading stand still so."""
    pressure_frozen_headroom: float = 0.5e5
    """...and only where that pulse can move air: an intake counts while the chamber is more
    than this (Pa) below the supply, an exhaust while it is more than this above the
    atmosphere. Through 0.5 bar an ISO 6358 valve still passes about half its choked flow,
    12 counts a pulse; at the supply nothing flows in, whatever the transducer. A rod side
    pumped to 0.2 bar under the supply, next to a cap whose exhaust had stuck shut, read
    the same ten periods running and was named as a frozen transducer in place of the cap."""
    supply_frozen_reads: int = 20
    """The supply's raw reading bit-identical for this many reads (1 kHz) in which the
    intakes surely drew from it (``supply_draw_air``) is frozen: every draw dips the manifold
    behind the regulator, up to 0.15 bar. Measured healthy over the exercise library with
    a relaxed and a resisting foot on the nominal unit (seeds 1-2), drawn builds 3, 8, 11,
    22, 34 and 54, and the nominal unit with the quietest transducers a build may have (50
    and 75 Pa), 5 s each: intakes drew in nearly every period, and the reading stood still
    through at most one such period (4 reads). A frozen supply transducer is named in
    20-24 ms while the legs move; at rest only the flicker rule (``pressure_still_reads``)
    tells it, in about 0.2 s. 0: not judged so.

    A period counts as drawing only where its intakes together surely drew
    ``supply_draw_air``: counted by the pulses' length alone (one just over the response
    time), drawn build 99, whose valves open late and whose transducers are too quiet to
    flicker, was tripped healthy in the isometric hold with a resisting foot (4.3 s in):
    the hold's doses barely opened its intakes and the manifold did not dip a count. And
    counted at the flow the readings say, drawn build 81 was tripped in the hold with a
    relaxed foot (8.0 s in): an intake held open into a chamber that had all but reached
    the supply, whose transducer read 0.08 bar above the manifold."""
    supply_draw_air: float = 0.05
    """Air (Pa m3) the intakes of a control period must surely have drawn for the period to
    count in ``supply_frozen_reads``, by :func:`drawn_surely`. Drawn from the 48 cm3 behind
    the supply hose (the manifold and the hose, device/plant/params.py), 0.05 Pa m3 dips
    the supply reading about 1,000 Pa, four counts of its transducer, before the hose
    refills it (about 25 ms): a live reading cannot stay in its code. A pulse 1 ms past its
    edge into a chamber 1.5 bar under the supply surely draws 0.14 Pa m3 on the calibrated
    nominal unit; the loop's pulses in motion, 0.2-0.5 Pa m3 a period. In this form the
    library with both feet on drawn builds 0-99 (1,200 runs of 10 s) tripped nothing."""
    supply_draw_edge: float = 1.5e-3
    """On a unit whose valves were not identified: the pulse length (s) from which every
    valve a build may have surely opened (the slowest opening delay, 1.21 ms, and three
    times the 0.1 ms jitter; device.calibration.PULSE_OPENS_MAX). The loop's pulses in
    motion are mostly 1.4-1.7 ms long, so such a unit counts few periods as drawing: it
    cannot be sure its short pulses drew anything, and does not name a frozen supply
    reading by this rule (it did in 21 ms, with the false trips above)."""
    valve_window_periods: int = 5
    """PWM periods (4 ms each) in which a chamber must answer its valves (20 ms)."""
    valve_duty_fraction: float = 0.5
    """An intake (or exhaust) energised for at least this share of the window, the other
    never, ..."""
    valve_min_change: float = 0.1e5
    """...must move the chamber's pressure at least this much the right way (Pa). A valve
    open half of 20 ms moves a chamber by about a bar; 0.1 bar is 40 pressure counts."""
    valve_headroom: float = 0.5e5
    """...unless the chamber is already within this of where that valve can take it (Pa):
    the supply for an intake, the atmosphere for an exhaust."""
    air_window_periods: int = 50
    """Control periods (4 ms) over which a chamber's air is balanced against its valves
    (0.2 s): long enough to average the minimum-pulse dither out."""
    air_per_slot: float = 0.02
    """Air (p V, Pa m3) one slot (1/7 ms) of an open valve moves, in or out, at working
    pressures: ISO 6358 flow of C = 0.3 dm3/(s bar) from 7 to 5 bar (about 2 g/s) times
    R T. A rough figure on purpose: the check asks only for a fraction of it."""
    air_one_sided: float = 0.25
    """Only a window in which the valves moved air essentially one way (the other way at most
    this share) is judged: in the dither of a held chamber the two ways nearly cancel and
    their difference says nothing."""
    air_headroom: float = 1.5e5
    """A window is judged only while the chamber is this far (Pa) below the supply (intake)
    or above the atmosphere (exhaust), where a valve's flow is within about half of the
    figure above."""
    air_open_after_slots: int = 6
    """Slots of each pulse that pass no air: the armature's delay (0.8 ms)."""
    air_min_expected: float = 2.0
    """Only a window whose valves were told to move at least this much air (Pa m3, about a
    fifteenth of a chamber at mid stroke: 100 slots past the armature's delay) is judged.
    The one-sided rule already leaves out the dither of a held chamber; this leaves out
    windows so small that the piston's own compression of the air (p V read raw) or a slow
    valve's short pulses decide the share. With an intake or exhaust stuck shut
    mid-exercise the loop keeps asking it for 2-3 Pa m3 a window (pulses of about 10
    slots, the mirror's valve doing the work) while the chamber's air goes the other way
    (shares -0.2 to -1.5) and its pressure sinks a bar in 0.4 s: 3 Pa m3 (the first figure)
    caught 16 of the safety benchmark's 72 stuck-shut valves, 2 catches 40 (14 of the 32
    left were never told to open). Measured healthy over the exercise library with a
    relaxed and a resisting foot on the nominal unit (seeds 1, 2, 4-7) and drawn builds
    0-49, 672 runs of 10 s: no window told to move 2 Pa m3 or more one way fell short where
    the headroom and mirror rules judge it (the lowest share 0.60, but for build 8's
    mirrors). At 1.5 one did (drawn build 22, passive range of motion against a resisting
    foot: a cap told to let out 1.6 Pa m3 that the foot was compressing kept 0.8-0.9 of
    it), a false service warning."""
    air_min_fraction: float = 0.2
    """...and the chamber's measured air (p V with V from the measured piston) must have
    changed by at least this share of it, the same way. A leak takes what the intake brings;
    a stuck valve does not pass it; a leg sensor that stopped hides the volume the piston
    really makes."""
    air_mirror_share: float = 0.5
    """...unless the other chamber of the leg, told by its own valves to move air the other
    way in the same window, followed less than this share of it as well. The two chambers
    of a leg are driven as mirrors (one fills while the other empties); when both fall short,
    the leg's valves passed less air than the window's rough figure says (valves slower than
    the type's, whose short pulses pass little), or air crossed the piston from one to the
    other (a clearance seal leaks by design): neither is a fault of one chamber. Both then
    still moved the way their valves did, only less; a chamber whose air went against its
    valves is judged alone (slow valves pass less air, never air the other way). A leak to
    the room, a valve stuck shut or a stopped leg sensor takes one chamber's air, and its
    mirror follows its valves. Measured: drawn build 8 (the slowest valves of the ensemble)
    in a passive range-of-motion exercise with a resisting foot dithered a leg's chambers
    in turns, cap in 8 slots and out 14 each other period, and both windows fell short
    (cap 0.16, rod 0.19 of their figures), a false service warning without this rule."""
    valve_conductance: float = 0.30e-8
    """ISO 6358 sonic conductance C of one valve as the air observer assumes it (m3/(s Pa)):
    0.30 dm3/(s bar), the middle of what the Matrix valve's rated 100 NL/min means (0.24 if
    rated choked at 7 bar abs, 0.37 if rated 6 -> 5 bar gauge with b = 0.4). A real valve of
    the type may sit anywhere in that range: ``observer_flow_tolerance`` covers it."""
    valve_critical_ratio: float = 0.4
    """ISO 6358 b the observer assumes (0.3-0.5 for a small poppet valve)."""
    observer_polytropic: float = 1.2
    """Polytropic index that turns a chamber's change of p V into air moved: between the
    adiabatic 1.4 of a fast fill and the nearly isothermal 1.0 of a discharge (Richer and
    Hurmuzlu 2000); the 15 % either way is in ``observer_flow_tolerance``."""
    observer_flow_tolerance: float = 0.45
    """Share of the air the valves were told to move that the observer forgives: the valve
    type's conductance range (-20/+23 % about the assumed C), each valve's own 10 %, the
    critical ratio (up to 15 % at a chamber near the supply) and the polytropic index
    (15 %). A stuck-open intake brings what the exhaust fighting it is told to let out
    (the residual is then about 100 % of the expected flow), a leak of half a valve takes
    what the intake is told to bring; neither hides inside 45 %."""
    observer_pulse_time: float = 0.7e-3
    """Per PWM pulse, the time (s) of full flow the observer forgives on top: how much a
    valve's opening and closing delays may differ from each other and from the type's
    (0.55-1.05 ms opening, 0.6-1.2 ms closing, 15 % per valve; device/plant/params.py).
    A minimum pulse (1 ms) may thus pass anything from nothing to nearly twice its length:
    at rest, in the dither of minimum pulses, an observer that does not know this build's
    valves can see only a fault larger than that dither (a leak of a third of a valve, a
    valve stuck open), not a stuck-closed exhaust the loop hardly uses. Once the start-up
    identification measured each valve, ``observer_pulse_time_identified`` applies."""
    observer_pulse_time_identified: float = 0.2e-3
    """...and what it forgives once the start-up identification (device.identify) measured
    each valve's own air per pulse: the valves' jitter (up to 0.1 ms rms per switching) and
    what the identification's straight line misses of a pulse at another pressure. A pulse
    near its valve's opening delay is forgiven half of itself on top (pulse_seconds)."""
    observer_flow_tolerance_identified: float = 0.15
    """...and the share of the flow, once identified: what is left of the type's range is
    the critical ratio at another pressure than the identification's (up to 10 %) and the
    polytropic index of a mixed period. Measured healthy over the exercise library with a
    relaxed and a resisting foot on the nominal unit and drawn builds 0-49: the residual
    reached at most 0.80 of this tolerance (build 54, see ``observer_span_error``). In the
    safety benchmark's matrix a valve stuck open is named in 17-33 ms everywhere (96 of
    96), a 0.5 C leak in 21-45 ms but as the legs settle (47 of 48), a valve stuck shut
    while the legs move in 35-331 ms (69 of 96, 21 of the others never told to open; 39
    and up to 431 ms with the type's range)."""
    observer_pulse_edge_margin: float = 0.15e-3
    """Beyond the lengths the start-up test found a valve to stay shut up to and to open from
    (device.identify), this much more (s, a slot) either way counts as where the delay's
    jitter decides: three tries at each length may miss its tails."""
    observer_span_error: float = 0.02
    """Share of its reading a pressure transducer's span may be off (2 %: the plant's
    range; the start-up identification finds each zero, not the spans). The expected flow
    is figured with the supply's and the chamber's readings that far apart either way, and
    half the difference is forgiven: choked, about 2 % of the flow; a rod side 0.14 bar
    under a 5.85 bar supply (drawn build 54, whose transducers' spans are off by up to
    1.6 %), where its intake's flow hangs on the difference of two readings, nearly all of
    it. Before, that rod side's intake, held open 22-28 slots a period, passed about half
    the flow the readings said and asked for service at 2.4 times the tolerance."""
    use_identified_valves: bool = True
    """Judge the air against this build's valves once the start-up identification measured
    them (its gains, extra times and where each valve starts to open). Before the opening
    edges were measured this was off: on draw 11 (the slowest valves of the drawn builds)
    a strength exercise raised a false service warning at 1.6 of the narrowed tolerance,
    its loop's 7-8 slot pulses shorter than its valves' opening delays (up to 1.09 ms), so
    they passed nothing where the straight line expected 0.3-1 ms of flow. With the edges,
    over the exercise library with a relaxed and a resisting foot on the nominal unit
    (seeds 1, 2) and drawn builds 0-73 (10 s each, 912 runs), the residual took at most
    0.80 of its tolerance and nothing asked for service."""
    observer_volume_tolerance: float = 0.35
    """Share of the air a pressure change alone seems to move (V dp / k) that the observer
    forgives: the dead volume of a real build (port and tube, 4-15 cm3 for 0.3-1 m of tube)
    differs from the design's 7.3 cm3 by up to this share of a chamber at mid stroke."""
    observer_floor: float = 5.0
    """Air residual (Pa m3/s, about 0.06 g/s) the observer always forgives: the healthy
    leaks of a build (past a piston 0.5 NL/min, through each closed seat up to 0.5 NL/min)
    and the transducers' noise over a control period."""
    observer_cutoff_hz: float = 8.0
    """Low-pass (Hz) on the residual and its tolerance: the air in the tube reaches the
    transducer and the piston milliseconds apart, and a pulse's air arrives over the next
    period; 8 Hz (20 ms time constant) averages that while a large fault still shows within
    tens of milliseconds."""
    observer_periods: int = 5
    """Control periods (4 ms) in a row over tolerance before the device asks for service
    (20 ms)."""
    observer_wake_periods: int = 2
    """...or this many, within ``observer_wake_window`` periods of its leg waking from the
    quiet hold because it drifted off its target (device.quiet's ``wake``, 0.5 mm) while
    its valves were shut but for the hold's doses: that drift is a second witness,
    independent of the air's. A leak that strikes a resting leg wakes it, and the loop then
    holds the leg with pulses whose timing the observer must forgive (valve 15 stuck open
    while holding: over its tolerance for the 2 periods before the wake at 20 ms, then
    0.8-1.0 of it, named by the 0.2 s air windows only at the first window's end, 201 ms).
    A foot that pushes a resting leg off moves its air spring, not its air."""
    observer_wake_window: int = 3
    """Control periods (12 ms) after a leg woke by drifting in which the shorter count
    applies."""
    answer_window: float = 0.016
    """Time constant (s) of the sums over which each valve's pulses are held against what
    came (``answer_share``): four periods, two pulses of a valve the loop pulses every
    other period, as it does mid-exercise (an intake in one period, the exhaust in the
    next). At 24 ms the healthy air from before a fault faded more slowly: exhausts stuck
    shut were named in up to 56 ms against 48, with the same healthy margin."""
    answer_share: float = 0.9
    """A valve held to its own pulses: of the air its sure pulses (past the opening edge the
    start-up identification found, :func:`pulse_seconds`) should have moved, at most this
    share came, even granting that the chamber's other valve moved the least it may
    (its pulses' tolerance of the air observer, the other way), the volume term
    ``answer_dead_volume_error`` and ``answer_floor``: the valve did not answer, stuck
    shut, or its chamber leaks what it brings. The device asks for service, as the air
    observer does.

    The air observer above waits for its residual to outgrow the tolerance of every pulse,
    the healthy valve's as well: with the loop pulsing intake and exhaust in turn, a dead
    valve kept it near that tolerance for tens of milliseconds (valves stuck shut
    mid-exercise, while the foot pushed and as the legs settled named in 51-331 ms, four
    not within 0.5 s). Held one at a time, a dead valve's share sits at 0.2-0.6 (what the
    other valve's tolerance and the volume term grant it) and falls below 0.9 within
    48 ms of the fault in all 72 of those runs; a healthy valve's sits above 1 (what it
    passed plus those grants). Measured healthy over the exercise library with a relaxed
    and a resisting foot on the nominal unit (seeds 1-3) and drawn builds 0-49 and 53-54
    (660 runs of 10 s): at least 1.28 (drawn build 40, a range-of-motion assessment),
    1.42 times this share."""
    answer_min_air: float = 0.3
    """Air (Pa m3, in the decaying sum) a valve's sure pulses must have been told to move
    before it is judged: a pulse of about 12 slots into a chamber at mid stroke. The
    quiet hold's doses are shorter and rarer, and are not judged so: a valve stuck shut at
    rest is named by the air observer once its leg drifts, or not at all. At 0.2 some
    were, and a resisting foot's isometric hold on drawn build 45 came to 1.08 of the
    share."""
    answer_dead_volume_error: float = 4.0e-6
    """How far (m3) a chamber's dead volume as the start-up identification measured it may be
    from its true one: on drawn builds 0-11 it was off by -14 to +32 % of 5-11 cm3, at most
    2.9 cm3. The air observer forgives 35 % of a chamber at mid stroke for the design's
    dead volume (``observer_volume_tolerance``), several times this, which hid a dead
    valve behind the pressure swings its chamber's other valve makes; the answer rule,
    judging only valves the identification measured, forgives this much volume of every
    pressure change instead."""
    answer_floor: float = 3.0
    """Air (Pa m3/s) the answer rule always forgives: a build's healthy leaks at their most
    (past a piston 0.5 NL/min, through each closed seat up to 0.5 NL/min: 2.5 Pa m3/s) and
    the transducers' noise. The air observer's floor (5) was measured to cost a dead valve
    a fifth of a pulse per period of the sums."""
    answer_periods: int = 1
    """Control periods (4 ms) in a row below the share before the device asks for service:
    one. A pulse's air reaches the transducer within its own period or the next, and the
    rule already holds a valve only to its pulses of the periods before (see
    :func:`answered`); a second period cost up to 68 ms on the runs above and gained
    little margin (healthy at least 1.35 against 1.28)."""
    residual_cutoff_hz: float = 5.0
    """Low-pass on the force-balance residual: a leg's accelerating force in a step or a fast
    sine is brief and alternating, a wrong reading or a leak persists."""
    residual_limit: float = 30.0
    """Filtered residual (N) above which a leg's force balance is wrong: about 0.6 bar on a
    cap chamber. The largest healthy residual measured on the nominal plant is about 10 N
    (10 and 20 mm leg steps, pitch sines up to the axis speed limit, a resisting patient);
    the margin leaves room for stiffer seals and a platform mass a kilogram off."""
    residual_periods: int = 5
    """Control periods (4 ms) the filtered residual must stay above the limit (20 ms)."""
    balance_one_leg_share: float = 0.8
    """A leg that carries this share (of the sum of squares) of the six legs' filtered
    force-balance residuals or more carries a fault of its own: its pressure transducers,
    valves or tubes. A wrong force/torque reading spreads over several legs instead (its
    false wrench, through J^-T): over 126 runs of a force or torque offset on every channel
    (20-30 N, 2-3 N m; six exercises, the nominal unit and drawn builds 5 and 17) no leg
    carried more than 0.57 of it, while a transducer 0.3-0.6 bar off put 0.93-1.0 on its
    own leg (108 runs). A trip of the wrench checks (force, sideways, moment, vertical) is
    then ``FORCE_BALANCE`` on that leg, not ``FORCE_SENSOR``: before, 47 of those 108 were
    named as the force/torque sensor and 11 as the leg's length sensor."""
    balance_steady_floor: float = 5.0
    """A leg that carries the residual alone (``balance_one_leg_share``) and more than this
    (N) plus twice its seals' identified friction (a sticking seal holds up to its
    breakaway, at most twice its sliding friction), for ``balance_steady_periods``, trips
    ``FORCE_BALANCE``: judged only where the start-up identification measured the seals. A
    transducer 0.3 bar off (13-15 N on its leg) went unnamed under the 30 N limit before.
    Healthy, over the library with both feet on the nominal unit and drawn builds 0-29
    (372 runs of 10 s), the filtered residual of a leg that carried 0.8 of it rose at most
    0.65 N above twice its friction, for a moment, and held for 0.1 s stayed 3.9 N under
    it; with the rule in place, over the nominal unit (seeds 1-3) and drawn builds 0-99
    (1,236 runs) nothing tripped and the residual reached at most 0.52 of this floor
    (``M_STEADY_PEAK``)."""
    balance_steady_periods: int = 25
    """See ``balance_steady_floor``: 0.1 s (control periods of 4 ms)."""
    wrench_force_limit: float = 45.0
    """Filtered residual force at the ankle (N, magnitude) above which the force/torque
    sensor and the legs disagree. The legs' own errors set it: the seals beyond their
    identified friction in a fast heave or a 15 deg sine, a platform a kilogram off its
    model and each transducer's zero. Largest healthy value measured over the exercise
    library, leg steps of 10-20 mm and sines up to the axis speed limit, on the nominal
    plant and seven drawn ones: 30 N (11 N nominal). Where the seals' friction was not
    identified (the start-up identification's own heave, a unit run without its
    calibration), what they may hold is allowed for on top, leg by leg
    (:func:`device.controller.wrench_allowance`). An offset of 80 N on any force
    channel is caught; one of 30 N is not here (sideways ``side_force_limit`` catches it,
    vertically ``lift_floor`` on a unit whose load bias was identified)."""
    side_force_limit: float = 18.0
    """Sideways (x and y, magnitude) residual force at the ankle (N) above which the
    force/torque sensor reads a load that is not there. The legs' residual is what they
    push beyond holding the platform's weight and the load the sensor reads: the platform's
    inertial force, the seals' friction and the sensor's error. So this check takes out the
    platform's modelled spatial inertia (and the pistons' mass along their legs) times the
    acceleration of the measured pose, and each leg's identified friction against its
    measured rate: a real push of the foot,
    however fast, is in the sensor and the platform's motion alike, and what the legs lag
    behind it accelerates the platform. What stays is what the model leaves out (friction
    at low speed, each transducer's zero, the acceleration's noise). Largest healthy value,
    filtered as below: 9.8 N over the exercise library with a relaxed and a resisting foot
    (10 s each) on the nominal unit (seeds 1-3) and eighteen drawn builds; 10.5 N with the
    foot kicking each rotational axis at K 0-100 (torque ramps of 300 N m/s to 10 and 15 N
    m, and an 8 N m sine at 3 Hz) on the nominal unit and drawn builds 7 and 11; 4.4-4.9 N
    in the benchmark's boundary run (see ``SIDE_ARM_PERIODS``); 5.4 N in the lab's 2 deg
    pitch sweep to 40 Hz, whose inertial force reaches 39 N. Without the friction the
    library read 13.0 N (draw 11, seals of 4.5 N), without the inertial force a kick 19.5
    N; with the acceleration taken as the present period's (it is the previous one's, a
    difference of differences) the 2 deg sweep read 18.9 N at 20 Hz.
    Vertically the residual reached 24 N before the unit's load bias was taken out (a
    platform a kilogram off its model, the transducers' spans, the seals in a heave): the
    vertical check (``lift_floor``) judges only with it. Measured with the
    benchmark's scenarios: 30 N of offset on Fx or Fy is caught in 14-18 ms, where the
    following check had tripped at 46-130 ms with the platform 3-8 mm off; 20 N in 22-46
    ms. An offset much under this limit is not caught here; it acts like a patient's push
    of its size, which the following bound and the range of motion limit."""
    side_cutoff_hz: float = 25.0
    """Low-pass (Hz) on the sideways residual after the pose rate's own (the residual goes
    through that first, so that it lags as the measured acceleration does): the legs' chase
    of a sudden load rings for some 20 ms."""
    side_friction_speed: float = 0.01
    """Leg rate (m/s) over which the seals' identified friction, taken out of the sideways
    residual against each leg's measured rate, turns from one direction to the other (a
    ``tanh``'s scale): the filtered leg rate's noise at rest is a few mm/s, and a leg that
    hardly moves holds anything between its two frictions."""
    side_mass_uncertainty: float = 1.0
    """How far (kg) the platform's true mass may be from the model the sideways check takes
    its inertial force out with (``ControllerConfig.platform_mass``, 2.5 kg): a build with a
    heavier plate or straps weighs up to 3.5 kg (docs/plant.md). The check's limit grows by
    this times the sideways acceleration the plate's measured turning gives its centre of
    mass (``controller.side_allowance``; translations do not count), so a foot that swings
    a heavy plate fast is not taken for a sensor fault, while a sensor offset, which
    appears before the plate moves, meets the limit as it is. Measured: drawn
    build 27 (3.39 kg, its centre of mass 12 mm lower than the model's) kicked in roll or
    pitch read 18.1-18.6 N sideways against the 18 N limit; 10.1 N with its plate set to
    2.5 kg and nothing else changed."""
    side_com_uncertainty: float = 0.025
    """...and how far (m) its centre of mass may be from the model's (2 cm up or down, 1 cm
    each way across, docs/plant.md): the limit grows by this times the heaviest plate's mass
    (``platform_mass`` plus ``side_mass_uncertainty``) times the platform's angular
    acceleration, the sideways force such an error leaves when the plate turns fast."""
    side_leg_mass_uncertainty: float = 0.1
    """...and how far (kg) each piston's mass may be from the model's (0.20-0.35 kg against
    0.25): the limit grows by this times each leg's acceleration along it, sideways."""
    side_turn_floor: float = 20.0
    """Angular acceleration (rad/s2) of the measured pose that the allowances above leave
    out: its noise. The acceleration is a difference of differences of the pose from 24 um
    leg counts: on the nominal unit (seeds 1-3, 10 s each) it read 6 rad/s2 on average and
    at most 19 held at home, 8-12 and at most 27 mid-exercise and while the patient pushed
    (the exercise's own is under 2). With no floor the allowance stood at 1-3 N, which let
    a 15 N sideways offset at home go uncaught; with it, at most 0.2 N. A foot that swings
    the plate turns it at hundreds."""
    side_leg_rough: float = 0.25e-3
    """A leg reading whose second difference between three reads (1 ms apart) is larger than
    this (m; 250 m/s2, three times what a leg at its speed limit reversing within 10 ms
    makes, over five times the rms a healthy sensor's 15 um of noise and its 24 um counts
    give) makes the measured pose no acceleration for the sideways check (a noisy or
    loose leg sensor is the leg rules' to name, not a force sensor fault): measured, a leg
    sensor's noise burst (0.5 mm rms) tripped it as FORCE_SENSOR 2-16 ms before the leg
    jump rule named the leg."""
    side_rough_reads: int = 30
    """...for this many reads after (30 ms): the pose rate's and the check's low-passes
    have forgotten such a read by then."""
    turn_floor: float = 1.0
    """Moment residual about the ankle (N m, each of roll, pitch and yaw, base frame) that
    the moment cross-check always forgives, beside the legs' friction and the inertia
    (below): what the model leaves at any speed, the plate's weight off its model (1 kg,
    its centre of mass 1-2 cm off: 0.3-0.8 N m as it tilts) and each transducer's zero.
    The check filters and arms as the sideways one does (``side_cutoff_hz``,
    ``SIDE_ARM_PERIODS``) and takes the platform's inertia out with the same model. A
    torque offset of the force/torque sensor acts on the loop as a patient's torque would
    (on a compliant axis it turns the platform; on a held one the load compensation feeds
    it to the legs), but the legs then carry nothing of it: it stays in their residual,
    unlike a real torque, which they carry."""
    turn_stick: float = 2.0
    """Share of a leg's identified seal friction (``Calibration.leg_friction``) its seals may
    hold when the leg does not slide (its measured rate well under
    ``side_friction_speed``): breakaway friction is 1.2-2 times the Coulomb friction
    (docs/plant.md), and a resting leg holds anything up to it either way. The allowance
    for each leg, times its moment arm about the axis, shrinks from this to ``turn_slip``
    as the leg's rate rises (``tanh(rate / side_friction_speed)``)."""
    turn_slip: float = 1.0
    """...and how far a sliding leg's friction may be from its identified value, as a share
    of it: the start-up identification measures it once, in a slow heave with nobody on the
    plate; the seals' friction grows with the chamber pressures and falls past the Stribeck
    speed. A whole share: the check is there for a torque that moves the platform, not for
    the legs' friction."""
    turn_viscous: float = 35.0
    """...and per leg, this (N s/m) times its measured rate: the seals' viscous friction
    (2-20 N s/m, not identified) and what the pressures' latency leaves in a fast swing.
    Measured: a foot swinging drawn build 27's roll at K 0 with an 8 N m sine at 3 Hz (200
    deg/s, its legs at 0.35 m/s; viscous seals of 19 N s/m, a 3.39 kg plate) left 4.2 N m
    at the fastest against 0.5-2 N m at the reversals: about 30 N s/m over the legs' arms.
    At 25 N s/m that kick took 0.91 of its allowance. A phantom torque is caught before the
    platform moves that fast: at 0.1 m/s this adds 0.3-1.3 N m."""
    turn_friction_unidentified: float = 5.0
    """Without a calibration (no friction identified, nothing taken out), the friction each
    leg may hold in place of its identified one (N): the top of the plausible range
    (docs/plant.md). Uncalibrated the check is only a broad one."""
    pressure_zero_unidentified: float = 10.0e3
    """Without a calibration (no transducer zero read, nothing subtracted), how far (Pa) each
    chamber transducer's zero may be off: the type's zero band, 1 % of its 1 MPa span (the
    plant draws each channel's zero within it; docs/plant.md). A leg's cap side and rod
    side off by it in opposite ways make its chambers seem to push (or hold) up to that
    times both areas, 9.3 N on the design's cylinder, that no sensor is at fault for: the
    moment check (:func:`device.controller.turn_allowance`) allows for it leg by leg, as
    it does for the seals. Uncalibrated, drawn builds 47 and 48 went 1-1.4 % over the
    moment allowance without it in the library (7 of 600 runs on builds 0-49). The wrench
    check's 45 N covers the zeros (an 80 N vertical offset, uncalibrated, reaches 77 N in
    its residual: allowing 9.3 N a leg there too would hide it)."""
    turn_periods: int = 1
    """Control periods over the allowance before the trip, as ``side_periods``."""
    lift_floor: float = 10.0
    """Vertical residual force at the ankle (N) that the vertical cross-check always forgives,
    beside what each leg's seals may hold times its vertical share (as the moment check's:
    ``turn_stick``, ``turn_slip``, ``turn_viscous``), the inertial model's errors at the
    measured vertical acceleration (``side_mass_uncertainty``, ``side_leg_mass_uncertainty``)
    and the force sensor's span (``lift_ft_span``); filtered and armed as the sideways check.
    Judged only on a unit whose load bias was identified (``Calibration.load_bias``): without
    it the plate's weight off its model (up to 10 N) and the transducers' spans (up to 4 N a
    leg) stand in the vertical residual (24 N over drawn builds 0-19), and a vertical offset
    stays the wrench check's. With it, the allowance on the calibrated nominal unit is 22-25
    N and the healthy residual at most 4.3 N; over the exercise library on the nominal unit
    and drawn builds 0-73 (912 runs of 10 s) the residual took at most 0.42 of its
    allowance, and never exceeded the seals' and inertia's part alone (the floor is margin
    for what was not run). 30 N on Fz, which acts on the loop as a foot pushing 30 N, is
    named in 22-28 ms (56 as the legs settled when ``SIDE_ARM_PERIODS`` was 0.1 s); 20 N
    either way in 2 of 4 runs; 10 N never."""
    lift_ft_span: float = 0.02
    """...and this share of the vertical load the force sensor reads: its span error
    (docs/plant.md, up to 2 %)."""
    side_periods: int = 1
    """Control periods (4 ms) over the limit before the trip: the filters are the averaging.
    With a second period, a 30 N offset mid-exercise was caught up to 16 ms later (the
    residual swings while the legs chase the phantom load)."""
    wrench_torque_limit: float = 5.5
    """...and residual moment about the ankle (N m, magnitude): largest healthy value
    measured as above 3.8 N m (2.1 nominal), from the stiffest seals' friction. A torque
    offset smaller than this is indistinguishable from friction, and acts on the platform
    like a patient's torque of that size (bounded by the range of motion)."""
    following_translation: float = 2.0e-3
    """In task mode, measured pose further than this (m) from the commanded pose along x, y
    or z is a following error: something pushes the platform that the loop cannot hold
    (a force/torque reading of a load that is not there, fed to the legs by the load
    compensation; a valve or leak the loop cannot overcome). The commanded pose includes
    the rendered compliance, so a foot moving a compliant axis is not an error. Largest
    healthy value over every library exercise with a relaxed and a resisting foot on the
    nominal plant and 38 drawn builds (draws 0-39 but 15 and 17, which oscillate, issue 12):
    2.11 mm (draw 11, ROM assessment; 1.7 mm on every other build). 30 N of force-sensor
    offset on Fx or Fy walked a held platform 7-9 mm within 0.5 s, below the wrench
    cross-check, before ``side_force_limit`` caught it first; this bound stops a smaller
    one at about its own size."""
    following_rotation: float = math.radians(1.5)
    """...and about roll, pitch or yaw (rad). Largest healthy value as above: 1.24 deg."""
    following_lag: float = 0.1
    """...plus the commanded speed along (about) that axis times this (s): a loop that lags
    its command by a fixed time is this far behind it at that speed. The position loop lags
    a sine by 20-80 ms (|1 - G| / w of the measured frequency responses of every axis, 0.5-40
    Hz): an exercise's own motion, or a foot swinging a compliant axis, is not an error.
    Held axes, where a false load pushes, have no command speed. The legs that turn the
    plate about the ankle also shift it when the rotation lags: in a 2 deg pitch sine at 8
    Hz the pitch lagged about 1 deg and the ankle moved 2.4 mm along x with it (dynamic
    coupling; the error at the plate's centre was no smaller). So the translational bound
    also grows by the rotation's own error times ``ankle_height`` (device.geometry, 0.1 m),
    a lever of the right size: 1.7 mm for that 1 deg. A rotation that lags little may still
    drag the plate: with no foot on it, a 2 N m push on roll at K 5 swung the plate 11.8 deg
    in 0.15 s (2.3 rad/s), and while the roll stopped on its command the ankle was 2.5 mm
    off along y. So it grows too by the lag the rotations' commanded speed allows
    (``following_lag`` times that speed, held as it decays) times the same lever."""
    following_turn: float = 0.02
    """Time constant (s) of the low-pass against which a rotation's commanded rate counts
    as changing (``following_lag``): about the position loop's own lag (12-35 ms, from the
    damping it adds to a rendered impedance, README), so a steady turn or an exercise's
    slow sine (0.14 rad/s of change at 0.1 s, a 1.4 mm allowance that let a 30 N force
    offset walk a pitching platform 7.6 mm) barely widens the bound while a plate swung and
    stopped within tens of milliseconds does."""
    following_periods: int = 2
    """Pose periods (4 ms) in a row past the bound before the trip (8 ms), against a single
    bad reading: 30 N of phantom force accelerates platform and foot about 100 mm/s within
    30 ms, so each period more lets the platform run 0.4 mm further."""
    release_gain: float = 0.1
    """While the platform is released no intake opens: a chamber whose air (p^(1/k) V, as
    compression leaves it) rose this share above the least it had since the release began,
    its pressure ``release_rise`` over its least too, is fed by an intake stuck open. The
    release stops and its exhaust holds it, its leg's other side fed to match
    (``release_balance``; device.controller.watch_release). Measured on the nominal unit,
    an intake stuck open as the strength exercise's platform was released filled its
    chamber to the supply within 0.5 s and drove its leg onto the end stop, the platform
    10 deg in roll, unseen. Held at home and released, a stuck intake is now held
    1.06-1.32 deg and 2.61-2.73 mm off (by its exhaust alone 1.2-1.7 deg and 3.1-3.6 mm;
    4.2-4.5 mm at a gain of 0.2, the motion coming before the chamber gained enough to be
    told apart); no healthy release of the library stopped."""
    release_rise: float = 0.1e5
    """See ``release_gain`` (Pa): a reading that moved, not the noise on a near-empty one.
    Also the least gauge pressure at which air is judged: at the atmosphere an exhaust lets
    air back in as the foot expands a vented chamber (healthy, measured: the strength
    exercise's foot drew a vented chamber to -0.07 bar and back to +0.17)."""
    release_judged: float = 1.0e5
    """A chamber above this gauge pressure (Pa) when the release began, and still above it,
    is judged by how its air falls (``release_lag``); one below can hardly carry its leg,
    and one vented below it may draw air back through its exhaust."""
    release_lag: float = 0.25
    """Once the judged chambers' median lost ``release_median`` of its air, one that lost
    less than this share of that median's loss did not vent: its exhaust stuck shut or its
    tube blocked. The release stops and every valve holds. Measured on the nominal unit, a
    cap-side exhaust stuck shut as the platform was released kept its air while the others
    vented, pushed its leg onto the end stop and the platform to 11 deg in roll, unseen."""
    release_median: float = 0.15
    """See ``release_lag``: enough loss that a chamber keeping its air is not the vent's
    first pulses (the nominal unit's chambers lose about 30 % in the first 0.5 s)."""
    release_ahead: float = 0.1
    """A released chamber still above ``release_rise`` gauge that lost this share of its
    air more than ``release_ahead_ratio`` times the judged chambers' median loss empties
    through more than its exhaust's pulses: that exhaust stuck open, or a leak. The release
    stops and its intake holds it (device.controller.watch_release). Measured on the
    nominal unit held at home, leg 1's rod-side exhaust stuck open lost 34 % of its air in
    the release's first 50 ms against a few for the others, and then ran the leg 37 mm."""
    release_ahead_ratio: float = 3.0
    """See ``release_ahead``."""
    release_window: int = 50
    """The rules of ``release_lag`` and ``release_ahead`` judge each chamber's loss twice:
    since the release began, and over a recent window, against its air's trailing average
    over about this many reads (an exponential average, 50 ms): a valve that fails halfway
    through a release changes a chamber's recent loss at once while its loss since the
    start still looks like the others'. Measured on the nominal unit held at home, an
    exhaust that stuck shut 0.5 s into the release tilted the platform 14 deg, and one
    stuck open ran its leg 9 mm, both unseen by the rules since the start. Over the recent
    window a chamber is judged while above ``release_judged`` now; the kept rule needs the
    median's recent loss at ``release_recent_median``. Measured over 588 healthy releases
    (the library x both feet, the nominal unit and drawn builds 0-47, released after a hold
    or an e-stop at a drawn moment): the least recent loss was 0.43 of the median's (the
    rule: under ``release_lag``), the most 0.043 over three times the median (the rule:
    ``release_ahead`` over); run with the rule, 564 more (builds 48-83, 0-9 and the nominal
    unit) stopped none."""
    release_recent_median: float = 0.03
    """See ``release_window``: the judged chambers' median loss against their trailing
    averages at which one that lost less than ``release_lag`` of it kept its air (a chamber
    venting steadily through its pulses loses about 3-7 % against a 50-read average)."""
    release_balance: bool = True
    """A release stopped by a stuck intake, or one named with every valve shut (the
    service's HOLD and READY, device.controller.watch_shut): its exhaust cannot hold the
    chamber (it rises toward the supply), so the leg's other chamber is fed by what the
    stuck one gained since it was named, times their areas' ratio, keeping the leg's force
    where it was (device.controller.bleed, ``HOLD_BALANCE``). Held at home with every valve
    shut (``ankle bench shutwatch``: the calibrated nominal unit, both feet, every axis
    over 3 s), each of the twelve intakes stuck open: by the exhaust alone 0.38-2.02 deg
    and 0.99-3.70 mm (leg 5's cap side the most), with the other side fed 0.11-1.49 deg
    and 0.28-2.73 mm. Measured on the nominal unit, intakes
    stuck open 0-1.5 s into a release held at home (valves 0, 2, 8, 10): without it the
    legs ran until their half-vented other chambers balanced them, up to 10.7 deg and 12.2
    mm (relaxed foot) and 7.3 deg, 13.0 mm (resisting); with it at most 2.4 deg and 4.4 mm,
    and 1.3 deg, 3.3 mm (``ankle bench shutwatch``, calibrated and held 0.3 s first: up to
    3.7 deg and 6.4 mm half a second in, over the targets). Off (False), the exhaust alone
    holds. Only after a stuck intake was named: a reading that jumped up once feeds
    nothing, as only what the chamber gained *since* it was named is matched."""
    release_refill: bool = True
    """A release stopped because a chamber emptied first (an exhaust stuck open, a leak):
    its intake feeds it back to the air the judged chambers' median share of loss since the
    start would have left it (never above its pressure at the release's start, never below
    its pressure now), not to where the stuck exhaust had already taken it; the leg's
    force is then about what the others' venting left it (device.controller.watch_release).
    Measured on the nominal unit, exhausts stuck open at 0-1 s into a release held at
    home (valves 1, 3, 9, 11), both feet: held where found, 0.80-2.25 deg and 1.98-3.68 mm;
    refilled, 0.40-1.23 deg and 0.88-1.72 mm. A reading that jumped down is the jump
    rule's first (``PRESSURE_SENSOR``, and the watch leaves its chamber alone): measured
    with offsets of -0.3 to -0.7 bar injected the same way."""
    shut_air: float = 0.05
    """With every valve shut (IDLE: the service's HOLD and READY, not released) a chamber's
    air (``p^(1/k) V``) moving this share, and its pressure ``release_rise`` the same way,
    within one ``shut_reads`` window has a valve stuck open or a leak: a VALVE trip names it
    and a valve of its own holds it (device.controller.watch_shut). Measured on the nominal
    unit held 18 s: the seals' leaks past their pistons moved each chamber's air 2-4 % (0.02
    % a window; a leg's two together 0.1 %); a stuck exhaust takes a third in 50 ms, a leak
    of a tenth of a valve 7.6 % in 0.1 s (at 10 % it was named only once its leg had sunk
    8 mm, at 5 % within 0.7 mm; a twentieth of a valve still ran 6.9 mm first, now named
    by ``shut_slow_air``)."""
    shut_reads: int = 100
    """See ``shut_air``: the window (reads, 0.1 s), the first one starting
    ``shut_settle_reads`` after the valves shut."""
    shut_settle_reads: int = 10
    """Reads after the valves shut before the first reference is taken (10 ms): the air
    on its way down the tubes (3 ms) arrives and the valves close. The whole first window
    (0.1 s) was waited for before: a valve failing in it was named only once the window
    ended, an exhaust stuck open 0-80 ms after the hold that ended the matrix's pitch
    exercise at 26-106 ms, by when its leg had sunk 4.2-12.8 mm and the platform turned
    2.8-6.1 deg, and a rod-side intake stuck then was not named at all (1.7-1.9 deg,
    2.5-3.0 mm). Healthy, measured on 132 holds after the library's exercises stopped at
    drawn moments (the nominal unit and drawn builds 0-9, both feet): from a reference
    taken 3 reads after the shut, no chamber's air moved more than 0.5 % over the next
    window (``shut_air`` is 5 %), 0.6 % from 10 reads. The plant has no thermal settling:
    a real chamber's air cools to the walls after a fill, but a hold begins after the
    loop's small corrections at rest, and a fill of 0.1 bar cooling whole moves a chamber's
    air about 1 %."""
    shut_slow_air: float = 0.04
    """A slower leak, judged against each chamber's trailing averages over about
    ``shut_slow_reads`` reads: its air this share away from its average, and its pressure
    ``release_rise`` the same way. ``shut_air`` in one window sets a floor on the rate it
    sees (5 % in 0.1 s): a leak of a twentieth of a valve (3.8 % in 0.1 s) ran the platform
    3.6 deg and 6.9 mm and was never named on some holds. The average's lag turns a rate
    into a share (a steady 13 % a second is 4 % against a 0.3 s average), so this rule
    sees a leak faster than about 13 % of a chamber's air a second; the chambers' settling
    after motion (their air warming or cooling to the walls, a foot still pushing) stays
    under it: over 372 holds of 10 s after the library's exercises stopped at drawn moments
    (the nominal unit and drawn builds 0-29, both feet) the largest was 1.9 % of a
    chamber's air with 0.088 bar; run with the rule, 396 holds of 20 s (the nominal unit,
    builds 0-7 and 30-53) tripped none."""
    shut_slow_reads: int = 300
    """See ``shut_slow_air`` (reads, 0.3 s)."""
    shut_leg_air: float = 0.02
    """A leak slower than ``shut_slow_air`` sees, judged on a leg's air (its two chambers'
    together, so what its piston's clearance passes from one side to the other does not
    count) against its trailing average over about ``shut_leg_reads`` reads, less what its
    valves' closed seats and its piston would have moved by their model (:func:`leak_terms`,
    at the rates that explain the other five legs best), less what the transducers' spans
    (``observer_span_error``) and, on a unit whose zeros were not read, their zeros
    (``pressure_zero_unidentified``) leave unknown of that: a leg that lost this share of
    its air more, and more than cooling may take (``shut_thermal_time``), has a leak; of
    its two chambers the one that lost more is named and held by its intake
    (device.controller.watch_shut). Before, a leak of a hundredth of a valve (about 2 % of
    its leg's air a second) tilted the resting platform 7 deg and moved it 8 mm in 15 s,
    unnamed. A leg's air alone does not tell: a worn seat passes 0.5 NL/min, as much as a
    leak of a two-hundredth of a valve, and resting 30 s the drawn builds' legs lost up to
    12 % (their exhausts' seats) or gained 20 % (their intakes', into a chamber near the
    atmosphere); against the model the most a healthy leg lost was 0.64 % (recorded: 120
    holds after the library's exercises and 42 rests after homing, the nominal unit and
    drawn builds 0-19, both feet; 1.45 % with both of the model's indices at the observer's
    1.2). Without the spans' allowance drawn build 33 (seats of 0.50 NL/min, a leg's two
    transducers 1.4 % low) took 0.79 of this share. Measured with the rule on the
    calibrated nominal unit and drawn builds 1, 3, 6, 10, 17 and 33, both feet, leaks of
    0.005-0.05 of a valve on chambers 0, 2, 4-7, 9 and 11, injected 0.3 s or 5 s into READY
    after homing or into a hold after the library's exercises: 448 of 448 named on their
    chamber; a two-hundredth of a valve in 1.20-4.86 s (the slowest just after homing,
    whose fills' cooling is allowed for), a hundredth in 0.54-2.06 s; the platform at most
    1.18 deg and 1.96 mm off its healthy twin when named, 1.46 deg and 2.27 mm over the
    next seconds, held. A three-hundredth: 47 of 64 named within 8 s, at most 1.36 deg and
    1.82 mm off. Healthy: 492 holds of 20 s after the library's exercises stopped at drawn
    moments (the nominal unit and drawn builds 0-39, both feet) took at most 0.24 of this
    share, 62 rests of 30 s after homing (builds 0-29) 0.07, 14 of 120 s (the builds with
    the most worn seats) 0.08, and 36 holds on builds 1, 16 and 33 with their spans drawn
    up to 2 % off and seats of 0.5 NL/min 0.35; none named."""
    shut_leg_reads: int = 3000
    """See ``shut_leg_air`` (reads, 3 s): the slowest leak named loses this share over this
    time, about 0.7 % of its leg's air a second."""
    shut_charge_index: float = 1.4
    """Polytropic index of air coming into a chamber through a seat or across its piston
    (adiabatic, as the observer's ``observer_polytropic`` notes after Richer and Hurmuzlu
    2000), and ``shut_discharge_index`` of air leaving it (near isothermal): the model of
    ``shut_leg_air``. With both at the observer's 1.2 the healthy holds below left up to
    1.45 % instead of 0.64 %, still under the threshold."""
    shut_discharge_index: float = 1.0
    """See ``shut_charge_index``."""
    shut_seat_most: float = 2.0
    """NL/min from 6 bar gauge to the atmosphere: the most the fit of ``shut_leg_air`` may
    take a closed valve's seat to pass (four times a worn one), and ``shut_piston_most``
    a piston's clearance (four times the most a plausible build's passes): a fit on legs
    whose air hardly moves (just after the shut, or at rest near the seats' balance) is
    not let explain a leak away as seats."""
    shut_piston_most: float = 8.0
    """See ``shut_seat_most``."""
    shut_thermal_time: float = 1.0
    """s: a real chamber's air, filled quickly (adiabatically), gives its heat back to the
    walls over about this long ("for a second or so", :data:`device.identify.LOST_MAX`),
    and its ``p^(1/k) V`` falls as it does: a fill of ``dp`` at most ``(1 - 1/1.4) dp / k``
    of the chamber's absolute pressure. The plant has no such cooling. So what the valves
    filled within about this time before the shut (each chamber's reading above its low
    envelope, ``M_FILLED``) is allowed for on top of ``shut_leg_air`` as a share of the
    leg's air, decaying over this time and ``shut_leg_reads`` together: a settling of this
    time constant shows against the trailing average at most 0.58 of its whole and within
    1 % of that decay (computed). Fills alone are counted, though a vented chamber warms
    back and gains: the worst case. Measured over the healthy holds of ``shut_leg_air``:
    up to 3.3 % of a leg's air after an exercise, 6.2 % after homing, which pressurises
    the chambers; the allowance makes a leak present at the shut wait for it (a
    two-hundredth of a valve named up to 4.86 s after it began 0.3 s after homing, 4.23 s
    5 s after)."""


class SupervisionParams(NamedTuple):
    atm: float
    open_below: float
    short_above: float
    pressure_jump: float
    supply_low: float
    supply_resume: float
    supply_loss: float
    supply_high: float
    supply_low_reads: int
    supply_resume_reads: int
    supply_trip_reads: int
    intake_margin: float
    ft_force_sat: float
    ft_torque_sat: float
    ft_saturated_reads: int
    ft_zero_reads: int
    ft_frozen_reads: int
    ft_force_jump: float
    ft_torque_jump: float
    ft_torque_step: float
    leg_jump: float
    leg_stuck_force: float
    leg_stuck_floor: float
    leg_stuck_seals: float
    leg_stuck_error: float
    leg_stuck_target_move: float
    leg_stuck_reads: int
    leg_stuck_blame_reads: int
    leg_blind_reads: int
    leg_blind_band: float
    pressure_frozen_periods: int
    pressure_frozen_headroom: float
    supply_frozen_reads: int
    supply_draw_air: float
    supply_draw_edge: float
    air_window: int
    air_per_slot: float
    air_one_sided: float
    air_headroom: float
    air_open_after: int
    air_min_expected: float
    air_min_fraction: float
    air_mirror_share: float
    obs_conductance: float
    obs_b: float
    obs_k: float
    obs_flow_tol: float
    obs_pulse_time: float
    obs_edge_margin: float
    obs_span: float
    obs_volume_tol: float
    obs_floor: float
    obs_alpha: float
    obs_periods: int
    obs_wake_periods: int
    obs_wake_window: int
    answer_decay: float
    answer_share: float
    answer_min_air: float
    answer_volume_error: float
    answer_floor: float
    answer_periods: int
    slot_time: float
    valve_window: int
    valve_slots: int
    valve_min_change: float
    valve_headroom: float
    residual_alpha: float
    residual_limit: float
    residual_periods: int
    balance_one_leg_share: float
    balance_steady_floor: float
    balance_steady_periods: int
    wrench_force_limit: float
    wrench_torque_limit: float
    side_force_limit: float
    side_alpha: float
    side_periods: int
    side_friction_speed: float
    side_mass_tol: float
    side_com_tol: float
    side_leg_mass_tol: float
    side_turn_floor: float
    side_leg_rough: float
    side_rough_reads: int
    turn_floor: float
    turn_stick: float
    turn_slip: float
    turn_viscous: float
    turn_friction_unidentified: float
    zero_hold: float  # N a leg's chambers may seem to push from unread transducer zeros
    turn_periods: int
    lift_floor: float
    lift_ft_span: float
    following_translation: float
    following_rotation: float
    following_lag: float
    following_lever: float
    following_decay: float
    following_turn_decay: float
    following_periods: int
    release_gain: float
    release_rise: float
    release_judged: float
    release_lag: float
    release_median: float
    release_ahead: float
    release_ahead_ratio: float
    release_window: int
    release_recent_median: float
    release_balance: bool
    release_refill: bool
    shut_air: float
    shut_reads: int
    shut_settle_reads: int
    shut_slow_air: float
    shut_slow_reads: int
    shut_leg_air: float
    shut_leg_reads: int
    shut_charge: float
    shut_discharge: float
    shut_seat_most: float  # the fit's largest seat rate, in leak_terms' units (m3/s)
    shut_piston_most: float  # ...and piston's
    shut_cooling: float  # share of a fill's dp / p that cooling takes of the air
    shut_zero: float  # Pa a reading's zero may be off (0: the zeros were read)
    shut_fill_alpha: float  # the fill envelope's rise per read
    shut_allow_decay: float  # the cooling allowance's decay per read
    read_dt: float


def build(
    config: SupervisionConfig,
    atmosphere: float,
    control_dt: float,
    identified: bool = False,
    lever: float = 0.0,
    zero_area: float = 0.0,
    read_dt: float = 1.0e-3,
) -> SupervisionParams:
    """The compiled thresholds; ``identified``: the calibration knows each valve's air per
    pulse (device.identify), and the air observer forgives less; ``lever``: the ankle's
    height above the platform's joint plane (m, see ``following_lag``); ``zero_area``: on
    a unit whose transducer zeros were not read, a leg's cap and rod areas together (m2),
    over which ``pressure_zero_unidentified`` is allowed for (0: the zeros were read)."""
    zero = config.pressure_zero_unidentified
    if not (math.isfinite(zero) and zero >= 0.0 and zero_area >= 0.0):
        raise ValueError(
            "pressure_zero_unidentified must be finite and 0 or more (Pa), zero_area 0 or more"
        )
    if not (config.leg_stuck_floor >= 0.0 and config.leg_stuck_seals >= 0.0):
        raise ValueError("leg_stuck_floor and leg_stuck_seals must be 0 or more")
    if config.leg_blind_reads < 1 or not config.leg_blind_band >= 0.0:
        raise ValueError("leg_blind_reads must be 1 or more and leg_blind_band 0 or more")
    if not (
        0.0 < config.release_gain < 10.0
        and 0.0 < config.release_rise < 1.0e6
        and 0.0 <= config.release_judged < 1.0e6
        and 0.0 < config.release_lag < 1.0
        and 0.0 < config.release_median < 1.0
        and 0.0 < config.release_ahead < 1.0
        and 1.0 <= config.release_ahead_ratio < 100.0
        and config.release_window >= 1
        and 0.0 < config.release_recent_median < 1.0
        and 0.0 < config.shut_air < 1.0
        and config.shut_reads >= 1
        and config.shut_settle_reads >= 1
        and 0.0 < config.shut_slow_air < 1.0
        and config.shut_slow_reads >= 1
        and 0.0 < config.shut_leg_air < 1.0
        and config.shut_leg_reads >= 1
    ):
        raise ValueError(
            "release_gain must be in (0, 10), release_rise in (0, 1e6) Pa, release_judged in "
            "[0, 1e6) Pa, release_lag, release_median, release_recent_median, release_ahead "
            "shut_air and shut_slow_air in (0, 1), release_ahead_ratio in [1, 100), "
            "release_window, shut_reads, shut_settle_reads and shut_slow_reads 1 or more; "
            "shut_leg_air in (0, 1) and shut_leg_reads 1 or more"
        )
    if not (
        1.0 <= config.shut_charge_index <= 2.0
        and 1.0 <= config.shut_discharge_index <= 2.0
        and config.shut_seat_most > 0.0
        and config.shut_piston_most > 0.0
        and config.shut_thermal_time > 0.0
        and read_dt > 0.0
    ):
        raise ValueError(
            "shut_charge_index and shut_discharge_index must be in [1, 2], shut_seat_most "
            "and shut_piston_most over 0 NL/min, shut_thermal_time over 0 s"
        )
    # NL/min from 6 bar gauge to the atmosphere, laminar, as leak_terms' rate: the air
    # (p^(1/k) V, p in atmospheres) it moves a second per unit of its term.
    rated = ((atmosphere + 6.0e5) / atmosphere) ** 2 - 1.0
    per_nl_min = 1.0e-3 / 60.0 * (1.0e5 / atmosphere) / (config.observer_polytropic * rated)
    leg_reads_s = config.shut_leg_reads * read_dt
    if not (math.isfinite(config.turn_floor) and config.turn_floor > 0.0):
        raise ValueError("turn_floor must be a finite moment > 0 (N m)")
    if not (math.isfinite(config.lift_floor) and config.lift_floor > 0.0):
        raise ValueError("lift_floor must be a finite force > 0 (N)")
    if not (math.isfinite(config.lift_ft_span) and config.lift_ft_span >= 0.0):
        raise ValueError("lift_ft_span must be a finite share, 0 or more")
    for name in ("turn_stick", "turn_slip", "turn_viscous", "turn_friction_unidentified"):
        value = getattr(config, name)
        if not (math.isfinite(value) and value >= 0.0):
            raise ValueError(f"{name} must be finite and 0 or more")
    if config.turn_periods < 1:
        raise ValueError("turn_periods must be 1 or more")
    if config.supply_frozen_reads < 0:
        raise ValueError("supply_frozen_reads must be 0 (not judged) or more")
    if not (config.supply_draw_air > 0.0 and config.supply_draw_edge >= 0.0):
        raise ValueError("supply_draw_air must be > 0 (Pa m3) and supply_draw_edge 0 s or more")
    if not config.ft_torque_step > 0.0:
        raise ValueError("ft_torque_step must be a moment > 0 (N m)")
    if not (config.answer_window > 0.0 and 0.0 < config.answer_share <= 1.0):
        raise ValueError("answer_window must be > 0 (s) and answer_share over 0, at most 1")
    if not (config.answer_min_air > 0.0 and config.answer_periods >= 1):
        raise ValueError("answer_min_air must be > 0 (Pa m3) and answer_periods 1 or more")
    for name in ("answer_dead_volume_error", "answer_floor"):
        value = getattr(config, name)
        if not (math.isfinite(value) and value >= 0.0):
            raise ValueError(f"{name} must be finite and 0 or more")
    return SupervisionParams(
        atm=atmosphere,
        open_below=config.pressure_open_below,
        short_above=config.pressure_short_above,
        pressure_jump=config.pressure_jump,
        supply_low=config.supply_low,
        supply_resume=config.supply_resume,
        supply_loss=config.supply_loss,
        supply_high=config.supply_high,
        supply_low_reads=config.supply_low_reads,
        supply_resume_reads=config.supply_resume_reads,
        supply_trip_reads=config.supply_trip_reads,
        intake_margin=config.intake_margin,
        ft_force_sat=config.ft_saturated_fraction * config.ft_force_full_scale,
        ft_torque_sat=config.ft_saturated_fraction * config.ft_torque_full_scale,
        ft_saturated_reads=config.ft_saturated_reads,
        ft_zero_reads=config.ft_zero_reads,
        ft_frozen_reads=config.ft_frozen_reads,
        ft_force_jump=config.ft_force_jump,
        ft_torque_jump=config.ft_torque_jump,
        ft_torque_step=config.ft_torque_step,
        leg_jump=config.leg_jump,
        leg_stuck_force=config.leg_stuck_force,
        leg_stuck_floor=config.leg_stuck_floor,
        leg_stuck_seals=config.leg_stuck_seals,
        leg_stuck_error=config.leg_stuck_error,
        leg_stuck_target_move=config.leg_stuck_target_move,
        leg_stuck_reads=config.leg_stuck_reads,
        leg_stuck_blame_reads=config.leg_stuck_blame_reads,
        leg_blind_reads=config.leg_blind_reads,
        leg_blind_band=config.leg_blind_band,
        pressure_frozen_periods=config.pressure_frozen_periods,
        pressure_frozen_headroom=config.pressure_frozen_headroom,
        supply_frozen_reads=config.supply_frozen_reads,
        supply_draw_air=config.supply_draw_air,
        supply_draw_edge=config.supply_draw_edge,
        air_window=config.air_window_periods,
        air_per_slot=config.air_per_slot,
        air_one_sided=config.air_one_sided,
        air_headroom=config.air_headroom,
        air_open_after=config.air_open_after_slots,
        air_min_expected=config.air_min_expected,
        air_min_fraction=config.air_min_fraction,
        air_mirror_share=config.air_mirror_share,
        obs_conductance=config.valve_conductance,
        obs_b=config.valve_critical_ratio,
        obs_k=config.observer_polytropic,
        obs_flow_tol=config.observer_flow_tolerance_identified
        if identified
        else config.observer_flow_tolerance,
        obs_pulse_time=config.observer_pulse_time_identified
        if identified
        else config.observer_pulse_time,
        obs_edge_margin=config.observer_pulse_edge_margin,
        obs_span=config.observer_span_error,
        obs_volume_tol=config.observer_volume_tolerance,
        obs_floor=config.observer_floor,
        obs_alpha=1.0 - math.exp(-2.0 * math.pi * config.observer_cutoff_hz * control_dt),
        obs_periods=config.observer_periods,
        obs_wake_periods=config.observer_wake_periods,
        obs_wake_window=config.observer_wake_window,
        answer_decay=math.exp(-control_dt / config.answer_window),
        answer_share=config.answer_share,
        answer_min_air=config.answer_min_air,
        answer_volume_error=config.answer_dead_volume_error,
        answer_floor=config.answer_floor,
        answer_periods=config.answer_periods,
        slot_time=control_dt / 28,
        valve_window=config.valve_window_periods,
        valve_slots=math.ceil(config.valve_duty_fraction * 28 * config.valve_window_periods),
        valve_min_change=config.valve_min_change,
        valve_headroom=config.valve_headroom,
        residual_alpha=1.0 - math.exp(-2.0 * math.pi * config.residual_cutoff_hz * control_dt),
        residual_limit=config.residual_limit,
        residual_periods=config.residual_periods,
        balance_one_leg_share=config.balance_one_leg_share,
        balance_steady_floor=config.balance_steady_floor,
        balance_steady_periods=config.balance_steady_periods,
        wrench_force_limit=config.wrench_force_limit,
        wrench_torque_limit=config.wrench_torque_limit,
        side_force_limit=config.side_force_limit,
        side_alpha=1.0 - math.exp(-2.0 * math.pi * config.side_cutoff_hz * control_dt),
        side_periods=config.side_periods,
        side_friction_speed=config.side_friction_speed,
        side_mass_tol=config.side_mass_uncertainty,
        side_com_tol=config.side_com_uncertainty,
        side_leg_mass_tol=config.side_leg_mass_uncertainty,
        side_turn_floor=config.side_turn_floor,
        side_leg_rough=config.side_leg_rough,
        side_rough_reads=config.side_rough_reads,
        turn_floor=config.turn_floor,
        lift_floor=config.lift_floor,
        lift_ft_span=config.lift_ft_span,
        turn_stick=config.turn_stick,
        turn_slip=config.turn_slip,
        turn_viscous=config.turn_viscous,
        turn_friction_unidentified=config.turn_friction_unidentified,
        zero_hold=config.pressure_zero_unidentified * zero_area,
        turn_periods=config.turn_periods,
        following_translation=config.following_translation,
        following_rotation=config.following_rotation,
        following_lag=config.following_lag,
        following_lever=lever,
        following_decay=math.exp(-control_dt / config.following_lag),
        following_turn_decay=math.exp(-control_dt / config.following_turn),
        following_periods=config.following_periods,
        release_gain=config.release_gain,
        release_rise=config.release_rise,
        release_judged=config.release_judged,
        release_lag=config.release_lag,
        release_median=config.release_median,
        release_ahead=config.release_ahead,
        release_ahead_ratio=config.release_ahead_ratio,
        release_window=config.release_window,
        release_recent_median=config.release_recent_median,
        release_balance=config.release_balance,
        release_refill=config.release_refill,
        shut_air=config.shut_air,
        shut_reads=config.shut_reads,
        shut_settle_reads=config.shut_settle_reads,
        shut_slow_air=config.shut_slow_air,
        shut_slow_reads=config.shut_slow_reads,
        shut_leg_air=config.shut_leg_air,
        shut_leg_reads=config.shut_leg_reads,
        shut_charge=config.shut_charge_index,
        shut_discharge=config.shut_discharge_index,
        shut_seat_most=config.shut_seat_most * per_nl_min,
        shut_piston_most=config.shut_piston_most * per_nl_min,
        shut_cooling=(1.0 - 1.0 / config.shut_charge_index) / config.observer_polytropic,
        shut_zero=config.pressure_zero_unidentified if zero_area > 0.0 else 0.0,
        shut_fill_alpha=1.0 - math.exp(-read_dt / config.shut_thermal_time),
        shut_allow_decay=math.exp(-read_dt / (config.shut_thermal_time + leg_reads_s)),
        read_dt=read_dt,
    )


@njit_inline
def check_reading(
    monitor: NDArray[np.float64],
    counters: NDArray[np.int64],
    sensors: NDArray[np.float64],
    q: SupervisionParams,
    moving: bool,
    leg_target: NDArray[np.float64],
    sensor_zero: NDArray[np.float64],
    leg_friction: NDArray[np.float64],
    still: NDArray[np.int64],
    drawing: bool = False,
) -> tuple[int, int]:
    """Checks of one fresh raw sensor vector (1 kHz): (trip code, channel), (0, -1) if fine.
    ``leg_target`` is in the calibrated frame, ``sensor_zero`` the calibration's zeros,
    ``leg_friction`` each leg's identified seal friction (N, 0 where none), ``still`` per
    pressure channel (13), then per force/torque channel (6), the reads in a row its
    reading may stay the same (0: not judged so; ``Calibration.still_reads``), ``drawing``
    whether an intake draws from the supply in this control period
    (``supply_frozen_reads``).

    The first fault found is the one returned, but every check runs on every read and keeps
    its references: after a trip the readings are still taken (device.controller.
    sensor_task, for the post-trip hold), and a reference left at the trip's read would
    take a chamber or a leg that moved since for a sensor that jumped."""
    code, part = Trip.NONE, -1
    counters[C_READS] += 1
    first = counters[C_READS] == 1
    # Pressure transducers: open wire, short, a jump no air makes, or a reading that stood
    # still longer than its noise lets a live one, whatever the mode.
    for c in range(13):
        if sensors[c] < q.open_below or sensors[c] > q.short_above:
            if code == Trip.NONE:
                code, part = Trip.PRESSURE_SENSOR, c
        if not first and abs(sensors[c] - monitor[M_P_READ + c]) > q.pressure_jump:
            if code == Trip.NONE:
                code, part = Trip.PRESSURE_SENSOR, c
    for c in range(13):
        changed = first or sensors[c] != monitor[M_P_READ + c]
        if c < 12 and changed and not first:
            monitor[M_P_MOVED + c] = 1.0
        monitor[M_P_READ + c] = sensors[c]
        counters[C_P_STILL + c] = 0 if changed else counters[C_P_STILL + c] + 1
        if still[c] > 0 and counters[C_P_STILL + c] >= still[c]:
            if code == Trip.NONE:
                code, part = Trip.PRESSURE_SENSOR, c
    # The supply's reading, while an intake draws from it (C_P_STILL is 0 where it changed).
    if counters[C_P_STILL + 12] == 0:
        counters[C_SUPPLY_DRAWN] = 0
    elif drawing:
        counters[C_SUPPLY_DRAWN] += 1
    if q.supply_frozen_reads > 0 and counters[C_SUPPLY_DRAWN] >= q.supply_frozen_reads:
        if code == Trip.NONE:
            code, part = Trip.PRESSURE_SENSOR, 12
    # The supply.
    supply = sensors[12] - q.atm
    counters[C_SUPPLY_LOSS] = counters[C_SUPPLY_LOSS] + 1 if supply < q.supply_loss else 0
    counters[C_SUPPLY_HIGH] = counters[C_SUPPLY_HIGH] + 1 if supply > q.supply_high else 0
    counters[C_SUPPLY_LOW] = counters[C_SUPPLY_LOW] + 1 if supply < q.supply_low else 0
    counters[C_SUPPLY_OK] = counters[C_SUPPLY_OK] + 1 if supply > q.supply_resume else 0
    if counters[C_SUPPLY_LOW] >= q.supply_low_reads:
        counters[C_LOW_FLAG] = 1
    elif counters[C_SUPPLY_OK] >= q.supply_resume_reads:
        counters[C_LOW_FLAG] = 0
    if moving and counters[C_SUPPLY_LOSS] >= q.supply_trip_reads:
        if code == Trip.NONE:
            code, part = Trip.SUPPLY_LOSS, 12
    if moving and counters[C_SUPPLY_HIGH] >= q.supply_trip_reads:
        if code == Trip.NONE:
            code, part = Trip.SUPPLY_HIGH, 12
    # The force/torque sensor.
    saturated = False
    zero = True
    same = not first
    for k in range(6):
        v = sensors[19 + k]
        jump = q.ft_force_jump if k < 3 else q.ft_torque_jump
        if moving and not first and abs(v - monitor[M_FT_PREV + k]) > jump:
            if code == Trip.NONE:
                code, part = Trip.FORCE_SENSOR, k
        if k >= 3 and not first and abs(v - monitor[M_FT_PREV + k]) > q.ft_torque_step:
            counters[C_FT_STEPPED] = 1
        limit = q.ft_force_sat if k < 3 else q.ft_torque_sat
        if abs(v) >= limit:
            saturated = True
        if v != 0.0:
            zero = False
        stood = not first and v == monitor[M_FT_PREV + k]
        same = same and stood
        counters[C_FT_STILL + k] = counters[C_FT_STILL + k] + 1 if stood else 0
        monitor[M_FT_PREV + k] = v
    counters[C_FT_SAT] = counters[C_FT_SAT] + 1 if saturated else 0
    counters[C_FT_ZERO] = counters[C_FT_ZERO] + 1 if zero else 0
    counters[C_FT_SAME] = counters[C_FT_SAME] + 1 if same else 0
    if (
        counters[C_FT_SAT] >= q.ft_saturated_reads
        or counters[C_FT_ZERO] >= q.ft_zero_reads
        or counters[C_FT_SAME] >= q.ft_frozen_reads
    ) and code == Trip.NONE:
        code, part = Trip.FORCE_SENSOR, -1
    # One channel dead or frozen alone (the whole sensor's rules above want all six): it
    # stood still longer than its noise lets a live one (tens of reads, after theirs).
    for k in range(6):
        if still[13 + k] > 0 and counters[C_FT_STILL + k] >= still[13 + k]:
            if code == Trip.NONE:
                code, part = Trip.FORCE_SENSOR, k
    # Leg length sensors.
    alone = leg_alone(monitor, q)
    pushes = 0.0  # the loop's pushes' sum of squares (N^2)
    for i in range(6):
        pushes += monitor[M_PUSH + i] ** 2
    if counters[C_POSE_ROUGH] > 0:
        counters[C_POSE_ROUGH] -= 1
    for i in range(6):
        x = sensors[13 + i]
        prev = monitor[M_LEG_PREV + i]
        prev2 = monitor[M_LEG_PREV2 + i]
        monitor[M_LEG_PREV + i] = x
        monitor[M_LEG_PREV2 + i] = prev
        if first:
            monitor[M_LEG_TARGET_SEEN + i] = leg_target[i]
            monitor[M_LEG_PREV2 + i] = x
            continue
        if abs(x - prev) > q.leg_jump:
            if code == Trip.NONE:
                code, part = Trip.LEG_SENSOR, i
        if abs(x - 2.0 * prev + prev2) > q.side_leg_rough:
            counters[C_POSE_ROUGH] = q.side_rough_reads
        push = monitor[M_PUSH + i]
        if x != prev or not moving:
            monitor[M_LEG_TARGET_SEEN + i] = leg_target[i]
            monitor[M_PUSH_SEEN + i] = push
            counters[C_LEG_STILL + i] = 0
        else:
            counters[C_LEG_STILL + i] += 1
        ran_away = abs(leg_target[i] - monitor[M_LEG_TARGET_SEEN + i]) > q.leg_stuck_target_move
        # The loop's push beyond the load it is given, or beyond the load as measured (the
        # push plus what the compensation withholds from a still leg, blind_load).
        force = q.leg_stuck_force
        if leg_friction[i] > 0.0:
            force = min(force, q.leg_stuck_floor + q.leg_stuck_seals * leg_friction[i])
        measured = push + monitor[M_BLIND + i]
        spread = pushes > 0.0 and push * push < q.balance_one_leg_share * pushes
        if spread or (i == alone and abs(monitor[M_RESIDUAL + i]) > q.balance_steady_floor):
            # Counted is only what the loop pushes beyond what it pushed while the reading
            # last changed: a frozen reading makes the loop push ever harder. A steady push
            # on a leg that stands still is the loop holding it against a force that is not
            # there. This leg alone carries a force-balance residual (leg_alone): its force
            # reading may be what is off (a transducer 0.3 bar off: 12-15 N the integral term
            # makes up, while the leg stands still on its target; over 600 runs of
            # transducers 0.3 bar off, the push alone named the leg's length sensor in
            # three); a wrong force the force balance names (check_steady). Or the loop
            # pushes several legs at once (``spread``: this one less than
            # ``balance_one_leg_share`` of their pushes' sum of squares), as against a
            # wrench, not one leg's frozen reading: a force/torque sensor off, whose phantom
            # load the compensation hands to the legs (Fy 10-14 N off with roll rendered at
            # 15 N m/rad: a healthy leg 0.6 mm short of its target held at 10 N by the loop,
            # 0.46 of the pushes, stood still 33 reads and its length sensor was named).
            seen = monitor[M_PUSH_SEEN + i]
            push = min(abs(push), abs(push - seen))
            measured = min(abs(measured), abs(measured - seen))
        pushed = max(abs(push), abs(measured)) > force
        driven = pushed or (
            ran_away and abs(leg_target[i] + sensor_zero[13 + i] - x) > q.leg_stuck_error
        )
        if moving and x == prev and driven:
            counters[C_LEG_SAME + i] += 1
            if counters[C_LEG_SAME + i] >= q.leg_stuck_reads:
                if code == Trip.NONE:
                    code, part = Trip.LEG_SENSOR, i
        else:
            counters[C_LEG_SAME + i] = 0
    return code, part


@njit_inline
def blind_load(
    monitor: NDArray[np.float64],
    counters: NDArray[np.int64],
    leg: int,
    force: float,
    q: SupervisionParams,
) -> float:
    """The load compensation (N) to give ``leg``, whose compensation would be ``force``: all
    of it while the leg's reading moves, at most ``leg_blind_band`` from what it was last
    given then while the reading stands still (``leg_blind_reads``). Records what is
    withheld (:data:`M_BLIND`) for the stuck rule of :func:`check_reading`."""
    given = force
    if counters[C_LEG_STILL + leg] >= q.leg_blind_reads:
        seen = monitor[M_BLIND_SEEN + leg]
        given = min(max(force, seen - q.leg_blind_band), seen + q.leg_blind_band)
    else:
        monitor[M_BLIND_SEEN + leg] = force
    monitor[M_BLIND + leg] = given - force
    return given


@njit_inline
def track_fills(
    monitor: NDArray[np.float64],
    pressure: NDArray[np.float64],
    q: SupervisionParams,
    first: bool,
) -> None:
    """Each chamber's low envelope (``M_FILLED``), every read in every mode: it follows a
    falling reading at once and rises back to it over about ``shut_thermal_time``, so the
    reading above it is what the valves filled lately, still warm in a real chamber. It
    starts at the first read's (``first``): what came before is not known to be a fill."""
    for c in range(12):
        low = pressure[c] if first else monitor[M_FILLED + c]
        monitor[M_FILLED + c] = min(pressure[c], low + (pressure[c] - low) * q.shut_fill_alpha)


@njit_inline
def leak_terms(
    pr: NDArray[np.float64],
    supply: float,
    q: SupervisionParams,
    seats: NDArray[np.float64],
    piston: NDArray[np.float64],
) -> None:
    """Per chamber, the rate at which its valves' closed seats (``seats``) and its piston's
    clearance (``piston``) move its air (``p^(1/k) V``), per unit of their rate: both leak
    laminar (flow ``p1^2 - p2^2``), the seats from the supply in through the intake and out
    to the atmosphere through the exhaust, the clearance in from the leg's other side; air
    coming in raises the pressure by the charging index, air going out by the discharging
    one, and ``p^(1/k)`` takes ``p^(1/k - 1) / k`` of that (the 1/k is in the rates).
    ``pr``: the chambers' absolute pressures, ``supply`` the supply's, in atmospheres."""
    for c in range(12):
        pc = pr[c]
        scale = pc ** (1.0 / q.obs_k - 1.0)
        fed = supply * supply - pc * pc  # through its intake's seat
        vented = 1.0 - pc * pc  # through its exhaust's seat (negative: out)
        fed_index = q.shut_charge if fed > 0.0 else q.shut_discharge
        vent_index = q.shut_charge if vented > 0.0 else q.shut_discharge
        seats[c] = scale * (fed_index * fed + vent_index * vented)
        across = pr[c ^ 1] * pr[c ^ 1] - pc * pc
        piston[c] = scale * (q.shut_charge if across > 0.0 else q.shut_discharge) * across


@njit_inline
def _fit_leaks(
    s11: float, s12: float, s22: float, t1: float, t2: float, q: SupervisionParams
) -> tuple[float, float]:
    """The seats' and the pistons' rates (both 0 or more, at most ``shut_seat_most`` and
    ``shut_piston_most``) that best explain the chambers' air by least squares, from the
    sums of their terms' squares and products (``s``) and of each term times the air
    (``t``)."""
    seat = max(t1 / s11, 0.0) if s11 > 0.0 else 0.0
    clearance = max(t2 / s22, 0.0) if s22 > 0.0 else 0.0
    # One rate alone: the one that takes more off the sum of squares.
    if seat * t1 >= clearance * t2:
        best_seat, best_clearance = seat, 0.0
    else:
        best_seat, best_clearance = 0.0, clearance
    det = s11 * s22 - s12 * s12
    if det > 1.0e-9 * s11 * s22 and s11 > 0.0 and s22 > 0.0:
        both_seat = (t1 * s22 - t2 * s12) / det
        both_clearance = (s11 * t2 - s12 * t1) / det
        if both_seat >= 0.0 and both_clearance >= 0.0:
            best_seat, best_clearance = both_seat, both_clearance
    return min(best_seat, q.shut_seat_most), min(best_clearance, q.shut_piston_most)


@njit_inline
def judge_leg_air(
    monitor: NDArray[np.float64],
    air: NDArray[np.float64],
    pressure: NDArray[np.float64],
    supply_abs: float,
    q: SupervisionParams,
    first: bool,
) -> int:
    """With every valve shut, each leg's air against its trailing average (``M_LEG_AIR``)
    and what its seats and piston moved by :func:`leak_terms`, at the rates that explain
    the other five legs' chambers best (:func:`_fit_leaks`): the chamber to hold of the
    leg that lost ``shut_leg_air`` more than that, and more than what cooling after the
    fills before the shut may take (``shut_thermal_time``), the one of its two that lost
    more; -1 if none. ``air``: each chamber's ``p^(1/k) V``, pressures in atmospheres;
    ``first``: the references are set now (``shut_settle_reads`` after the shut).

    What was measured is in ``SupervisionConfig.shut_leg_air``."""
    m = M_LEG_AIR
    pr = np.empty(12)
    for c in range(12):
        pr[c] = max(pressure[c] + q.atm, 1.0) / q.atm
    supply = max(supply_abs, 1.0) / q.atm
    seats = np.empty(12)
    piston = np.empty(12)
    leak_terms(pr, supply, q, seats, piston)
    # What the transducers' spans and zeros leave unknown of the terms: each leg's caps'
    # readings, then its rods', then the supply's, that far up (seats2, piston2).
    seat_off = np.zeros(6)
    piston_off = np.zeros(6)
    shifted = np.empty(12)
    seats2 = np.empty(12)
    piston2 = np.empty(12)
    for side in range(3):
        for c in range(12):
            up = q.obs_span * abs(pressure[c]) + q.shut_zero
            shifted[c] = pr[c] + (up / q.atm if side < 2 and c % 2 == side else 0.0)
        up = q.obs_span * abs(supply_abs - q.atm) + q.shut_zero
        leak_terms(shifted, supply + (up / q.atm if side == 2 else 0.0), q, seats2, piston2)
        for i in range(6):
            a, b = 2 * i, 2 * i + 1
            seat_off[i] += abs(seats2[a] - seats[a] + seats2[b] - seats[b])
            piston_off[i] += abs(piston2[a] - piston[a] + piston2[b] - piston[b])
    if first:
        for c in range(12):
            monitor[m + c] = air[c]
            monitor[m + 12 + c] = 0.0
            monitor[m + 24 + c] = 0.0
        for i in range(6):
            cooled = 0.0
            for c in range(2 * i, 2 * i + 2):
                filled = max(pressure[c] - monitor[M_FILLED + c], 0.0)
                cooled += q.shut_cooling * filled / (pressure[c] + q.atm) * air[c]
            monitor[m + 36 + i] = cooled / max(air[2 * i] + air[2 * i + 1], 1e-12)
            monitor[m + 43 + i] = 0.0
            monitor[m + 49 + i] = 0.0
        monitor[m + 42] = 0.0
        return -1
    keep = 1.0 - 1.0 / q.shut_leg_reads
    moved = np.empty(12)  # each chamber's air less its trailing average
    s11 = s12 = s22 = t1 = t2 = 0.0
    for c in range(12):
        monitor[m + c] += (air[c] - monitor[m + c]) / q.shut_leg_reads
        moved[c] = air[c] - monitor[m + c]
        monitor[m + 12 + c] = (monitor[m + 12 + c] + seats[c] * q.read_dt) * keep
        monitor[m + 24 + c] = (monitor[m + 24 + c] + piston[c] * q.read_dt) * keep
        g, h = monitor[m + 12 + c], monitor[m + 24 + c]
        s11 += g * g
        s12 += g * h
        s22 += h * h
        t1 += g * moved[c]
        t2 += h * moved[c]
    found, worst = -1, 0.0
    for i in range(6):
        monitor[m + 36 + i] *= q.shut_allow_decay
        monitor[m + 43 + i] = (monitor[m + 43 + i] + seat_off[i] * q.read_dt) * keep
        monitor[m + 49 + i] = (monitor[m + 49 + i] + piston_off[i] * q.read_dt) * keep
        a, b = 2 * i, 2 * i + 1
        ga, ha = monitor[m + 12 + a], monitor[m + 24 + a]
        gb, hb = monitor[m + 12 + b], monitor[m + 24 + b]
        seat, clearance = _fit_leaks(
            s11 - ga * ga - gb * gb,
            s12 - ga * ha - gb * hb,
            s22 - ha * ha - hb * hb,
            t1 - ga * moved[a] - gb * moved[b],
            t2 - ha * moved[a] - hb * moved[b],
            q,
        )  # on the other five legs
        left_a = moved[a] - seat * ga - clearance * ha
        left_b = moved[b] - seat * gb - clearance * hb
        unknown = seat * monitor[m + 43 + i] + clearance * monitor[m + 49 + i]
        legs = max(air[a] + air[b], 1e-12)
        lost = -(left_a + left_b + unknown) / legs - monitor[m + 36 + i]
        monitor[m + 42] = max(monitor[m + 42], lost / q.shut_leg_air)
        if lost > q.shut_leg_air and lost > worst:
            found, worst = (a if left_a < left_b else b), lost
    return found


@njit_inline
def intake_allowed(supply_abs: float, chamber_gauge: float, q: SupervisionParams) -> bool:
    """Whether an intake may open: the supply must be above the chamber (else the chamber
    vents backwards into the supply line)."""
    return supply_abs - q.atm > chamber_gauge + q.intake_margin


@njit_inline
def _window(
    monitor: NDArray[np.float64],
    counters: NDArray[np.int64],
    count_at: int,
    start_at: int,
    in_at: int,
    out_at: int,
    c: int,
    length: int,
    air: float,
    into: float,
    out: float,
) -> tuple[bool, float, float, float]:
    """One control period of chamber ``c``'s accounting window: what went in and out, and the
    chamber's air at its start. Returns (ended, in, out, air change) of the window that just
    ended; a new one starts with this period's ``into`` and ``out``."""
    n = counters[count_at + c]
    ended = n >= length
    total_in, total_out = monitor[in_at + c], monitor[out_at + c]
    change = air - monitor[start_at + c]
    if ended:
        n = 0
    if n == 0:
        monitor[start_at + c] = air
        monitor[in_at + c] = 0.0
        monitor[out_at + c] = 0.0
    monitor[in_at + c] += into
    monitor[out_at + c] += out
    counters[count_at + c] = n + 1
    return ended, total_in, total_out, change


VALVES_OK = 0
VALVE_DEAD = 1
"""A trip (Trip.VALVE): closing every valve stops whatever the dead valve was for."""
VALVE_OUTRUN = 2
"""A service warning, not a trip: the air leaves by another path, a leak or the exhaust
stuck open, and closing every valve would leave that path alone to move the leg
(an exhaust stuck open while holding: 13.5 mm within 0.5 s of a trip). The loop keeps the
leg by outrunning it while the segment finishes, and nothing new starts (C_SERVICE)."""
VALVE_STALLED = 3
"""Told to take air in, the chamber's air stayed where it was: its intake does not open,
or a leak or its exhaust stuck open takes what it brings. A trip, unless the chamber's air
already did not add up (C_SERVICE names it): then the other path is known, and the loop's
to outrun as for VALVE_OUTRUN."""


@njit_inline
def check_valves(
    monitor: NDArray[np.float64],
    counters: NDArray[np.int64],
    c: int,
    slots: int,
    pressure: float,
    volume: float,
    supply: float,
    q: SupervisionParams,
) -> int:
    """One PWM period of chamber ``c`` (gauge pressure, its volume in m3, gauge supply) with
    ``slots`` about to be driven (+ intake, - exhaust). Over the window just ended:
    :data:`VALVES_OK`, :data:`VALVE_DEAD` (the chamber did not answer the exhaust it was
    told to use: that valve does not open, or its transducer is wrong),
    :data:`VALVE_STALLED` (nor the intake) or
    :data:`VALVE_OUTRUN` (told to take air in, it lost air: a leak or its exhaust stuck
    open takes more than the intake brings).

    The air in the chamber is judged, not its pressure: ``p V`` (absolute pressure times the
    volume from the measured piston) rises only by an intake and falls only by an exhaust,
    whatever the piston does, where the pressure alone stays flat while a moving piston
    makes room for what an intake brings.
    """
    air = (pressure + q.atm) * volume
    ended, intake, exhaust, moved = _window(
        monitor, counters, C_WINDOW, M_P_START, M_VALVE_IN, M_VALVE_OUT, c, q.valve_window,
        air, max(0, slots), max(0, -slots),
    )  # fmt: skip
    if not ended:
        return VALVES_OK
    change = moved / volume
    if intake >= q.valve_slots and exhaust == 0 and pressure < supply - q.valve_headroom:
        if change >= q.valve_min_change:
            return VALVES_OK
        return VALVE_OUTRUN if change <= -q.valve_min_change else VALVE_STALLED
    if exhaust >= q.valve_slots and intake == 0 and pressure > q.valve_headroom:
        # Not the mirror case: while the loop exhausts a chamber its piston is compressing
        # it, and the air read as p V may rise without any intake (a stuck-closed exhaust
        # mid-exercise read so); a stuck-open intake is the observer's (check_air_flow).
        return VALVES_OK if -change >= q.valve_min_change else VALVE_DEAD
    return VALVES_OK


@njit_inline
def check_frozen(
    monitor: NDArray[np.float64],
    counters: NDArray[np.int64],
    c: int,
    reading: float,
    driven: bool,
    q: SupervisionParams,
) -> bool:
    """Chamber ``c``'s raw reading at a control period, and whether its valves were driven in
    the period before. True when it stayed frozen through enough driven periods: the same
    at every read (1 kHz) in between, not only at the periods' ends. A live transducer on a
    chamber whose pressure does not move (an exhaust stuck shut, driven) still flickers by
    a count at 1 kHz with its noise; compared only every fourth read, one read the same
    ten periods running and was named as the frozen transducer."""
    same = reading == monitor[M_P_LAST + c] and monitor[M_P_MOVED + c] == 0.0
    monitor[M_P_MOVED + c] = 0.0
    monitor[M_P_LAST + c] = reading
    if not same:
        counters[C_P_SAME + c] = 0
    elif driven:
        counters[C_P_SAME + c] += 1
    return bool(counters[C_P_SAME + c] >= q.pressure_frozen_periods)


@njit_inline
def valve_flow(p_up: float, p_down: float, q: SupervisionParams) -> float:
    """ISO 6358 flow of one open valve from ``p_up`` to ``p_down`` (Pa abs) as air moved per
    second (Pa m3/s at the air's temperature: mass flow times R T); 0 if none goes that way."""
    if p_up <= p_down:
        return 0.0
    ratio = p_down / p_up
    phi = 1.0
    if ratio > q.obs_b:
        x = (ratio - q.obs_b) / (1.0 - q.obs_b)
        phi = math.sqrt(max(0.0, 1.0 - x * x))
    return q.obs_conductance * p_up * phi * 1.0e5  # rho_ANR R T_ANR = 1 bar


@njit_inline
def pulse_seconds(
    length: float, extra: float, shut: float, opens: float, q: SupervisionParams
) -> tuple[float, float]:
    """A pulse of ``length`` (s) of a valve whose pulses pass ``extra`` beyond their length,
    and which the start-up test left shut up to ``shut`` and opened every time from
    ``opens`` (both 0: not tested). Returns the time of full flow it is expected to pass
    and how far either way it may be (s). The armature starts to move only after the
    valve's opening delay: a coil released before stays shut, one released after opens the
    valve for at least its closing delay. Near the delay its jitter decides, and the
    expectation is half of the open pulse, give or take that half."""
    full = max(0.0, length + extra)
    if opens <= 0.0:
        return full, 0.0
    if length <= shut - q.obs_edge_margin:
        return 0.0, 0.0
    if length < opens + q.obs_edge_margin:
        return 0.5 * full, 0.5 * full
    return full, 0.0


@njit_inline
def drawn_surely(
    c: int,
    slots: int,
    chamber: float,
    supply: float,
    q: SupervisionParams,
    valves: NDArray[np.float64],
) -> float:
    """The air (Pa m3) chamber ``c``'s intake, driven ``slots`` this period, surely drew
    from ``supply`` into ``chamber`` (both Pa abs): only the pulse's time past the valve's
    opening edge (the identified one, else ``supply_draw_edge``), at the least flow the
    readings allow (their span errors, ``observer_span_error``) less the observer's
    tolerance. 0 for an exhaust, a pulse that may not have opened the valve, or a chamber
    the readings cannot tell from the supply: near it the flow hangs on the small
    difference of two readings, which their span errors may wholly take (drawn build 81's
    supply read 0.08 bar above its manifold while an intake held open filled a chamber
    that had all but reached it: no air moved)."""
    if slots <= 0:
        return 0.0
    opens = valves[V_OPENS, 2 * c]
    edge = opens + q.obs_edge_margin if opens > 0.0 else q.supply_draw_edge
    past = slots * q.slot_time - edge
    if past <= 0.0:
        return 0.0
    least = valve_flow(supply * (1.0 - q.obs_span), chamber * (1.0 + q.obs_span), q)
    return least * float(valves[V_GAIN, 2 * c]) * (1.0 - q.obs_flow_tol) * past


@njit_inline
def pulse_air(
    c: int,
    slots: int,
    chamber: float,
    supply: float,
    q: SupervisionParams,
    valves: NDArray[np.float64],
) -> tuple[float, float, float]:
    """The air (Pa m3, + in) chamber ``c`` at ``chamber`` (Pa abs) is expected to take
    through a period in which its valves are driven ``slots`` (+ intake, - exhaust) from
    ``supply`` (Pa abs), as this build's valve passes a pulse (device.identify); how far
    either way it may be (Pa m3: a pulse near the valve's opening delay, and what the
    transducers' spans leave unknown of the flow, ``observer_span_error``); and the
    valve's flow while open (Pa m3/s, signed)."""
    width = abs(slots)
    into = slots > 0
    high, low = 1.0 + q.obs_span, 1.0 - q.obs_span
    if into:
        flow = valve_flow(supply, chamber, q)
        spread = valve_flow(supply * high, chamber * low, q) - valve_flow(
            supply * low, chamber * high, q
        )
    else:
        flow = -valve_flow(chamber, q.atm, q)
        spread = valve_flow(chamber * high, q.atm, q) - valve_flow(chamber * low, q.atm, q)
    open_time = width * q.slot_time
    unsure = 0.0
    gain = 1.0
    if width < 28:  # a pulse: as this build's valve passes one
        v = 2 * c + (0 if into else 1)
        gain = valves[V_GAIN, v]
        flow *= gain
        open_time, unsure = pulse_seconds(
            open_time, valves[V_EXTRA, v], valves[V_SHUT, v], valves[V_OPENS, v], q
        )
    # What the transducers' span errors leave unknown of the flow: little while it is
    # choked, nearly all of it where the chamber nears the supply (or an exhaust the
    # atmosphere) and the flow hangs on the small difference of two readings.
    reading = 0.5 * abs(spread) * gain * (open_time + unsure)
    return flow * open_time, unsure * abs(flow) + reading, flow


@njit_inline
def check_air_flow(
    monitor: NDArray[np.float64],
    counters: NDArray[np.int64],
    c: int,
    slots: int,
    pressure: float,
    volume: float,
    supply: float,
    q: SupervisionParams,
    valves: NDArray[np.float64],
) -> bool:
    """Observe chamber ``c``'s air over the control period that just ended, in which its
    valves were driven ``slots`` (+ intake, - exhaust); ``pressure`` and ``supply`` gauge
    (Pa), ``volume`` from the measured piston (m3). True when the air that came in (from the
    change of p V, polytropic) stayed further from what the valves' ISO 6358 flow should
    have brought than the model's own uncertainty, for ``observer_periods`` in a row: a
    leak, a valve stuck open or closed, or a leg sensor that hides the volume its piston
    really makes. The sign of the residual says which way (see :data:`M_OBS_R`).
    ``valves``: the calibration's figures per valve (:data:`V_GAIN` ...): what each pulse
    of this build's valves passes against the model and where each starts to open
    (:func:`pulse_seconds`)."""
    p_abs = pressure + q.atm
    air = p_abs * volume
    n = counters[C_OBS + c]
    counters[C_OBS + c] = n + 1
    air0, v0 = monitor[M_OBS_PV + c], monitor[M_OBS_V + c]
    monitor[M_OBS_PV + c] = air
    monitor[M_OBS_V + c] = volume
    sums = M_ANSWER + ANSWER_SUMS * c
    if n == 0:
        monitor[M_OBS_R + c] = 0.0
        monitor[M_OBS_T + c] = 0.0
        counters[C_OBS_OVER + c] = 0
        counters[C_ANSWER + c] = 0
        for i in range(ANSWER_SUMS):
            monitor[sums + i] = 0.0
        return False
    p0 = air0 / v0
    k = q.obs_k
    came_in = (air - air0 + (k - 1.0) * 0.5 * (p0 + p_abs) * (volume - v0)) / k
    p_mid = 0.5 * (p0 + p_abs)
    expected = 0.0
    unsure = 0.0
    pulse_tolerance = 0.0  # what the valves' flow leaves unknown of the period's air
    if slots != 0:
        expected, unsure, flow = pulse_air(c, slots, p_mid, supply + q.atm, q, valves)
        pulse_tolerance = q.obs_flow_tol * abs(expected) + unsure
        if abs(slots) < 28:  # a pulse, not a valve held open through the period
            pulse_tolerance += q.obs_pulse_time * abs(flow)
    tolerance = q.obs_volume_tol * abs(v0 * (p_abs - p0)) / k + pulse_tolerance
    dt = 28 * q.slot_time
    # The answer rule's own volume term: the dead volume as the start-up identification
    # measured it, off by at most ``answer_dead_volume_error``, not the design's.
    slack = q.answer_volume_error * abs(p_abs - p0) / k + q.answer_floor * dt
    dead = answered(
        monitor, counters, c, slots, came_in, expected, unsure, pulse_tolerance, slack, q,
        valves,
    )  # fmt: skip
    r = monitor[M_OBS_R + c]
    r += q.obs_alpha * ((came_in - expected) / dt - r)
    monitor[M_OBS_R + c] = r
    t = monitor[M_OBS_T + c]
    t += q.obs_alpha * (tolerance / dt - t)
    monitor[M_OBS_T + c] = t
    limit = t + q.obs_floor
    monitor[M_OBS_PEAK] = max(monitor[M_OBS_PEAK], abs(r) / limit)
    counters[C_OBS_OVER + c] = counters[C_OBS_OVER + c] + 1 if abs(r) > limit else 0
    return dead or bool(counters[C_OBS_OVER + c] >= q.obs_periods)


@njit_inline
def answered(
    monitor: NDArray[np.float64],
    counters: NDArray[np.int64],
    c: int,
    slots: int,
    came_in: float,
    expected: float,
    unsure: float,
    tolerance: float,
    slack: float,
    q: SupervisionParams,
    valves: NDArray[np.float64],
) -> bool:
    """Hold each valve of chamber ``c`` to its own pulses (``answer_share``): decaying sums
    of the air that came in the period that just ended (``came_in``), and of what the
    period's pulse (``slots``, + intake) surely moved (``expected`` less ``unsure``) and
    how far it may be off (``tolerance``, the pulse's share of the observer's), kept apart
    for the intake and the exhaust. True when, for ``answer_periods`` in a row, a valve
    told to move at least ``answer_min_air`` surely moved at most ``answer_share`` of it,
    even granting the other valve passed the least it may and the volume term and the
    floor (``slack``, this period's) their most. Only a valve whose opening edge the start-up
    identification measured is held so: where a pulse starts to pass air is then known."""
    sums = M_ANSWER + ANSWER_SUMS * c
    decay = q.answer_decay
    for i in range(ANSWER_SUMS):
        monitor[sums + i] *= decay
    monitor[sums + ANSWER_CAME] += came_in
    monitor[sums + ANSWER_VOLUME_TOL] += slack
    v = 2 * c + (0 if slots > 0 else 1)
    sure = 0.0
    if slots != 0 and valves[V_OPENS, v] > 0.0:
        sure = max(0.0, abs(expected) - unsure)
        if slots > 0:
            monitor[sums + ANSWER_IN] += sure
            monitor[sums + ANSWER_IN_TOL] += tolerance + unsure
        else:
            monitor[sums + ANSWER_OUT] -= sure
            monitor[sums + ANSWER_OUT_TOL] += tolerance + unsure
    came = monitor[sums + ANSWER_CAME]
    into, in_tol = monitor[sums + ANSWER_IN], monitor[sums + ANSWER_IN_TOL]
    out, out_tol = monitor[sums + ANSWER_OUT], monitor[sums + ANSWER_OUT_TOL]
    allowed = monitor[sums + ANSWER_VOLUME_TOL]
    # A pulse's air reaches the transducer within its own period or the next: a valve is
    # held to its pulses before this period's, whose air may not have come yet (any of
    # it that did counts in its favour), while the other valve's air, a period old or
    # more, has all come.
    into_before = into - (sure if slots > 0 else 0.0)
    out_before = out + (sure if slots < 0 else 0.0)
    worst = math.inf
    if into_before >= q.answer_min_air:  # the most the intake may have brought
        worst = min(worst, (came - out + out_tol + allowed) / into_before)
    if -out_before >= q.answer_min_air:  # the most the exhaust may have let out
        worst = min(worst, (into - came + in_tol + allowed) / -out_before)
    if worst == math.inf:
        counters[C_ANSWER + c] = 0
        return False
    near = q.answer_share / max(worst, q.answer_share * 1.0e-3)
    monitor[M_ANSWER_PEAK] = max(monitor[M_ANSWER_PEAK], near)
    counters[C_ANSWER + c] = counters[C_ANSWER + c] + 1 if worst < q.answer_share else 0
    return bool(counters[C_ANSWER + c] >= q.answer_periods)


@njit_inline
def woke_short(counters: NDArray[np.int64], leg: int, q: SupervisionParams) -> int:
    """The chamber of ``leg`` whose air has been over its tolerance for
    ``observer_wake_periods`` while the leg is watched after it drifted out of its rest
    (:data:`C_WOKE`), -1 if none; counts the watch down."""
    if counters[C_WOKE + leg] <= 0:
        return -1
    counters[C_WOKE + leg] -= 1
    for c in (2 * leg, 2 * leg + 1):
        if counters[C_OBS_OVER + c] >= q.obs_wake_periods:
            return c
    return -1


@njit_inline
def check_air(
    monitor: NDArray[np.float64],
    counters: NDArray[np.int64],
    c: int,
    slots: int,
    pressure: float,
    volume: float,
    supply: float,
    q: SupervisionParams,
    valves: NDArray[np.float64],
) -> int:
    """Balance chamber ``c``'s air (gauge ``pressure`` and ``supply``, ``volume`` from the
    measured piston) against what its valves were told to move, over a window of control
    periods: the rough figure per slot, or, where the start-up test found where each valve
    starts to open, what the air observer expects of the pulse (:func:`pulse_air`). Call
    it for a leg's cap chamber, then its rod chamber, every period: their windows end
    together, and the rod's call judges the leg. Returns the chamber whose
    valves moved a lot of air one way, hardly any the other, while its measured air did
    not follow (a leak, a stuck valve, a leg sensor that stopped) and its mirror's did
    (``air_mirror_share``); -1 while all adds up."""
    air = (pressure + q.atm) * volume
    if valves[V_OPENS, 2 * c] > 0.0 and slots != 0:
        # What the pulse surely moves, and the most it may: near its valve's opening delay
        # a pulse passes nothing or its whole closing delay's worth.
        expected, unsure, _ = pulse_air(c, slots, pressure + q.atm, supply + q.atm, q, valves)
        moved = max(0.0, abs(expected) - unsure)
        most = abs(expected) + unsure
    else:
        moved = max(0, abs(slots) - q.air_open_after) * q.air_per_slot
        most = moved
    n = counters[C_AIR + c]
    in_most, out_most = monitor[M_AIR_IN_MOST + c], monitor[M_AIR_OUT_MOST + c]
    ended, into, out, measured = _window(
        monitor, counters, C_AIR, M_AIR_START, M_AIR_EXPECT, M_AIR_OUT, c, q.air_window,
        air, moved if slots > 0 else 0.0, moved if slots < 0 else 0.0,
    )  # fmt: skip
    if n == 0 or ended:
        monitor[M_AIR_IN_MOST + c] = 0.0
        monitor[M_AIR_OUT_MOST + c] = 0.0
    monitor[M_AIR_IN_MOST + c] += most if slots > 0 else 0.0
    monitor[M_AIR_OUT_MOST + c] += most if slots < 0 else 0.0
    if not ended:
        return -1
    # Judged by what the valves surely moved one way against the most the other way may
    # have (the same where the start-up test did not find the valves' opening edges): a
    # window of pulses near an exhaust's opening delay and sure intakes reads one-sided
    # by what is sure alone, while the exhausts passed air (the controller's own heave
    # at start-up, 11 of 50 drawn builds asked for service so).
    if into >= out:
        expected = into - out_most
        one_sided = out_most <= q.air_one_sided * into
    else:
        expected = in_most - out
        one_sided = in_most <= q.air_one_sided * out
    # Only where the flow is near its estimate: an intake far enough below the supply, an
    # exhaust far enough above the atmosphere (near either the flow dwindles).
    where_ok = pressure < supply - q.air_headroom if expected > 0.0 else pressure > q.air_headroom
    way = math.copysign(1.0, expected) if one_sided and expected != 0.0 else 0.0
    monitor[M_AIR_WAY + c] = way
    monitor[M_AIR_SHARE + c] = measured * way / abs(expected) if way != 0.0 else 1.0
    judged = way != 0.0 and where_ok and abs(expected) >= q.air_min_expected
    monitor[M_AIR_JUDGED + c] = 1.0 if judged else 0.0
    if c % 2 == 0:
        return -1
    return air_leg(monitor, c // 2, q)


@njit_inline
def air_leg(monitor: NDArray[np.float64], leg: int, q: SupervisionParams) -> int:
    """The chamber of ``leg`` whose last air window fell short on its own, -1 if none. When
    both did, the one whose air followed its valves least (or went furthest against them):
    a leak on the rod side drags its mirror short too (leak 5 mid-exercise: the cap's
    exhaust 0.01 of its figure, the leaking rod's intake -0.47), and the cap, asked first,
    was named."""
    named = -1
    for a in (2 * leg, 2 * leg + 1):
        share = monitor[M_AIR_SHARE + a]
        if monitor[M_AIR_JUDGED + a] == 0.0 or share >= q.air_min_fraction:
            continue
        # Its mirror is asked only which way its valves moved air and how much of it
        # followed, wherever it stood: an intake near the supply passes even less than the
        # rough figure, which says the same about the leg's valves.
        b = a ^ 1
        mirror = monitor[M_AIR_SHARE + b]
        if (
            share >= 0.0
            and monitor[M_AIR_WAY + b] == -monitor[M_AIR_WAY + a]
            and 0.0 <= mirror < q.air_mirror_share
        ):
            continue  # both short, as mirrors: the leg's valves, not one chamber's air
        if named < 0 or share < monitor[M_AIR_SHARE + named]:
            named = a
    return named


@njit
def reset_valve_windows(counters: NDArray[np.int64]) -> None:
    for c in range(12):
        counters[C_WINDOW + c] = 0


@njit_inline
def check_balance(
    monitor: NDArray[np.float64],
    counters: NDArray[np.int64],
    leg: int,
    residual: float,
    q: SupervisionParams,
) -> bool:
    """Filter one leg's force-balance residual (N); True when it stayed over the limit."""
    r = monitor[M_RESIDUAL + leg]
    r += q.residual_alpha * (residual - r)
    monitor[M_RESIDUAL + leg] = r
    if abs(r) > q.residual_limit:
        counters[C_RESIDUAL + leg] += 1
    else:
        counters[C_RESIDUAL + leg] = 0
    return bool(counters[C_RESIDUAL + leg] >= q.residual_periods)


@njit_inline
def check_wrench(
    monitor: NDArray[np.float64],
    counters: NDArray[np.int64],
    wrench: NDArray[np.float64],
    q: SupervisionParams,
    force_allow: float = 0.0,
    torque_allow: float = 0.0,
) -> bool:
    """Filter the legs' residual as a wrench at the ankle (force N, moment N m, base frame);
    True when its force or its moment stayed over its limit, plus what the seals may hold
    where their friction was not identified (``force_allow`` N, ``torque_allow`` N m:
    :func:`device.controller.wrench_allowance`)."""
    force2, torque2 = 0.0, 0.0
    for k in range(6):
        r = monitor[M_WRENCH + k]
        r += q.residual_alpha * (wrench[k] - r)
        monitor[M_WRENCH + k] = r
        if k < 3:
            force2 += r * r
        else:
            torque2 += r * r
    force, torque = math.sqrt(force2), math.sqrt(torque2)
    monitor[M_WRENCH_PEAK] = max(monitor[M_WRENCH_PEAK], force)
    monitor[M_WRENCH_PEAK + 1] = max(monitor[M_WRENCH_PEAK + 1], torque)
    over = (
        force > q.wrench_force_limit + force_allow or torque > q.wrench_torque_limit + torque_allow
    )
    counters[C_WRENCH] = counters[C_WRENCH] + 1 if over else 0
    return bool(counters[C_WRENCH] >= q.residual_periods)


@njit_inline
def accel_trusted(counters: NDArray[np.int64]) -> bool:
    """Whether the measured pose's acceleration can be taken as the platform's: not within
    ``SIDE_ARM_PERIODS`` of start-up or a new command, nor while a leg reading moves as no
    leg can (``side_leg_rough``)."""
    return bool(counters[C_SIDE_ARMED] >= SIDE_ARM_PERIODS and counters[C_POSE_ROUGH] == 0)


@njit_inline
def check_side(
    monitor: NDArray[np.float64],
    counters: NDArray[np.int64],
    fx: float,
    fy: float,
    allowance: float,
    q: SupervisionParams,
) -> int:
    """Filter the sideways residual force at the ankle less the platform's inertial force
    (N, base frame) and the ``allowance`` (N) for what the inertial model may get wrong at
    the present acceleration (``side_mass_uncertainty``), alike; the component (0 x, 1 y)
    when the residual stayed over its limit plus the allowance, else -1."""
    if not accel_trusted(counters):
        counters[C_SIDE] = 0
        return -1
    rx = monitor[M_SIDE] + q.side_alpha * (fx - monitor[M_SIDE])
    ry = monitor[M_SIDE + 1] + q.side_alpha * (fy - monitor[M_SIDE + 1])
    allow = monitor[M_SIDE_ALLOW] + q.side_alpha * (allowance - monitor[M_SIDE_ALLOW])
    monitor[M_SIDE] = rx
    monitor[M_SIDE + 1] = ry
    monitor[M_SIDE_ALLOW] = allow
    side = math.sqrt(rx * rx + ry * ry)
    monitor[M_SIDE_PEAK] = max(monitor[M_SIDE_PEAK], side)
    counters[C_SIDE] = counters[C_SIDE] + 1 if side > q.side_force_limit + allow else 0
    if counters[C_SIDE] < q.side_periods:
        return -1
    return 0 if abs(rx) >= abs(ry) else 1


@njit_inline
def check_turn(
    monitor: NDArray[np.float64],
    counters: NDArray[np.int64],
    moment: NDArray[np.float64],
    allowance: NDArray[np.float64],
    q: SupervisionParams,
) -> int:
    """Filter the moment residual about the ankle less the platform's inertia (``moment``,
    N m, roll pitch yaw, base frame), and its ``allowance`` (N m, each: the legs' friction
    and the inertial model's errors, ``turn_floor`` on) as it falls; the wrench component
    (3-5) that stayed furthest over its allowance, else -1."""
    if not accel_trusted(counters):
        counters[C_TURN] = 0
        return -1
    worst, share = -1, 0.0
    for k in range(3):
        r = monitor[M_TURN + k] + q.side_alpha * (moment[k] - monitor[M_TURN + k])
        # The allowance rises at once (a leg that sticks holds its friction at once, and the
        # check arms with nothing filtered yet) and falls as the residual's filter forgets.
        a = monitor[M_TURN_ALLOW + k]
        a = allowance[k] if allowance[k] > a else a + q.side_alpha * (allowance[k] - a)
        monitor[M_TURN + k] = r
        monitor[M_TURN_ALLOW + k] = a
        ratio = abs(r) / a  # a >= turn_floor > 0: the allowance starts there
        if ratio > share:
            worst, share = k, ratio
    monitor[M_TURN_PEAK] = max(monitor[M_TURN_PEAK], share)
    counters[C_TURN] = counters[C_TURN] + 1 if share > 1.0 else 0
    if counters[C_TURN] < q.turn_periods:
        return -1
    return 3 + worst


@njit_inline
def check_lift(
    monitor: NDArray[np.float64],
    counters: NDArray[np.int64],
    fz: float,
    allowance: float,
    q: SupervisionParams,
) -> bool:
    """Filter the vertical residual force at the ankle less the platform's inertial force
    and the legs' identified load bias (``fz``, N, base frame) and its ``allowance`` (N: the
    legs' friction, the inertial model's errors and the force sensor's span, ``lift_floor``
    on) as the moment check does (:func:`check_turn`); whether the residual stayed over it."""
    if not accel_trusted(counters):
        counters[C_LIFT] = 0
        return False
    r = monitor[M_LIFT] + q.side_alpha * (fz - monitor[M_LIFT])
    a = monitor[M_LIFT_ALLOW]
    a = allowance if allowance > a else a + q.side_alpha * (allowance - a)
    monitor[M_LIFT] = r
    monitor[M_LIFT_ALLOW] = a
    share = abs(r) / a  # a >= lift_floor > 0: the allowance starts there
    monitor[M_LIFT_PEAK] = max(monitor[M_LIFT_PEAK], share)
    counters[C_LIFT] = counters[C_LIFT] + 1 if share > 1.0 else 0
    return bool(counters[C_LIFT] >= q.turn_periods)


@njit_inline
def wrench_component(monitor: NDArray[np.float64], q: SupervisionParams) -> int:
    """The component (0..5) of the filtered wrench residual furthest over its limit."""
    worst, share = 0, -1.0
    for k in range(6):
        limit = q.wrench_force_limit if k < 3 else q.wrench_torque_limit
        v = abs(monitor[M_WRENCH + k]) / limit
        if v > share:
            worst, share = k, v
    return worst


@njit_inline
def residual_share(monitor: NDArray[np.float64]) -> tuple[int, float]:
    """The leg carrying the most of the filtered force-balance residual and its share of
    the six legs' sum of squares; (-1, 0) while there is none."""
    total = 0.0
    worst, most = -1, 0.0
    for i in range(6):
        r2 = monitor[M_RESIDUAL + i] ** 2
        total += r2
        if r2 > most:
            worst, most = i, r2
    return (worst, most / total) if worst >= 0 else (-1, 0.0)


@njit_inline
def one_leg(monitor: NDArray[np.float64], leg: int) -> bool:
    """Whether ``leg`` carries most of the filtered force-balance residual (more than half
    of its sum of squares): a fault of that leg (its transducers, valves, tube). A wrong
    force/torque reading spreads over several legs instead."""
    worst, share = residual_share(monitor)
    return bool(worst == leg and share > 0.5)


@njit_inline
def leg_frozen(counters: NDArray[np.int64], q: SupervisionParams) -> int:
    """The leg whose reading has stayed the same longest while driven, if that is
    ``leg_stuck_blame_reads`` or more; -1 if none."""
    found, longest = -1, q.leg_stuck_blame_reads - 1
    for i in range(6):
        if counters[C_LEG_SAME + i] > longest:
            found, longest = i, counters[C_LEG_SAME + i]
    return found


@njit_inline
def leg_alone(monitor: NDArray[np.float64], q: SupervisionParams) -> int:
    """The leg that carries ``balance_one_leg_share`` or more of the filtered force-balance
    residual (of its sum of squares), -1 if none: a fault of that leg, not of the
    force/torque sensor."""
    worst, share = residual_share(monitor)
    return worst if share >= q.balance_one_leg_share else -1


@njit_inline
def check_steady(
    monitor: NDArray[np.float64],
    counters: NDArray[np.int64],
    friction: NDArray[np.float64],
    q: SupervisionParams,
) -> int:
    """The leg that has carried the filtered force-balance residual alone
    (:func:`leg_alone`), at more than ``balance_steady_floor`` plus twice its seals'
    identified ``friction`` (N), for ``balance_steady_periods``; -1 if none. A leg whose
    seals were not identified (friction 0), or one of whose chambers asked for service, is
    not judged so."""
    alone = leg_alone(monitor, q)
    found = -1
    for i in range(6):
        over = False
        # A leg whose chamber's air did not add up (C_SERVICE_LEGS) is held by the loop while
        # the segment finishes: a leak there leaves its leg short of force, and closing every
        # valve would let that chamber empty (see C_SERVICE). The 30 N limit still judges it.
        if i == alone and friction[i] > 0.0 and not counters[C_SERVICE_LEGS] & (1 << i):
            share = abs(monitor[M_RESIDUAL + i]) / (q.balance_steady_floor + 2.0 * friction[i])
            monitor[M_STEADY_PEAK] = max(monitor[M_STEADY_PEAK], share)
            over = share > 1.0
        counters[C_STEADY + i] = counters[C_STEADY + i] + 1 if over else 0
        if counters[C_STEADY + i] >= q.balance_steady_periods:
            found = i
    return found


@njit_inline
def _past(ratio: NDArray[np.float64]) -> int:
    """The index of the largest error past its bound (``ratio``: error / bound), -1 if none."""
    worst, share = -1, 1.0
    for k in range(len(ratio)):
        if ratio[k] > share:
            worst, share = k, ratio[k]
    return worst


@njit_inline
def _follow(counters: NDArray[np.int64], worst: int, q: SupervisionParams) -> int:
    """``worst``: the axis (or leg) furthest past its bound, -1 if none."""
    if worst < 0:
        counters[C_FOLLOW_ARMED] = min(counters[C_FOLLOW_ARMED] + 1, FOLLOW_ARM_PERIODS)
        counters[C_FOLLOW] = 0
        return -1
    if counters[C_FOLLOW_ARMED] < FOLLOW_ARM_PERIODS:
        counters[C_FOLLOW_ARMED] = 0
        return -1
    # A chamber whose air does not add up is what pushes (a valve stuck open, a leak): the
    # air checks name it and the loop keeps holding against it (see C_SERVICE). Closing
    # every valve here would leave that valve alone to drive its leg.
    if counters[C_SERVICE] > 0:
        return -1
    for c in range(12):
        if counters[C_OBS_OVER + c] > 0:
            return -1
    counters[C_FOLLOW] += 1
    return worst if counters[C_FOLLOW] >= q.following_periods else -1


@njit_inline
def check_following(
    monitor: NDArray[np.float64],
    counters: NDArray[np.int64],
    pose: NDArray[np.float64],
    command: NDArray[np.float64],
    command_rate: NDArray[np.float64],
    compliant: NDArray[np.float64],
    q: SupervisionParams,
) -> int:
    """Task mode: the axis (0..5) whose following error stayed past its bound, -1 while all
    is well. Counts only once armed: after the platform has been within every bound for
    FOLLOW_ARM_PERIODS since motion (re)started. The speed allowance decays with the loop's
    lag once the command stops (a ramp's end), as the platform's own lag does. An axis that
    renders an impedance (``compliant`` > 0.5) is not judged: the foot's measured torque
    moves its command, a false torque included, and a hard push on a light virtual inertia
    runs the command ahead of any loop (2 N m for 0.1 s on roll at K 5, 11.8 deg); its lag
    still widens the translational bound."""
    tilt = swerve = 0.0
    for k in range(6):
        speed = max(abs(command_rate[k]), q.following_decay * monitor[M_FOLLOW_SPEED + k])
        monitor[M_FOLLOW_SPEED + k] = speed
        if k >= 3:
            tilt += (pose[k] - command[k]) ** 2
            lp = monitor[M_FOLLOW_TURN + k - 3]
            swerve += (command_rate[k] - lp) ** 2
            monitor[M_FOLLOW_TURN + k - 3] = command_rate[k] + q.following_turn_decay * (
                lp - command_rate[k]
            )
    swerve = max(math.sqrt(swerve), q.following_decay * monitor[M_FOLLOW_SWERVE])
    monitor[M_FOLLOW_SWERVE] = swerve
    # How far the rotation lags, or may lag where its commanded rate changes: the legs that
    # turn the plate about the ankle drag it sideways by that much times the lever.
    sway = q.following_lever * (math.sqrt(tilt) + q.following_lag * swerve)
    ratio = np.zeros(6)
    for k in range(6):
        if compliant[k] > 0.5:
            continue
        bound = q.following_translation if k < 3 else q.following_rotation
        bound += q.following_lag * monitor[M_FOLLOW_SPEED + k]
        if k < 3:
            bound += sway
        ratio[k] = abs(pose[k] - command[k]) / bound
    return _follow(counters, _past(ratio), q)


@njit_inline
def check_leg_following(
    counters: NDArray[np.int64],
    x: NDArray[np.float64],
    target: NDArray[np.float64],
    q: SupervisionParams,
) -> int:
    """Joint mode (homing, legs held at targets): the leg (0..5) that stayed further from
    its target than the translational bound, -1 while all is well; armed as above. A leg
    error of that size moves the ankle by about as much."""
    return _follow(counters, _past(np.abs(x - target) / q.following_translation), q)


@njit_inline
def supply_by_air(counters: NDArray[np.int64], chamber: int) -> bool:
    """Chamber ``chamber``'s air did not add up: True once chambers of two legs or more have
    not. Each leg has its own valves, tubes and seals, and one fault of them shows in its
    own leg's chambers; what the legs share is the supply. A supply that fails while its
    transducer is frozen (or lies) reads as a healthy one, and the chambers' air is then
    the only witness: measured, the air observer flagged a second leg 41-49 ms after the
    supply was lost mid-exercise (205 ms holding), where nothing had tripped before. No
    healthy run flagged even one chamber (README, safety benchmark)."""
    legs = counters[C_SERVICE_LEGS] | (1 << (chamber // 2))
    counters[C_SERVICE_LEGS] = legs
    return bool(legs & (legs - 1))  # more than one bit


@njit
def settle_side(counters: NDArray[np.int64]) -> None:
    """A new command: the sideways, moment and vertical checks wait ``SIDE_ARM_PERIODS``
    before they judge, unless they have judged less than that since their last wait. Each
    new command used to restart the wait: a host that sent a new segment every 30 ms (or a
    hold and a resume) kept them blind for good, and a 3 N m offset on a torque channel or
    30 N on a sideways force channel went unnamed while the legs pushed against it. Now
    they judge at least half the time however fast commands come, and a command that
    arrives while they wait does not lengthen the wait: its own start is judged sooner
    (measured in the safety benchmark's boundary run, a new segment every 5-10 ms, and its
    healthy runs: no false trip, README)."""
    if counters[C_SIDE_JUDGED] < SIDE_ARM_PERIODS:
        return
    counters[C_SIDE_ARMED] = 0
    counters[C_SIDE_JUDGED] = 0
    counters[C_SIDE] = 0


@njit
def disarm_following(counters: NDArray[np.int64]) -> None:
    """Motion (re)starts: the following check waits until the platform is on command."""
    counters[C_FOLLOW] = 0
    counters[C_FOLLOW_ARMED] = 0


@njit
def reset_motion(monitor: NDArray[np.float64], counters: NDArray[np.int64]) -> None:
    """Forget what motion-bound checks accumulated (a new motion starts from a hold)."""
    for i in range(6):
        counters[C_LEG_SAME + i] = 0
        counters[C_RESIDUAL + i] = 0
        counters[C_STEADY + i] = 0
        counters[C_WOKE + i] = 0
        monitor[M_RESIDUAL + i] = 0.0
        monitor[M_PUSH + i] = 0.0
        monitor[M_WRENCH + i] = 0.0
    counters[C_WRENCH] = 0
    for k in range(2):
        monitor[M_SIDE + k] = 0.0
    monitor[M_SIDE_ALLOW] = 0.0
    for k in range(3):
        monitor[M_TURN + k] = 0.0
        monitor[M_TURN_ALLOW + k] = 0.0
    monitor[M_LIFT] = 0.0
    monitor[M_LIFT_ALLOW] = 0.0
    for i in range(6):
        monitor[M_LEG_LAG + i] = 0.0
    counters[C_SIDE] = 0
    counters[C_TURN] = 0
    counters[C_LIFT] = 0
    disarm_following(counters)
    for c in range(12):
        counters[C_P_SAME + c] = 0
        counters[C_AIR + c] = 0
        counters[C_OBS + c] = 0
    reset_valve_windows(counters)
