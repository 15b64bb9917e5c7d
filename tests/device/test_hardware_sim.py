"""The simulated hardware driven one tick at a time from Python, as identification and a
board's loop drive it: the same plant as through numba's dispatcher, via typed entries."""

from __future__ import annotations

import numba
import numpy as np
import pytest
from numpy.typing import NDArray

from device._jit import typed_entry
from device.hardware import SimulatedHardware
from device.plant import model
from device.plant.params import PlantConfig
from device.signals import N_SENSORS, N_VALVES

PATTERN = np.zeros(N_VALVES, dtype=np.uint8)
PATTERN[0::4] = 1  # some intakes open: the legs move


def test_one_tick_at_a_time_is_the_dispatchers_plant_bit_for_bit() -> None:
    # The plant's noise generator is one per process: each run starts from its seed.
    hw = SimulatedHardware(PlantConfig(), seed=3)
    got = np.zeros(N_SENSORS)
    for _ in range(700):
        hw.write_valves(PATTERN)
        hw.wait_tick()
    hw.read_sensors(got)

    plain = SimulatedHardware(PlantConfig(), seed=3)
    want = np.zeros(N_SENSORS)
    for _ in range(700):
        model.write_valves(plain.state, plain.params, PATTERN)
        model.plant_tick(plain.state, plain.params)
    model.read_sensors(plain.state, plain.params, want)

    assert np.array_equal(got, want)
    assert np.array_equal(hw.state.pressure, plain.state.pressure)
    assert not np.array_equal(hw.state.pressure, SimulatedHardware().state.pressure)  # moved


def test_valves_of_another_type_are_converted_and_a_wrong_length_refused() -> None:
    hw = SimulatedHardware(PlantConfig(), seed=1)
    strided = np.zeros(2 * N_VALVES, dtype=np.uint8)
    strided[::2] = PATTERN
    hw.write_valves(strided[::2])  # not contiguous: copied into the plant's own buffer
    assert np.array_equal(hw.state.valve_cmd, PATTERN)
    hw.write_valves(np.zeros(N_VALVES))  # type: ignore[arg-type]  # untyped callers: converted
    assert not hw.state.valve_cmd.any()
    with pytest.raises(ValueError, match="broadcast"):
        hw.write_valves(np.zeros(N_VALVES - 1, dtype=np.uint8))


@numba.njit(cache=False)
def _scale(x: NDArray[np.float64], k: float) -> float:
    x *= k
    return float(x.sum())


def test_typed_entry_is_the_compiled_function_without_its_dispatcher() -> None:
    entry = typed_entry(_scale, np.ones(3), 2.0)
    assert not isinstance(entry, numba.core.dispatcher.Dispatcher)
    x = np.ones(3)
    assert entry(x, 2.0) == _scale(np.ones(3), 2.0) == 6.0
    assert np.array_equal(x, [2.0, 2.0, 2.0])  # works on the caller's array
    assert typed_entry(_scale.py_func, np.ones(3), 2.0) is _scale.py_func  # not compiled
