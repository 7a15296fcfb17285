"""The simulator's firmware logic on a fake clock: deterministic timing of the protocol rules."""
import struct

import pytest

from lightstage_driver import protocol as p
from lightstage_driver.firmware_model import FirmwareLimits, FirmwareModel


class Harness:
    def __init__(self, **limits):
        self.latches, self.pulses = [], []
        self.model = FirmwareModel(FirmwareLimits(**limits), on_latch=lambda t, w: self.latches.append((t, w)),
                                   on_pulse=lambda t, w: self.pulses.append((t, w)))
        self.sent = [p.decode_frame(f) for f in self.model.boot(0.0)]
        self.seq = 0

    def send(self, cmd, payload=b'', now=0.0, seq=None):
        if seq is None:
            self.seq += 1
            seq = self.seq
        out = [p.decode_frame(f) for f in self.model.receive(p.encode_frame(seq, cmd, payload), now)]
        self.sent += out
        return out

    def poll(self, now):
        out = [p.decode_frame(f) for f in self.model.poll(now)]
        self.sent += out
        return out


def nak_of(frames):
    naks = [p.Nak.unpack(f.payload) for f in frames if f.cmd == p.NAK_CMD]
    assert len(naks) == 1, frames
    return naks[0]


def test_boot_sends_ready_with_identity():
    h = Harness()
    assert h.sent[0].cmd == p.Event.READY and h.sent[0].seq == 0
    ident = p.Identity.unpack(h.sent[0].payload)
    assert (ident.led_count, ident.sites, ident.channels, ident.pwm_bits) == (32, 8, 4, 0)
    assert (ident.min_exposure_us, ident.max_exposure_us, ident.watchdog_ms) == (20, 2_000_000, 1000)


def test_fire_lights_the_armed_pattern_for_exactly_the_exposure():
    h = Harness()
    h.send(p.Command.SET_PATTERN, p.pack_set_pattern(0xA5, False), now=0.1)
    assert h.latches == []                    # armed, not lit
    assert h.send(p.Command.FIRE, p.pack_u32(5000), now=0.2) == []   # reply comes after the exposure
    assert h.latches == [(0.2, 0xA5)]
    assert h.poll(0.2049) == []
    reply, = h.poll(0.21)
    t0, t1 = p.unpack_u32_pair(reply.payload, 'FIRE')
    assert (t0, t1) == (200_000, 205_000)
    assert h.latches[-1] == (pytest.approx(0.205), 0)
    assert h.pulses == [(0.2, pytest.approx(5000))]


def test_duplicate_fire_is_answered_from_the_cache_not_fired_twice():
    h = Harness()
    h.send(p.Command.SET_PATTERN, p.pack_set_pattern(1, False))
    h.send(p.Command.FIRE, p.pack_u32(100), now=1.0)
    first, = h.poll(1.001)
    again = h.send(p.Command.FIRE, p.pack_u32(100), now=1.01, seq=h.seq)   # retry, same seq
    assert again == [first]
    assert len(h.pulses) == 1


