import numpy as np
import pytest


@pytest.fixture(scope="session")
def toy_stacks():
    """Small, learnable but noisy problem: 4 classes x 8 samples, 3 images of 120 x 120."""
    rng = np.random.default_rng(0)
    n_classes, per_class, k = 4, 8, 3
    yy, xx = np.mgrid[:120, :120].astype(np.float32)
    prototypes = np.stack([
        np.stack([(np.sin((xx * np.cos(a) + yy * np.sin(a)) / (6 + j)) + 1) * 400
                  for j in range(k)])
        for a in np.linspace(0, np.pi, n_classes, endpoint=False)
    ])
    y = np.repeat(np.arange(n_classes), per_class)
    stacks = prototypes[y] + rng.normal(0, 150, (y.size, k, 120, 120)).astype(np.float32)
    return stacks.astype(np.float32), y
