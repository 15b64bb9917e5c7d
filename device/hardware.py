"""The hardware interface: the controller's only way to the sensors and valves.

Two kinds stand behind it, chosen by name in one place (:func:`open_hardware`): the plant
simulation (``sim``) and a real I/O board (``board``). Either one reads the sensor vector and
writes the valve vector of :mod:`device.signals`, so the controller never knows which.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any

import numpy as np
from numpy.typing import NDArray

from device._jit import typed_entry
from device.plant import model
from device.plant.faults import Fault, FaultKind, fault_row
from device.plant.params import HARDWARE_KINDS, PlantConfig, PlantParams, build_params
from device.signals import N_SENSORS, N_VALVES


class HardwareError(RuntimeError):
    """The hardware cannot be opened or has failed."""


class Hardware(ABC):
    """Sensors in, valves out, one tick at a time."""

    @abstractmethod
    def read_sensors(self, out: NDArray[np.float64]) -> None:
        """Sample every sensor into ``out`` (``device.signals`` layout)."""

    @abstractmethod
    def write_valves(self, valves: NDArray[np.uint8]) -> None:
        """Set the 24 valve coils (1 energised)."""

    @abstractmethod
    def wait_tick(self) -> None:
        """Let one tick pass: the simulation integrates it; a board waits for its interrupt."""

    def close(self) -> None:
        """Release the hardware; valves are de-energised first."""
        self.write_valves(np.zeros(24, dtype=np.uint8))


class SimulatedHardware(Hardware):
    """The plant simulation behind the hardware interface."""

    def __init__(self, config: PlantConfig = PlantConfig(), seed: int = 0) -> None:
        self.config = config
        self.params: PlantParams = build_params(config)
        self.state = model.new_state(self.params)
        model.seed(seed)
        # One tick at a time from Python (identification, a board's loop run on the plant):
        # the plant's functions are resolved once for this state's and these parameters'
        # types, on buffers of this object's own, so nothing of another type reaches them.
        self._sensors = np.zeros(N_SENSORS)
        self._valves = np.zeros(N_VALVES, dtype=np.uint8)
        self._entries: tuple[Any, Any, Any] | None = None

    def _resolved(self) -> tuple[Any, Any, Any]:
        if self._entries is None:
            s, p = self.state, self.params
            self._entries = (
                typed_entry(model.read_sensors, s, p, self._sensors),
                typed_entry(model.write_valves, s, p, self._valves),
                typed_entry(model.plant_tick, s, p),
            )
        return self._entries

    def read_sensors(self, out: NDArray[np.float64]) -> None:
        self._resolved()[0](self.state, self.params, self._sensors)
        out[:] = self._sensors

    def write_valves(self, valves: NDArray[np.uint8]) -> None:
        self._valves[:] = valves
        self._resolved()[1](self.state, self.params, self._valves)

    def wait_tick(self) -> None:
        self._resolved()[2](self.state, self.params)

    def script_torque(self, axis: int, kind: int, t0: float, a: float, b: float) -> None:
        """Script the patient's active torque about one rotational axis (3, 4 or 5)."""
        if axis not in (3, 4, 5):
            raise ValueError("the patient's torque acts about roll (3), pitch (4) or yaw (5)")
        self.state.script[axis, :] = (kind, t0, a, b)

    def script_force(self, axis: int, kind: int, t0: float, a: float, b: float) -> None:
        """Script the patient's active force (N, at the ankle, base frame) along x (0),
        y (1) or z (2): a foot pushing sideways, forward or down."""
        if axis not in (0, 1, 2):
            raise ValueError("the patient's force acts along x (0), y (1) or z (2)")
        self.state.script[axis, :] = (kind, t0, a, b)

    def inject(self, fault: Fault) -> None:
        """Add ``fault`` to the plant's fault table; it acts from ``fault.time`` (plant time).

        A fault whose time has passed acts from the next tick. Raises ValueError when the
        table is full or the fault makes no sense for this plant.
        """
        if not isinstance(fault, Fault):
            raise ValueError(f"inject needs a Fault, not {type(fault).__name__}")
        if fault.kind == FaultKind.SUPPLY_DROOP:
            setting = (self.params.p_supply - self.params.p_atm) / 1e5
            if fault.value >= setting:
                raise ValueError(
                    f"supply_droop to {fault.value:g} bar gauge is no droop: "
                    f"the supply is set to {setting:g} bar gauge"
                )
        table = self.state.faults
        free = [r for r in range(table.shape[0]) if table[r, 0] == 0.0]
        if not free:
            raise ValueError(
                f"the plant's fault table is full ({table.shape[0]} faults); clear_faults() first"
            )
        table[free[0], :] = fault_row(fault)

    def clear_faults(self) -> None:
        """Remove every fault. Sensors read true at once; a stuck valve moves with its coil
        again; a lost or drooped supply recovers through its line, as a real one would."""
        self.state.faults[:] = 0.0


def open_hardware(kind: str, config: PlantConfig = PlantConfig(), seed: int = 0) -> Hardware:
    """The one place the sim/real switch is resolved."""
    if kind == "sim":
        return SimulatedHardware(config, seed)
    if kind == "board":
        raise HardwareError(
            "no I/O board driver is installed on this machine; run with the simulation (sim)"
        )
    raise HardwareError(
        f"unknown hardware kind {kind!r}; choose one of {', '.join(HARDWARE_KINDS)}"
    )
