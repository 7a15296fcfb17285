"""`lightstage train` and `lightstage eval`: the search and the evaluation on a capture folder.

With --json only the JSON document goes to stdout; progress and logs go to stderr.
"""
from __future__ import annotations

import argparse
import contextlib
import json
import sys
from pathlib import Path

from lightstage_physics.rig import DEFAULT_DIMMER
from lightstage_physics.workers import jobs_type, usable_cores

from .column_count import COUNT_RULES
from .cluster import DASK_SCHEDULER_ENV, DEFAULT_TIMEOUT_S, scheduler_from_env
from .data import NOISE_HELP, resolve_noise
from .greedy import REFINE_TOP
from .holdout import HOLDOUT_BY
from .report import DEFAULT_METHODS, METHODS
from .splits import INNER_GROUPS, describe_inner


def _hog_config(args):
    from mux_classifier.hog import HogConfig
    try:
        return HogConfig(image_size=args.image_size, cell_px=args.cell_px,
                         block_cells=args.block_cells)
    except ValueError as exc:
        raise SystemExit(f'lightstage: bad feature options: {exc}') from None


def _common(p: argparse.ArgumentParser, capture_optional: bool = False) -> None:
    p.add_argument('capture_dir', metavar='CAPTURE_DIR', nargs='?' if capture_optional else None,
                   help='capture folder (holds rig.yaml)'
                        + ('; omit it with --from-results' if capture_optional else ''))
    p.add_argument('--repeats', type=int, default=400,
                   help='random 75/25 inner splits per candidate (default: 400, the paper)')
    p.add_argument('--inner-groups', choices=INNER_GROUPS, default='auto',
                   help='what the inner splits that choose and score every method hold out: '
                        'whole physical samples ("instances": an estimate for objects never '
                        'seen in training), pose indices ("poses", the paper\'s rule: it holds '
                        'only for the objects trained on) or "auto" (default: physical samples '
                        'where the capture has two or more of every class, else poses)')
    p.add_argument('--max-images', type=int, default=8,
                   help='most pattern columns to select (greedy, SNR-optimal: 4 exposures '
                        'each per colour; learned: its exposures, one image per pattern; '
                        'default: 8)')
    p.add_argument('--seed', type=int, default=0, help='seed of splits and noise (default: 0)')
    p.add_argument('--jobs', type=jobs_type, default=usable_cores(),
                   help='joblib workers for candidate evaluation (default: the cores this process '
                        f'may use, {usable_cores()} here; -1 = all of them). The results do not '
                        'depend on it')
    p.add_argument('--dask-scheduler', metavar='ADDRESS', default=scheduler_from_env(),
                   help='evaluate the candidates on this existing Dask cluster (e.g. '
                        'tcp://HOST:8786, as `dask scheduler` prints) instead of --jobs local '
                        f'processes; the same results. Default: ${DASK_SCHEDULER_ENV}, else local')
    p.add_argument('--dask-timeout', type=float, default=DEFAULT_TIMEOUT_S, metavar='SECONDS',
                   help='give up on a Dask scheduler that cannot be reached, or that has no '
                        f'connection or no workers, for this long (default: {DEFAULT_TIMEOUT_S:g})')
    p.add_argument('--count-rule', choices=COUNT_RULES, default='max',
                   help='how many pattern columns a model keeps: the best mean split accuracy '
                        '("max", the paper\'s; default) or the fewest columns within one '
                        'standard error of it ("one_se": steadier where the cue is near the noise)')
    p.add_argument('--json', action='store_true', help='print the results as one JSON document')
    p.add_argument('--quiet', action='store_true', help='no progress on stderr')
    g = p.add_argument_group('features (defaults: the paper\'s HOG, 900 values per image)')
    g.add_argument('--features', default='hog_grid', metavar='NAME' + ('[,NAME]' if capture_optional else ''),
                   help='feature extractor the search scores with and the classifier uses: '
                        'hog_grid (the paper\'s, default), intensity_stats (object reflectance '
                        'statistics: any placement), pooled_hog, pooled_hog_stats, pose_hog '
                        '(docs/SEARCH.md compares them)'
                        + ('; several, comma-separated: every method once per extractor'
                           if capture_optional else ''))
    g.add_argument('--image-size', type=int, default=120)
    g.add_argument('--cell-px', type=int, default=12)
    g.add_argument('--block-cells', type=int, default=10)


