"""Stamped camera frames: decoding ``mono16`` images and matching them to trigger stamps.

Everything that lights patterns on the stage and collects the images they caused (the
classifier, model acquisition, noise calibration: `stage_client.StageClient`) pairs images
with patterns the same way: the driver reports a trigger stamp per pattern, the camera stamps
each image with the stamp of the trigger that caused it, and `ImageMatcher.collect` hands
back the images whose header stamps *equal* those trigger stamps, in pattern order; never by
arrival order. Images that arrive before the trigger stamps are known (the camera can be
faster than the driver's reply) wait in a small buffer. A trigger whose frame the camera lost
(its ``FrameLost`` notice: failed buffer, grab timeout, camera removed, ...) ends the wait at
once with the camera's reason, instead of waiting out the timeout; so does a later image
arriving first (the stream is reliable and in trigger order: the missing one will not come).

No rclpy here: `add_message` / `add_lost_message` take a ``sensor_msgs/Image`` /
``lightstage_interfaces/FrameLost`` duck-typed.
"""
from __future__ import annotations

import threading
import time
from collections import OrderedDict
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from .errors import MissingImagesError
from .names import FRAME_LOST_TOPIC, ILLUMINATION_TOPIC, IMAGE_TOPIC
from .stamps import format_stamp, stamp_to_ns

__all__ = ["ImageMatcher", "image_from_buffer", "mono16_to_gray", "MONO16_ENCODINGS"]

MONO16_ENCODINGS = ("mono16", "16UC1")


# --------------------------------------------------------------------------- images


def image_from_buffer(data, height: int, width: int, step: int, encoding: str,
                      is_bigendian: bool = False) -> np.ndarray:
    """A ``mono16`` image message's fields -> uint16 (H, W); ValueError if it is not one."""
    if encoding not in MONO16_ENCODINGS:
        raise ValueError(f"image encoding is {encoding!r}; 16-bit mono "
                         f"({' or '.join(MONO16_ENCODINGS)}) is needed, as the light-stage camera "
                         "publishes")
    if height < 1 or width < 1 or step < 2 * width:
        raise ValueError(f"image is {width}x{height} with step {step}: not a valid mono16 image")
    buf = np.frombuffer(data, dtype=np.uint8)
    if buf.size < height * step:
        raise ValueError(f"image data holds {buf.size} bytes, a {width}x{height} mono16 image "
                         f"with step {step} needs {height * step}")
    rows = buf[:height * step].reshape(height, step)[:, :2 * width]
    dtype = np.dtype(">u2" if is_bigendian else "<u2")
    return np.ascontiguousarray(rows).view(dtype).reshape(height, width).astype(np.uint16)


def mono16_to_gray(image: np.ndarray, bit_depth: int = 10) -> np.ndarray:
    """MSB-aligned 16-bit values -> float32 gray levels in camera units (10-bit: value / 64)."""
    if not 8 <= int(bit_depth) <= 16:
        raise ValueError(f"bit_depth must be 8..16, got {bit_depth}")
    gray = np.asarray(image, dtype=np.float32)
    gray *= np.float32(1.0 / (1 << (16 - int(bit_depth))))
    return gray


# --------------------------------------------------------------------------- matching


@dataclass
class _Entry:
    image: np.ndarray | None
    error: str
    arrival_ns: int
    lost: bool = False  # the camera said this trigger's frame will not come


