"""One training run: capture folder in, trained-classifier artifact out.

Shared by `lightstage train` (cli.py) and the trainer node's Train action, so that both
build the same estimator from the same options and write the same artifact.
"""
from __future__ import annotations

import os
import time
from pathlib import Path

from lightstage_physics.workers import check_jobs

from .cluster import DEFAULT_TIMEOUT_S, dask_cluster
from .data import resolve_noise

METHODS = ('greedy', 'snr_optimal', 'naive', 'learned')
MODES = ('per_colour', 'joint')


# Random splits per candidate: the paper's 400 take ~3 min for the default search on 2 cores
# and the time grows in proportion; far beyond MAX_REPEATS a run would take days.
PAPER_REPEATS = 400
MAX_REPEATS = 10_000
MAX_SEED = 2**32 - 1  # numpy's seeds


def check_repeats(repeats: int) -> None:
    """ValueError for a split count out of 1 .. MAX_REPEATS, with what it would cost."""
    if not 1 <= repeats <= MAX_REPEATS:
        cost = (f'; the search time grows in proportion: {repeats} would take about '
                f'{repeats / PAPER_REPEATS:.3g} x the time of the paper\'s {PAPER_REPEATS}'
                if repeats > MAX_REPEATS else '')
        raise ValueError(f'repeats (random splits per candidate) must be 1 .. {MAX_REPEATS}, got '
                         f'{repeats}{cost}')


def check_seed(seed: int) -> None:
    if not 0 <= seed <= MAX_SEED:
        raise ValueError(f'seed must be 0 .. {MAX_SEED} (a numpy seed), got {seed}')


def check_options(method: str, mode: str, noise: str, max_images: int, repeats: int,
                  seed: int = 0, inner_groups: str = 'auto') -> None:
    """Raise ValueError naming the first bad option and the allowed values."""
    from .splits import check_inner_groups
    if method not in METHODS:
        raise ValueError(f'unknown method {method!r}; use one of {", ".join(METHODS)}')
    if mode not in MODES:
        raise ValueError(f'unknown mode {mode!r}; use one of {", ".join(MODES)}')
    resolve_noise(noise)  # ValueError naming the problem (unknown preset, bad noise file)
    if max_images < 1:
        raise ValueError(f'max_images must be >= 1, got {max_images}')
    check_repeats(repeats)
    check_seed(seed)
    check_inner_groups(inner_groups)


class ArtifactNotWritten(OSError):
    """A finished training whose artifact could not be written where asked. `summary` is the
    run's summary ('artifact': where it was kept instead, None if nowhere); the message says
    what to do."""

    def __init__(self, message: str, summary: dict):
        super().__init__(message)
        self.summary = summary


def check_artifact_path(out_path, force: bool = False) -> Path:
    """Refuse, before any work, an artifact path that cannot take the file: a folder, a path
    under a regular file, a folder this user cannot create files in (checked by creating
    one), and an existing file that is not a trained artifact (a capture's rig.yaml, any user
    file) unless `force`; an artifact is replaced (retraining). Raises ValueError naming the
    path and what to do."""
    from lightstage_physics.errors import DestinationError
    from lightstage_physics.output_files import check_output_file
    try:
        path = check_output_file(out_path, overwrite=True)
    except DestinationError as exc:
        raise ValueError(f'cannot write the artifact {out_path}: {exc}') from None
    if not force and (path.exists() or path.is_symlink()):
        from mux_classifier.artifact import ArtifactError, TrainedArtifact
        try:
            TrainedArtifact.load(path)
        except ArtifactError as exc:
            raise ValueError(f'{out_path} exists and is not a trained artifact ({exc}); '
                             'training would replace it: give another --out, or --force to '
                             'replace it all the same') from None
    return path


def _save_artifact(artifact, out: Path, summary: dict) -> None:
    """Save to `out`; if that fails after all, keep it in a rescue folder and raise
    ArtifactNotWritten saying where (the training is not lost)."""
    from lightstage_physics.output_files import save_in_rescue_dir
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        artifact.save(out)
        return
    except OSError as exc:
        error = f'could not write the artifact {out} ({exc.strerror or exc})'
    name = f'{out.stem}.{time.strftime("%Y%m%d-%H%M%S")}.{os.getpid()}{out.suffix or ".npz"}'
    try:
        kept = save_in_rescue_dir(name, artifact.save)
    except OSError as exc:
        summary['artifact'] = None
        raise ArtifactNotWritten(f'{error}, nor in a rescue folder ({exc}); the trained '
                                 'artifact is lost: free space or set LIGHTSTAGE_RESCUE_DIR '
                                 'to a writable folder, then train again', summary) from None
    summary['artifact'] = str(kept)
    raise ArtifactNotWritten(f'{error}; the trained artifact is kept in {kept}: move it where '
                             f'you want it (mv {kept} {out}); no need to train again', summary)


def check_features(features: str) -> None:
    """A feature extractor the search and the classifier can use, or ValueError listing them."""
    from mux_classifier.features import searchable_extractor
    searchable_extractor(features)