def _feature_names(prog: str, value: str, several: bool) -> list[str]:
    from mux_classifier.features import searchable_extractor
    names = [n.strip() for n in value.split(',') if n.strip()]
    if not names or (len(names) > 1 and not several):
        raise SystemExit(f'{prog}: --features takes {"names" if several else "one name"}, '
                         f'got {value!r}')
    for name in names:
        try:
            searchable_extractor(name)
        except ValueError as exc:
            raise SystemExit(f'{prog}: {exc}') from None
    return list(dict.fromkeys(names))


def _positive(args, *names):
    from .training import check_repeats, check_seed
    for name in names:
        if getattr(args, name) < 1:
            raise SystemExit(f'lightstage: --{name.replace("_", "-")} must be >= 1, '
                             f'got {getattr(args, name)}')
    for option, check, value in (('--repeats', check_repeats, args.repeats),
                                 ('--seed', check_seed, args.seed)):
        try:
            check(value)
        except ValueError as exc:
            raise SystemExit(f'lightstage: {option}: {exc}') from None


def _on_cluster(prog: str, args):
    """The Dask cluster of --dask-scheduler for the block (nothing without it); a scheduler
    that cannot be reached or is lost ends the command with a message naming it."""
    from .cluster import ClusterUnavailable, dask_cluster
    if args.dask_timeout <= 0:
        raise SystemExit(f'{prog}: --dask-timeout must be > 0 s, got {args.dask_timeout}')

    @contextlib.contextmanager
    def block():
        try:
            with dask_cluster(args.dask_scheduler, args.dask_timeout):
                yield
        except ClusterUnavailable as exc:
            raise SystemExit(f'{prog}: {exc}') from None
    return block()


def _load(capture_dir: str, hog_config):
    from .training import load_training_set
    try:
        return load_training_set(capture_dir, hog_config.image_size)
    except ValueError as exc:
        hint = ''
        if 'larger size' in str(exc):
            hint = ('; the features need images of at least --image-size px (default 120): '
                    'for a small capture pass e.g. --image-size 24 --cell-px 6 --block-cells 4')
        raise SystemExit(f'lightstage: cannot load capture {capture_dir}: {exc}{hint}') from None


def _learned_arguments(p: argparse.ArgumentParser) -> None:
    from .learned_schedule import DEFAULT_STEPS
    g = p.add_argument_group('learned illumination (--method learned)')
    g.add_argument('--binary', action='store_true',
                   help='on/off LED levels (boards with pwm_bits 0) instead of graded ones '
                        '(pwm_bits 8)')
    g.add_argument('--steps', type=int, default=None,
                   help=f'gradient steps on the LED levels from each start descended (the random '
                        f'one, greedy\'s columns and the best raking split; snapshots scored by the '
                        f'inner splits, the best kept); default: {DEFAULT_STEPS}, the starts '
                        f'alone (docs/LEARNED.md, "Gradient steps on the levels")')


def _learned_options(prog: str, args) -> dict:
    """--binary / --steps for the learned method (refused with another one)."""
    from .learned_schedule import check_steps
    if args.method != 'learned':
        if args.binary or args.steps is not None:
            raise SystemExit(f'{prog}: --binary and --steps apply to --method learned only')
        return {}
    if args.steps is not None:
        try:
            check_steps(args.steps)
        except ValueError as exc:
            raise SystemExit(f'{prog}: --steps: {exc}') from None
    return {'binary': args.binary, 'steps': args.steps}


