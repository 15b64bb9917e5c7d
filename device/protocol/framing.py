"""Frames on the serial byte stream: ``COBS(header + body + CRC-16) + 0x00``.

Header (little-endian): protocol version (u8), message type (u8), sequence number (u16),
body length (u16). The CRC is CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF) over header and
body, appended little-endian. COBS leaves no zero byte inside a frame, so the zero that ends
one is an unambiguous place to resynchronise after garbage or a lost byte.

The decoder never raises on input bytes and never returns a frame that failed a check: a
frame with a bad COBS encoding, a length that disagrees with its header, a CRC mismatch or
another protocol version (except a handshake, see :data:`HANDSHAKE_TYPE`) is dropped and
counted in :class:`DecoderStats`.
"""

from __future__ import annotations

import binascii
import struct
from dataclasses import dataclass, field

from cobs import cobs

PROTOCOL_VERSION = 3
"""2: trip SOFTWARE, NACK DEVICE_FAULT, events of 120 bytes of text. 3: telemetry's
``clock_resets``."""
HANDSHAKE_TYPE = 1
"""Message type of the handshake in every protocol version. A frame of this type is delivered
whatever its version, so each side can tell the other which version it speaks instead of
timing out; every other frame of a foreign version is dropped."""
HEADER = struct.Struct("<BBHH")
CRC = struct.Struct("<H")
MAX_BODY = 1024
"""Largest body (bytes); telemetry is the largest message and fits well inside."""
MAX_ENCODED = HEADER.size + MAX_BODY + CRC.size + (HEADER.size + MAX_BODY + CRC.size) // 254 + 2
"""Longest COBS-encoded frame; the decoder drops anything longer without waiting for its end."""


def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE (the C implementation in the standard library)."""
    return binascii.crc_hqx(data, 0xFFFF)


@dataclass(frozen=True)
class Frame:
    type: int
    seq: int
    body: bytes
    version: int = PROTOCOL_VERSION


def encode_frame(frame: Frame) -> bytes:
    """The wire bytes of one frame, delimiter included."""
    if not 0 <= frame.type <= 0xFF or not 0 <= frame.seq <= 0xFFFF:
        raise ValueError("message type must fit a byte and sequence number 16 bits")
    if len(frame.body) > MAX_BODY:
        raise ValueError(f"body of {len(frame.body)} bytes exceeds {MAX_BODY}")
    raw = HEADER.pack(frame.version, frame.type, frame.seq, len(frame.body)) + frame.body
    encoded: bytes = cobs.encode(raw + CRC.pack(crc16(raw)))
    return encoded + b"\x00"


@dataclass
class DecoderStats:
    """What the decoder dropped, by reason. Frames acted on are counted in ``frames``."""

    frames: int = 0
    bad_encoding: int = 0
    bad_length: int = 0
    bad_crc: int = 0
    bad_version: int = 0
    overflow: int = 0

    @property
    def dropped(self) -> int:
        return self.bad_encoding + self.bad_length + self.bad_crc + self.bad_version + self.overflow


@dataclass
class FrameDecoder:
    """Turns a byte stream, fed in pieces of any size, into checked frames."""

    version: int = PROTOCOL_VERSION
    stats: DecoderStats = field(default_factory=DecoderStats)
    _buffer: bytearray = field(default_factory=bytearray)
    _discarding: bool = False

    def feed(self, data: bytes) -> list[Frame]:
        frames: list[Frame] = []
        start = 0
        while True:
            end = data.find(b"\x00", start)
            if end < 0:
                self._append(data[start:])
                return frames
            self._append(data[start:end])
            if self._discarding:
                self._discarding = False  # the overflowed frame ends here: resynchronised
            elif self._buffer:
                frame = self._check(bytes(self._buffer))
                if frame is not None:
                    frames.append(frame)
            self._buffer.clear()
            start = end + 1

    def reset(self) -> None:
        """Forget a frame half received (its sender has gone); the counts stay."""
        self._buffer.clear()
        self._discarding = False

    def _append(self, chunk: bytes) -> None:
        if self._discarding:
            return
        self._buffer += chunk
        if len(self._buffer) > MAX_ENCODED:
            self.stats.overflow += 1
            self._buffer.clear()
            self._discarding = True

    def _check(self, encoded: bytes) -> Frame | None:
        try:
            raw: bytes = cobs.decode(encoded)
        except cobs.DecodeError:
            self.stats.bad_encoding += 1
            return None
        if len(raw) < HEADER.size + CRC.size:
            self.stats.bad_length += 1
            return None
        payload, (crc,) = raw[: -CRC.size], CRC.unpack(raw[-CRC.size :])
        version, mtype, seq, length = HEADER.unpack_from(payload)
        if length != len(payload) - HEADER.size:
            self.stats.bad_length += 1
            return None
        if crc16(payload) != crc:
            self.stats.bad_crc += 1
            return None
        if version != self.version and mtype != HANDSHAKE_TYPE:
            self.stats.bad_version += 1
            return None
        self.stats.frames += 1
        return Frame(mtype, seq, payload[HEADER.size :], version)