def build_model(method='greedy', mode='per_colour', noise='sigma3', max_images=8, repeats=400,
                seed=0, n_jobs=1, hog_config=None, fixed_count=False, inner_classifier=None,
                final_classifier='linear_svm', beam_width=1, progress=False, callback=None,
                refine_top=None, features='hog_grid', count_rule='max', inner_groups='auto'):
    """The unfitted estimator for these options (greedy search or a baseline).

    inner_groups: what the inner splits hold out ('auto': physical samples where the capture
    has two or more of every class, else poses; `search_params.SplitScoring`).
    inner_classifier: the classifier of the split accuracies; None = the method's default
    (greedy: the ridge screen with `refine_top` candidates re-scored by the exact SVM;
    baselines, which score one matrix per image count: the exact SVM). refine_top: greedy
    only; None = `search_params.REFINE_TOP`. features: the feature extractor the search scores
    with and the classifier uses (`mux_classifier.features`; "hog_grid" is the paper's).
    """
    from .baselines import NaiveClassifier, SnrOptimalClassifier
    from .greedy import GreedyPatternSelector
    from .search_params import (Execution, FinalClassifier, Refinement, Rendering,
                                SplitScoring)

    check_options(method, mode, noise, max_images, repeats, inner_groups=inner_groups)
    check_jobs(n_jobs)
    check_features(features)
    common = dict(scoring=SplitScoring(n_repeats=repeats, classifier=inner_classifier,
                                       inner_groups=inner_groups),
                  rendering=Rendering(noise=noise, hog_config=hog_config, features=features),
                  final_classifier=FinalClassifier(estimator=final_classifier), seed=seed,
                  execution=Execution(n_jobs=n_jobs, progress=progress), count_rule=count_rule)
    if method == 'greedy':
        return GreedyPatternSelector(mode=mode, max_patterns=max_images,
                                     n_patterns=max_images if fixed_count else None,
                                     beam_width=beam_width, callback=callback,
                                     refinement=Refinement() if refine_top is None
                                     else Refinement(top=refine_top), **common)
    if method == 'snr_optimal':
        return SnrOptimalClassifier(n_images=max_images, **common)
    return NaiveClassifier(**common)


def load_training_set(capture_dir, image_size: int = 120):
    """The capture folder's models, downscaled to the classifier's image size; every class
    must have the same number of poses (the pose splits need it)."""
    from lightstage_physics.capture_format import check_equal_poses, load_capture

    path = Path(capture_dir)
    if not path.is_dir():
        raise ValueError(f'{capture_dir}: no such capture folder (write one with '
                         '`lightstage synth OUT_DIR`)')
    modelset = load_capture(path, downscale_to=image_size)
    check_equal_poses(modelset, str(path))
    return modelset


def train_from_capture(capture_dir, out_path, *, image_size: int = 120, dask_scheduler: str = '',
                       dask_timeout_s: float = DEFAULT_TIMEOUT_S, **options) -> dict:
    """Load a capture folder and `train_modelset` on it (options are checked before the load).

    dask_scheduler: the address of an existing Dask scheduler to search on ('' = locally);
    cannot reach it / lost it -> `cluster.ClusterUnavailable` (a ConnectionError) naming it.
    """
    hog_config = options.get('hog_config')
    if hog_config is not None:
        image_size = hog_config.image_size
    check_options(options.get('method', 'greedy'), options.get('mode', 'per_colour'),
                  options.get('noise', 'sigma3'), options.get('max_images', 8),
                  options.get('repeats', 400), options.get('seed', 0),
                  options.get('inner_groups', 'auto'))
    check_jobs(options.get('n_jobs', 1))
    check_features(options.get('features', 'hog_grid'))
    check_artifact_path(out_path)
    with dask_cluster(dask_scheduler, dask_timeout_s):  # connect first: fail before the load
        modelset = load_training_set(capture_dir, image_size)
        return train_modelset(modelset, out_path, capture=capture_dir, **options)


