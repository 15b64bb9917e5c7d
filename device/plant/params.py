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


_ROWS: tuple[Param, ...] = (
    # Air supply
    Param(
        "supply_pressure",
        7.0e5,
        "Pa abs",
        "6 bar gauge: a common compressor/regulator setting, as DESIGN assumes",
    ),
    Param("atmosphere", 1.01325e5, "Pa abs", "standard atmosphere"),
    Param(
        "supply_volume",
        50.0e-6,
        "m3",
        "supply side behind the regulator: manifold of the 12 intake valves (about 20 cm3) plus 1 m of 6 mm bore hose (28 cm3). Only faults use it: healthy, the regulator holds the supply",
    ),
    Param(
        "supply_line_conductance",
        2.0,
        "dm3/(s bar)",
        "ISO 6358 C of 1 m of 6 mm hose with a 1/4 in quick coupling (about 2; same b as the valves). With supply_volume: choked blowdown time constant V/(C rho0 R T) = 25 ms when the hose comes off",
    ),
    Param(
        "supply_droop_time_constant",
        0.5,
        "s",
        "a regulator sagging to a lower output (compressor tank drawn below its set point) changes over seconds; 0.5 s is the fast end, a harsher test",
    ),
    Param(
        "temperature",
        293.15,
        "K",
        "supply air at room temperature; chambers exchange heat with the walls",
    ),
    Param("gas_constant", 287.05, "J/(kg K)", "dry air"),
    Param("alpha_in", 1.4, "-", "polytropic index of charging: adiabatic (Richer & Hurmuzlu 2000)"),
    Param("alpha_out", 1.0, "-", "discharge close to isothermal (Richer & Hurmuzlu 2000)"),
    Param("alpha_work", 1.2, "-", "volume-change term between the two (Richer & Hurmuzlu 2000)"),
    # Valves
    Param(
        "valve_conductance",
        0.30,
        "dm3/(s bar)",
        "ISO 6358 sonic conductance C. 100 NL/min is 0.24 if rated choked at 7 bar abs and 0.37 if rated 6->5 bar gauge with b = 0.4: the middle of that range",
    ),
    Param(
        "valve_critical_ratio",
        0.40,
        "-",
        "ISO 6358 b for a small poppet solenoid valve (typical 0.3-0.5)",
    ),
    Param(
        "valve_laminar_ratio",
        0.999,
        "-",
        "ISO 6358-3 laminar branch above this pressure ratio: finite, linear flow near equal pressures",
    ),
    Param(
        "valve_delay",
        0.8e-3,
        "s",
        "armature does not move until the coil has been on (or off) this long; with the travel, the paper's ~1 ms response",
    ),
    Param(
        "valve_travel",
        0.2e-3,
        "s",
        "armature travel from closed to open (and back); on/off symmetric as the paper assumes",
    ),
    # Cylinders (double-acting, low friction)
    Param(
        "bore",
        25.0e-3,
        "m",
        "25 mm: about 290 N per leg at 6 bar, ample for ankle torques near 50 N m on a 0.1 m platform",
    ),
    Param("rod", 8.0e-3, "m", "8 mm rod of a 25 mm glass/graphite cylinder; area ratio r = 0.90"),
    Param(
        "dead_volume",
        7.3e-6,
        "m3",
        "per chamber: 0.5 m of 4 mm tube from the control box (6.3 cm3) plus 1 cm3 in the cylinder end",
    ),
    Param("leg_mass", 0.25, "kg", "piston, rod and rod-end joint moving with each leg"),
    Param(
        "friction_coulomb",
        1.0,
        "N",
        "glass/graphite piston: Coulomb about 1 N (haptic-grade cylinders)",
    ),
    Param("friction_static", 1.5, "N", "breakaway about 1.5 N"),
    Param(
        "friction_stribeck_velocity",
        5.0e-3,
        "m/s",
        "Stribeck velocity of lubricated glass/graphite",
    ),
    Param("friction_viscous", 5.0, "N s/m", "viscous friction of the piston and rod seal"),
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
        "aluminium plate (1.2 kg), force/torque sensor (0.3 kg), foot plate and straps (1.0 kg)",
    ),
    Param(
        "platform_com_below_ankle", 0.09, "m", "platform centre of mass 1 cm above the joint plane"
    ),
    Param(
        "platform_radius_of_gyration",
        0.07,
        "m",
        "disc of 0.12 m radius about a diameter (r/2 = 0.06) plus the sensor and straps",
    ),
    Param("foot_mass", 1.1, "kg", "foot of a 75 kg adult: 1.45 % of body mass (de Leva 1996)"),
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
    ),
    Param("ankle_stiffness_roll", 20.0, "N m/rad", "passive ankle stiffness, frontal plane"),
    Param("ankle_stiffness_yaw", 10.0, "N m/rad", "passive stiffness about the shank axis"),
    Param("ankle_damping", 0.3, "N m s/rad", "passive ankle damping, relaxed"),
    Param(
        "resist_factor",
        4.0,
        "-",
        "co-contraction of a patient who resists multiplies ankle stiffness about fourfold",
    ),
    # Sensors
    Param("pressure_range", 1.0e6, "Pa", "0-10 bar absolute transducers, 12-bit ADC"),
    Param("pressure_noise", 100.0, "Pa", "1 mbar rms electrical noise"),
    Param("leg_sensor_bits", 12.0, "bit", "12-bit ADC over the stroke: 0.024 mm per count"),
    Param("leg_noise", 5.0e-6, "m", "5 um rms noise of the linear position sensor"),
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
    lines = ["| parameter | value | unit | why |", "|---|---|---|---|"]
    lines += [f"| `{p.name}` | {p.value:g} | {p.unit} | {p.reason} |" for p in _ROWS]
    return "\n".join(lines)


