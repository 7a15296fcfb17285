"""The decoder takes anything: random and mutated frames raise only the protocol's errors.

LIGHTSTAGE_FUZZ_EXAMPLES=5000 runs a longer fuzz (default 300 examples per test).
"""
import os

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from lightstage_driver import protocol as p
from lightstage_driver.errors import ProtocolError

COMMANDS = [int(c) for c in p.Command] + [int(e) for e in p.Event] + [p.NAK_CMD]


@st.composite
def valid_frames(draw):
    seq = draw(st.integers(0, 255))
    cmd = draw(st.sampled_from(COMMANDS) | st.integers(0, 255))
    payload = draw(st.binary(max_size=p.MAX_PAYLOAD))
    return p.encode_frame(seq, cmd, payload)


@st.composite
def mutated_frames(draw):
    frame = bytearray(draw(valid_frames()))
    for _ in range(draw(st.integers(1, 4))):
        kind = draw(st.sampled_from(['flip', 'drop', 'insert', 'truncate', 'len']))
        if kind == 'flip' and frame:
            i = draw(st.integers(0, len(frame) - 1))
            frame[i] ^= 1 << draw(st.integers(0, 7))
        elif kind == 'drop' and frame:
            del frame[draw(st.integers(0, len(frame) - 1))]
        elif kind == 'insert':
            frame.insert(draw(st.integers(0, len(frame))), draw(st.integers(0, 255)))
        elif kind == 'truncate':
            del frame[draw(st.integers(0, len(frame))):]
        elif kind == 'len' and len(frame) > 1:
            frame[1] = draw(st.integers(0, 255))
    return bytes(frame)


FUZZ = settings(max_examples=int(os.environ.get('LIGHTSTAGE_FUZZ_EXAMPLES', 300)), deadline=None, suppress_health_check=[HealthCheck.too_slow])

PARSERS = [p.Identity.unpack, p.Status.unpack, p.Nak.unpack, p.TriggerEvent.unpack, p.SequenceDone.unpack,
           p.unpack_set_pattern, p.unpack_set_levels, p.unpack_sequence_header,
           lambda b: p.unpack_sequence_entries(b, b[4] if len(b) > 4 else 0),
           lambda b: p.unpack_u32(b, 'x'), lambda b: p.unpack_u32_pair(b, 'x')]


@FUZZ
@given(st.binary(max_size=300) | mutated_frames())
def test_decode_frame_raises_only_protocol_errors(data):
    try:
        frame = p.decode_frame(data)
    except ProtocolError:
        return
    # anything accepted must re-encode to exactly the same bytes
    assert frame.encode() == data


@FUZZ
@given(st.binary(max_size=p.MAX_PAYLOAD))
def test_payload_parsers_raise_only_protocol_errors(payload):
    for parse in PARSERS:
        try:
            parse(payload)
        except ProtocolError:
            pass


@FUZZ
@given(st.lists(st.binary(max_size=80) | mutated_frames() | valid_frames(), max_size=8), st.data())
def test_stream_decoder_never_raises_and_finds_every_intact_frame_after_noise(chunks, data):
    decoder = p.FrameDecoder()
    stream = b''.join(chunks)
    target = data.draw(valid_frames())
    out = []
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=5)))
    pieces = [stream[a:b] for a, b in zip([0] + cuts, cuts + [len(stream)])]
    for piece in pieces:
        out += decoder.feed(piece, now=0.0)
    # the line goes quiet (inter-byte timeout), then an intact frame arrives
    out += decoder.feed(target, now=1.0)
    for item in out:
        assert isinstance(item, (p.Frame, p.BadFrame))
    assert p.decode_frame(target) in out
    assert len(decoder.buffer) == 0
