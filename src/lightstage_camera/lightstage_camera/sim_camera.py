"""The simulated camera: the sample "on the stage", relit by the LEDs of a trigger, plus noise.

One frame = ``render_led_patterns`` of the current sample's relightable model under the
trigger's 32 LED intensities (the authors' dimmer included), then Gaussian noise from the
affine model at the trigger's gain and exposure (`noise.NoiseModel`), clipped to the
camera's range, quantised to whole gray levels and MSB-aligned in 16 bits (``mono16``, as
a Basler camera delivers 10-bit data: value << 6).

As in the authors' released simulator the *mean* image does not depend on gain and
exposure (exposure is taken to scale as 1/gain); gain and exposure change only the noise.
With ``exposure_scales_light`` the mean is the light integrated over the exposure instead:
the render times exposure_us / the rig's exposure_us (the exposure the models were captured
at), so an LED at drive 0.5 for 10 ms gives the image of drive 1.0 for 5 ms, as a graded
stage lights an LED for its level's fraction of the exposure.
Noise is drawn at the model's full resolution, as a real camera's would be.
"""
from __future__ import annotations

import difflib
import math
from dataclasses import replace
from typing import Callable

import numpy as np

from .camera_backend import BackendStatus, CameraBackend, Frame, Trigger
from lightstage_physics.capture_format import load_capture
from lightstage_physics.errors import SampleError
from lightstage_physics.noise import PAPER_CALIBRATION, PRESETS, NoiseModel
from lightstage_physics.render import render_led_patterns
from lightstage_physics.rig import DEFAULT_DIMMER
from lightstage_physics.scene_models import ModelSet

NOISE_CHOICES = ('auto', 'none', *PRESETS)


def resolve_sample(modelset: ModelSet, sample) -> int:
    """Index of a sample given by name (``"banana-fake/s2/p03"``) or index (``3``, ``"3"``)."""
    n = len(modelset)
    if n == 0:
        raise SampleError('the capture holds no samples')
    text = str(sample).strip()
    if isinstance(sample, (int, np.integer)) or text.lstrip('-').isdigit():
        index = int(text)
        if not 0 <= index < n:
            raise SampleError(f'sample index {index} is out of range: the capture has {n} samples '
                              f'(0..{n - 1})')
        return index
    if text in modelset.sample_names:
        return modelset.sample_names.index(text)
    close = difflib.get_close_matches(text, modelset.sample_names, n=3)
    hint = (f'did you mean {", ".join(close)}?' if close else
            f'e.g. {", ".join(modelset.sample_names[:3])}')
    raise SampleError(f'unknown sample {text!r}: the capture has {n} samples named '
                      f'label/sample/pose ({hint}); give one of those names or an index 0..{n - 1}')


def parse_noise(noise) -> str | NoiseModel:
    """'auto' | 'none' | 'sigma1'..'sigma3' (case-insensitive), or a NoiseModel as is."""
    if isinstance(noise, NoiseModel):
        return noise
    key = str(noise).strip().lower()
    if key not in NOISE_CHOICES:
        raise ValueError(f'unknown noise setting {noise!r}; use one of {", ".join(NOISE_CHOICES)} '
                         '(auto: from each trigger\'s gain and exposure)')
    return key


