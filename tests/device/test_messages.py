"""Message layouts: round trips, refusals of bodies that do not fit, bit flips, README table."""

import math
import re
import struct
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from device.protocol import messages as m
from device.protocol.framing import (
    HANDSHAKE_TYPE,
    PROTOCOL_VERSION,
    Frame,
    FrameDecoder,
    encode_frame,
)

ALL = [*m.DEVICE_MESSAGES.values(), *m.HOST_MESSAGES.values()]
README = Path(__file__).resolve().parents[2] / "README.md"


def _value(spec: Any) -> st.SearchStrategy[Any]:
    if spec.is_text:
        n = int(spec.fmt[:-1])
        return st.text(st.characters(min_codepoint=32, max_codepoint=126), max_size=n)
    if spec.enum is not None:
        one: st.SearchStrategy[Any] = st.sampled_from(list(spec.enum))
    elif spec.fmt == "f":
        one = st.floats(width=32)
    elif spec.fmt == "d":
        one = st.floats()
    elif spec.fmt == "?":
        one = st.booleans()
    else:
        size = struct.calcsize(spec.fmt)
        signed = spec.fmt.islower()
        lo = -(1 << (8 * size - 1)) if signed else 0
        hi = (1 << (8 * size - 1)) - 1 if signed else (1 << (8 * size)) - 1
        one = st.integers(lo, hi)
    if spec.count > 1:
        return st.tuples(*[one] * spec.count)
    return one


@st.composite
def messages(draw: st.DrawFn) -> m.Message:
    cls = draw(st.sampled_from(ALL))
    return cls(**{spec.name: draw(_value(spec)) for spec in cls.layout()})


@given(messages(), st.integers(0, 0xFFFF))
@settings(max_examples=400)
def test_every_message_round_trips_through_the_wire(message: m.Message, seq: int) -> None:
    wire = m.encode(message, seq)
    frames = FrameDecoder().feed(wire)
    assert len(frames) == 1 and frames[0].seq == seq
    back = m.decode(frames[0], message.SENDER)
    assert type(back) is type(message)
    # Bitwise equal (NaN != NaN, so compare the packed bodies as well as the fields).
    assert m.pack(back) == m.pack(message)
    for spec in message.layout():
        a, b = getattr(back, spec.name), getattr(message, spec.name)
        if spec.fmt not in ("f", "d"):
            assert a == b


