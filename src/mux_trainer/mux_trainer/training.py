"""One training run: capture folder in, trained-classifier artifact out.

Shared by `lightstage train` (cli.py) and the trainer node's Train action, so that both
build the same estimator from the same options and write the same artifact.
"""
from __future__ import annotations

import time
from pathlib import Path

from .data import resolve_noise

METHODS = ('greedy', 'snr_optimal', 'naive')
MODES = ('per_colour', 'joint')


def check_options(method: str, mode: str, noise: str, max_images: int, repeats: int) -> None:
    """Raise ValueError naming the first bad option and the allowed values."""
    if method not in METHODS:
        raise ValueError(f'unknown method {method!r}; use one of {", ".join(METHODS)}')
    if mode not in MODES:
        raise ValueError(f'unknown mode {mode!r}; use one of {", ".join(MODES)}')
    resolve_noise(noise)  # ValueError naming the problem (unknown preset, bad noise file)
    if max_images < 1 or repeats < 1:
        raise ValueError(f'max_images and repeats must be >= 1, got {max_images} and {repeats}')


def build_model(method='greedy', mode='per_colour', noise='sigma3', max_images=8, repeats=400,
                seed=0, n_jobs=1, hog_config=None, fixed_count=False, inner_classifier=None,
                final_classifier='linear_svm', beam_width=1, progress=False, callback=None,
                refine_top=None):
    """The unfitted estimator for these options (greedy search or a baseline).

    inner_classifier: the classifier of the split accuracies; None = the method's default
    (greedy: the ridge screen with `refine_top` candidates re-scored by the exact SVM;
    baselines, which score one matrix per image count: the exact SVM). refine_top: greedy
    only; None = `greedy.REFINE_TOP`.
    """
    from .baselines import NaiveClassifier, SnrOptimalClassifier
    from .greedy import REFINE_TOP, GreedyPatternSelector

    check_options(method, mode, noise, max_images, repeats)
    common = dict(n_repeats=repeats, seed=seed, n_jobs=n_jobs, noise=noise, hog_config=hog_config,
                  final_classifier=final_classifier)
    if method == 'greedy':
        return GreedyPatternSelector(mode=mode, max_patterns=max_images,
                                     n_patterns=max_images if fixed_count else None,
                                     beam_width=beam_width, progress=progress,
                                     callback=callback, inner_classifier=inner_classifier or 'ridge',
                                     refine_top=REFINE_TOP if refine_top is None else refine_top,
                                     **common)
    common['inner_classifier'] = inner_classifier or 'squared_hinge'
    if method == 'snr_optimal':
        return SnrOptimalClassifier(n_images=max_images, **common)
    return NaiveClassifier(**common)


def load_training_set(capture_dir, image_size: int = 120):
    """The capture folder's models, downscaled to the classifier's image size."""
    from lightstage_camera.capture_format import load_capture

    path = Path(capture_dir)
    if not path.is_dir():
        raise ValueError(f'{capture_dir}: no such capture folder (write one with '
                         '`lightstage synth OUT_DIR`)')
    return load_capture(path, downscale_to=image_size)


def train_from_capture(capture_dir, out_path, *, image_size: int = 120, **options) -> dict:
    """Load a capture folder and `train_modelset` on it (options are checked before the load)."""
    hog_config = options.get('hog_config')
    if hog_config is not None:
        image_size = hog_config.image_size
    check_options(options.get('method', 'greedy'), options.get('mode', 'per_colour'),
                  options.get('noise', 'sigma3'), options.get('max_images', 8),
                  options.get('repeats', 400))
    modelset = load_training_set(capture_dir, image_size)
    return train_modelset(modelset, out_path, capture=capture_dir, **options)


def train_modelset(modelset, out_path, *, capture=None, **options) -> dict:
    """Fit `build_model(**options)` on a ModelSet and save its artifact to `out_path`.

    Returns a JSON-ready summary: method, mode, noise, artifact path, class names, patterns,
    images per pattern, split accuracy by column count, best column count, seconds.
    """
    model = build_model(**options)
    t0 = time.perf_counter()
    model.fit(modelset)
    seconds = time.perf_counter() - t0
    provenance = {'train_seconds': seconds}
    if capture is not None:
        provenance['capture'] = str(Path(capture).resolve())
    artifact = model.to_artifact(provenance=provenance)
    out = Path(out_path)
    out.parent.mkdir(parents=True, exist_ok=True)
    artifact.save(out)
    summary = {
        'method': options.get('method', 'greedy'), 'mode': model.mode,
        'noise': options.get('noise', 'sigma3'), 'artifact': str(out),
        'class_names': list(model.class_names_),
        'patterns': model.patterns_.astype(int).tolist(),
        'images_per_pattern': int(model.images_per_pattern),
        'accuracy_by_images': {str(k): float(v) for k, v in model.accuracy_by_images_.items()},
        'best_n_images': int(model.best_n_patterns_),
        'train_seconds': seconds,
    }
    if hasattr(model, 'improved_'):
        summary['improved'] = [bool(v) for v in model.improved_]
    return summary
