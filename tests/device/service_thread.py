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
def service_in_thread(hardware: SimulatedHardware, config: ServiceConfig) -> Iterator[PtyLink]:
    """The service running on ``hardware``; its link. Stopped, joined and shut down after."""
    link = PtyLink()
    service = DeviceService(Rig(hardware), link, config)
    thread = threading.Thread(target=service.run, daemon=True)
    thread.start()
    try:
        yield link
    finally:
        service.stop()
        thread.join(5.0)
        assert not thread.is_alive(), "the service loop did not stop"
        service.shutdown()
