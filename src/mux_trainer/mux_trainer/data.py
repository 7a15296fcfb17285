"""From a capture (ModelSet) to the arrays the search works on, at the feature resolution."""
from __future__ import annotations

import numpy as np
from lightstage_camera.noise import preset
from mux_classifier.hog import HogConfig

from .rendering import DEFAULT_DIMMER, SearchData

NOISE_SETTINGS = ('sigma1', 'sigma2', 'sigma3', 'none')


def object_type_of(class_name: str) -> str:
    """"banana-fake" -> "banana" (the capture format's label convention)."""
    return str(class_name).split('-', 1)[0]


def search_data(modelset, noise: str = 'sigma3', *, hog_config: HogConfig | None = None,
                dimmer: float = DEFAULT_DIMMER) -> SearchData:
    """A ModelSet -> SearchData at the HOG configuration's image size with a noise setting.

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
    model = preset(noise)
    a = b = 0.0
    if model is not None:
        a = float(model.sigma_p2 * modelset.noise_scale)
        b = float(model.sigma_r2 * modelset.noise_scale)
    return SearchData.from_models(
        modelset.models, modelset.labels, modelset.pose_index, modelset.class_names,
        dimmer=dimmer, noise_a=a, noise_b=b, max_level=float(modelset.max_level),
        noise_name=str(noise).lower(), hog_config=hog_config)


def noise_dict(noise: str) -> dict:
    """The noise setting as stored in an artifact (name and coefficients; None if unknown)."""
    name = str(noise).lower()
    model = preset(name) if name in NOISE_SETTINGS else None
    if model is None:
        if name != 'none':
            return {'name': name, 'sigma_p2': None, 'sigma_r2': None, 'gain_db': None,
                    'exposure_ms': None}
        return {'name': 'none', 'sigma_p2': None, 'sigma_r2': None, 'gain_db': None,
                'exposure_ms': None}
    return {'name': str(noise).lower(), 'sigma_p2': model.sigma_p2, 'sigma_r2': model.sigma_r2,
            'gain_db': model.gain_db, 'exposure_ms': model.exposure_ms}


def sample_object_types(data: SearchData) -> np.ndarray:
    """Object type of every sample of the data (e.g. "banana" for "banana-fake")."""
    types = np.array([object_type_of(c) for c in data.class_names])
    return types[data.labels]
