"""The compiled firmware and the Python firmware model answer the same command stream
the same way: a seeded random script of valid, invalid, malformed and retried commands
(graded levels, level tables and level sequences among them) is played against both, and
the replies, events, LED words on the pins and each LED's on-time in each trigger pulse
are compared (timestamps aside, which depend on when things happened)."""
import struct
import time

import numpy as np
import pytest

from lightstage_driver import protocol as p
from lightstage_driver.sim_backend import PythonSimBackend

from helpers.firmware_wire import Wire
from helpers.graded_pins import on_times_us

C = p.Command


def random_script(seed: int, n: int):
    """(seq, cmd, payload, waits_for_sequence_done) tuples; a repeated seq is a retry."""
    rng = np.random.default_rng(seed)
    script, seq = [], 0

    def u32(lo, hi):
        return int(rng.integers(lo, hi))

    for _ in range(n):
        kind = rng.choice(['pattern', 'fire', 'sequence', 'off', 'watchdog', 'levels', 'heartbeat',
                           'identify', 'unknown', 'badlen', 'retry', 'table', 'levelseq'],
                          p=[.12, .15, .06, .06, .04, .1, .08, .03, .03, .09, .08, .08, .08])
        if kind == 'retry' and script:
            script.append(script[-1])
            continue
        seq = seq % 255 + 1
        if kind == 'pattern':
            flags = int(rng.choice([0, 1, 1, 2, 0x81]))
            cmd, payload = C.SET_PATTERN, struct.pack('<BI', flags, u32(0, 2**32))
        elif kind == 'fire':
            cmd, payload = C.FIRE, p.pack_u32(int(rng.choice([u32(20, 300), u32(20, 3000), 19, 2_000_001, 0])))
        elif kind == 'sequence':
            count = int(rng.choice([1, 2, 5, 16, 0, 17]))
            gap = int(rng.choice([0, 100, 1_000_001]))
            entries = [p.SequenceEntry(u32(0, 2**32), int(rng.choice([u32(20, 500), 10])
                                                          if rng.random() < 0.1 else u32(20, 500)))
                       for _ in range(min(count, 16))]
            cmd, payload = C.RUN_SEQUENCE, struct.pack('<IB', gap, count) + b''.join(
                struct.pack('<II', e.word, e.exposure_us) for e in entries)
        elif kind == 'off':
            cmd, payload = C.ALL_OFF, b''
        elif kind == 'watchdog':
            cmd, payload = C.SET_WATCHDOG, struct.pack('<H', int(rng.choice([2000, 60000, 49, 60001, 0])))
        elif kind == 'levels':
            levels = [int(v) for v in rng.choice([0, 1, 127, 254, 255, int(rng.integers(0, 256))], size=32)]
            if rng.random() < 0.1:
                levels[int(rng.integers(0, 32))] = int(rng.choice([256, 4095]))
            flags = int(rng.choice([0, 0, 1, 4]))
            cmd, payload = C.SET_LEVELS, struct.pack('<B32H', flags, *levels)
        elif kind == 'table':
            rows = int(rng.choice([1, 2, 4]))
            first = int(rng.choice([0, 4, 12, 14, 15]))
            cmd, payload = C.SET_LEVEL_TABLE, bytes([first]) + bytes(rng.integers(0, 256, 32 * rows, dtype='uint8'))
        elif kind == 'levelseq':
            count = int(rng.choice([1, 3, 16, 0, 17]))
            gap = int(rng.choice([0, 100, 1_000_001]))
            entries = [(int(rng.choice([u32(0, 16), 16])) if rng.random() < 0.1 else u32(0, 16),
                        int(rng.choice([u32(20, 3000), 10])) if rng.random() < 0.1 else u32(20, 3000))
                       for _ in range(min(count, 16))]
            cmd, payload = C.RUN_LEVEL_SEQUENCE, struct.pack('<IB', gap, count) + b''.join(
                struct.pack('<BI', row, e) for row, e in entries)
        elif kind == 'heartbeat':
            cmd, payload = C.HEARTBEAT, b''
        elif kind == 'identify':
            cmd, payload = C.IDENTIFY, b''
        elif kind == 'unknown':
            cmd, payload = int(rng.choice([0x00, 0x09, 0x41, 0x7F, 0x81])), bytes(rng.integers(0, 256, 3, dtype='uint8'))
        else:
            cmd = int(rng.choice([C.IDENTIFY, C.HEARTBEAT, C.SET_PATTERN, C.FIRE, C.ALL_OFF, C.SET_WATCHDOG,
                                  C.RUN_SEQUENCE]))
            payload = bytes(rng.integers(0, 256, int(rng.choice([1, 3, 6, 7])), dtype='uint8'))
        script.append((seq, cmd, payload))
    return script