def _learned_eval_arguments(p: argparse.ArgumentParser) -> None:
    from .learned_schedule import DEFAULT_STEPS, EVAL_EXPOSURES
    g = p.add_argument_group('learned illumination (method learned, not in the default list)')
    g.add_argument('--learned-exposures', default=','.join(map(str, EVAL_EXPOSURES)),
                   metavar='K[,K]', help='exposure counts to train a learned model for, one '
                   'model each (default: %(default)s)')
    g.add_argument('--learned-steps', type=int, default=DEFAULT_STEPS,
                   help='gradient steps of each learned model from each start descended '
                        '(default: %(default)s, the starts alone)')
    g.add_argument('--learned-binary', action='store_true',
                   help='on/off LED levels instead of graded ones')


def _learned_eval_options(args, methods) -> dict | None:
    from .learned_schedule import check_steps
    if 'learned' not in methods:
        return None
    try:
        exposures = sorted({int(k) for k in args.learned_exposures.split(',') if k.strip()})
        check_steps(args.learned_steps)
    except ValueError as exc:
        raise SystemExit(f'lightstage eval: --learned-exposures / --learned-steps: {exc}') from None
    if not exposures or exposures[0] < 1:
        raise SystemExit(f'lightstage eval: --learned-exposures must list counts >= 1, got '
                         f'{args.learned_exposures!r}')
    return {'exposures': exposures, 'steps': args.learned_steps, 'binary': args.learned_binary}


def train_main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog='lightstage train',
        description='Learn illumination patterns and a classifier per image count from a '
                    'capture folder; write the trained artifact (.npz).')
    _common(p)
    p.add_argument('--out', required=True, metavar='ARTIFACT',
                   help='artifact file to write (.npz); an existing artifact is replaced, any '
                        'other existing file only with --force')
    p.add_argument('--force', action='store_true',
                   help='replace --out even if it is an existing file that is not an artifact')
    p.add_argument('--method', choices=('greedy', 'snr_optimal', 'naive', 'learned'),
                   default='greedy',
                   help='greedy (the paper\'s search, default), snr_optimal, naive, or learned '
                        '(LED levels and a classifier trained end to end; --max-images is its '
                        'number of exposures, one image per learned pattern; docs/LEARNED.md)')
    _learned_arguments(p)
    p.add_argument('--mode', choices=('per_colour', 'joint'), default='per_colour',
                   help='greedy only: 8-site patterns per colour (paper) or 32-LED patterns')
    p.add_argument('--noise', default='sigma3', help=f'{NOISE_HELP} (default: sigma3)')
    p.add_argument('--fixed-count', action='store_true',
                   help='greedy: select --max-images columns even when accuracy stops improving')
    p.add_argument('--inner-classifier', choices=('ridge', 'squared_hinge', 'linear_svm'),
                   help='classifier of the split accuracies: ridge (fast screen), '
                        'squared_hinge (the linear SVM solved exactly in kernel form) or '
                        'linear_svm (one LinearSVC per split, slowest; docs/SEARCH.md has the '
                        'timings). Default: ridge screen for greedy, squared_hinge for the '
                        'baselines')
    p.add_argument('--refine-top', type=int, default=REFINE_TOP,
                   help='greedy with the ridge screen: re-score its best N candidates per '
                        f'column with the exact linear SVM, which picks the column (default: '
                        f'{REFINE_TOP}; 0 = the screen picks)')
    p.add_argument('--classifier', choices=('linear_svm', 'ridge'), default='linear_svm',
                   help='classifier stored in the artifact (default: linear_svm, the paper)')
    p.add_argument('--beam-width', type=int, default=1, help='joint mode: beam width')
    args = p.parse_args(argv)
    _positive(args, 'repeats', 'max_images', 'beam_width')
    learned = _learned_options('lightstage train', args)
    if args.refine_top < 0:
        raise SystemExit(f'lightstage: --refine-top must be >= 0, got {args.refine_top}')
    hog_config = _hog_config(args)
    features = _feature_names('lightstage train', args.features, several=False)[0]
    from .training import ArtifactNotWritten, check_artifact_path, train_modelset
    try:  # before the capture is loaded: a run must not end in an unwritable path
        check_artifact_path(args.out, args.force)
    except ValueError as exc:
        raise SystemExit(f'lightstage train: {exc}') from None
    not_written = None
    with _on_cluster('lightstage train', args):
        modelset = _load(args.capture_dir, hog_config)
        try:
            doc = train_modelset(
                modelset, args.out, capture=args.capture_dir, method=args.method, mode=args.mode,
                noise=args.noise, max_images=args.max_images, repeats=args.repeats, seed=args.seed,
                n_jobs=args.jobs, hog_config=hog_config, fixed_count=args.fixed_count,
                inner_classifier=args.inner_classifier, final_classifier=args.classifier,
                beam_width=args.beam_width, refine_top=args.refine_top, progress=not args.quiet,
                features=features, count_rule=args.count_rule, force=args.force,
                inner_groups=args.inner_groups, **learned)
        except ValueError as exc:
            raise SystemExit(f'lightstage train: {exc}') from None
        except ArtifactNotWritten as exc:  # the result is printed all the same
            not_written, doc = exc, exc.summary
    out, seconds = doc['artifact'], doc['train_seconds']
    if args.json:
        print(json.dumps(doc))
    elif not args.quiet or not_written:
        print(f'{"kept" if not_written else "wrote"} {out} ({seconds:.1f} s)')
        print(train_text(doc))
    if not_written:
        print(f'lightstage train: {not_written}', file=sys.stderr)
        return 1
    return 0


