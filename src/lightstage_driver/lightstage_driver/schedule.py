"""Graded LED levels as on-times: the latch schedule of one exposure (pure integers).

The same computation as the AVR firmware's `firmware/src/schedule.c` (the differential
test compares the words both latch): LED i with level `l` of `full` is lit from the
trigger's rising edge to round(l * E / full) timer ticks (0.5 us) of the exposure's E,
by re-latching the 74HC595 chain at the sorted off-instants. A new word needs
`SHIFT_TICKS` to be shifted in after a latch and the end's zeros `ZERO_TICKS`, so
off-instants closer than that share a latch (docs/PROTOCOL.md, "Graded levels").
"""
from __future__ import annotations

from dataclasses import dataclass

TICKS_PER_US = 2          # Timer1 at F_CPU / 8 = 2 MHz
SHIFT_TICKS = 72          # latch to latch: a 32-bit word's shift-out plus bookkeeping (36 us)
ZERO_TICKS = 40           # the end's zero shift plus bookkeeping (20 us)
LEVEL_FULL = 255          # 8-bit levels


@dataclass(frozen=True)
class Schedule:
    rise_word: int                        # latched at the rising edge
    steps: tuple[tuple[int, int], ...]    # (tick from the rising edge, word latched)
    ticks: int                            # the exposure in ticks (the end: every LED off)

    def off_ticks(self, led_count: int = 32) -> list[int]:
        """Tick at which each LED goes dark (0: never lit)."""
        out = []
        for i in range(led_count):
            if not self.rise_word >> i & 1:
                out.append(0)
                continue
            out.append(next((at for at, word in self.steps if not word >> i & 1), self.ticks))
        return out


def off_tick(level: int, ticks: int, full: int = LEVEL_FULL) -> int:
    """round(level * ticks / full), halves up, as the firmware computes it."""
    q, r = divmod(ticks, full)
    return level * q + (level * r + full // 2) // full


def build(levels, ticks: int, full: int = LEVEL_FULL) -> Schedule:
    """The latch schedule of `levels` (0..full, LED order) over an exposure of `ticks`."""
    word = sum(1 << i for i, level in enumerate(levels) if level)
    order = sorted((i for i, level in enumerate(levels) if 0 < level < full), key=lambda i: (levels[i], i))
    rise_word = word
    steps: list[list[int]] = []
    last = 0
    k = 0

    def off_at_last(mask: int) -> None:
        nonlocal rise_word
        if steps:
            steps[-1][1] &= ~mask
        else:
            rise_word &= ~mask

    while k < len(order):
        t = off_tick(levels[order[k]], ticks, full)
        mask = 0
        while k < len(order) and off_tick(levels[order[k]], ticks, full) == t:
            mask |= 1 << order[k]
            k += 1
        if t >= ticks:
            break
        nxt = last + SHIFT_TICKS
        if t <= last or (t < nxt and 2 * (t - last) <= SHIFT_TICKS) or \
                (nxt + ZERO_TICKS > ticks and t - last <= ticks - t):
            off_at_last(mask)
        elif nxt + ZERO_TICKS > ticks or t + ZERO_TICKS > ticks:
            break
        else:
            at = max(t, nxt)
            word &= ~mask
            steps.append([at, word])
            last = at
            continue
        word &= ~mask
    return Schedule(rise_word, tuple((at, w) for at, w in steps), ticks)


def max_off_error_ticks() -> float:
    """Bound on |actual - ideal| off-instant, in ticks (rounding of the ideal included)."""
    return max(SHIFT_TICKS / 2, (SHIFT_TICKS + ZERO_TICKS) / 2, ZERO_TICKS) + 0.5
