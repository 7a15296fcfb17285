"""Protocol rules every firmware must follow (docs/PROTOCOL.md), checked on each backend over a pty."""
import struct
import time

import pytest

from lightstage_driver import protocol as p
from lightstage_driver.errors import NakError

from helpers.driver import wait_until

pytestmark = pytest.mark.process


def raw_exchange(stage, frame: bytes, replies: int, timeout_s: float = 1.0) -> list:
    """Write a frame as is and collect the next `replies` frames."""
    link = stage.link
    link._serial.write(frame)
    got = []
    deadline = time.monotonic() + timeout_s
    while len(got) < replies and time.monotonic() < deadline:
        got += [item for item in link._decoder.feed(link._read(0.05)) if isinstance(item, p.Frame)]
    return got


@pytest.mark.parametrize('cmd, payload, reason, value', [
    (p.Command.FIRE, b'\x01\x02\x03', p.NakReason.BAD_LENGTH, 3),
    (p.Command.SET_PATTERN, struct.pack('<BI', 0x80, 1), p.NakReason.BAD_FLAGS, 0x80),
    (p.Command.SET_WATCHDOG, struct.pack('<H', 60001), p.NakReason.WATCHDOG_RANGE, 60001),
    (p.Command.SET_WATCHDOG, struct.pack('<H', 10), p.NakReason.WATCHDOG_RANGE, 10),
    (p.Command.RUN_SEQUENCE, struct.pack('<IB', 0, 0), p.NakReason.SEQUENCE_LENGTH, 0),
    (p.Command.RUN_SEQUENCE, struct.pack('<IB', 0, 17) + bytes(8), p.NakReason.SEQUENCE_LENGTH, 17),
    (p.Command.RUN_SEQUENCE, p.pack_sequence(1_000_001, [p.SequenceEntry(1, 100)]), p.NakReason.GAP_RANGE,
     1_000_001),
    (p.Command.RUN_SEQUENCE, p.pack_sequence(0, [p.SequenceEntry(1, 100), p.SequenceEntry(2, 0)]),
     p.NakReason.EXPOSURE_RANGE, 0),
])
def test_refusals_carry_reason_and_value_and_change_nothing(stage, backend, cmd, payload, reason, value):
    stage.set_pattern([0.0] * 31 + [1.0], show_now=True)
    assert wait_until(lambda: backend.current_word() == 1 << 31, 2.0)
    backend.reset_observations()
    with pytest.raises(NakError) as info:
        stage.link.transact(cmd, payload)
    assert (info.value.command, info.value.reason, info.value.value) == (cmd, reason, value)
    status = stage.heartbeat()
    assert status.leds_lit and not status.sequence_running
    time.sleep(0.02)
    assert backend.trigger_pulses() == [] and all(w.word == 1 << 31 for w in backend.led_words())


def test_set_levels_is_refused_by_on_off_firmware(stage):
    if stage.identity.pwm_bits:
        pytest.skip('this firmware dims')
    with pytest.raises(NakError, match='UNSUPPORTED'):
        stage.link.transact(p.Command.SET_LEVELS, p.pack_set_levels([0] * 32, True))


def test_a_repeated_fire_is_answered_from_the_cache_not_fired_twice(stage, backend):
    stage.set_pattern([1.0] + [0.0] * 31, show_now=False)
    seq = stage.link._next_seq()
    frame = p.encode_frame(seq, p.Command.FIRE, p.pack_u32(1000))
    first = raw_exchange(stage, frame, 1)
    again = raw_exchange(stage, frame, 1)
    assert len(first) == 1 and first == again and first[0].cmd == p.Command.FIRE | p.REPLY_BIT
    time.sleep(0.05)
    assert len(backend.trigger_pulses()) == 1
    stage.heartbeat()


def test_during_a_sequence_only_heartbeat_and_all_off_are_served(stage, backend):
    events = []
    on_event = stage.link.on_event
    stage.link.on_event = lambda frame, t: (events.append(frame), on_event(frame, t))
    try:
        payload = p.pack_sequence(0, [p.SequenceEntry(0b101, 200_000)] * 3)
        assert stage.link.transact(p.Command.RUN_SEQUENCE, payload).frame.payload == b'\x03'
        with pytest.raises(NakError, match='BUSY'):
            stage.link.transact(p.Command.FIRE, p.pack_u32(100))
        assert stage.heartbeat().sequence_running
        assert wait_until(lambda: backend.current_word() == 0b101, 1.0)
        stage.all_off()
        assert backend.current_word() == 0 or wait_until(lambda: backend.current_word() == 0, 1.0)
        done = [p.SequenceDone.unpack(f.payload) for f in events if f.cmd == p.Event.SEQUENCE_DONE]
        assert done and done[0].status == p.SequenceStatus.ABORTED_BY_ALL_OFF and done[0].count_done < 3
        assert not stage.heartbeat().sequence_running
        assert wait_until(lambda: len(backend.trigger_pulses()) >= 1, 1.0)
        assert backend.trigger_pulses()[0].width_us < 200_000     # cut short
    finally:
        stage.link.on_event = on_event


def test_watchdog_aborts_a_running_sequence(stage, backend):
    events = []
    on_event = stage.link.on_event
    stage.link.on_event = lambda frame, t: (events.append(frame), on_event(frame, t))
    try:
        stage.set_watchdog(100)
        payload = p.pack_sequence(300_000, [p.SequenceEntry(1, 1000)] * 3)   # long dark gaps
        stage.link.transact(p.Command.RUN_SEQUENCE, payload)
        stage.link.wait_until(lambda: {p.Event.SEQUENCE_DONE, p.Event.WATCHDOG} <= {f.cmd for f in events}, 3.0)
        done = [p.SequenceDone.unpack(f.payload) for f in events if f.cmd == p.Event.SEQUENCE_DONE]
        assert done and done[0].status == p.SequenceStatus.ABORTED_BY_WATCHDOG
        assert done[0].count_done == 1
        assert any(f.cmd == p.Event.WATCHDOG for f in events)
    finally:
        stage.link.on_event = on_event