def eval_main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog='lightstage eval',
        description='Evaluate naive, naive + BoW, SNR-optimal and greedy illumination on a '
                    'capture folder (Table 1 and accuracy vs image count of the paper), on '
                    'held-out poses rendered with fresh noise.')
    _common(p, capture_optional=True)
    p.add_argument('--noise', default='sigma3',
                   help='comma-separated noise settings, e.g. sigma1,sigma2,sigma3 (default: '
                        'sigma3); the JSON\'s top-level "methods" are those of the first. Each '
                        f'is {NOISE_HELP}')
    p.add_argument('--methods', default=','.join(DEFAULT_METHODS),
                   help=f'comma-separated, from {",".join(METHODS)} (default: '
                        f'{",".join(DEFAULT_METHODS)})')
    p.add_argument('--holdout', type=float, default=0.25,
                   help='fraction of pose indices (or of physical samples, see --holdout-by) '
                        'held out for testing (default: 0.25)')
    p.add_argument('--holdout-by', choices=HOLDOUT_BY, default=HOLDOUT_BY[0],
                   help='hold out pose indices, the same for every class (default, the '
                        'paper\'s rule: a test object is seen in training in other poses), or '
                        'physical samples with all their poses (objects never seen in '
                        'training)')
    p.add_argument('--renders', type=int, default=4,
                   help='noisy renders of each held-out sample (default: 4)')
    p.add_argument('--beam-width', type=int, default=1, help='greedy_joint: beam width')
    p.add_argument('--joint-max-images', type=int,
                   help='greedy_joint: most 32-LED pattern columns, one exposure each (default: '
                        '--max-images; 4 x --max-images matches the per-colour search\'s '
                        'exposures)')
    p.add_argument('--answers', action=argparse.BooleanOptionalAction, default=True,
                   help='calibrate each pattern method as `lightstage train` does and report '
                        'its answers on the held-out samples: the anytime rule against the '
                        'fixed count, calibration error and reliability, accuracy against '
                        'coverage, and object types never trained flagged unknown (default: '
                        'on; --no-answers skips it)')
    _learned_eval_arguments(p)
    p.add_argument('--out', metavar='DIR', help='write results.json, CSVs and PNG plots here')
    p.add_argument('--no-plots', action='store_true', help='with --out: skip the PNG plots')
    p.add_argument('--from-results', metavar='FILE',
                   help='with --out: write the CSVs and plots of an earlier run from its '
                        'results.json (e.g. one kept in the rescue folder), evaluate nothing')
    args = p.parse_args(argv)
    if args.from_results:
        return _outputs_from_results(p, args)
    if not args.capture_dir:
        p.error('give CAPTURE_DIR (or --from-results FILE --out DIR)')
    _positive(args, 'repeats', 'max_images', 'renders', 'beam_width')
    if args.joint_max_images is not None:
        _positive(args, 'joint_max_images')
    noises = [n.strip() for n in args.noise.split(',') if n.strip()]
    if not noises:
        raise SystemExit(f'lightstage eval: no noise setting given; use {NOISE_HELP}')
    try:
        noises = [resolve_noise(n)[0] for n in noises]
    except ValueError as exc:
        raise SystemExit(f'lightstage eval: {exc}') from None
    methods = [m.strip() for m in args.methods.split(',') if m.strip()]
    bad = [m for m in methods if m not in METHODS]
    if not methods or bad:
        raise SystemExit(f'lightstage eval: unknown method(s) {bad}; use {", ".join(METHODS)}')
    learned_options = _learned_eval_options(args, methods)
    if not 0 < args.holdout < 1:
        raise SystemExit(f'lightstage eval: --holdout must be in (0, 1), got {args.holdout}')
    hog_config = _hog_config(args)
    features = _feature_names('lightstage eval', args.features, several=True)
    from .report import check_output_dir, json_ready, keep_outputs, run_evaluation, write_outputs
    if args.out:
        try:  # before the evaluation: its results must not end in an unwritable folder
            check_output_dir(args.out)
        except ValueError as exc:
            raise SystemExit(f'lightstage eval: {exc}') from None
    with _on_cluster('lightstage eval', args):
        modelset = _load(args.capture_dir, hog_config)
        try:
            results = run_evaluation(modelset, noises, methods, features=features,
                                     n_repeats=args.repeats,
                                     max_images=args.max_images, holdout_fraction=args.holdout,
                                     n_renders=args.renders, seed=args.seed, n_jobs=args.jobs,
                                     hog_config=hog_config, beam_width=args.beam_width,
                                     joint_max_images=args.joint_max_images, quiet=args.quiet,
                                     progress=not args.quiet, holdout_by=args.holdout_by,
                                     count_rule=args.count_rule, inner_groups=args.inner_groups,
                                     learned_options=learned_options, answers=args.answers)
        except ValueError as exc:
            raise SystemExit(f'lightstage eval: {exc}') from None
    results['capture'] = str(Path(args.capture_dir).resolve())
    results['settings'] = {'repeats': args.repeats, 'max_images': args.max_images,
                           'joint_max_images': args.joint_max_images or args.max_images,
                           'holdout': args.holdout, 'holdout_by': args.holdout_by,
                           'count_rule': args.count_rule, 'inner_groups': args.inner_groups,
                           'renders': args.renders, 'seed': args.seed, 'answers': args.answers,
                           'methods': methods, 'noise': noises, 'features': features,
                           'dimmer': DEFAULT_DIMMER}
    doc = json_ready(results)
    if args.json:
        print(json.dumps(doc), flush=True)
    else:
        for feature, f in doc['by_features'].items():
            for noise, r in f['by_noise'].items():
                held = (f'test samples {r["test_instances"]} of every class, all poses'
                        if r.get('test_instances') is not None
                        else f'test poses {r["test_poses"]}')
                print(f'noise {noise}: held-out accuracy ({held})')
                _print_methods(r['methods'])
        sys.stdout.flush()
    if args.out:
        try:
            written = write_outputs(results, args.out, plots=not args.no_plots)
        except OSError as exc:  # the folder changed during the run: keep the results
            print(f'lightstage eval: {keep_outputs(doc, args.out, exc)}', file=sys.stderr)
            return 1
        for path in written:
            if not args.quiet:
                print(f'wrote {path}', file=sys.stderr)
    return 0


