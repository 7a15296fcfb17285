"""Protocol v1 details of the compiled firmware that the driver's backend-parametrized
suite does not reach through `LightStage` (which never sends a malformed frame): every
NAK reason, framing errors, resynchronisation and the duplicate-reply cache."""
import struct
import time

import numpy as np
import pytest

from lightstage_driver import protocol as p

C = p.Command
R = p.NakReason


def test_identify_reports_the_chip_limits(wire):
    identity = p.Identity.unpack(wire.expect_ok(C.IDENTIFY))
    assert identity == p.Identity(
        protocol_version=1, fw_version=(1, 1, 0), led_count=32, sites=8, channels=4, pwm_bits=8,
        min_exposure_us=20, max_exposure_us=2_000_000, watchdog_ms=1000, max_sequence=16,
        max_payload=136, name='lightstage-avr')


def test_firmware_announces_itself_after_reset(avr, wire):
    avr.reset()
    ready = wire.event(p.Event.READY, timeout_s=2.0)
    assert ready.seq == 0
    assert p.Identity.unpack(ready.payload).name == 'lightstage-avr'


ENTRY = struct.pack('<II', 1, 100)

REFUSALS = [
    # (command, payload, reason, value)
    (C.IDENTIFY, b'\x00', R.BAD_LENGTH, 1),
    (C.HEARTBEAT, b'\x00\x00', R.BAD_LENGTH, 2),
    (C.SET_PATTERN, b'\x01\x0f\x00\x00', R.BAD_LENGTH, 4),
    (C.SET_PATTERN, b'\x02\x0f\x00\x00\x00', R.BAD_FLAGS, 2),
    (C.SET_PATTERN, b'\x81\x0f\x00\x00\x00', R.BAD_FLAGS, 0x81),
    (C.SET_LEVELS, p.pack_set_levels([1] * 31 + [256], True), R.LEVEL_RANGE, 31 << 16 | 256),
    (C.SET_LEVELS, p.pack_set_levels([1] * 32, True)[:-1], R.BAD_LENGTH, 64),
    (C.SET_LEVELS, b'\x02' + p.pack_set_levels([1] * 32, True)[1:], R.BAD_FLAGS, 2),
    (C.SET_LEVEL_TABLE, b'\x00' + bytes(31), R.BAD_LENGTH, 32),
    (C.SET_LEVEL_TABLE, b'\x00' + bytes(2 * 32 + 1), R.BAD_LENGTH, 66),
    (C.SET_LEVEL_TABLE, b'\x0e' + bytes(3 * 32), R.ROW_RANGE, 16),
    (C.RUN_LEVEL_SEQUENCE, struct.pack('<IB', 0, 1) + struct.pack('<BI', 16, 100), R.ROW_RANGE, 16),
    (C.RUN_LEVEL_SEQUENCE, struct.pack('<IB', 0, 2) + struct.pack('<BI', 0, 100), R.BAD_LENGTH, 10),
    (C.RUN_LEVEL_SEQUENCE, struct.pack('<IB', 0, 1) + struct.pack('<BI', 0, 19), R.EXPOSURE_RANGE, 19),
    (C.RUN_LEVEL_SEQUENCE, struct.pack('<IB', 0, 17) + struct.pack('<BI', 0, 100) * 17, R.SEQUENCE_LENGTH, 17),
    (C.FIRE, b'\x64\x00\x00', R.BAD_LENGTH, 3),
    (C.FIRE, p.pack_u32(19), R.EXPOSURE_RANGE, 19),
    (C.FIRE, p.pack_u32(2_000_001), R.EXPOSURE_RANGE, 2_000_001),
    (C.FIRE, p.pack_u32(0xFFFFFFFF), R.EXPOSURE_RANGE, 0xFFFFFFFF),
    (C.RUN_SEQUENCE, b'\x00\x00\x00\x00', R.BAD_LENGTH, 4),
    (C.RUN_SEQUENCE, struct.pack('<IB', 0, 0), R.SEQUENCE_LENGTH, 0),
    (C.RUN_SEQUENCE, struct.pack('<IB', 0, 17) + ENTRY * 16, R.SEQUENCE_LENGTH, 17),
    (C.RUN_SEQUENCE, struct.pack('<IB', 0, 2) + ENTRY, R.BAD_LENGTH, 13),
    (C.RUN_SEQUENCE, struct.pack('<IB', 1_000_001, 1) + ENTRY, R.GAP_RANGE, 1_000_001),
    (C.RUN_SEQUENCE, struct.pack('<IB', 0, 2) + ENTRY + struct.pack('<II', 1, 5), R.EXPOSURE_RANGE, 5),
    (C.ALL_OFF, b'\x00', R.BAD_LENGTH, 1),
    (C.SET_WATCHDOG, b'\x64', R.BAD_LENGTH, 1),
    (C.SET_WATCHDOG, struct.pack('<H', 49), R.WATCHDOG_RANGE, 49),
    (0x0B, b'', R.UNKNOWN_COMMAND, 0x0B),
    (0x40, b'', R.UNKNOWN_COMMAND, 0x40),
    (0x85, p.pack_u32(100), R.UNKNOWN_COMMAND, 0x85),
]