class PlantParams(NamedTuple):
    """Parameters in SI units as the compiled plant step reads them."""

    p_supply: float
    p_atm: float
    supply_volume: float  # m3, the supply side behind the regulator (faults only)
    supply_line_fraction: float  # supply line's ISO 6358 C / a valve's C
    supply_droop_tau: float  # s
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
    valve_delay: float
    valve_travel: float
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
    pressure_lsb: float
    pressure_top: float  # Pa, the ADC's top code: what a shorted transducer reads
    pressure_noise: float
    leg_lsb: float
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

    def with_overrides(self, **values: float) -> PlantConfig:
        return replace(self, overrides=(*self.overrides, *values.items()))


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

    def v(name: str) -> float:
        return _value(config, name)

    g = config.geometry
    bore, rod = v("bore"), v("rod")
    area_cap = math.pi * bore**2 / 4.0
    area_annulus = area_cap - math.pi * rod**2 / 4.0

    # Platform and foot as one rigid body about the task origin (the ankle centre).
    m_p = v("platform_mass")
    c_p = np.array([0.0, 0.0, -v("platform_com_below_ankle")])
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
    return PlantParams(
        p_supply=v("supply_pressure"),
        p_atm=p_atm,
        supply_volume=v("supply_volume"),
        supply_line_fraction=v("supply_line_conductance") / v("valve_conductance"),
        supply_droop_tau=v("supply_droop_time_constant"),
        temperature=t,
        gas_r=v("gas_constant"),
        alpha_in=v("alpha_in"),
        alpha_out=v("alpha_out"),
        alpha_work=v("alpha_work"),
        conductance=v("valve_conductance") * 1e-3 / 1e5,
        critical_ratio=v("valve_critical_ratio"),
        laminar_ratio=v("valve_laminar_ratio"),
        rho_anr=1.185,
        t_anr=293.15,
        valve_delay=v("valve_delay"),
        valve_travel=v("valve_travel"),
        area_cap=area_cap,
        area_annulus=area_annulus,
        dead_volume=v("dead_volume"),
        stroke=g.stroke,
        min_length=g.min_length,
        leg_mass=v("leg_mass"),
        f_coulomb=v("friction_coulomb"),
        f_static=v("friction_static"),
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
        pressure_lsb=v("pressure_range") / 4096.0,
        pressure_top=v("pressure_range") / 4096.0 * 4095.0,
        pressure_noise=v("pressure_noise"),
        leg_lsb=g.stroke / 2.0 ** v("leg_sensor_bits"),
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


def param_names() -> list[str]:
    """Names accepted in :attr:`PlantConfig.overrides`."""
    return list(PARAMETERS)