def _print_methods(methods: dict) -> None:
    for name, m in methods.items():
        print(f'  {method_row(name, m)}')
        if m.get('answers'):
            for line in answers_lines(m['answers']):
                print(f'      {line}')


def answers_lines(a: dict) -> list[str]:
    """A method's calibrated answers on the held-out samples, in words (`report.answers_summary`)."""
    accepted = ('none reached it' if a.get('accepted_accuracy') is None else
                f'{100 * a["accepted_share"]:.0f} % accepted, right {100 * a["accepted_accuracy"]:.1f} %')
    lines = [f'anytime (stop at {100 * a["stop_probability"]:.0f} %): '
             f'{100 * a["anytime_accuracy"]:.1f} % at a mean of {a["anytime_mean_images"]:.1f} '
             f'of {a["budget_images"]} exposures, against {100 * a["full_accuracy"]:.1f} % at '
             f'{a["budget_images"]}; {accepted}',
             f'calibration error {a["full_calibration_error"]:.3f} (every exposure), '
             f'{a["anytime_calibration_error"]:.3f} (anytime), on {a["answers"]} answers '
             f'(a calibrated classifier would measure about '
             f'{a["full_calibration_error_floor"]:.3f} on as many)']
    curve = {round(100 * c['coverage']): c['accuracy'] for c in a.get('coverage_curve', [])}
    if curve:
        lines.append('accuracy of the surest answers: ' + ', '.join(
            f'{100 * curve[k]:.1f} % of {k} %' for k in (50, 80, 100) if k in curve))
    u = a.get('unknown')
    if u:
        worst = min(u['by_left_out_type'].items(),
                    key=lambda kv: -1 if kv[1]['flagged'] is None else kv[1]['flagged'])
        lines.append(f'unknown objects (each type left out of the novelty model in turn): '
                     f'{100 * u["flagged"]:.1f} % flagged (worst: {worst[0]} '
                     f'{100 * worst[1]["flagged"]:.0f} %), false alarms on trained types '
                     f'{100 * u["false_alarms"]:.1f} % (stated {100 * u["false_alarm_rate"]:g} %)')
    return lines