def test_every_refusal_names_its_reason_and_changes_nothing(avr, wire):
    wire.set_pattern(0x00C0_FFEE, show_now=True)
    avr.reset_observations()
    for cmd, payload, reason, value in REFUSALS:
        nak = wire.expect_nak(cmd, payload)
        assert (nak.cmd, nak.reason, nak.value) == (cmd, reason, value), (hex(cmd), payload.hex())
    # no LED, no trigger moved; the armed pattern and the watchdog setting are intact
    assert avr.led_words() == [] and avr.trigger_pulses() == []
    assert p.Identity.unpack(wire.expect_ok(C.IDENTIFY)).watchdog_ms == 1000
    wire.fire(50)
    assert avr.wait_for(lambda w, pl: len(w) >= 2, 1.0)
    assert [w.word for w in avr.led_words()] == [0x00C0_FFEE, 0]


def test_a_frame_with_a_bad_crc_gets_a_bad_crc_nak_and_counts(avr, wire):
    errors_before = wire.heartbeat().rx_errors
    frame = bytearray(p.encode_frame(77, C.SET_PATTERN, p.pack_set_pattern(0xFF, True)))
    frame[6] ^= 0x10                     # corrupt a payload byte
    received_crc = frame[-2] | frame[-1] << 8
    wire.send_raw(bytes(frame))
    reply = wire.reply_to(77)
    assert reply.cmd == p.NAK_CMD
    assert p.Nak.unpack(reply.payload) == p.Nak(C.SET_PATTERN, R.BAD_CRC, received_crc)
    assert wire.heartbeat().rx_errors == errors_before + 1
    assert avr.led_words() == []


def test_receiver_drops_a_stalled_frame_and_takes_the_next(avr, wire):
    errors_before = wire.heartbeat().rx_errors
    frame = p.encode_frame(90, C.SET_PATTERN, p.pack_set_pattern(0xAAAA, True))
    wire.send_raw(frame[:5])             # half a frame, then silence past the 10 ms timeout
    time.sleep(0.05)
    assert wire.set_pattern(0x5555, show_now=True) >= 0
    assert wire.heartbeat().rx_errors == errors_before + 1
    assert avr.wait_for(lambda w, pl: len(w) >= 1, 1.0)
    assert [w.word for w in avr.led_words()] == [0x5555]