def train_modelset(modelset, out_path, *, capture=None, force: bool = False,
                   calibrate: bool = True, **options) -> dict:
    """Fit `build_model(**options)` on a ModelSet and save its artifact to `out_path`.

    Returns a JSON-ready summary: method, mode, noise, artifact path, class names, patterns,
    images per pattern, split accuracy by column count, best column count, seconds. The
    artifact path is checked first; an artifact that cannot be written at the end after all
    is kept in a rescue folder (ArtifactNotWritten, an OSError, says where). `force`: replace
    an existing file that is not an artifact. `calibrate`: fit calibrated probabilities and the
    anytime stop rule on held-out inner answers (`calibration`), and the unknown-object models
    on held-out physical samples (`novelty_fit`), for every method.
    """
    out = check_artifact_path(out_path, force)
    if options.get('method') == 'learned':
        return _train_learned(modelset, out, capture, calibrate=calibrate, **options)
    model = build_model(**options)
    t0 = time.perf_counter()
    model.fit(modelset)
    seconds = time.perf_counter() - t0
    provenance = {'train_seconds': seconds}
    if capture is not None:
        provenance['capture'] = str(Path(capture).resolve())
    artifact = model.to_artifact(provenance=provenance)
    confidence = None
    if calibrate:
        import dataclasses

        from .calibration import calibrate_pattern_model
        from .novelty_fit import fit_pattern_novelty
        t1 = time.perf_counter()
        confidence = calibrate_pattern_model(model)
        artifact = dataclasses.replace(artifact, confidence=confidence,
                                       novelty=fit_pattern_novelty(model))
        seconds += time.perf_counter() - t1
    summary = {
        'method': options.get('method', 'greedy'), 'mode': model.mode,
        'noise': options.get('noise', 'sigma3'), 'features': model.rendering.features,
        'artifact': str(out),
        'class_names': list(model.class_names_),
        'patterns': model.patterns_.astype(int).tolist(),
        'images_per_pattern': int(model.images_per_pattern),
        'accuracy_by_images': {str(k): float(v) for k, v in model.accuracy_by_images_.items()},
        'best_n_images': int(model.best_n_patterns_),
        'n_exposures': int(model.best_n_patterns_ * model.images_per_pattern),
        'inner_estimate': model.inner_estimate_,
        'confidence': None if confidence is None else confidence.to_dict(),
        'novelty': _novelty_summary(artifact),
        'train_seconds': seconds,
    }
    if hasattr(model, 'improved_'):
        summary['improved'] = [bool(v) for v in model.improved_]
    _save_artifact(artifact, out, summary)
    return summary


def _novelty_summary(artifact) -> dict | None:
    """The unknown-object models of an artifact as the training summary gives them."""
    return {str(k): {'false_alarm_rate': m.false_alarm_rate_,
                     'held_out_false_alarm': m.held_out_false_alarm_}
            for k, m in (artifact.novelty or {}).items()} or None


def _train_learned(modelset, out: Path, capture, *, noise='sigma3', max_images=8, seed=0,
                   repeats=400, hog_config=None, progress=False, binary=False, steps=None,
                   callback=None, inner_groups='auto', calibrate=True,
                   **_search_options) -> dict:
    """`train_modelset` for method 'learned' (`learned_method`): ``max_images`` exposures,
    one learned pattern each, graded or on/off (``binary``), at most ``steps`` steps,
    candidates scored on ``repeats`` inner splits (as the search's, by physical sample or by
    pose as ``inner_groups`` says). The search's other
    options (mode, features, n_jobs, ...) do not apply: a learned model classifies with its
    own statistics (intensity_stats). Its progress goes to stderr."""
    import contextlib
    import sys

    from .learned_method import build_learned, learned_artifact, level_kind, pattern_levels
    model = build_learned(max_images, binary=binary, steps=steps, noise=noise,
                          hog_config=hog_config, seed=seed, progress=progress, callback=callback,
                          n_repeats=int(repeats), inner_groups=inner_groups)
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(sys.stderr):  # stdout: only the result (--json)
        model.fit(modelset)
    seconds = time.perf_counter() - t0
    provenance = {'train_seconds': seconds}
    if capture is not None:
        provenance['capture'] = str(Path(capture).resolve())
    artifact = learned_artifact(model, provenance)
    if calibrate:
        import dataclasses

        from .calibration import calibrate_learned_model
        from .data import search_data
        from .novelty_fit import fit_learned_novelty
        t1 = time.perf_counter()
        data = search_data(modelset, noise, hog_config=hog_config)
        artifact = dataclasses.replace(artifact, confidence=calibrate_learned_model(model),
                                       novelty=fit_learned_novelty(model, data))
        seconds += time.perf_counter() - t1
    summary = {
        'method': 'learned', 'mode': artifact.mode, 'binary': bool(binary),
        'noise': noise if isinstance(noise, str) else artifact.noise['name'],
        'features': artifact.features,
        # beside each image's statistics: the cross-image relief statistics (ratio_stats)
        'cross_image_stats': bool(model.model_.ratio_offset),
        'head': artifact.provenance['head'],
        'chosen': str(model.chosen_),
        'artifact': str(out),
        'class_names': list(artifact.class_names),
        'patterns': pattern_levels(model.patterns_),
        # what the kept patterns are: 'graded' or 'on/off' (a graded search may keep an
        # on/off start)
        'levels': level_kind(model.patterns_),
        'images_per_pattern': 1,
        'accuracy_by_images': {str(k): float(v) for k, v in model.accuracy_by_images_.items()},
        'best_n_images': int(model.best_n_patterns_),
        'n_exposures': int(model.best_n_patterns_),
        'inner_estimate': model.inner_estimate_,
        'best_step': int(model.best_step_), 'max_steps': int(model.descent.max_steps),
        'confidence': None if artifact.confidence is None else artifact.confidence.to_dict(),
        'novelty': _novelty_summary(artifact),
        'train_seconds': seconds,
    }
    _save_artifact(artifact, out, summary)
    return summary