def _count(n: int, word: str) -> str:
    return f'{n} {word}' + ('' if n == 1 else 's')


def exposures_text(n_columns: int, per_column: int = 1) -> str:
    """A size in exposures (images taken), with its pattern columns where one column takes
    several exposures (per colour: R, G, B and NIR)."""
    n_exp = int(n_columns) * int(per_column)
    if int(per_column) == 1:
        return _count(n_exp, 'exposure')
    return (f'{_count(n_exp, "exposure")} ({_count(int(n_columns), "pattern column")} x '
            f'{int(per_column)})')


def features_text(m: dict) -> str:
    """The features a result's classifier uses, in words."""
    name = str(m.get('features', '?'))
    if name == 'bow_dense_hog':
        return 'bag of words on dense HOG'
    return name + (' + cross-image statistics' if m.get('cross_image_stats') else '')


def method_row(name: str, m: dict) -> str:
    """One method's line of `lightstage eval`: held-out accuracy, exposures (and pattern
    columns), its own features, per object type."""
    types = ', '.join(f'{t} {100 * a:.1f}' for t, a in m['accuracy_by_type'].items())
    extra = ''
    if m.get('mode') == 'learned':
        extra = f', {m.get("levels", "graded")} levels'
    inner = m.get('inner_estimate')
    if inner:
        extra += (f', inner estimate {100 * inner["accuracy"]:.1f} % by '
                  f'{inner["held_out"]}')
    size = exposures_text(m['n_images'], m.get('images_per_pattern', 1))
    return (f'{name:<13} {100 * m["accuracy"]:6.2f} %  at {size}, features '
            f'{features_text(m)}{extra}  [{types}]')


