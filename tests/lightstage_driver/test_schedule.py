"""The graded-level latch schedule (`lightstage_driver.schedule`, the firmware's schedule.c
in Python): every LED goes dark within the stated bound of level / 255 of the exposure,
latches keep a shift-out apart and leave the end's zero shift its time."""
import os

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from lightstage_driver import schedule as sched

levels = st.lists(st.integers(0, 255) | st.sampled_from([0, 1, 254, 255]), min_size=32, max_size=32)
exposure_ticks = st.integers(40, 4_000_000) | st.sampled_from([40, 41, 112, 200, 254, 255, 256, 18360])


@settings(max_examples=int(os.environ.get('LIGHTSTAGE_FUZZ_EXAMPLES', 300)), deadline=None)
@given(levels, exposure_ticks)
def test_off_instants_within_the_bound_and_latches_a_shift_out_apart(lv, ticks):
    s = sched.build(lv, ticks)
    off = np.array(s.off_ticks(), dtype=float)
    ideal = np.array(lv) / 255 * ticks
    assert np.abs(off - ideal).max() <= sched.max_off_error_ticks()
    at = [0] + [a for a, _ in s.steps]
    assert all(b - a >= sched.SHIFT_TICKS for a, b in zip(at, at[1:]))
    assert ticks - at[-1] >= sched.ZERO_TICKS
    # words only ever switch LEDs off, and only lit LEDs
    words = [s.rise_word] + [w for _, w in s.steps]
    assert all(b & ~a == 0 for a, b in zip(words, words[1:]))
    assert s.rise_word & ~sum(1 << i for i, v in enumerate(lv) if v) == 0


def test_every_level_has_its_own_off_tick_from_128_us():
    assert len({sched.off_tick(level, 256) for level in range(256)}) == 256
    assert len({sched.off_tick(level, 254) for level in range(256)}) < 256
    # adjacent levels of one pattern get latches of their own from 255 shift-outs
    ticks = 255 * sched.SHIFT_TICKS
    s = sched.build(list(range(100, 132)), ticks)
    assert len(s.steps) == 32 and np.array_equal(s.off_ticks(), [sched.off_tick(v, ticks) for v in range(100, 132)])
