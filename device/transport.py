"""Byte transports of the serial link, both ends. The only module that imports pyserial.

Device end (:func:`open_link`): non-blocking links the service polls once per control
chunk, so reading and writing never wait and never disturb the pacing of the loop.

- ``pty``: a pseudo-terminal pair; the service keeps the master and prints the slave's
  name (``/dev/pts/N``) for the home station to open like a serial port.
- ``tcp://HOST:PORT``: the byte stream served over TCP (port 0 picks a free one); the host
  opens ``socket://HOST:PORT`` with pyserial. A new connection replaces the old one, and
  the link says so (:meth:`Link.take_new_peer`): the service holds what the old one commanded.
- anything else is a serial port name (``/dev/ttyUSB0``) opened with pyserial at ``baud``.

Host end (:func:`open_stream`): an asyncio stream pair over pyserial-asyncio-fast for a port
name or any pyserial URL (``socket://``).
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import os
import socket
import tty
from abc import ABC, abstractmethod
from urllib.parse import urlsplit

import serial

READ_MAX = 4096
"""Most bytes read per poll: bounds the work a garbage burst can cause in one chunk."""
TX_BUFFER_MAX = 32768
"""Most bytes queued for a host that does not read. A frame that must not be dropped (an
ACK, a NACK, an event, a HELLO) and would pass it means the host is gone: the link drops
the connection (a TCP link) or discards what was queued (a port has no connection)."""
TX_DROPPABLE_MAX = TX_BUFFER_MAX // 2
"""Beyond this many bytes queued, droppable frames (telemetry) are refused: a slow host
loses samples long before the frames it must hear."""


class LinkError(OSError):
    """The link cannot be opened."""


class LinkSpecError(LinkError):
    """The link's spelling is wrong (an argument error, not a failure to open it)."""


class Link(ABC):
    """The device's end of the byte stream: non-blocking, polled by the service loop."""

    name: str
    """What the host opens: a port name or a ``socket://`` URL."""
    bits_per_second: float | None = None
    """Line rate for a real serial port (None: a pty or TCP has no line rate to respect)."""

    def __init__(self) -> None:
        self._tx = bytearray()
        self.tx_dropped = 0
        """Droppable frames refused because the host did not read."""
        self.tx_overflows = 0
        """Times a frame that must not be dropped found the queue full: the host was gone."""
        self._new_peer = False

    @abstractmethod
    def _read(self, limit: int) -> bytes: ...

    @abstractmethod
    def _write(self, data: bytes | bytearray) -> int: ...

    def read(self, limit: int = READ_MAX) -> bytes:
        """Whatever has arrived (up to ``limit`` bytes), ``b""`` if nothing."""
        try:
            return self._read(min(limit, READ_MAX))
        except (BlockingIOError, InterruptedError):
            return b""

    def send(self, frame: bytes, droppable: bool = False) -> bool:
        """Queue one whole frame; a droppable one is refused when the host is not reading.

        Never more than :data:`TX_BUFFER_MAX` bytes are queued: a frame that must not be
        dropped and does not fit means the host stopped reading, and is handled as a host
        gone (:meth:`_overflow`); the frame is not sent either.
        """
        if droppable and len(self._tx) + len(frame) > TX_DROPPABLE_MAX:
            self.tx_dropped += 1
            return False
        if len(self._tx) + len(frame) > TX_BUFFER_MAX:
            self.flush()  # what the link takes now, before giving up on the host
            if len(self._tx) + len(frame) > TX_BUFFER_MAX:
                self.tx_overflows += 1
                self._overflow()
                return False
        self._tx += frame
        self.flush()
        return True

    def _overflow(self) -> None:
        """The host does not read: what was queued for it is discarded (a port has no
        connection to drop; a host that opens it again asks for lost events)."""
        self._tx.clear()

    def take_new_peer(self) -> bool:
        """True once after a new host connected (TCP): nothing it sent commanded the motion
        under way. A port cannot tell (its host opens it without the device knowing)."""
        new, self._new_peer = self._new_peer, False
        return new

    def flush(self) -> None:
        """Write as much of the queue as the link takes now."""
        while self._tx:
            try:
                n = self._write(self._tx)
            except (BlockingIOError, InterruptedError):
                return
            if n <= 0:
                return
            del self._tx[:n]

    @property
    def pending(self) -> int:
        return len(self._tx)

    def discard_output(self) -> None:
        self._tx.clear()

    @abstractmethod
    def close(self) -> None: ...