class ImageMatcher:
    """Images keyed by their header stamp (ns), waited for by trigger stamp. Thread-safe.

    `add` is called from the image subscription; `collect` from the service handler. Images
    may arrive before they are asked for: the ``capacity`` most recent ones nobody has asked
    for yet are kept. Images whose stamps are `claim`ed (a sequence known to need them, not
    yet collected) are never evicted; `collect` releases them. `clock` gives the arrival time
    in ns, on the same time base as the trigger stamps.

    The camera's image stream is reliable and in trigger order, and `add` is called in
    arrival order (one subscription callback at a time): so once an image stamped *later*
    than a missing one has arrived, the missing one will not come. `collect(..., since_ns=T)`
    then fails at once, without waiting out its timeout (only images that arrived at or
    after T count, T being a time before which none of the awaited images can have come: a
    bag played again from its start repeats older stamps).
    """

    def __init__(self, capacity: int = 64, clock: Callable[[], int] = time.time_ns):
        if capacity < 1:
            raise ValueError(f"capacity must be >= 1, got {capacity}")
        self.capacity = int(capacity)
        self.clock = clock
        self._entries: OrderedDict[int, _Entry] = OrderedDict()
        self._claimed: dict[int, int] = {}  # stamp -> number of sequences waiting for it
        self._unclaimed = 0
        self._latest: tuple[int, int] | None = None  # (stamp, arrival) of the last image in
        self._cond = threading.Condition()
        self.received = 0
        self.evicted = 0

    def __len__(self) -> int:
        with self._cond:
            return len(self._entries)

    def set_capacity(self, capacity: int) -> None:
        """Keep at most `capacity` unclaimed images from now on."""
        if capacity < 1:
            raise ValueError(f"capacity must be >= 1, got {capacity}")
        with self._cond:
            self.capacity = int(capacity)
            self._evict()

    def claim(self, stamps_ns: Sequence[int]) -> None:
        """A sequence needs the images stamped `stamps_ns`: keep them until it collects (or
        `release`s) them, however many other images arrive meanwhile."""
        with self._cond:
            self._claim(map(int, stamps_ns))

    def _claim(self, stamps) -> None:
        for s in stamps:
            self._claimed[s] = self._claimed.get(s, 0) + 1
            if self._claimed[s] == 1 and s in self._entries:
                self._unclaimed -= 1

    def release(self, stamps_ns: Sequence[int]) -> None:
        """Undo one `claim` of `stamps_ns` (their images become evictable again)."""
        with self._cond:
            self._release(map(int, stamps_ns))
            self._evict()

    def _release(self, stamps) -> None:
        for s in stamps:
            n = self._claimed.get(s, 0) - 1
            if n > 0:
                self._claimed[s] = n
            elif n == 0:
                del self._claimed[s]
                if s in self._entries:
                    self._unclaimed += 1

    def _evict(self) -> None:
        """Drop the oldest unclaimed images beyond `capacity` (lock held)."""
        if self._unclaimed <= self.capacity:
            return
        for stamp in list(self._entries):
            if self._unclaimed <= self.capacity:
                break
            if stamp not in self._claimed:
                del self._entries[stamp]
                self._unclaimed -= 1
                self.evicted += 1

    def add(self, stamp_ns: int, image: np.ndarray | None, error: str = "",
            lost: bool = False) -> None:
        """An image (or, with `error`, the reason it was unusable; with `lost`, the camera's
        reason it will not come) stamped `stamp_ns`."""
        stamp = int(stamp_ns)
        entry = _Entry(image, error, int(self.clock()), lost)
        with self._cond:
            if stamp in self._entries:
                del self._entries[stamp]
            elif stamp not in self._claimed:
                self._unclaimed += 1
            self._entries[stamp] = entry
            if not lost:  # lost notices come on their own topic, not in the images' order
                self._latest = (stamp, entry.arrival_ns)
            self._evict()
            self.received += 1
            self._cond.notify_all()

    def add_message(self, msg) -> None:
        """A ``sensor_msgs/Image`` (duck-typed: no ROS import here), by its header stamp; one
        that is not 16-bit mono is kept as unusable, with the reason."""
        stamp = stamp_to_ns(msg.header.stamp)
        try:
            image = image_from_buffer(msg.data, msg.height, msg.width, msg.step, msg.encoding,
                                      bool(msg.is_bigendian))
        except ValueError as exc:
            self.add(stamp, None, error=str(exc))
            return
        self.add(stamp, image)

    def add_lost(self, stamp_ns: int, reason: str) -> None:
        """The camera lost the frame of the trigger stamped `stamp_ns`, for `reason`: a
        `collect` waiting for it fails at once."""
        self.add(stamp_ns, None, error=reason, lost=True)

    def add_lost_message(self, msg) -> None:
        """A ``lightstage_interfaces/FrameLost`` notice (duck-typed), by its header stamp."""
        self.add_lost(stamp_to_ns(msg.header.stamp), str(msg.reason))

    def collect(self, stamps_ns: Sequence[int], timeout_s: float,
                sequences: Sequence[int] | None = None,
                since_ns: int | None = None) -> tuple[list[np.ndarray], int]:
        """The images stamped ``stamps_ns`` in that order, and the last one's arrival time.

        Waits up to `timeout_s`; or, at once, until the camera reports one of them lost, or
        (with `since_ns`: none of them can have arrived before that time) an image stamped
        later than a missing one arrives at or after `since_ns`: the in-order stream has then
        gone past it. Raises MissingImagesError naming each image (position, trigger
        sequence, stamp) that the camera lost, did not come, did not arrive or arrived
        unusable. Collected images leave the buffer; while it waits, the ones that came are
        kept whatever else arrives (`claim`).
        """
        stamps = [int(s) for s in stamps_ns]
        deadline = time.monotonic() + max(0.0, float(timeout_s))
        with self._cond:
            self._claim(stamps)
            try:
                while True:
                    missing = [i for i, s in enumerate(stamps) if s not in self._entries]
                    lost = [i for i, s in enumerate(stamps)
                            if s in self._entries and self._entries[s].lost]
                    passed = [i for i in missing if self._passed(stamps[i], since_ns)]
                    remaining = deadline - time.monotonic()
                    if not missing or lost or passed or remaining <= 0:
                        break
                    self._cond.wait(remaining)
                bad = [i for i, s in enumerate(stamps)
                       if s in self._entries and self._entries[s].image is None]
                if missing or bad:
                    waiting = [i for i in missing if i not in passed]
                    # ended by a lost or passed frame: the images still on their way are not late
                    late = waiting if remaining <= 0 and not (lost or passed) else []
                    raise self._missing_error(stamps, sequences, late, bad, timeout_s,
                                              awaited=len(waiting) - len(late), passed=passed)
                entries = [self._entries.pop(s) for s in stamps]
            finally:
                self._release(stamps)
                self._evict()
        return [e.image for e in entries], max(e.arrival_ns for e in entries)

    def _passed(self, stamp: int, since_ns: int | None) -> bool:
        """Whether an image stamped later than `stamp` arrived at or after `since_ns`."""
        return (since_ns is not None and self._latest is not None and self._latest[0] > stamp
                and self._latest[1] >= since_ns)

    def _missing_error(self, stamps, sequences, missing, bad, timeout_s,
                       awaited: int = 0, passed=()) -> MissingImagesError:
        def name(i: int) -> str:
            seq = f"trigger sequence {sequences[i]}, " if sequences is not None else ""
            return f"image {i + 1} ({seq}stamp {format_stamp(stamps[i])})"

        parts = []
        if missing:
            parts.append(f"{len(missing)} of {len(stamps)} images did not arrive within "
                         f"{float(timeout_s):g} s: {', '.join(name(i) for i in missing)}; is the "
                         f"camera node running, subscribed to {ILLUMINATION_TOPIC} and publishing "
                         f"{IMAGE_TOPIC} stamped with the trigger stamps?")
        if passed:
            one = len(passed) == 1
            parts.append(f"{', '.join(name(i) for i in passed)} did not come: a later image "
                         f"(stamp {format_stamp(self._latest[0])}) arrived first, and the "
                         f"camera's images arrive in trigger order, so {'it was' if one else 'they were'} "
                         "lost on the way (dropped by the camera, the transport or a recording)")
        lost_by_reason: dict[str, list[int]] = {}  # one camera fault often loses several
        for i in bad:
            entry = self._entries[stamps[i]]
            if entry.lost:
                lost_by_reason.setdefault(entry.error, []).append(i)
            else:
                parts.append(f"{name(i)} is unusable: {entry.error}")
        for reason, lost in lost_by_reason.items():
            parts.append(f"{', '.join(name(i) for i in lost)} {'was' if len(lost) == 1 else 'were'} "
                         f"lost by the camera ({FRAME_LOST_TOPIC}): {reason}")
        if awaited:
            parts.append(f"not waiting for the other {awaited} image(s) still on their way")
        return MissingImagesError("; ".join(parts), sorted([*missing, *passed, *bad]))