@pytest.mark.parametrize('cmd, payload, reason, value', [
    (p.Command.FIRE, p.pack_u32(19), p.NakReason.EXPOSURE_RANGE, 19),
    (p.Command.FIRE, p.pack_u32(2_000_001), p.NakReason.EXPOSURE_RANGE, 2_000_001),
    (p.Command.FIRE, b'\x01', p.NakReason.BAD_LENGTH, 1),
    (p.Command.SET_PATTERN, struct.pack('<BI', 0x02, 1), p.NakReason.BAD_FLAGS, 2),
    (p.Command.SET_LEVELS, p.pack_set_levels([0] * 32, True), p.NakReason.UNSUPPORTED, p.Command.SET_LEVELS),
    (p.Command.SET_WATCHDOG, struct.pack('<H', 49), p.NakReason.WATCHDOG_RANGE, 49),
    (p.Command.RUN_SEQUENCE, p.pack_sequence(0, []), p.NakReason.SEQUENCE_LENGTH, 0),
    (p.Command.RUN_SEQUENCE, p.pack_sequence(0, [p.SequenceEntry(1, 100)] * 17)[:p.MAX_PAYLOAD],
     p.NakReason.SEQUENCE_LENGTH, 17),
    (p.Command.RUN_SEQUENCE, p.pack_sequence(0, [p.SequenceEntry(1, 100)] * 2)[:-1], p.NakReason.BAD_LENGTH, 20),
    (p.Command.RUN_SEQUENCE, p.pack_sequence(2_000_000, [p.SequenceEntry(1, 100)]), p.NakReason.GAP_RANGE,
     2_000_000),
    (p.Command.RUN_SEQUENCE, p.pack_sequence(0, [p.SequenceEntry(1, 100), p.SequenceEntry(2, 5)]),
     p.NakReason.EXPOSURE_RANGE, 5),
    (0x33, b'', p.NakReason.UNKNOWN_COMMAND, 0x33),
])
def test_refused_commands_change_nothing(cmd, payload, reason, value):
    h = Harness()
    h.send(p.Command.SET_PATTERN, p.pack_set_pattern(0xF0, True))
    latches = list(h.latches)
    nak = nak_of(h.send(cmd, payload, now=0.001))
    assert (nak.cmd, nak.reason, nak.value) == (cmd, reason, value)
    h.poll(0.5)
    assert h.latches == latches and h.pulses == []
    assert h.model.armed_word == 0xF0


def test_bad_crc_gets_a_nak_and_counts():
    h = Harness()
    frame = bytearray(p.encode_frame(4, p.Command.ALL_OFF))
    frame[-1] ^= 0x10
    out = [p.decode_frame(f) for f in h.model.receive(bytes(frame), 0.0)]
    assert nak_of(out).reason == p.NakReason.BAD_CRC
    status = p.Status.unpack(h.send(p.Command.HEARTBEAT)[0].payload)
    assert status.rx_errors == 1


def test_sequence_runs_on_schedule_with_events_and_rejects_other_commands():
    h = Harness()
    entries = [p.SequenceEntry(1 << k, 1000 * (k + 1)) for k in range(3)]
    out = h.send(p.Command.RUN_SEQUENCE, p.pack_sequence(500, entries), now=1.0)
    assert out[0].cmd == p.Command.RUN_SEQUENCE | p.REPLY_BIT and out[0].payload == b'\x03'
    assert nak_of(h.send(p.Command.FIRE, p.pack_u32(100), now=1.0005)).reason == p.NakReason.BUSY
    assert h.send(p.Command.HEARTBEAT, now=1.0006)[0].cmd == p.Command.HEARTBEAT | p.REPLY_BIT
    events = h.poll(2.0)
    triggers = [p.TriggerEvent.unpack(e.payload) for e in events if e.cmd == p.Event.TRIGGER]
    assert [(t.index, t.t_trigger_us, t.t_end_us) for t in triggers] == \
        [(0, 1_000_000, 1_001_000), (1, 1_001_500, 1_003_500), (2, 1_004_000, 1_007_000)]
    done = [p.SequenceDone.unpack(e.payload) for e in events if e.cmd == p.Event.SEQUENCE_DONE]
    assert done == [p.SequenceDone(3, p.SequenceStatus.COMPLETE)]
    assert [w for _, w in h.latches] == [1, 0, 2, 0, 4, 0]
    assert [round(w) for _, w in h.pulses] == [1000, 2000, 3000]


