"""Each LED's on-time inside each trigger pulse, decoded from the latched chain words."""
from __future__ import annotations

import numpy as np


def on_times_us(words, pulses, led_count: int = 32) -> list[np.ndarray]:
    """Per trigger pulse, how long each LED was lit during it [us].

    `words`: LatchedWord (time_s, word) in order; `pulses`: TriggerPulse (start_s, width_us).
    The word latched at the rising edge (the same instant) counts from the edge; the word
    lit when the pulse ends is cut there.
    """
    out = []
    eps = 1e-9
    for pulse in pulses:
        start, end = pulse.start_s, pulse.start_s + pulse.width_us / 1e6
        lit = 0
        for w in words:
            if w.time_s < start - eps:
                lit = w.word
        times = [start] + [w.time_s for w in words if start - eps <= w.time_s < end - eps] + [end]
        states = [lit] + [w.word for w in words if start - eps <= w.time_s < end - eps]
        on = np.zeros(led_count)
        for (t0, t1), word in zip(zip(times, times[1:]), states):
            for i in range(led_count):
                if word >> i & 1:
                    on[i] += (max(t1, start) - max(t0, start)) * 1e6
        out.append(on)
    return out
