"""`LightStage`: the typed host API of the stage (what the driver node and notebooks use).

Patterns go in as LED drives (length-32, site-major, in [0, 1]) and exposures in
microseconds; they are checked against the firmware's identity before anything is sent.
Trigger times come back on the firmware clock and mapped to the host's monotonic clock.
"""
from __future__ import annotations

import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from . import protocol as p
from .clock import FirmwareClock
from .errors import LinkError, PatternError, ProtocolError
from .link import DEFAULT_BAUD, SerialLink
from .patterns import (applied_drives, check_on_off, lit_word, pattern_levels, pattern_word,
                       validate_exposure, validate_patterns)


@dataclass(frozen=True)
class Trigger:
    """One camera trigger: what was lit, when, for how long."""
    index: int                 # position in the applied list
    word: int                  # LED word lit during the exposure
    exposure_us: int
    firmware_us: int           # unwrapped firmware time of the trigger edge
    host_time_s: float         # the same instant on the host's time.monotonic() clock
    uncertainty_s: float       # half the best clock-probe round trip
    applied: tuple[float, ...] | None = None   # the drives the board applied (rounded levels)


class LightStage:
    """Host side of the stage: connect, identify, set patterns, fire, run sequences."""

    def __init__(self, port: str, baud: int = DEFAULT_BAUD, timeout_s: float = 0.1, retries: int = 3,
                 connect_timeout_s: float = 3.0, watchdog_ms: int | None = None,
                 on_watchdog: Callable[[int], None] | None = None, auto_reopen: bool = True):
        self.clock = FirmwareClock()
        self.watchdog_ms = watchdog_ms
        self.on_watchdog = on_watchdog or (lambda t_us: None)
        self.link = SerialLink(port, baud, timeout_s, retries, connect_timeout_s,
                               on_event=self._on_event, on_connect=self._on_connect,
                               auto_reopen=auto_reopen)
        self.watchdog_trips = 0
        self._seq_events: list[p.TriggerEvent] = []
        self._seq_done: p.SequenceDone | None = None
        self._running_seq = -1
        self._seq_entries: list[tuple[int, int, tuple[float, ...]]] = []   # word, exposure, applied
        self._seq_first = 0
        self._seq_on_trigger: Callable[[Trigger], None] | None = None

    # ------------------------------------------------------------------ connection
    def connect(self) -> p.Identity:
        return self.link.open()

    def close(self, all_off: bool = True) -> None:
        """Switch the LEDs off (best effort) and close the port."""
        if all_off and self.link.is_open:
            self.try_all_off()
        self.link.close()

    def __enter__(self) -> 'LightStage':
        self.connect()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def identity(self) -> p.Identity:
        if self.link.identity is None:
            self.link.ensure_open()
        return self.link.identity

    def _on_connect(self, identity: p.Identity) -> None:
        self.clock.reset()
        # the firmware may have reset: restore our watchdog setting and sync the clock
        if self.watchdog_ms is not None and identity.watchdog_ms != self.watchdog_ms:
            self._set_watchdog_raw(self.watchdog_ms)
        self._probe()

    def _on_event(self, frame: p.Frame, host_s: float) -> None:
        try:
            if frame.cmd == p.Event.TRIGGER and frame.seq == self._running_seq:
                event = p.TriggerEvent.unpack(frame.payload)
                self._seq_events.append(event)
                if self._seq_on_trigger is not None and event.index < len(self._seq_entries):
                    word, exposure, applied = self._seq_entries[event.index]
                    self._seq_on_trigger(self._trigger(self._seq_first + event.index, word,
                                                       exposure, event.t_trigger_us, applied))
            elif frame.cmd == p.Event.SEQUENCE_DONE and frame.seq == self._running_seq:
                self._seq_done = p.SequenceDone.unpack(frame.payload)
            elif frame.cmd == p.Event.WATCHDOG:
                self.watchdog_trips += 1
                self.on_watchdog(struct.unpack('<I', frame.payload)[0] if len(frame.payload) == 4 else 0)
            elif frame.cmd == p.Event.READY:
                self.clock.reset()   # the firmware rebooted under us
        except ProtocolError:
            self.link.stats.crc_errors += 1

    # ------------------------------------------------------------------ simple commands
    def _add_probe(self, reply, raw_us: int) -> None:
        if reply.attempts == 1:     # after a retry the reply may answer an earlier send
            self.clock.add_probe(reply.host_send_s, raw_us, reply.host_recv_s)
        else:
            self.clock.unwrap(raw_us)

    def _probe(self) -> p.Status:
        reply = self.link._transact_once(p.Command.HEARTBEAT, b'', self.link.timeout_s, self.link.retries)
        if reply is None:
            raise LinkError(f'{self.link.port}: no HEARTBEAT reply while connecting')
        status = p.Status.unpack(reply.frame.payload)
        self._add_probe(reply, status.t_us)
        return status

    def heartbeat(self) -> p.Status:
        """Keep the watchdog fed; also a clock-sync probe. Returns the firmware status."""
        reply = self.link.transact(p.Command.HEARTBEAT)
        status = p.Status.unpack(reply.frame.payload)
        self._add_probe(reply, status.t_us)
        return status

    def all_off(self) -> None:
        reply = self.link.transact(p.Command.ALL_OFF)
        self._add_probe(reply, p.unpack_u32(reply.frame.payload, 'ALL_OFF reply'))

    def try_all_off(self) -> str:
        """Switch every LED off if the board answers: '' when done, else why it failed."""
        try:
            self.all_off()
        except LinkError as exc:
            return str(exc)
        return ''

    def _set_watchdog_raw(self, timeout_ms: int) -> None:
        reply = self.link._transact_once(p.Command.SET_WATCHDOG, struct.pack('<H', timeout_ms),
                                         self.link.timeout_s, self.link.retries)
        if reply is None:
            raise LinkError(f'{self.link.port}: no reply to SET_WATCHDOG while connecting')

    def set_watchdog(self, timeout_ms: int) -> None:
        lo, hi = p.WATCHDOG_RANGE_MS
        if isinstance(timeout_ms, bool) or not isinstance(timeout_ms, (int, np.integer)) \
                or not lo <= timeout_ms <= hi:
            raise PatternError(f'watchdog timeout_ms {timeout_ms!r} must be an integer in {lo}..{hi}')
        self.link.transact(p.Command.SET_WATCHDOG, struct.pack('<H', int(timeout_ms)))
        self.watchdog_ms = int(timeout_ms)

    # ------------------------------------------------------------------ patterns
    def _check(self, patterns, exposures_us) -> tuple[np.ndarray, list[int]]:
        ident = self.identity
        array = validate_patterns(patterns, ident.led_count)
        if np.isscalar(exposures_us) or np.ndim(exposures_us) == 0:
            exposures_us = [exposures_us] * len(array)
        exposures_us = list(exposures_us)
        if len(exposures_us) != len(array):
            raise PatternError(f'{len(array)} patterns but {len(exposures_us)} exposures: give one '
                               f'exposure per pattern (or a single one for all)')
        checked = [validate_exposure(e, ident.min_exposure_us, ident.max_exposure_us,
                                     f'exposure_us of pattern {k}') for k, e in enumerate(exposures_us)]
        if not ident.pwm_bits:
            check_on_off(array, f'the board ({ident.name} {ident.version_string})')
        return array, checked

    def _send_pattern(self, pattern: np.ndarray, show_now: bool) -> p.Reply:
        ident = self.identity
        if ident.pwm_bits and ((pattern != 0) & (pattern != 1)).any():
            payload = p.pack_set_levels(pattern_levels(pattern, ident.pwm_bits), show_now)
            return self.link.transact(p.Command.SET_LEVELS, payload)
        # on/off patterns take the short SET_PATTERN on any board
        return self.link.transact(p.Command.SET_PATTERN, p.pack_set_pattern(pattern_word(pattern), show_now))

    def set_pattern(self, pattern, show_now: bool = True) -> int:
        """Light (or only arm) one pattern without a trigger. Returns the word of the LEDs lit."""
        array = validate_patterns(pattern, self.identity.led_count)
        if len(array) != 1:
            raise PatternError(f'set_pattern takes one pattern, got {len(array)}')
        if not self.identity.pwm_bits:
            check_on_off(array, f'the board ({self.identity.name} {self.identity.version_string})')
        reply = self._send_pattern(array[0], show_now)
        self._add_probe(reply, p.unpack_u32(reply.frame.payload, 'SET_PATTERN reply'))
        return lit_word(array[0], self.identity.pwm_bits)

    def fire(self, exposure_us: int, index: int = 0, word: int | None = None,
             on_trigger: Callable[[Trigger], None] | None = None) -> Trigger:
        """Trigger the camera with the armed pattern lit for exposure_us."""
        ident = self.identity
        exposure = validate_exposure(exposure_us, ident.min_exposure_us, ident.max_exposure_us)
        reply = self.link.transact(p.Command.FIRE, p.pack_u32(exposure), extra_timeout_s=exposure / 1e6)
        t_trigger, _ = p.unpack_u32_pair(reply.frame.payload, 'FIRE reply')
        trigger = self._trigger(index, word if word is not None else -1, exposure, t_trigger)
        if on_trigger is not None:
            on_trigger(trigger)
        return trigger

    def _trigger(self, index: int, word: int, exposure: int, raw_us: int,
                 applied: tuple[float, ...] | None = None) -> Trigger:
        if not self.clock.synced:
            self.heartbeat()
        host = self.clock.to_host(raw_us)
        return Trigger(index, word, exposure, self.clock.unwrap(raw_us), host, self.clock.uncertainty_s,
                       applied)

    def apply(self, patterns, exposures_us, trigger: bool = True, gap_us: int = 0,
              on_trigger: Callable[[Trigger], None] | None = None) -> list[Trigger]:
        """Show patterns in order. trigger=True: one camera trigger each (LEDs dark after);
        trigger=False: only light them, the last one stays lit. Everything is checked first.
        `on_trigger(trigger)` is called as each trigger is reported (before apply returns)."""
        array, exposures = self._check(patterns, exposures_us)
        if not isinstance(gap_us, (int, np.integer)) or not 0 <= gap_us <= p.MAX_GAP_US:
            raise PatternError(f'gap_us {gap_us!r} must be an integer in 0..{p.MAX_GAP_US}')
        if not trigger:
            for pattern in array:
                self.set_pattern(pattern, show_now=True)
            return []
        ident = self.identity
        applied = [tuple(float(v) for v in applied_drives(pattern, ident.pwm_bits)) for pattern in array]
        chunk = ident.max_sequence
        graded = any(0 < v < 1 for drives in applied for v in drives)
        if graded and ident.pwm_bits == p.TABLE_LEVEL_BITS and len(array) > 1:
            # the patterns' levels go to the board's level table, then one sequence per chunk
            out: list[Trigger] = []
            for start in range(0, len(array), chunk):
                out += self.run_level_sequence(array[start:start + chunk], exposures[start:start + chunk],
                                               gap_us, first_index=start, on_trigger=on_trigger)
            return out
        if graded:
            # no level table (12-bit levels) or a single pattern: SET_LEVELS + FIRE each
            out = []
            for k, pattern in enumerate(array):
                self._send_pattern(pattern, show_now=False)
                trig = self.fire(exposures[k], k, lit_word(pattern, ident.pwm_bits))
                out.append(replace(trig, applied=applied[k]))
                if on_trigger is not None:
                    on_trigger(out[-1])
            return out
        words = [pattern_word(pattern) for pattern in array]
        if len(words) == 1:
            self.link.transact(p.Command.SET_PATTERN, p.pack_set_pattern(words[0], False))
            trig = replace(self.fire(exposures[0], 0, words[0]), applied=applied[0])
            if on_trigger is not None:
                on_trigger(trig)
            return [trig]
        out = []
        for start in range(0, len(words), chunk):
            out += self.run_sequence(words[start:start + chunk], exposures[start:start + chunk],
                                     gap_us, first_index=start, on_trigger=on_trigger)
        return out

    def run_level_sequence(self, patterns: np.ndarray, exposures_us: Sequence[int], gap_us: int = 0,
                           first_index: int = 0, on_trigger: Callable[[Trigger], None] | None = None
                           ) -> list[Trigger]:
        """Run up to max_sequence checked graded patterns as one firmware sequence: their
        distinct level vectors go to the level table (SET_LEVEL_TABLE, 4 rows a frame), the
        sequence names a row per trigger (RUN_LEVEL_SEQUENCE)."""
        bits = self.identity.pwm_bits
        full = (1 << bits) - 1
        rows: list[tuple[int, ...]] = []
        row_of: list[int] = []
        for pattern in patterns:
            levels = tuple(pattern_levels(pattern, bits))
            if levels not in rows:
                rows.append(levels)
            row_of.append(rows.index(levels))
        for first in range(0, len(rows), p.TABLE_ROWS_PER_FRAME):
            self.link.transact(p.Command.SET_LEVEL_TABLE,
                               p.pack_level_table(first, rows[first:first + p.TABLE_ROWS_PER_FRAME]))
        entries = [p.LevelSequenceEntry(row, int(e)) for row, e in zip(row_of, exposures_us)]
        words = [sum(1 << i for i, level in enumerate(rows[row]) if level) for row in row_of]
        applied = [tuple(level / full for level in rows[row]) for row in row_of]
        return self._run_sequence(p.Command.RUN_LEVEL_SEQUENCE, p.pack_level_sequence(int(gap_us), entries),
                                  words, list(exposures_us), gap_us, first_index, on_trigger, applied)

    def run_sequence(self, words: Sequence[int], exposures_us: Sequence[int], gap_us: int = 0,
                     first_index: int = 0, on_trigger: Callable[[Trigger], None] | None = None) -> list[Trigger]:
        """Run one firmware sequence (checked words and exposures) and wait for its triggers."""
        entries = [p.SequenceEntry(int(w), int(e)) for w, e in zip(words, exposures_us)]
        applied = [tuple(float(w >> i & 1) for i in range(p.LED_COUNT)) for w in words]
        return self._run_sequence(p.Command.RUN_SEQUENCE, p.pack_sequence(int(gap_us), entries),
                                  [e.word for e in entries], [e.exposure_us for e in entries], gap_us,
                                  first_index, on_trigger, applied)

    def _wait_for_sequence(self, exposures_us: list[int], gap_us: int) -> float | None:
        """Wait for the end of the running sequence; None once it ended, else the budget it
        overran. The budget restarts at every trigger event: what is left of the sequence plus
        the link's reply margin. A busy host (the trigger callbacks publish, other processes
        run) then cannot fail a sequence that is visibly progressing; a silent line still fails
        within one margin of its last event."""
        margin_s = self.link.timeout_s * (self.link.retries + 1)
        count = len(exposures_us)
        while self._seq_done is None:
            seen = len(self._seq_events)
            budget_s = sum(exposures_us[seen:]) / 1e6 + (count - seen) * (gap_us / 1e6 + 0.005) + margin_s
            if not self.link.wait_until(lambda: self._seq_done is not None or len(self._seq_events) != seen,
                                        budget_s):
                return budget_s
        return None

    def _run_sequence(self, cmd: p.Command, payload: bytes, words: list[int], exposures_us: list[int],
                      gap_us: int, first_index: int, on_trigger, applied: list[tuple[float, ...]]
                      ) -> list[Trigger]:
        entries = [(w, e, a) for w, e, a in zip(words, exposures_us, applied)]
        self._seq_events, self._seq_done = [], None
        self._seq_entries, self._seq_first, self._seq_on_trigger = entries, first_index, on_trigger
        with self.link.lock:
            self.link.require_open()
            self._running_seq = self.link._seq % 255 + 1   # the seq transact will use
            try:
                self.link.transact(cmd, payload)
                stalled_s = self._wait_for_sequence(exposures_us, gap_us)
                if stalled_s is not None:
                    off_failed = self.try_all_off()
                    leds = (f'switching the LEDs off failed too ({off_failed}): their state is unknown'
                            if off_failed else 'LEDs switched off')
                    raise LinkError(f'{self.link.port}: sequence of {len(entries)} did not finish within '
                                    f'{stalled_s:.3f} s of its last progress (got {len(self._seq_events)} '
                                    f'triggers); {leds}')
            finally:
                self._running_seq = -1
                self._seq_on_trigger = None
        done = self._seq_done
        if done.status != p.SequenceStatus.COMPLETE:
            why = p.SequenceStatus(done.status).name if done.status in tuple(p.SequenceStatus) else done.status
            raise LinkError(f'{self.link.port}: sequence stopped after {done.count_done} of {len(entries)} '
                            f'triggers ({why})')
        got = {event.index: event for event in self._seq_events}
        missing = [k for k in range(len(entries)) if k not in got]
        if missing:
            raise LinkError(f'{self.link.port}: trigger event(s) {missing} of the sequence were lost on the '
                            f'line (corrupted); the camera was triggered but their stamps are unknown')
        return [self._trigger(first_index + k, entries[k][0], entries[k][1], got[k].t_trigger_us, entries[k][2])
                for k in range(len(entries))]
