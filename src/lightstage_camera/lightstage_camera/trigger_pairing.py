"""Pairing grabbed frames with the triggers that caused them, without guessing.

A triggered camera delivers frames in trigger order, each with a `BlockID` that counts up by
one per frame the camera sent. The triggers come from elsewhere (the light stage reports each
on ``/illumination``; with a software trigger the backend fires them itself), and a frame may
arrive before or after its trigger is known. `TriggerPairing` pairs the n-th frame with the
n-th trigger and refuses to pair when that could be wrong:

- a BlockID gap of k: the next k triggers lost their frames (lost in transfer);
- a failed buffer (incomplete grab): its trigger is lost, with the camera's reason;
- a trigger with no frame within its time limit: it is lost, and because its frame may still
  come late (it would then be taken for the next trigger's) the pairing is *out of step*:
  every trigger is reported lost until the camera has been quiet (no trigger waiting, no
  frame for one time limit), then pairing starts afresh;
- a frame that no trigger claims within the time limit is dropped and counted.

A lost trigger is never shifted onto another frame. No rclpy, no camera API here.
"""
from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Callable

import numpy as np

from .camera_backend import Frame, LostFrame, Trigger


@dataclass
class GrabbedFrame:
    """One buffer the camera delivered: `image` uint16 mono16 (None if the grab failed)."""
    block_id: int | None
    image: np.ndarray | None
    bit_depth: int
    error: str = ''
    info: dict | None = None


class TriggerPairing:
    """Frames and triggers in, `Frame` / `LostFrame` outcomes out (thread-safe).

    `timeout_s(trigger)` is the time a trigger may wait for its frame (its exposure plus
    readout and transfer); `early_limit_s` the time a frame may wait for its trigger to be
    announced (a hardware-triggered frame can come before the driver's message). `clock`
    returns seconds (monotonic).
    """

    def __init__(self, timeout_s: Callable[[Trigger], float], early_limit_s: float = 1.0,
                 clock: Callable[[], float] = time.monotonic):
        self.timeout_s = timeout_s
        self.early_limit_s = float(early_limit_s)
        self.clock = clock
        self._lock = threading.Lock()
        self._pending: deque[tuple[Trigger, float]] = deque()    # triggers waiting for a frame
        self._early: deque[tuple[GrabbedFrame, float]] = deque()  # frames waiting for a trigger
        self._next_block: int | None = None
        self._owed = 0            # frames known lost before their triggers were announced
        self._out_of_step = ''    # why pairing stopped ('' while in step)
        self._out_of_step_since = -float('inf')
        self._last_frame = -float('inf')
        self._frame_limit_s = 0.0   # the longest time limit of a trigger seen so far
        self.paired = 0
        self.lost = 0
        self.timeouts = 0
        self.unclaimed = 0

    # ------------------------------------------------------------------ inputs
    def add_trigger(self, trigger: Trigger) -> list:
        now = self.clock()
        with self._lock:
            self._frame_limit_s = max(self._frame_limit_s, self.timeout_s(trigger))
            if self._out_of_step and self._quiet(now):
                self._out_of_step, self._next_block = '', None
                self._early.clear()
            if self._out_of_step:
                return [self._lose(trigger, f'camera out of step ({self._out_of_step}); '
                                            'waiting for it to fall quiet before pairing again')]
            if self._owed:
                self._owed -= 1
                return [self._lose(trigger, 'its frame was lost in transfer (BlockID gap)')]
            if self._early:
                frame, _ = self._early.popleft()
                return [self._pair(trigger, frame)]
            self._pending.append((trigger, now))
            return []

    def add_frame(self, frame: GrabbedFrame) -> list:
        now = self.clock()
        out = []
        with self._lock:
            self._last_frame = now
            if self._out_of_step:
                self.unclaimed += 1
                return out
            if frame.block_id is not None and self._next_block is not None:
                if frame.block_id < self._next_block:
                    self.unclaimed += 1   # older than a frame already paired: never re-pair it
                    return out
                gap = frame.block_id - self._next_block
                for _ in range(gap):
                    if self._pending:
                        trigger, _ = self._pending.popleft()
                        out.append(self._lose(trigger, f'its frame was lost in transfer (BlockID '
                                                       f'{self._next_block} missing, got {frame.block_id})'))
                    else:
                        self._owed += 1
            if frame.block_id is not None:
                self._next_block = frame.block_id + 1
            if self._pending:
                trigger, _ = self._pending.popleft()
                out.append(self._pair(trigger, frame))
            else:
                self._early.append((frame, now))
        return out

    def expire(self) -> list:
        """Triggers past their time limit (lost: no frame) and unclaimed frames (dropped)."""
        now = self.clock()
        out = []
        with self._lock:
            if self._pending:
                trigger, since = self._pending[0]
                limit = self.timeout_s(trigger)
                if now - since > limit:
                    self._pending.popleft()
                    self.timeouts += 1
                    out.append(self._lose(trigger, f'no frame within {limit:.3g} s of the trigger '
                                                   '(grab timeout: the trigger did not reach the '
                                                   'camera, or the camera was not ready for it)'))
                    self._out_of_step = f'trigger {trigger.sequence} had no frame'
                    self._out_of_step_since = now
                    while self._pending:
                        other, _ = self._pending.popleft()
                        out.append(self._lose(other, f'camera out of step ({self._out_of_step})'))
            while self._early and now - self._early[0][1] > max(self.early_limit_s, self._frame_limit_s):
                self._early.popleft()
                self.unclaimed += 1
        return out

    def fail_all(self, reason: str) -> list:
        """The camera is gone: every waiting trigger is lost; pairing starts afresh."""
        with self._lock:
            out = [self._lose(t, reason) for t, _ in self._pending]
            self._pending.clear()
            self._early.clear()
            self._next_block, self._owed, self._out_of_step = None, 0, ''
        return out

    @property
    def waiting(self) -> int:
        with self._lock:
            return len(self._pending)

    # ------------------------------------------------------------------ helpers
    def _quiet(self, now: float) -> bool:
        # a late frame of the trigger that timed out may still come: one more time limit
        since = max(self._last_frame, self._out_of_step_since)
        return not self._pending and now - since > self._frame_limit_s

    def _lose(self, trigger: Trigger, reason: str) -> LostFrame:
        self.lost += 1
        return LostFrame(trigger, reason)

    def _pair(self, trigger: Trigger, frame: GrabbedFrame):
        if frame.image is None:
            return self._lose(trigger, f'failed buffer: {frame.error or "the grab failed"}')
        self.paired += 1
        info = dict(frame.info or {})
        if frame.block_id is not None:
            info['block_id'] = frame.block_id
        return Frame(trigger, frame.image, frame.bit_depth, info)