def train_text(doc: dict) -> str:
    """What `lightstage train` kept, in plain words: the method, its exposures and pattern
    columns, its features, the inner accuracy by exposure count, the inner estimate and how
    it was made; for the learned method also graded or on/off and which candidate it kept."""
    lines = []
    per = int(doc.get('images_per_pattern', 1))
    if doc['method'] == 'learned':
        from .learned_method import describe_choice
        lines.append(f'learned: {exposures_text(doc["best_n_images"])}, one learned pattern '
                     f'each; features '
                     f'{features_text(doc)}; head '
                     + ('gated by object type' if doc.get('head') == 'by_type' else 'one linear SVM'))
        asked = 'on/off' if doc.get('binary') else 'graded'
        kept = doc.get('levels', asked)
        note = ('; graded levels were allowed, the kept candidate has none'
                if kept == 'on/off' and asked == 'graded' else '')
        lines.append(f'LED levels: {kept} (' + ('every LED fully on or off' if kept == 'on/off'
                                               else 'LEDs dimmed between off and full') + f'{note})')
        lines.append(f'kept {describe_choice(doc["chosen"], doc.get("max_steps", 0))}')
    else:
        columns = len(doc['patterns'][0]) if doc['patterns'] else 0
        colours = ' (R, G, B, NIR)' if per == 4 else ''
        lines.append(f'{doc["method"]}: {_count(columns, "pattern column")} of '
                     f'{doc["mode"].replace("_", "-")} patterns, {_count(per, "exposure")} per '
                     f'column{colours}; features {features_text(doc)}')
        lines.append(f'best: the first {exposures_text(doc["best_n_images"], per)}, by the '
                     'inner accuracy (the artifact holds a classifier for each column count)')
    acc = ', '.join(f'{_count(int(k) * per, "exposure")} {100 * v:.1f} %'
                    for k, v in sorted(doc['accuracy_by_images'].items(), key=lambda kv: int(kv[0])))
    lines.append(f'inner accuracy by exposures: {acc}')
    inner = doc.get('inner_estimate')
    if inner:
        lines.append(describe_inner(inner, inner['accuracy']))
    confidence = doc.get('confidence')
    if confidence:
        lines.append(confidence_text(confidence))
    elif doc['method'] == 'learned':
        lines.append('uncalibrated: scores only, every exposure taken')
    return '\n'.join(lines)


def confidence_text(confidence: dict) -> str:
    """The calibration and the anytime rule a training fitted, in plain words."""
    e = confidence.get('estimate', {})
    target = 100 * float(confidence['stop_probability'])
    counts = confidence.get('temperatures', {})
    if len(counts) == 1:  # one image count: nothing to stop early, the target accepts
        text = (f'calibrated probabilities; every exposure taken, the answer accepted at '
                f'{target:.3g} % (else "not sure")')
        if e:
            text += (f'; on {e.get("answers", 0)} held-out answers ({e.get("held_out", "?")}) '
                     f'{100 * e["full_accuracy"]:.1f} % right; calibration error '
                     f'{e["calibration_error_full"]:.3f}')
        return text
    text = (f'calibrated probabilities; anytime: stops after the first pattern column whose top '
            f'class reaches {target:.3g} %')
    if e:
        text += (f'; on {e.get("answers", 0)} held-out answers ({e.get("held_out", "?")}) '
                 f'{100 * e["anytime_accuracy"]:.1f} % at a mean of '
                 f'{e["anytime_mean_images"]:.1f} exposures, against '
                 f'{100 * e["full_accuracy"]:.1f} % at {e["full_images"]}; calibration error '
                 f'{e["calibration_error_anytime"]:.3f}')
    return text


def _outputs_from_results(p: argparse.ArgumentParser, args) -> int:
    """`eval --from-results FILE --out DIR`: the outputs of a finished run, no evaluation."""
    from .report import check_output_dir, write_outputs
    if not args.out or args.capture_dir:
        p.error('--from-results FILE takes --out DIR and no CAPTURE_DIR')
    try:
        doc = json.loads(Path(args.from_results).read_text())
    except (OSError, ValueError) as exc:
        raise SystemExit(f'lightstage eval: cannot read {args.from_results} as JSON '
                         f'({getattr(exc, "strerror", None) or exc}); give the results.json '
                         'named in the message of the run') from None
    try:
        check_output_dir(args.out)
        written = write_outputs(doc, args.out, plots=not args.no_plots)
    except (OSError, ValueError) as exc:
        raise SystemExit(f'lightstage eval: {exc}') from None
    except (KeyError, TypeError, AttributeError) as exc:  # JSON, but not an eval's results
        raise SystemExit(f'lightstage eval: {args.from_results} is not a results.json of '
                         f'lightstage eval ({type(exc).__name__}: {exc}); give one it wrote') \
            from None
    for path in written:
        if not args.quiet:
            print(f'wrote {path}', file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(train_main())
