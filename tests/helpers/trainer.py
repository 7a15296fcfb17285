"""Small structured light-stage data for the search tests.

Class information is placed in a few (site, channel) images only: class k adds an oriented
grating to site `2 * (k % 2)`'s red image and to site 1's NIR image with a class-dependent
orientation, on top of a random per-pose texture that every site sees. Lighting the
informative sites helps; lighting the others only adds nuisance and noise, so the greedy
search has real choices to make.
"""
import numpy as np
from lightstage_physics.rig import Rig
from lightstage_physics.scene_models import ModelSet
from mux_classifier.hog import HogConfig

from mux_trainer.rendering import SearchData

TINY_HOG = HogConfig(image_size=24, cell_px=6, block_cells=4)
TINY = ['--image-size', '24', '--cell-px', '6', '--block-cells', '4']  # the CLI options of TINY_HOG


def make_models(n_types=2, n_poses=8, size=24, n_sites=8, seed=0, signal=60.0):
    rng = np.random.default_rng(seed)
    class_names = [f'fruit{t}-{kind}' for t in range(n_types) for kind in ('fake', 'real')]
    n_classes = len(class_names)
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float32)
    models, labels, poses = [], [], []
    for k in range(n_classes):
        for p in range(n_poses):
            texture = rng.uniform(60, 140, size=(size, size)).astype(np.float32)
            m = np.empty((4, n_sites, size, size), np.float32)
            for s in range(n_sites):
                gain = rng.uniform(0.5, 1.5, size=4).astype(np.float32)
                m[:, s] = gain[:, None, None] * texture[None]
            angle = np.pi * k / n_classes + rng.normal(0, 0.05)
            grating = signal * np.sin(0.9 * (np.cos(angle) * xx + np.sin(angle) * yy))
            m[0, 2 * (k % 2) % n_sites] += grating
            m[3, 1 % n_sites] += grating * (1 + k) / n_classes
            models.append(m)
            labels.append(k)
            poses.append(p)
    return np.stack(models), np.array(labels), np.array(poses), class_names


def make_modelset(**kwargs) -> ModelSet:
    models, labels, poses, names = make_models(**kwargs)
    size = models.shape[-1]
    sample_names = [f'{names[lab]}/s0/p{p:02d}' for lab, p in zip(labels, poses)]
    return ModelSet(models, labels, names, sample_names, poses, np.zeros_like(labels),
                    Rig.paper_default(size))


def make_search_data(noise_a=0.9, noise_b=100.0, **kwargs) -> SearchData:
    models, labels, poses, names = make_models(**kwargs)
    return SearchData.from_models(models, labels, poses, names, noise_a=noise_a,
                                  noise_b=noise_b, hog_config=TINY_HOG, noise_name='custom')