@given(messages(), st.data())
@settings(max_examples=200)
def test_a_single_bit_flip_anywhere_is_caught(message: m.Message, data: st.DataObject) -> None:
    wire = bytearray(m.encode(message, 7))
    bit = data.draw(st.integers(0, len(wire) * 8 - 1))
    wire[bit // 8] ^= 1 << (bit % 8)
    dec = FrameDecoder()
    assert dec.feed(bytes(wire)) + dec.feed(b"\x00") == []
    assert dec.stats.dropped >= 1


def test_every_bit_of_a_telemetry_frame_is_covered() -> None:
    wire = m.encode(m.Telemetry(time=12.5, mode=m.DeviceMode.ACTIVE, pose=(0.1,) * 6), 3)
    for bit in range(len(wire) * 8):
        flipped = bytearray(wire)
        flipped[bit // 8] ^= 1 << (bit % 8)
        dec = FrameDecoder()
        assert dec.feed(bytes(flipped)) + dec.feed(b"\x00") == [], bit


@pytest.mark.parametrize("cls", ALL, ids=lambda c: c.__name__)
def test_a_body_of_the_wrong_length_is_malformed(cls: type[m.Message]) -> None:
    for body in (b"\x01" * (cls.size() + 1), b"\x01" * max(0, cls.size() - 1)):
        if len(body) == cls.size():
            continue
        with pytest.raises(m.MessageError) as err:
            m.unpack(cls, body)
        assert err.value.code == m.NackCode.MALFORMED
        assert cls.__name__ in str(err.value)


def test_an_unknown_enum_value_is_malformed() -> None:
    body = bytearray(m.pack(m.StartSegment(segment_id=1)))
    offset = struct.calcsize("<If")  # segment_id, duration, then the six waveforms
    body[offset] = 9
    with pytest.raises(m.MessageError, match=r"^waveform of x: 9 is not a known Waveform$") as err:
        m.unpack(m.StartSegment, bytes(body))
    assert err.value.code == m.NackCode.MALFORMED
    assert (err.value.field, err.value.axis) == ("waveform", 0)  # named in the NACK


def test_a_bool_byte_other_than_0_or_1_is_malformed() -> None:
    """``struct`` reads any non-zero byte as true: a compliant byte of 7 was taken as a
    compliant axis. Only 0 and 1 are a bool on the wire."""
    body = bytearray(m.pack(m.StartSegment(segment_id=1)))
    offset = m.StartSegment.size() - 2 * 24 - 2 * 4 - 6  # the six compliant bytes
    for value in (0, 1):
        body[offset + 5] = value
        read = m.unpack(m.StartSegment, bytes(body))
        assert isinstance(read, m.StartSegment) and read.compliant[5] is bool(value)
    body[offset + 5] = 7
    with pytest.raises(m.MessageError, match=r"^compliant of yaw: 7 is not 0 or 1$") as err:
        m.unpack(m.StartSegment, bytes(body))
    assert err.value.code == m.NackCode.MALFORMED
    assert (err.value.field, err.value.axis) == ("compliant", 5)


def test_an_unknown_type_is_an_unknown_command() -> None:
    with pytest.raises(m.MessageError) as err:
        m.decode(Frame(99, 0, b""), "host")
    assert err.value.code == m.NackCode.UNKNOWN_COMMAND


def test_type_numbers_are_unique_per_direction_and_the_handshake_is_shared() -> None:
    assert m.HOST_MESSAGES[HANDSHAKE_TYPE] is m.Hello
    assert m.DEVICE_MESSAGES[HANDSHAKE_TYPE] is m.DeviceHello
    assert all(t < 16 for t in m.DEVICE_MESSAGES)
    assert all(t == HANDSHAKE_TYPE or t >= 16 for t in m.HOST_MESSAGES)
    with pytest.raises(TypeError, match="taken"):

        class Clash(m.Message, type_=2, sender="device"):
            pass


def test_a_handshake_of_another_version_is_delivered_other_frames_are_not() -> None:
    dec = FrameDecoder()
    hello = encode_frame(Frame(HANDSHAKE_TYPE, 1, b"", version=PROTOCOL_VERSION + 1))
    other = encode_frame(Frame(2, 2, b"", version=PROTOCOL_VERSION + 1))
    frames = dec.feed(hello + other)
    assert [(f.type, f.version) for f in frames] == [(HANDSHAKE_TYPE, PROTOCOL_VERSION + 1)]
    assert dec.stats.bad_version == 1


def test_text_longer_than_its_field_is_cut_not_refused() -> None:
    nack = m.Nack(text="x" * 500)
    assert m.unpack(m.Nack, m.pack(nack)).text == "x" * 96  # type: ignore[attr-defined]


def test_non_finite_field_names_the_first_bad_float() -> None:
    assert m.non_finite_field(m.SetImpedance()) is None
    bad = m.SetImpedance(stiffness=(0, 0, 0, 0, math.nan, 0))
    assert m.non_finite_field(bad) == "stiffness"


def test_largest_message_fits_a_frame_and_a_250_hz_stream_fits_a_fast_uart() -> None:
    assert max(c.size() for c in ALL) <= 1024
    frame = len(m.encode(m.Telemetry(), 0))
    assert frame * 250 * 10 < 921600  # bits per second at 8N1


def test_readme_protocol_table_is_generated_from_the_code() -> None:
    text = README.read_text()
    found = re.search(r"<!-- protocol:start -->\n(.*?)<!-- protocol:end -->", text, re.S)
    assert found, "README lacks the protocol section markers"
    assert found.group(1) == m.markdown_table(), (
        "README is stale: paste the output of `ankle protocol` between the markers"
    )
