import itertools

import pytest
from hypothesis import given
from hypothesis import strategies as st

from device.protocol.framing import (
    MAX_BODY,
    PROTOCOL_VERSION,
    Frame,
    FrameDecoder,
    crc16,
    encode_frame,
)

frames = st.builds(
    Frame,
    type=st.integers(0, 255),
    seq=st.integers(0, 0xFFFF),
    body=st.binary(max_size=200),
)


def test_crc_is_ccitt_false() -> None:
    assert crc16(b"123456789") == 0x29B1


@given(st.lists(frames, max_size=8), st.integers(1, 17))
def test_round_trip_in_any_chunking(batch: list[Frame], chunk: int) -> None:
    wire = b"".join(encode_frame(f) for f in batch)
    assert wire.count(0) == len(batch)  # one delimiter per frame, none inside
    dec = FrameDecoder()
    out: list[Frame] = []
    for i in range(0, len(wire), chunk):
        out += dec.feed(wire[i : i + chunk])
    assert out == batch
    assert dec.stats.dropped == 0


@given(st.binary(max_size=3000))
def test_arbitrary_bytes_never_raise_and_yield_only_checked_frames(noise: bytes) -> None:
    dec = FrameDecoder()
    for f in dec.feed(noise):
        assert encode_frame(f)[:-1] in noise  # anything accepted was a whole valid frame


@given(st.binary(max_size=300), frames)
def test_reader_resynchronises_after_garbage(garbage: bytes, frame: Frame) -> None:
    dec = FrameDecoder()
    dec.feed(garbage + b"\x00")
    assert dec.feed(encode_frame(frame)) == [frame]


@given(st.lists(frames, min_size=1, max_size=3))
def test_every_single_bit_flip_is_caught(batch: list[Frame]) -> None:
    wire = b"".join(encode_frame(f) for f in batch)
    for pos, bit in itertools.product(range(len(wire)), range(8)):
        bad = bytearray(wire)
        bad[pos] ^= 1 << bit
        got = FrameDecoder().feed(bytes(bad) + b"\x00")
        # A flip may destroy a frame (dropped) but never forges one.
        assert all(f in batch for f in got)
        assert len(got) <= len(batch)


def test_each_check_counts_its_drop() -> None:
    good = encode_frame(Frame(3, 7, b"hello"))
    dec = FrameDecoder()
    flipped = bytearray(good)
    flipped[good.index(b"h")] ^= 0x10  # a body byte: only the CRC can tell
    dec.feed(bytes(flipped))
    dec.feed(b"\x05\x00")  # COBS says 4 more bytes follow: bad encoding
    dec.feed(b"\x02\x01\x00")  # decodes to 1 byte: too short
    dec.feed(encode_frame(Frame(3, 7, b"x", version=PROTOCOL_VERSION + 1)))
    dec.feed(b"\x07" * (2 * MAX_BODY) + b"\x00")
    assert dec.feed(good) == [Frame(3, 7, b"hello")]
    s = dec.stats
    assert (s.bad_crc, s.bad_encoding, s.bad_length, s.bad_version, s.overflow) == (1, 1, 1, 1, 1)
    assert s.frames == 1


def test_encoder_refuses_what_cannot_be_framed() -> None:
    with pytest.raises(ValueError, match="exceeds"):
        encode_frame(Frame(1, 1, b"\x00" * (MAX_BODY + 1)))
    with pytest.raises(ValueError, match="16 bits"):
        encode_frame(Frame(1, 70000, b""))
