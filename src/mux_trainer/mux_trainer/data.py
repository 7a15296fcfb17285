"""From a capture (ModelSet) to the arrays the search works on, at the feature resolution."""
from __future__ import annotations

import numpy as np
from lightstage_physics.noise import EXPOSURE_MS_RANGE, NoiseModel, load_noise_file, noise_setting
from lightstage_physics.rig import DEFAULT_DIMMER
from lightstage_physics.scene_models import object_type_of
from lightstage_graph.limits import check_gain_db, check_range
from mux_classifier.features import DEFAULT_EXTRACTOR
from mux_classifier.hog import HogConfig

from .rendering import SearchData

NOISE_SETTINGS = ('sigma1', 'sigma2', 'sigma3', 'none')
NOISE_HELP = ('sigma1|sigma2|sigma3|none, or a noise file written by `lightstage calibrate` '
              '(NOISE.yaml: its model at the gain and exposure it was measured at; '
              'NOISE.yaml@GAIN_DB:EXPOSURE_MS: generalized to that setting, e.g. '
              'noise.yaml@17.5:22.5)')


def resolve_noise(spec) -> tuple[str, NoiseModel | None]:
    """A noise setting -> (its name, the camera's NoiseModel at full resolution or None).

    spec: a preset name (NOISE_SETTINGS), a calibrated noise file (.yaml, written by
    `lightstage calibrate`), a file generalized to another setting ('FILE.yaml@GAIN_DB:
    EXPOSURE_MS', the affine model's gain/exposure rule), or a NoiseModel. ValueError (naming
    the problem) otherwise.
    """
    if isinstance(spec, NoiseModel):
        return 'calibrated', spec
    text = str(spec).strip()
    if text.lower() in NOISE_SETTINGS:
        return text.lower(), noise_setting(text.lower())
    if text.lower().endswith(('.yaml', '.yml')):
        return text, noise_setting(text)
    path, sep, setting = text.rpartition('@')
    if sep and path.lower().endswith(('.yaml', '.yml')):
        gain_db, exposure_ms = _setting_at(text, path, setting)
        return text, load_noise_file(path).at(gain_db, exposure_ms)
    raise ValueError(f'unknown noise setting {text!r}; use {NOISE_HELP}')


def _setting_at(text: str, path: str, setting: str) -> tuple[float, float]:
    """GAIN_DB:EXPOSURE_MS after the @ of a noise spec, each in the camera's range; ValueError
    naming which one is wrong."""
    parts = setting.split(':')
    numbers = []
    for part in parts:
        try:
            numbers.append(float(part))
        except ValueError:
            numbers.append(None)
    if len(parts) != 2 or None in numbers:
        raise ValueError(f'noise {text!r}: after the @ give GAIN_DB:EXPOSURE_MS, two numbers '
                         f'(e.g. {path}@17.5:22.5), not {setting!r}')
    gain_db, exposure_ms = numbers
    try:
        check_gain_db(gain_db, 'the gain (GAIN_DB, before the colon)', nan_is_default=False)
        check_range(exposure_ms, 'the exposure (EXPOSURE_MS, after the colon)',
                    *EXPOSURE_MS_RANGE, 'ms')
    except ValueError as exc:
        raise ValueError(f'noise {text!r}: {exc}') from None
    return gain_db, exposure_ms


def search_data(modelset, noise='sigma3', *, hog_config: HogConfig | None = None,
                dimmer: float = DEFAULT_DIMMER, features: str = DEFAULT_EXTRACTOR) -> SearchData:
    """A ModelSet -> SearchData at the HOG configuration's image size with a noise setting
    (anything `resolve_noise` takes), scored with the feature extractor `features`.

    The models are downscaled (area mean) if they are larger than the feature resolution;
    the noise variance is scaled by the downscale's factor (`ModelSet.noise_scale`), which
    is equivalent to adding the camera noise at full resolution and then downscaling.
    """
    hog_config = HogConfig() if hog_config is None else hog_config
    size = hog_config.image_size
    H, W = modelset.image_shape
    if (H, W) != (size, size):
        if H < size or W < size:
            raise ValueError(f'the capture images are {H} x {W} px, smaller than the '
                             f'{size} px the features need; capture at >= {size} px or pass a '
                             'HogConfig with a smaller image_size')
        modelset = modelset.downscaled(size)
    name, model = resolve_noise(noise)
    a = b = 0.0
    if model is not None:
        a = float(model.sigma_p2 * modelset.noise_scale)
        b = float(model.sigma_r2 * modelset.noise_scale)
    return SearchData.from_models(
        modelset.models, modelset.labels, modelset.pose_index, modelset.class_names,
        dimmer=dimmer, noise_a=a, noise_b=b, max_level=float(modelset.max_level),
        noise_name=name, noise_model=model, hog_config=hog_config, features=features,
        instance=modelset.instance)


def noise_dict(name: str, model: NoiseModel | None) -> dict:
    """The noise setting as stored in an artifact: its name, the camera's coefficients at
    full resolution and the gain / exposure the classifier node asks the stage for (None
    without noise)."""
    if model is None:
        return {'name': str(name), 'sigma_p2': None, 'sigma_r2': None, 'gain_db': None,
                'exposure_ms': None}
    return {'name': str(name), 'sigma_p2': float(model.sigma_p2),
            'sigma_r2': float(model.sigma_r2), 'gain_db': float(model.gain_db),
            'exposure_ms': float(model.exposure_ms)}


def sample_object_types(data: SearchData) -> np.ndarray:
    """Object type of every sample of the data (e.g. "banana" for "banana-fake")."""
    types = np.array([object_type_of(c) for c in data.class_names])
    return types[data.labels]


def class_type_groups(class_names) -> np.ndarray | None:
    """Each class's object type as 0 .. G - 1, in order of first appearance (the head gated
    by type, `mux_classifier.gated_head`), or None where gating would change nothing: one
    type, or one class per type."""
    types = [object_type_of(c) for c in class_names]
    order = list(dict.fromkeys(types))
    if len(order) < 2 or len(order) == len(types):
        return None
    return np.array([order.index(t) for t in types], np.int64)
