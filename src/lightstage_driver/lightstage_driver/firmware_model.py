"""The stage's microcontroller firmware as a pure state machine (no I/O, no threads).

`FirmwareModel` does what docs/PROTOCOL.md asks of the firmware: it takes received
bytes and the current time and returns the bytes to send; `poll(now)` advances timed
work (exposures, sequences, the watchdog). The pty process in `firmware_sim` drives it in
real time; tests can drive it with a fake clock.

The model's hardware timer is exact: a trigger pulse is exactly the requested exposure
on the firmware clock (the real AVR firmware is tested for that to within one timer
tick under simavr). Graded levels are on-times within the exposure, latched on the same
schedule as the AVR firmware's (`schedule.build`). Its outputs are reported through `on_latch(t_s, word)` and
`on_pulse(t_start_s, width_us)` on the firmware clock (seconds since boot).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from . import protocol as p
from . import schedule as sched
from .errors import PayloadError

FIRMWARE_NAME = 'lightstage-pysim'
FIRMWARE_VERSION = (1, 1, 0)


@dataclass
class FirmwareLimits:
    """What the firmware reports in IDENTIFY: the AVR firmware's values by default, except
    pwm_bits (0, an on/off board, as the authors' original rig; the AVR firmware from 1.1
    reports 8: `sim://?pwm_bits=8`)."""
    pwm_bits: int = 0
    min_exposure_us: int = 20
    max_exposure_us: int = 2_000_000
    max_sequence: int = p.MAX_SEQUENCE
    name: str = FIRMWARE_NAME

    def __post_init__(self):
        if self.pwm_bits not in (0, 8, 12):
            raise ValueError(f'pwm_bits must be 0 (on/off), 8 or 12, got {self.pwm_bits}')
        if not 1 <= self.min_exposure_us <= self.max_exposure_us <= 0xFFFFFFFF:
            raise ValueError(f'exposure range {self.min_exposure_us}..{self.max_exposure_us} us is invalid')
        if not 1 <= self.max_sequence <= p.MAX_SEQUENCE:
            raise ValueError(f'max_sequence must be 1..{p.MAX_SEQUENCE}, got {self.max_sequence}')


def levels_to_word(levels) -> int:
    return sum(1 << i for i, level in enumerate(levels) if level > 0)


class FirmwareModel:
    def __init__(self, limits: FirmwareLimits | None = None, boot_time: float = 0.0,
                 clock_offset_us: int = 0,
                 on_latch: Callable[[float, int], None] | None = None,
                 on_pulse: Callable[[float, float], None] | None = None):
        self.limits = limits or FirmwareLimits()
        self.boot_time = boot_time
        self.clock_offset_us = clock_offset_us   # lets tests start the clock near its wrap
        self.on_latch = on_latch or (lambda t, w: None)
        self.on_pulse = on_pulse or (lambda t, w: None)
        self.accept_frame: Callable[[p.Frame], bool] = lambda frame: True   # fault hook
        self.decoder = p.FrameDecoder()
        self.watchdog_ms = p.DEFAULT_WATCHDOG_MS
        self.armed_levels: tuple[int, ...] = (0,) * p.LED_COUNT
        self.level_table = [(0,) * p.LED_COUNT for _ in range(self.limits.max_sequence)]
        self._steps: list[tuple[float, int]] = []   # graded re-latches of the running exposure
        self.lit_word = 0
        self.trigger_high = False
        self.rx_errors = 0      # frames NAKed for a bad CRC (length / timeout drops: decoder)
        self.watchdog_tripped_flag = False
        self._tripped_this_silence = False
        self._last_activity = boot_time
        self._cache: tuple[int, int, bytes] | None = None   # seq, cmd, reply frame
        self._pending: list[p.Frame | p.BadFrame] = []      # frames received during a FIRE
        self._fire: tuple[int, int, float, float] | None = None  # seq, cmd, t_start, t_end
        self._seq: dict | None = None                       # running sequence state

    # ------------------------------------------------------------------ time and pins
    def t_us(self, now: float) -> int:
        return (int(round((now - self.boot_time) * 1e6)) + self.clock_offset_us) & 0xFFFFFFFF

    def end_us(self, t_start: float, t_end: float) -> int:
        """The exposure's end on the firmware clock: its start plus the exposure in whole us,
        as the firmware computes it (rounding both ends of the float times could make the
        difference 1 us off the exposure)."""
        return (self.t_us(t_start) + int(round((t_end - t_start) * 1e6))) & 0xFFFFFFFF

    def _fw_s(self, now: float) -> float:
        return now - self.boot_time

    def _latch(self, now: float, word: int) -> None:
        self.lit_word = word
        self.on_latch(self._fw_s(now), word)

    @property
    def full_scale(self) -> int:
        return (1 << self.limits.pwm_bits) - 1 if self.limits.pwm_bits else 1

    @property
    def armed_word(self) -> int:
        return levels_to_word(self.armed_levels)

    def identity(self) -> p.Identity:
        lim = self.limits
        return p.Identity(p.PROTOCOL_VERSION, FIRMWARE_VERSION, p.LED_COUNT, 8, 4, lim.pwm_bits,
                          lim.min_exposure_us, lim.max_exposure_us, self.watchdog_ms,
                          lim.max_sequence, p.MAX_PAYLOAD, lim.name)

    def boot(self, now: float) -> list[bytes]:
        """Power-up: everything off, EVT_READY."""
        self.boot_time = now
        self._last_activity = now
        return [p.encode_frame(0, p.Event.READY, self.identity().pack())]

    @property
    def busy(self) -> bool:
        return self._fire is not None

    @property
    def sequence_running(self) -> bool:
        return self._seq is not None

    def next_deadline(self) -> float | None:
        if self._fire is not None:
            return self._fire[3]
        if self._seq is not None:
            return self._seq['next_time']
        if self._watchdog_armed():
            return self._last_activity + self.watchdog_ms / 1000.0
        return None

    def _watchdog_armed(self) -> bool:
        return not self._tripped_this_silence and (self.lit_word != 0 or self.armed_word != 0
                                                   or self._seq is not None)

    # ------------------------------------------------------------------ input
    def receive(self, data: bytes, now: float) -> list[bytes]:
        out = self.poll(now)
        items = [item for item in self.decoder.feed(data, now)
                 if not isinstance(item, p.Frame) or self.accept_frame(item)]
        out += self._handle_items(items, now)
        return out

    def _handle_items(self, items, now: float) -> list[bytes]:
        out: list[bytes] = []
        for item in items:
            if self._fire is not None:
                self._pending.append(item)   # the MCU is busy timing the exposure
                continue
            out += self._handle(item, now)
        return out

    def _handle(self, item, now: float) -> list[bytes]:
        if isinstance(item, p.BadFrame):
            self.rx_errors = min(self.rx_errors + 1, 0xFFFF)
            return [self._nak(item.seq, item.cmd, p.NakReason.BAD_CRC, item.received_crc)]
        self._last_activity = now
        self._tripped_this_silence = False
        frame = item
        if self._cache and frame.cmd not in (p.Command.IDENTIFY, p.Command.HEARTBEAT) \
                and self._cache[0] == frame.seq and self._cache[1] == frame.cmd:
            return [self._cache[2]]
        try:
            replies = self._execute(frame, now)
        except PayloadError:
            replies = [self._nak(frame.seq, frame.cmd, p.NakReason.BAD_LENGTH, len(frame.payload))]
        if frame.cmd == p.Command.IDENTIFY:
            self._cache = None
        elif replies and frame.cmd != p.Command.HEARTBEAT and frame.cmd != p.Command.FIRE:
            self._cache = (frame.seq, frame.cmd, replies[-1])
        return replies

    def _nak(self, seq: int, cmd: int, reason: p.NakReason, value: int) -> bytes:
        return p.encode_frame(seq, p.NAK_CMD, p.Nak(cmd, int(reason), value & 0xFFFFFFFF).pack())

    def _reply(self, frame: p.Frame, payload: bytes = b'') -> bytes:
        return p.encode_frame(frame.seq, frame.cmd | p.REPLY_BIT, payload)

    def _execute(self, frame: p.Frame, now: float) -> list[bytes]:
        cmd, payload = frame.cmd, frame.payload
        lim = self.limits
        if self._seq is not None and cmd not in (p.Command.ALL_OFF, p.Command.HEARTBEAT):
            left = len(self._seq['entries']) - self._seq['index']
            return [self._nak(frame.seq, cmd, p.NakReason.BUSY, left)]
        if cmd == p.Command.IDENTIFY:
            if payload:
                raise PayloadError('IDENTIFY takes no payload')
            return [self._reply(frame, self.identity().pack())]
        if cmd == p.Command.HEARTBEAT:
            if payload:
                raise PayloadError('HEARTBEAT takes no payload')
            dropped = self.rx_errors + self.decoder.length_errors + self.decoder.timeouts
            status = p.Status(self.t_us(now), self.lit_word != 0, self._seq is not None,
                              self.watchdog_tripped_flag, min(dropped, 0xFFFF))
            self.watchdog_tripped_flag = False
            return [self._reply(frame, status.pack())]
        if cmd in (p.Command.SET_PATTERN, p.Command.SET_LEVELS):
            if cmd == p.Command.SET_PATTERN:
                flags, word = p.unpack_set_pattern(payload)
                levels = self._word_levels(word)
            else:
                if not lim.pwm_bits:
                    return [self._nak(frame.seq, cmd, p.NakReason.UNSUPPORTED, cmd)]
                flags, levels = p.unpack_set_levels(payload)
                for i, level in enumerate(levels):
                    if level > self.full_scale:
                        return [self._nak(frame.seq, cmd, p.NakReason.LEVEL_RANGE, i << 16 | level)]
            if flags & ~p.SHOW_NOW:
                return [self._nak(frame.seq, cmd, p.NakReason.BAD_FLAGS, flags)]
            self.armed_levels = tuple(levels)
            if flags & p.SHOW_NOW:
                self._latch(now, levels_to_word(levels))
            return [self._reply(frame, p.pack_u32(self.t_us(now)))]
        if cmd == p.Command.FIRE:
            exposure = p.unpack_u32(payload, 'FIRE')
            if not lim.min_exposure_us <= exposure <= lim.max_exposure_us:
                return [self._nak(frame.seq, cmd, p.NakReason.EXPOSURE_RANGE, exposure)]
            self._start_exposure(now, self.armed_levels, exposure)
            self._fire = (frame.seq, cmd, now, now + exposure / 1e6)
            return []
        if cmd == p.Command.SET_LEVEL_TABLE:
            if lim.pwm_bits != p.TABLE_LEVEL_BITS:
                return [self._nak(frame.seq, cmd, p.NakReason.UNSUPPORTED, cmd)]
            first, rows = p.unpack_level_table(payload)
            if first + len(rows) > lim.max_sequence:
                return [self._nak(frame.seq, cmd, p.NakReason.ROW_RANGE, first + len(rows) - 1)]
            self.level_table[first:first + len(rows)] = rows
            return [self._reply(frame, bytes((first, len(rows))))]
        if cmd in (p.Command.RUN_SEQUENCE, p.Command.RUN_LEVEL_SEQUENCE):
            graded = cmd == p.Command.RUN_LEVEL_SEQUENCE
            if graded and lim.pwm_bits != p.TABLE_LEVEL_BITS:
                return [self._nak(frame.seq, cmd, p.NakReason.UNSUPPORTED, cmd)]
            gap_us, count = p.unpack_sequence_header(payload)
            if not 1 <= count <= lim.max_sequence:
                return [self._nak(frame.seq, cmd, p.NakReason.SEQUENCE_LENGTH, count)]
            if graded:
                raw = p.unpack_level_sequence_entries(payload, count)
            else:
                raw = p.unpack_sequence_entries(payload, count)
            if gap_us > p.MAX_GAP_US:
                return [self._nak(frame.seq, cmd, p.NakReason.GAP_RANGE, gap_us)]
            if graded:
                for entry in raw:
                    if entry.row >= lim.max_sequence:
                        return [self._nak(frame.seq, cmd, p.NakReason.ROW_RANGE, entry.row)]
            for entry in raw:
                if not lim.min_exposure_us <= entry.exposure_us <= lim.max_exposure_us:
                    return [self._nak(frame.seq, cmd, p.NakReason.EXPOSURE_RANGE, entry.exposure_us)]
            # every entry as (levels, exposure): on/off words are levels of 0 or full scale
            entries = [(self.level_table[e.row] if graded else self._word_levels(e.word), e.exposure_us)
                       for e in raw]
            self._seq = {'seq': frame.seq, 'entries': entries, 'gap_s': gap_us / 1e6, 'index': 0,
                         'exposing': False, 'next_time': now, 't_start': now}
            out = [self._reply(frame, bytes((count,)))]
            return out + self.poll(now)
        if cmd == p.Command.ALL_OFF:
            if payload:
                raise PayloadError('ALL_OFF takes no payload')
            out = self._all_off(now, p.SequenceStatus.ABORTED_BY_ALL_OFF)
            return out + [self._reply(frame, p.pack_u32(self.t_us(now)))]
        if cmd == p.Command.SET_WATCHDOG:
            if len(payload) != 2:
                raise PayloadError('SET_WATCHDOG takes 2 bytes')
            timeout = payload[0] | payload[1] << 8
            lo, hi = p.WATCHDOG_RANGE_MS
            if not lo <= timeout <= hi:
                return [self._nak(frame.seq, cmd, p.NakReason.WATCHDOG_RANGE, timeout)]
            self.watchdog_ms = timeout
            return [self._reply(frame, payload)]
        return [self._nak(frame.seq, cmd, p.NakReason.UNKNOWN_COMMAND, cmd)]

    def _word_levels(self, word: int) -> tuple[int, ...]:
        return tuple(self.full_scale if word >> i & 1 else 0 for i in range(p.LED_COUNT))

    # ------------------------------------------------------------------ timed work
    def _start_exposure(self, now: float, levels, exposure_us: int) -> None:
        schedule = sched.build(levels, exposure_us * sched.TICKS_PER_US, self.full_scale)
        self._latch(now, schedule.rise_word)
        # the LED word stays "lit" until the end (as the firmware's HEARTBEAT reports it);
        # the re-latches are reported when they are due (`_emit_steps`)
        self.lit_word = levels_to_word(levels)
        self._steps = [(now + at / (sched.TICKS_PER_US * 1e6), word) for at, word in schedule.steps]
        self.trigger_high = True

    def _emit_steps(self, until: float) -> None:
        while self._steps and self._steps[0][0] < until:
            t, word = self._steps.pop(0)
            self.on_latch(self._fw_s(t), word)

    def _end_exposure(self, t_start: float, t_end: float) -> None:
        self._emit_steps(t_end)
        self.trigger_high = False
        self._latch(t_end, 0)
        self.on_pulse(self._fw_s(t_start), (t_end - t_start) * 1e6)
        self._last_activity = max(self._last_activity, t_end)

    def _all_off(self, now: float, status: p.SequenceStatus) -> list[bytes]:
        out: list[bytes] = []
        if self._seq is not None:
            seq = self._seq
            if seq['exposing']:
                self._emit_steps(now)
                self._steps = []
                self.trigger_high = False
                self.on_pulse(self._fw_s(seq['t_start']), (now - seq['t_start']) * 1e6)
            out.append(p.encode_frame(seq['seq'], p.Event.SEQUENCE_DONE,
                                      p.SequenceDone(seq['index'], int(status)).pack()))
            self._seq = None
        self.armed_levels = (0,) * p.LED_COUNT
        if self.lit_word:
            self._latch(now, 0)
        self.trigger_high = False
        return out

    def poll(self, now: float) -> list[bytes]:
        out: list[bytes] = []
        if self._fire is not None and now >= self._fire[3]:
            seq, cmd, t0, t1 = self._fire
            self._fire = None
            self._end_exposure(t0, t1)
            reply = p.encode_frame(seq, cmd | p.REPLY_BIT,
                                   p.pack_u32(self.t_us(t0)) + p.pack_u32(self.end_us(t0, t1)))
            self._cache = (seq, cmd, reply)
            out.append(reply)
            pending, self._pending = self._pending, []
            out += self._handle_items(pending, now)
        while self._seq is not None and now >= self._seq['next_time']:
            seq = self._seq
            levels, exposure_us = seq['entries'][seq['index']]
            if not seq['exposing']:
                # times are kept on the ideal (hardware timer) schedule, not the poll time
                t_start = seq['next_time']
                self._start_exposure(t_start, levels, exposure_us)
                seq['t_start'] = t_start
                seq['exposing'] = True
                seq['next_time'] = t_start + exposure_us / 1e6
                continue
            t_end = seq['next_time']
            self._end_exposure(seq['t_start'], t_end)
            out.append(p.encode_frame(seq['seq'], p.Event.TRIGGER, p.TriggerEvent(
                seq['index'], self.t_us(seq['t_start']), self.end_us(seq['t_start'], t_end)).pack()))
            seq['exposing'] = False
            seq['index'] += 1
            seq['next_time'] = t_end + seq['gap_s']
            if seq['index'] == len(seq['entries']):
                out.append(p.encode_frame(seq['seq'], p.Event.SEQUENCE_DONE, p.SequenceDone(
                    seq['index'], int(p.SequenceStatus.COMPLETE)).pack()))
                self._seq = None
        if self._fire is None and self._watchdog_armed() and not (self._seq and self._seq['exposing']) \
                and now - self._last_activity >= self.watchdog_ms / 1000.0:
            trip_time = self._last_activity + self.watchdog_ms / 1000.0
            out += self._all_off(trip_time, p.SequenceStatus.ABORTED_BY_WATCHDOG)
            self._tripped_this_silence = True
            self.watchdog_tripped_flag = True
            out.append(p.encode_frame(0, p.Event.WATCHDOG, p.pack_u32(self.t_us(trip_time))))
        return out
