"""The fast low-resolution path has the statistics of noise-at-full-resolution-then-downscale.

Both paths are run many times on the same models; per pixel we compare means (z-test) and
variances (F-test) at the 1 % level. Tolerance: the fraction of pixels rejected must stay
below 2.5 % (agreement gives ~1 %, give or take 0.1 % over the ~30 000 pixels tested), the
pooled variance ratio within 2 % of 1 (a wrong noise_scale is off by 2x or more) and the mean
difference within 0.05 gray levels; all away from 0 and saturation, where clipping before
vs after averaging differs by design.
"""
import numpy as np
import pytest
from scipy import ndimage, stats

from lightstage_physics.noise import PRESETS
from lightstage_physics.render import render_noisy
from lightstage_physics.rig import Rig
from lightstage_physics.scene_models import ModelSet


def smooth_models(n=2, size=96, seed=0):
    rng = np.random.default_rng(seed)
    field = ndimage.gaussian_filter(rng.standard_normal((n, 4, 8, size, size)),
                                    sigma=(0, 0, 0, 6, 6))
    field = (field - field.min()) / np.ptp(field)
    models = (20 + 90 * field).astype(np.float32)
    return ModelSet(models, np.arange(n) % 2, ["a-real", "a-fake"],
                    [f"m{i}" for i in range(n)], np.arange(n), np.zeros(n, int),
                    Rig.paper_default(size))


@pytest.mark.parametrize("factor", [2, 3])
def test_low_resolution_statistics_match_full_resolution(factor):
    noise = PRESETS["sigma3"]
    full = smooth_models(size=48 * factor)
    small = full.downscaled(48)
    assert small.noise_scale == pytest.approx(1 / factor ** 2)
    W = np.array([[1, 0, 1, 1, 0, 0, 1, 0], [0, 1, 0, 0, 1, 1, 0, 1]], float).T
    reps = 300
    rng = np.random.default_rng(11)
    fast = np.stack([render_noisy(small, W, noise, rng) for _ in range(reps)])
    # full-resolution path: render + noise at full resolution, then block-mean downscale
    slow = []
    for _ in range(reps):
        img = render_noisy(full, W, noise, rng)
        slow.append(img.reshape(*img.shape[:2], 48, factor, 48, factor).mean(axis=(3, 5)))
    slow = np.stack(slow)
    m_fast, m_slow = fast.mean(0), slow.mean(0)
    v_fast, v_slow = fast.var(0, ddof=1), slow.var(0, ddof=1)
    # stay clear of clipping: 4 full-resolution sigmas from 0 and from max_level
    clean_mean = np.clip(m_slow, 0, None)
    full_sd = np.sqrt(noise.variance(clean_mean))
    ok = (clean_mean - 4 * full_sd > 0) & (clean_mean + 4 * full_sd < noise.max_level)
    assert ok.mean() > 0.5
    z = (m_fast - m_slow) / np.sqrt((v_fast + v_slow) / reps)
    p_mean = 2 * stats.norm.sf(np.abs(z[ok]))
    f = v_fast[ok] / v_slow[ok]
    p_var = 2 * np.minimum(stats.f.cdf(f, reps - 1, reps - 1), stats.f.sf(f, reps - 1, reps - 1))
    assert np.mean(p_mean < 0.01) < 0.025
    assert np.mean(p_var < 0.01) < 0.025
    assert np.mean(v_fast[ok]) / np.mean(v_slow[ok]) == pytest.approx(1.0, abs=0.02)
    assert np.mean(m_fast[ok] - m_slow[ok]) == pytest.approx(0.0, abs=0.05)
