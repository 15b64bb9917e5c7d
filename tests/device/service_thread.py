"""The device service in a thread over a pty, for tests that drive it with the real client."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager

from device.hardware import SimulatedHardware
from device.rig import Rig
from device.service import DeviceService, ServiceConfig
from device.transport import PtyLink


@contextmanager
def service_in_thread(
    hardware: SimulatedHardware, config: ServiceConfig, rig: Rig | None = None
) -> Iterator[PtyLink]:
    """The service running on ``hardware`` (through ``rig``, to look into its controller,
    or a rig of its own); its link. Stopped, joined and shut down after."""
    link = PtyLink()
    service = DeviceService(rig if rig is not None else Rig(hardware), link, config)
    thread = threading.Thread(target=service.run, daemon=True)
    thread.start()
    try:
        yield link
    finally:
        service.stop()
        thread.join(5.0)
        assert not thread.is_alive(), "the service loop did not stop"
        service.shutdown()