class SimCamera:
    """A simulated monochrome camera looking at one sample of a ModelSet.

    Parameters
    ----------
    modelset : ModelSet
        Relightable models at the camera's resolution (gray levels, camera units).
    sample : str or int
        The sample on the stage (name or index); change it with `set_sample`.
    noise : {"auto", "none", "sigma1", "sigma2", "sigma3"} or NoiseModel
        ``auto`` derives the noise from each capture's gain and exposure with `calibration`
        (`NoiseModel.at`); a preset or NoiseModel ignores them; ``none`` is noise-free.
    dimmer : float
        The authors' scale of the single-LED images before multiplexing (`rig.DEFAULT_DIMMER`).
    calibration : NoiseModel
        The affine noise fit `auto` generalizes (default: the paper's 15 dB / 30 ms fit).
    default_gain_db : float or None
        Gain used when a capture asks for the camera default (NaN); None: the capture's.
    seed : int or None
        Noise seed (None: fresh entropy).
    exposure_scales_light : bool
        Scale the mean image by exposure_us / the rig's exposure_us (off: the authors'
        exposure-independent mean).
    """

    def __init__(self, modelset: ModelSet, sample=0, noise='auto', dimmer: float = DEFAULT_DIMMER,
                 calibration: NoiseModel = PAPER_CALIBRATION, default_gain_db: float | None = None,
                 seed: int | None = None, exposure_scales_light: bool = False):
        if not isinstance(modelset, ModelSet):
            raise TypeError(f'SimCamera needs a ModelSet, got {type(modelset).__name__}')
        if not (math.isfinite(dimmer) and dimmer > 0):
            raise ValueError(f'dimmer must be a positive number, got {dimmer}')
        self.modelset = modelset
        self.dimmer = float(dimmer)
        self.calibration = replace(calibration, max_level=modelset.max_level)
        self.default_gain_db = float(modelset.rig.gain_db if default_gain_db is None else default_gain_db)
        self.noise = parse_noise(noise)
        self.rng = np.random.default_rng(seed)
        self.sample_index = resolve_sample(modelset, sample)
        self.exposure_scales_light = bool(exposure_scales_light)

    # ---- what is on the stage
    @property
    def sample_name(self) -> str:
        return self.modelset.sample_names[self.sample_index]

    @property
    def label(self) -> str:
        return self.modelset.class_names[self.modelset.labels[self.sample_index]]

    def set_sample(self, sample) -> int:
        """Put another sample on the stage (name or index); returns its index."""
        self.sample_index = resolve_sample(self.modelset, sample)
        return self.sample_index

    @property
    def bit_depth(self) -> int:
        return self.modelset.rig.bit_depth

    @property
    def image_shape(self) -> tuple[int, int]:
        return self.modelset.image_shape

    # ---- physics
    def render(self, led_intensities) -> np.ndarray:
        """Noise-free, unclipped gray levels (H, W) float32 under one 32-LED pattern."""
        leds = np.asarray(led_intensities, dtype=np.float32).reshape(-1)
        index = self.sample_index
        model = self.modelset.models[index:index + 1]
        return render_led_patterns(model, leds, self.dimmer)[0, 0]

    def noise_model(self, exposure_us: float, gain_db: float = math.nan) -> NoiseModel | None:
        """The noise of one capture at (exposure, gain); None when noise is off."""
        if isinstance(self.noise, NoiseModel):
            return replace(self.noise, max_level=self.modelset.max_level)
        if self.noise == 'none':
            return None
        if self.noise != 'auto':
            return replace(PRESETS[self.noise], max_level=self.modelset.max_level)
        if not (math.isfinite(exposure_us) and exposure_us > 0):
            raise ValueError(f'exposure_us must be > 0 to derive the noise, got {exposure_us}')
        gain = self.default_gain_db if not math.isfinite(gain_db) else float(gain_db)
        return self.calibration.at(gain, exposure_us / 1000.0)

    def capture_gray(self, led_intensities, exposure_us: float, gain_db: float = math.nan) -> np.ndarray:
        """One noisy frame in gray levels (float32, clipped, not quantised)."""
        mean = self.render(led_intensities)
        if self.exposure_scales_light:
            mean *= np.float32(exposure_us / self.modelset.rig.exposure_us)
        model = self.noise_model(exposure_us, gain_db)
        if model is None:
            return np.clip(mean, 0, self.modelset.max_level, out=mean)
        return model.sample(mean, self.rng, noise_scale=self.modelset.noise_scale, out=mean)

    def capture(self, led_intensities, exposure_us: float, gain_db: float = math.nan) -> np.ndarray:
        """One frame as the camera delivers it: uint16 (H, W), whole gray levels << (16 - bits)."""
        return encode_mono16(self.capture_gray(led_intensities, exposure_us, gain_db), self.bit_depth)