def test_receiver_resynchronises_after_garbage_and_an_oversized_length(avr, wire):
    errors_before = wire.heartbeat().rx_errors
    # noise, an SOF with LEN 200 (> 136: dropped without a reply), then a valid frame
    wire.send_raw(b'\x00\x13\xff' + bytes([p.SOF, 200, 1, 3]) + p.encode_frame(91, C.SET_PATTERN,
                                                                                p.pack_set_pattern(0x77, True)))
    reply = wire.reply_to(91)
    assert reply.cmd == C.SET_PATTERN | p.REPLY_BIT
    assert wire.heartbeat().rx_errors == errors_before + 1
    assert not [f for f in wire.drain() if isinstance(f, p.Frame) and f.cmd == p.NAK_CMD]


def test_a_retried_fire_is_answered_from_the_cache_and_triggers_once(avr, wire):
    wire.set_pattern(0x3C, show_now=False)
    first = wire.call(C.FIRE, p.pack_u32(2000), seq=200)
    again = wire.call(C.FIRE, p.pack_u32(2000), seq=200)
    assert again == first
    assert avr.wait_for(lambda w, pl: len(pl) >= 1, 1.0)
    time.sleep(0.05)
    assert len(avr.trigger_pulses()) == 1
    # a new SEQ is a new command; IDENTIFY clears the cache
    wire.call(C.FIRE, p.pack_u32(2000), seq=201)
    wire.expect_ok(C.IDENTIFY)
    wire.call(C.FIRE, p.pack_u32(2000), seq=201)
    assert avr.wait_for(lambda w, pl: len(pl) >= 3, 1.0)


def test_duplicate_set_pattern_is_not_executed_twice(avr, wire):
    wire.call(C.SET_PATTERN, p.pack_set_pattern(0x1, True), seq=33)
    wire.call(C.ALL_OFF, seq=34)
    # a late retry of SEQ 34 must not matter, and a retried SEQ 33 after another command
    # is a new command (only the last one is remembered)
    wire.call(C.ALL_OFF, seq=34)
    wire.call(C.SET_PATTERN, p.pack_set_pattern(0x1, True), seq=33)
    assert avr.wait_for(lambda w, pl: len(w) >= 3, 1.0)
    assert [w.word for w in avr.led_words()] == [0x1, 0, 0x1]


@pytest.mark.parametrize('count', [1, 16])
def test_longest_sequence_fits_the_receive_buffer(avr, wire, count):
    entries = [p.SequenceEntry(1 << k, 20 + k) for k in range(count)]
    payload = p.pack_sequence(0, entries)
    assert len(payload) == 5 + 8 * count <= p.MAX_PAYLOAD
    seq = wire.send(C.RUN_SEQUENCE, payload)
    assert wire.reply_to(seq).payload == bytes([count])
    events = [p.TriggerEvent.unpack(wire.event(p.Event.TRIGGER).payload) for _ in range(count)]
    assert [e.t_end_us - e.t_trigger_us for e in events] == [20 + k for k in range(count)]
    assert p.SequenceDone.unpack(wire.event(p.Event.SEQUENCE_DONE).payload).count_done == count
    assert avr.wait_for(lambda w, pl: len(w) >= 2 * count, 1.0)
    assert [w.word for w in avr.led_words()][::2] == [1 << k for k in range(count)]


def test_line_noise_never_wedges_the_receiver(avr, wire):
    """Random bytes (with SOFs salted in), a pause past the inter-byte timeout, then a
    command: it is answered, and nothing on the pins moved."""
    rng = np.random.default_rng(16)
    for _ in range(12):
        noise = bytearray(rng.integers(0, 256, rng.integers(1, 300), dtype='uint8').tobytes())
        for at in rng.integers(0, len(noise), 4):
            noise[at] = p.SOF
        wire.send_raw(bytes(noise))
        time.sleep(0.03)
        wire.drain()      # BAD_CRC NAKs to the noise, whose SEQ may be anything
        assert p.Status.unpack(wire.expect_ok(C.HEARTBEAT)).leds_lit is False
    assert avr.crashed == '' and avr.running
    assert avr.led_words() == [] and avr.trigger_pulses() == []