def test_all_off_aborts_a_sequence():
    h = Harness()
    h.send(p.Command.RUN_SEQUENCE, p.pack_sequence(0, [p.SequenceEntry(7, 100_000)] * 3), now=0.0)
    out = h.send(p.Command.ALL_OFF, now=0.05)
    assert p.SequenceDone.unpack(out[0].payload) == p.SequenceDone(0, p.SequenceStatus.ABORTED_BY_ALL_OFF)
    assert out[1].cmd == p.Command.ALL_OFF | p.REPLY_BIT
    assert h.latches[-1][1] == 0 and not h.model.trigger_high


def test_watchdog_darkens_after_silence_and_reports_once():
    h = Harness()
    h.send(p.Command.SET_WATCHDOG, struct.pack('<H', 200), now=0.0)
    h.send(p.Command.SET_PATTERN, p.pack_set_pattern(0xFF, True), now=0.1)
    assert h.model.next_deadline() == pytest.approx(0.3)
    assert h.poll(0.299) == []
    out = h.poll(0.35)
    assert [f.cmd for f in out] == [p.Event.WATCHDOG]
    assert p.unpack_u32(out[0].payload, 'wd') == 300_000     # stamped at the trip time, not the poll
    assert h.latches[-1] == (pytest.approx(0.3), 0)
    assert h.model.armed_word == 0
    assert h.poll(5.0) == []                                   # once per silence
    status = p.Status.unpack(h.send(p.Command.HEARTBEAT, now=5.0)[0].payload)
    assert status.watchdog_tripped and not status.leds_lit


def test_watchdog_counts_from_the_end_of_a_long_exposure():
    h = Harness()
    h.send(p.Command.SET_WATCHDOG, struct.pack('<H', 100), now=0.0)
    h.send(p.Command.SET_PATTERN, p.pack_set_pattern(1, False), now=0.0)
    h.send(p.Command.FIRE, p.pack_u32(500_000), now=0.0)      # longer than the watchdog
    out = h.poll(0.5)
    assert [f.cmd for f in out] == [p.Command.FIRE | p.REPLY_BIT]
    assert h.poll(0.59) == []
    assert [f.cmd for f in h.poll(0.61)] == [p.Event.WATCHDOG]


def test_pwm_levels():
    h = Harness(pwm_bits=12)
    levels = [0] * 32
    levels[5] = 4095
    levels[6] = 1
    h.send(p.Command.SET_LEVELS, p.pack_set_levels(levels, True))
    assert h.latches[-1][1] == (1 << 5) | (1 << 6)
    levels[7] = 4096
    nak = nak_of(h.send(p.Command.SET_LEVELS, p.pack_set_levels(levels, True)))
    assert (nak.reason, nak.value) == (p.NakReason.LEVEL_RANGE, 7 << 16 | 4096)


def test_rx_errors_count_every_dropped_frame():
    h = Harness()
    h.model.receive(bytes([p.SOF, 200]), 0.0)                   # LEN too big
    h.model.receive(p.encode_frame(1, p.Command.HEARTBEAT)[:3], 0.1)   # stalls...
    status = p.Status.unpack(h.send(p.Command.HEARTBEAT, now=0.5)[0].payload)   # ...dropped at 10 ms
    assert status.rx_errors == 2


def test_an_exposures_end_is_its_start_plus_the_exposure_in_whole_us():
    """The firmware reports t_end = t_trigger + exposure_us. The model's float times, each
    rounded to whole us, made that 1 us off when a start fell near half a microsecond (the
    differential test against the firmware saw 306 for 307 once): starts at host-like times
    just there."""
    model = FirmwareModel(FirmwareLimits(), boot_time=0.0)
    rounded_apart = 0
    for k in range(2000):
        t0 = 23000.0 + (k + 0.5) * 1e-6
        for exposure in (306, 307, 22500):
            t1 = t0 + exposure / 1e6
            assert (model.end_us(t0, t1) - model.t_us(t0)) % 2**32 == exposure
            rounded_apart += (model.t_us(t1) - model.t_us(t0)) % 2**32 != exposure
    assert rounded_apart > 0  # what rounding both ends gives: the check above can fail