def encode_mono16(gray: np.ndarray, bit_depth: int) -> np.ndarray:
    """Gray levels -> whole camera levels, MSB-aligned uint16 (10-bit v -> v << 6)."""
    levels = np.clip(np.rint(gray), 0, (1 << bit_depth) - 1).astype(np.uint16)
    return levels << np.uint16(16 - bit_depth)


class SimCameraBackend(CameraBackend):
    """`CameraBackend` over a SimCamera: each trigger is rendered at once and delivered."""

    name = 'sim'

    def __init__(self, deliver: Callable[[Frame], None], camera: SimCamera, source: str = ''):
        super().__init__(deliver)
        self.camera = camera
        self.source = source
        self.frames = 0

    @classmethod
    def from_capture(cls, deliver: Callable[[Frame], None], capture_dir, **camera_kwargs) -> 'SimCameraBackend':
        """Load a capture folder (raises CaptureFormatError naming the problem) and wrap it."""
        modelset = load_capture(capture_dir)
        return cls(deliver, SimCamera(modelset, **camera_kwargs), source=str(capture_dir))

    def trigger(self, trigger: Trigger) -> None:
        image = self.camera.capture(trigger.led_intensities, trigger.exposure_us, trigger.gain_db)
        self.frames += 1
        self._deliver(Frame(trigger, image, self.camera.bit_depth,
                            {'sample': self.camera.sample_name, 'label': self.camera.label}))

    def status(self) -> BackendStatus:
        cam = self.camera
        noise = cam.noise if isinstance(cam.noise, str) else 'custom'
        h, w = cam.image_shape
        return BackendStatus(True, f'sample {cam.sample_name} on the stage', {
            'capture_dir': self.source, 'sample': cam.sample_name, 'sample_index': cam.sample_index,
            'samples': len(cam.modelset), 'image_size': f'{w}x{h}', 'bit_depth': cam.bit_depth,
            'noise': noise, 'dimmer': cam.dimmer, 'frames': self.frames})


def frame_moments(mean, variance, max_level: int = 1023) -> tuple[np.ndarray, np.ndarray]:
    """Exact mean and variance of one simulated frame's gray level per pixel.

    A frame is ``round(clip(N(mean, variance), 0, max_level))`` (`SimCamera.capture`), so
    its mean is not the model's near 0 and the maximum, and rounding adds about 1/12 to its
    variance. Uses E[Y] = sum_k P(Y >= k) and E[Y^2] = sum_k (2k - 1) P(Y >= k), k = 1..max,
    with P(Y >= k) = P(X >= k - 1/2). For checking averaged captures against their model.
    """
    from scipy.special import ndtr

    mu = np.asarray(mean, np.float64).ravel()
    sd = np.sqrt(np.maximum(np.asarray(variance, np.float64).ravel(), 1e-12))
    reach = int(math.ceil(9 * float(sd.max()))) + 2
    e1 = np.empty_like(mu)
    e2 = np.empty_like(mu)
    for start in range(0, mu.size, 4096):
        m, s = mu[start:start + 4096], sd[start:start + 4096]
        lo = np.clip(np.floor(m) - reach, 1, max_level)  # below lo: P(Y >= k) = 1
        k = lo[:, None] + np.arange(2 * reach + 2)[None, :]
        inside = k <= max_level
        p = np.where(inside, ndtr((m[:, None] - (k - 0.5)) / s[:, None]), 0.0)
        e1[start:start + 4096] = (lo - 1) + p.sum(axis=1)
        e2[start:start + 4096] = (lo - 1) ** 2 + ((2 * k - 1) * p).sum(axis=1)
    shape = np.shape(mean)
    return e1.reshape(shape), (e2 - e1 ** 2).reshape(shape)