def normalise(frame: p.Frame):
    """What must agree: everything but absolute firmware times and the firmware's name."""
    cmd, body = frame.cmd, frame.payload
    if cmd == p.NAK_CMD:
        return ('NAK', frame.seq, p.Nak.unpack(body))
    if cmd in (C.SET_PATTERN | p.REPLY_BIT, C.ALL_OFF | p.REPLY_BIT, C.SET_LEVELS | p.REPLY_BIT):
        return (cmd, frame.seq, len(body))
    if cmd == C.FIRE | p.REPLY_BIT:
        t0, t1 = p.unpack_u32_pair(body, 'FIRE')
        return (cmd, frame.seq, (t1 - t0) % 2**32)
    if cmd == C.HEARTBEAT | p.REPLY_BIT:
        status = p.Status.unpack(body)
        return (cmd, frame.seq, status.leds_lit, status.sequence_running, status.watchdog_tripped,
                status.rx_errors)
    if cmd in (C.IDENTIFY | p.REPLY_BIT, p.Event.READY):
        identity = p.Identity.unpack(body)
        return (cmd, frame.seq, identity.__class__(**{**identity.__dict__, 'name': ''}))
    if cmd == p.Event.TRIGGER:
        event = p.TriggerEvent.unpack(body)
        return (cmd, frame.seq, event.index, (event.t_end_us - event.t_trigger_us) % 2**32)
    return (cmd, frame.seq, body)


def play(backend, script):
    wire = Wire(backend.port)
    try:
        wire.call(C.IDENTIFY, timeout_s=3.0)
        wire.drain()
        backend.reset_observations()
        transcript = []
        previous = None
        for item in script:
            seq, cmd, payload = item
            reply = wire.call(cmd, payload, seq=seq, timeout_s=2.0)
            transcript.append(normalise(reply))
            retry = item == previous      # answered from the duplicate cache: nothing runs
            previous = item
            if cmd in (C.RUN_SEQUENCE, C.RUN_LEVEL_SEQUENCE) and reply.cmd == cmd | p.REPLY_BIT and not retry:
                done = wire.event(p.Event.SEQUENCE_DONE, timeout_s=2.0)
                wire.frames.append(done)
            # the events received meanwhile, in order (no others are due: nothing is running)
            transcript += [normalise(f) for f in wire.frames if isinstance(f, p.Frame)]
            wire.frames.clear()
        wire.call(C.ALL_OFF)
        # the observations come on their own channel (stdout): let the last ones in
        counts = None
        while counts != (len(backend.led_words()), len(backend.trigger_pulses())):
            counts = (len(backend.led_words()), len(backend.trigger_pulses()))
            time.sleep(0.2)
        words, pulses = backend.led_words(), backend.trigger_pulses()
        return transcript, [w.word for w in words], len(pulses), on_times_us(words, pulses)
    finally:
        wire.close()


@pytest.fixture(scope='module')
def python_sim():
    backend = PythonSimBackend(pwm_bits=8)     # as the AVR firmware
    backend.start()
    yield backend
    backend.close()


@pytest.mark.parametrize('seed', [1])
def test_firmware_and_model_agree_on_a_random_command_stream(avr, wire, python_sim, seed):
    script = random_script(seed, 150)
    assert len({cmd for _, cmd, _ in script}) >= 8
    python_sim.restart()
    expected = play(python_sim, script)
    avr.reset()
    got = play(avr, script)
    for k, (e, g) in enumerate(zip(expected[0], got[0])):
        assert g == e, f'frame {k}: model {e}, firmware {g}'
    assert len(got[0]) == len(expected[0])
    assert got[1] == expected[1]          # LED words latched, in order
    assert got[2] == expected[2]          # trigger pulses
    # each LED's on-time in each pulse: the firmware latches on the model's ticks (within
    # a few CPU cycles)
    for k, (e, g) in enumerate(zip(expected[3], got[3])):
        assert np.abs(g - e).max() <= 0.5, f'pulse {k}: model {e}, firmware {g}'
    assert any(0 < t < on.max() for on in got[3] for t in on)   # graded on-times were among them