class PtyLink(Link):
    """A pseudo-terminal pair; the slave end is the host's serial port."""

    def __init__(self) -> None:
        super().__init__()
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        # Holding the slave open too keeps the master readable across host reconnects
        # (otherwise it reports EIO whenever no host has the port open).
        self.name = os.ttyname(self._slave)

    def _read(self, limit: int) -> bytes:
        return os.read(self._master, limit)

    def _write(self, data: bytes | bytearray) -> int:
        return os.write(self._master, data)

    def close(self) -> None:
        for fd in (self._master, self._slave):
            with contextlib.suppress(OSError):
                os.close(fd)


class TcpLink(Link):
    """The byte stream over TCP, one host at a time (the newest connection wins).

    A station whose connection broke without a word (a cable, a sleeping laptop) must get
    back in at once, and the device cannot tell a live connection from such a dead one: so
    a new connection is not refused but takes over, and :meth:`take_new_peer` tells the
    service, which holds the motion the old connection commanded."""

    def __init__(self, host: str, port: int) -> None:
        super().__init__()
        self._server = socket.create_server((host, port))
        self._server.setblocking(False)
        bound_host, bound_port = self._server.getsockname()[:2]
        self.name = f"socket://{bound_host}:{bound_port}"
        self._conn: socket.socket | None = None

    def _accept(self) -> None:
        try:
            conn, _ = self._server.accept()
        except (BlockingIOError, InterruptedError):
            return
        if self._conn is not None:
            self._conn.close()
        conn.setblocking(False)
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._conn = conn
        self._tx.clear()  # what was queued for the previous host is meaningless now
        self._new_peer = True

    def _overflow(self) -> None:
        self._drop()  # a host that does not read is gone

    def _drop(self) -> None:
        if self._conn is not None:
            self._conn.close()
            self._conn = None
        self._tx.clear()

    def _read(self, limit: int) -> bytes:
        self._accept()
        if self._conn is None:
            return b""
        try:
            data = self._conn.recv(limit)
        except (ConnectionError, TimeoutError):
            self._drop()
            return b""
        if not data:  # orderly close by the host
            self._drop()
        return data

    def _write(self, data: bytes | bytearray) -> int:
        if self._conn is None:
            self._tx.clear()  # nobody to tell; the next host starts from a clean stream
            return 0
        try:
            return self._conn.send(data)
        except (ConnectionError, TimeoutError):
            self._drop()
            return 0

    def close(self) -> None:
        self._drop()
        self._server.close()


class SerialLink(Link):
    """A real serial port (pyserial; 8N1, no flow control)."""

    def __init__(self, port: str, baud: int) -> None:
        super().__init__()
        try:
            self._port = serial.Serial(port, baud, timeout=0, write_timeout=0, exclusive=True)
        except (serial.SerialException, ValueError) as exc:
            raise LinkError(errno.ENODEV, f"cannot open serial port {port}: {exc}") from None
        self.name = port
        self.bits_per_second = float(baud)

    def _read(self, limit: int) -> bytes:
        data: bytes = self._port.read(limit)
        return data

    def _write(self, data: bytes | bytearray) -> int:
        return os.write(self._port.fileno(), data)

    def close(self) -> None:
        self._port.close()


def open_link(spec: str, baud: int = 921600) -> Link:
    """The device's link from its command-line spelling: ``pty``, ``tcp://H:P`` or a port."""
    if spec == "pty":
        return PtyLink()
    if spec.startswith("tcp://"):
        try:
            url = urlsplit(spec)
            host, port = url.hostname, url.port  # .port raises for a port out of range
        except ValueError:
            host = port = None
        if host is None or port is None:
            raise LinkSpecError(
                errno.EINVAL, f"bad TCP link {spec!r}; expected tcp://HOST:PORT (port 0..65535)"
            )
        try:
            return TcpLink(host, port)
        except OSError as exc:
            raise LinkError(
                exc.errno or errno.EADDRINUSE, f"cannot listen on {spec}: {exc}"
            ) from None
    return SerialLink(spec, baud)


async def open_stream(
    url: str, baud: int = 921600
) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
    """The host's asyncio streams to a port name or pyserial URL (``socket://H:P``)."""
    try:
        import serial_asyncio_fast  # the host's side only: the device service never needs it

        reader, writer = await serial_asyncio_fast.open_serial_connection(
            url=url, baudrate=baud, exclusive=not url.startswith("socket://")
        )
    except (serial.SerialException, OSError, ValueError) as exc:
        raise LinkError(errno.ENODEV, f"cannot open {url}: {exc}") from None
    port = writer.transport.get_extra_info("serial")  # the pyserial object
    if port is not None and port.is_open and not url.startswith("socket://"):
        port.reset_input_buffer()  # bytes the device wrote before anyone had the port open
    return reader, writer
