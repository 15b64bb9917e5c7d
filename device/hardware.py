"""The hardware interface: the controller's only way to the sensors and valves.

Two kinds stand behind it, chosen by name in one place (:func:`open_hardware`): the plant
simulation (``sim``) and a real I/O board (``board``). Either one reads the sensor vector and
writes the valve vector of :mod:`device.signals`, so the controller never knows which.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np
from numpy.typing import NDArray

from device.plant import model
from device.plant.params import PlantConfig, PlantParams, build_params


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

    def read_sensors(self, out: NDArray[np.float64]) -> None:
        model.read_sensors(self.state, self.params, out)

    def write_valves(self, valves: NDArray[np.uint8]) -> None:
        model.write_valves(self.state, valves)

    def wait_tick(self) -> None:
        model.plant_tick(self.state, self.params)

    def script_torque(self, axis: int, kind: int, t0: float, a: float, b: float) -> None:
        """Script the patient's active torque about one rotational axis (3, 4 or 5)."""
        if axis not in (3, 4, 5):
            raise ValueError("the patient's torque acts about roll (3), pitch (4) or yaw (5)")
        self.state.script[axis, :] = (kind, t0, a, b)


HARDWARE_KINDS = ("sim", "board")


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
