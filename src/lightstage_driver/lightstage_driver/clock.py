"""Mapping the firmware's 32-bit microsecond clock to the host's monotonic clock.

The firmware stamps triggers with a free-running u32 microsecond counter (wraps every
71.6 min). `FirmwareClock` unwraps it and estimates the offset to `time.monotonic()`
from probes (host send time, firmware time, host receive time): the firmware time lies
between send and receive, so the midpoint is the estimate and half the round trip its
error bound. The probe with the smallest round trip among the recent ones wins (queueing
delays only ever add to a round trip); drift between the crystals (tens of ppm) is
absorbed because probes keep coming (the driver's heartbeat).
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

WRAP = 1 << 32
HALF = 1 << 31


@dataclass(frozen=True)
class ClockProbe:
    host_send_s: float
    firmware_us: int      # unwrapped
    host_recv_s: float

    @property
    def rtt_s(self) -> float:
        return self.host_recv_s - self.host_send_s

    @property
    def offset_s(self) -> float:
        return 0.5 * (self.host_send_s + self.host_recv_s) - self.firmware_us * 1e-6


class FirmwareClock:
    def __init__(self, window: int = 16):
        self._last_raw: int | None = None
        self._last_unwrapped = 0
        self.probes: deque[ClockProbe] = deque(maxlen=window)

    def reset(self) -> None:
        """The firmware rebooted: its clock restarted."""
        self._last_raw = None
        self._last_unwrapped = 0
        self.probes.clear()

    def unwrap(self, raw_us: int) -> int:
        """Unwrap a u32 stamp relative to the previous one (within +-2^31 us of it)."""
        if self._last_raw is None:
            unwrapped = raw_us
        else:
            delta = (raw_us - self._last_raw) % WRAP
            if delta >= HALF:
                delta -= WRAP
            unwrapped = self._last_unwrapped + delta
        if self._last_raw is None or unwrapped >= self._last_unwrapped:
            self._last_raw, self._last_unwrapped = raw_us, unwrapped
        return unwrapped

    def add_probe(self, host_send_s: float, raw_us: int, host_recv_s: float) -> ClockProbe:
        probe = ClockProbe(host_send_s, self.unwrap(raw_us), host_recv_s)
        self.probes.append(probe)
        return probe

    @property
    def synced(self) -> bool:
        return bool(self.probes)

    def best_probe(self) -> ClockProbe:
        if not self.probes:
            raise RuntimeError('firmware clock not synchronised yet: send a HEARTBEAT first')
        return min(self.probes, key=lambda pr: pr.rtt_s)

    @property
    def uncertainty_s(self) -> float:
        return 0.5 * self.best_probe().rtt_s

    def to_host(self, raw_us: int) -> float:
        """Host monotonic time [s] of a firmware stamp."""
        return self.unwrap(raw_us) * 1e-6 + self.best_probe().offset_s
