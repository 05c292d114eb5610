"""Falcon packet format: the notes' vectors, exhaustive int16 round trips, and the stream parser
against arbitrary chunking, garbage and truncated frames."""
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tearcloth.haptics.device import ProtocolError
from tearcloth.haptics.falcon_packets import (
    BUTTON_CENTER,
    HOMING_MODE,
    LED_BLUE,
    LED_GREEN,
    LED_RED,
    FrameParser,
    decode_command,
    decode_report,
    encode_command,
    encode_report,
)

# Vectors computed in /work/shared/notes/haptics.md, section 4.
VECTORS = [
    ((0, 0, 0), LED_GREEN, b"<AAAAAAAAAAAACA>"),
    ((0, 0, 0), LED_RED | HOMING_MODE, b"<AAAAAAAAAAAAJA>"),
    ((1000, -1, -324), LED_BLUE, b"<IODAPPPPMLOPEA>"),
    ((32767, -32768, 4096), 0, b"<PPPHAAAIAAABAA>"),
]


@pytest.mark.parametrize("efforts, control, frame", VECTORS)
def test_command_vectors_from_notes(efforts, control, frame):
    assert encode_command(efforts, control) == frame
    cmd = decode_command(frame)
    assert cmd.efforts == efforts
    assert cmd.control == control


def test_report_vector_status_byte_carries_homed_flags_and_buttons():
    # -96 = 0xFFA0 -> nibbles 0, A, F, F -> "AKPP"; status 0x41 + (7 << 4 | 4) = 0xB5.
    frame = b"<AKPPAKPPAKPP\xb5A>"
    rep = decode_report(frame)
    assert rep.encoders == (-96, -96, -96)
    assert rep.homed == 0b111 and rep.all_homed
    assert rep.buttons == BUTTON_CENTER
    assert encode_report((-96, -96, -96), 7, BUTTON_CENTER) == frame


def test_every_int16_effort_and_encoder_value_round_trips():
    # Exhaustive: every value in every motor slot (3 x 65536 encodes/decodes, ~0.5 s).
    for v in range(-32768, 32768):
        for slot in range(3):
            e = [0, 0, 0]
            e[slot] = v
            assert decode_command(encode_command(e, 0)).efforts[slot] == v
            assert decode_report(encode_report(e, 0, 0)).encoders[slot] == v


@given(
    st.tuples(*[st.integers(-32768, 32767)] * 3),
    st.integers(0, 15),
    st.integers(0, 7),
    st.integers(0, 15),
)
def test_round_trip_properties(values, control, homed, buttons):
    c = encode_command(values, control)
    assert len(c) == 16 and c[0:1] == b"<" and c[15:] == b">"
    assert decode_command(c) == (values, control)
    r = encode_report(values, homed, buttons)
    assert decode_report(r) == (values, homed, buttons)


@pytest.mark.parametrize("bad", [32768, -32769, 40000])
def test_out_of_range_effort_is_refused_not_wrapped(bad):
    with pytest.raises(ValueError, match="16-bit"):
        encode_command((bad, 0, 0))


def test_malformed_frames_raise_protocol_error():
    with pytest.raises(ProtocolError):
        decode_report(b"<AAAAAAAAAAAAAA)")  # wrong terminator
    with pytest.raises(ProtocolError):
        decode_report(b"<AAAAAZAAAAAAAA>")  # 'Z' is not a nibble
    with pytest.raises(ProtocolError):
        decode_command(b"<AAAAAAAAAAAA\xb5A>")  # status byte only valid device -> host
    with pytest.raises(ValueError):
        encode_command((0, 0, 0), 0x10)


reports = st.lists(
    st.tuples(st.tuples(*[st.integers(-32768, 32767)] * 3), st.integers(0, 7), st.integers(0, 15)),
    min_size=1,
    max_size=12,
)
# Noise never contains '>', so it can never complete a false frame (see FrameParser).
noise = st.binary(max_size=25).map(lambda b: b.replace(b">", b"?"))


@settings(max_examples=200, deadline=None)
@given(reports, st.data())
def test_stream_split_anywhere_with_garbage_parses_the_same(items, data):
    frames = [encode_report(*it) for it in items]
    stream = bytearray()
    for f in frames:
        stream += data.draw(noise)
        if data.draw(st.booleans()):
            stream += f[: data.draw(st.integers(1, 15))]  # a truncated frame before the real one
        stream += f
    stream += data.draw(noise)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=20)))
    parser = FrameParser("report")
    got = []
    prev = 0
    for c in cuts + [len(stream)]:
        got += parser.feed(bytes(stream[prev:c]))
        prev = c
    assert got == frames
    assert [decode_report(f) for f in got] == [tuple(it) for it in items]
    assert parser.pending < 16


def test_parser_keeps_partial_tail_across_chunks():
    f = encode_report((1, 2, 3), 7, 0)
    p = FrameParser()
    assert p.feed(f[:5]) == []
    assert p.pending == 5
    assert p.feed(f[5:]) == [f]
    assert p.pending == 0


def test_parser_counts_garbage_and_rejections():
    good = encode_report((5, -5, 0), 0, 0)
    p = FrameParser()
    out = p.feed(b"xx" + good[:7] + good + b"<ZZZZZZZZZZZZZZZZZZ" + good)
    assert out == [good, good]
    assert p.rejected >= 2
    assert p.garbage_bytes > 0


def test_command_parser_for_the_emulator():
    cmds = [encode_command((i, -i, 2 * i), i % 16) for i in range(10)]
    p = FrameParser("command")
    stream = b"".join(cmds)
    out = []
    for i in range(0, len(stream), 7):
        out += p.feed(stream[i : i + 7])
    assert out == cmds
    with pytest.raises(ValueError):
        FrameParser("nonsense")
