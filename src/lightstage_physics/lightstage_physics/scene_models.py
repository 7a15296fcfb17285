"""Relightable models of samples: one image per single LED, for every sample and pose.

A `ModelSet` holds the 32 single-LED images of every (sample, pose) as float32 gray levels
in camera units, laid out ``(n_samples, 4 channels, 8 sites, H, W)`` so that one colour's
8 site images are contiguous (the ``L`` of ``I = L @ w``).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .rig import CHANNELS, Rig


def object_type_of(class_name: str) -> str:
    """``"banana-fake"`` -> ``"banana"``: the label prefix before the first ``-``."""
    return class_name.split("-", 1)[0]


def block_mean_factor(size_in: int, size_out: int) -> int | None:
    """Integer downscale factor if ``size_in`` is a multiple of ``size_out``, else None."""
    return size_in // size_out if size_in % size_out == 0 else None


def downscale_images(images: np.ndarray, size: int | tuple[int, int]) -> tuple[np.ndarray, float]:
    """Area downscale of the last two axes; returns the images and the noise variance factor.

    Integer factors use an exact block mean (variance of i.i.d. noise shrinks by 1/f^2).
    Other ratios use `skimage.transform.resize_local_mean`; its variance factor (sum of
    squared weights) varies slightly across pixels, and the returned factor is its mean.
    """
    out_h, out_w = (size, size) if np.isscalar(size) else (int(size[0]), int(size[1]))
    h, w = images.shape[-2:]
    if out_h > h or out_w > w:
        raise ValueError(f"cannot downscale {h}x{w} images to a larger size {out_h}x{out_w}")
    fh, fw = block_mean_factor(h, out_h), block_mean_factor(w, out_w)
    lead = images.shape[:-2]
    if fh is not None and fw is not None:
        if fh == 1 and fw == 1:
            return images.astype(np.float32, copy=False), 1.0
        blocks = images.reshape(*lead, out_h, fh, out_w, fw)
        out = blocks.mean(axis=(-3, -1), dtype=np.float32)
        return out.astype(np.float32, copy=False), 1.0 / (fh * fw)
    from skimage.transform import resize_local_mean
    flat = images.reshape(-1, h, w)
    out = np.stack([resize_local_mean(im, (out_h, out_w), preserve_range=True) for im in flat])
    # Noise variance factor: push unit-variance white noise through the same operator.
    probe = np.random.default_rng(0).standard_normal((h, w))
    scale = float(np.var(resize_local_mean(probe, (out_h, out_w), preserve_range=True)))
    return out.reshape(*lead, out_h, out_w).astype(np.float32), scale


@dataclass
class ModelSet:
    """Relightable models of all (sample, pose) pairs of a capture, and what they are.

    models       float32 (n, 4, 8, H, W): [channel, site] single-LED images, camera units
    labels       int64 (n,) index into class_names
    class_names  e.g. ["banana-fake", "banana-real", ...]
    sample_names e.g. "banana-fake/s2/p03" (label/sample/pose)
    pose_index   int64 (n,) pose number within its class, 0..n_poses_per_class-1
    instance     int64 (n,) physical sample id within its class (held-out-sample splits)
    noise_scale  factor applied to the camera noise variance: 1.0 at full resolution,
                 1/f^2 after an f x f block-mean downscale
    """
    models: np.ndarray
    labels: np.ndarray
    class_names: list[str]
    sample_names: list[str]
    pose_index: np.ndarray
    instance: np.ndarray
    rig: Rig
    noise_scale: float = 1.0
    extra: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.models = np.asarray(self.models, dtype=np.float32)
        self.labels = np.asarray(self.labels, dtype=np.int64)
        self.pose_index = np.asarray(self.pose_index, dtype=np.int64)
        self.instance = np.asarray(self.instance, dtype=np.int64)
        self.class_names = [str(c) for c in self.class_names]
        self.sample_names = [str(s) for s in self.sample_names]
        if self.models.ndim != 5 or self.models.shape[1] != len(CHANNELS):
            raise ValueError(f"models must be (n, {len(CHANNELS)}, sites, H, W), "
                             f"got shape {self.models.shape}")
        if self.models.shape[2] != self.rig.n_sites:
            raise ValueError(f"models have {self.models.shape[2]} sites but the rig has "
                             f"{self.rig.n_sites}")
        n = self.models.shape[0]
        for name in ("labels", "pose_index", "instance"):
            if getattr(self, name).shape != (n,):
                raise ValueError(f"{name} must have shape ({n},), got {getattr(self, name).shape}")
        if len(self.sample_names) != n:
            raise ValueError(f"need {n} sample_names, got {len(self.sample_names)}")
        if n and (self.labels.min() < 0 or self.labels.max() >= len(self.class_names)):
            raise ValueError("labels must index class_names")

    def __len__(self) -> int:
        return int(self.models.shape[0])

    @property
    def n_classes(self) -> int:
        return len(self.class_names)

    @property
    def image_shape(self) -> tuple[int, int]:
        return tuple(self.models.shape[-2:])

    @property
    def object_type(self) -> list[str]:
        """Object type of every sample (label prefix, e.g. "banana")."""
        return [object_type_of(self.class_names[k]) for k in self.labels]

    @property
    def object_types(self) -> list[str]:
        """Distinct object types in class order."""
        return list(dict.fromkeys(object_type_of(c) for c in self.class_names))

    @property
    def max_level(self) -> int:
        return self.rig.max_level

    def subset(self, indices) -> "ModelSet":
        """The samples at ``indices`` (ints or a boolean mask); class list is unchanged."""
        idx = np.arange(len(self))[np.asarray(indices)]
        return replace(self, models=self.models[idx], labels=self.labels[idx],
                       sample_names=[self.sample_names[i] for i in idx],
                       pose_index=self.pose_index[idx], instance=self.instance[idx],
                       extra=dict(self.extra))

    def downscaled(self, size: int = 120) -> "ModelSet":
        """Area-downscaled models; `noise_scale` becomes the variance factor of that downscale.

        Rendering is linear, so downscaling the models first and then adding noise with
        variance ``noise_scale * var(mean)`` matches noise-at-full-resolution-then-downscale
        (exactly in mean and variance for integer factors, away from saturation).
        """
        small, factor = downscale_images(self.models, size)
        out_h, out_w = small.shape[-2:]
        rig = replace(self.rig, image_size=(out_h, out_w))
        return replace(self, models=small, rig=rig, noise_scale=self.noise_scale * factor,
                       extra=dict(self.extra))
