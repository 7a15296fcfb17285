"""`lightstage demo`: the whole method on the bundled simulated light stage, no hardware.

1. Synthesise a capture folder (relightable models of 5 fruit types x real/fake).
2. Train on the models of some physical samples per class: the greedy illumination
   search (the paper's method), learned illumination (LED levels, graded or on/off, chosen
   with the classifier by its inner splits, with fewer splits; docs/LEARNED.md) and the
   naive all-LEDs-on baseline, at noise setting Sigma3.
3. Bring up the graph (driver on the simulated firmware, simulated camera, classifier) as
   separate processes, with the recorder writing everything the graph says to the bag
   `OUT/stage_session` (replacing the previous demo's), put each held-out sample -- a physical
   sample never seen in training, the paper's captured-imagery experiment -- on the stage,
   and classify it through `/lightstage/classify`, with the greedy patterns, the naive one
   and the learned ones (the simulated firmware has graded levels, pwm_bits 8).
4. Print accuracy, images used, timings and the "not sure" and "unknown" answers per
   method; write them to `OUT/demo_results.json`;
   write `OUT/stage_params.yaml`, the demo's stage for `lightstage up`; print the commands
   that replay the bag into a classifier that only observes (`classify_observed`), which
   gives the greedy calls' labels again.

Steps 1 and 2 are cached in OUT (delete it or pass --fresh to redo them).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from pathlib import Path

from lightstage_bringup.launcher import DEFAULT_NODES, RECORDER
from lightstage_physics.workers import jobs_type
from lightstage_graph.names import (APPLY_PATTERNS_SERVICE, CAMERA_NODE, CLASSIFIER_NODE,
                                    CLASSIFY_SERVICE, IMAGE_TOPIC, ILLUMINATION_TOPIC,
                                    RESULT_TOPIC, resolved, service_event_topic)
from lightstage_graph.ros_env import apply_ros_environment, ros_environment
from mux_classifier.confidence import UNKNOWN, UNSURE

NOISE = 'sigma3'
BAG = 'stage_session'  # the bag of the stage session, in OUT
# what the recorder must have subscribed to before the first call, so that no call is cut
RECORDED = (ILLUMINATION_TOPIC, resolved(IMAGE_TOPIC), RESULT_TOPIC, service_event_topic(CLASSIFY_SERVICE),
            service_event_topic(APPLY_PATTERNS_SERVICE))


def _say(text: str) -> None:
    print(f'[demo] {text}', flush=True)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog='lightstage demo', description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('--out', default='out/demo', help='working folder (default: out/demo)')
    p.add_argument('--size', type=int, default=None,
                   help='synthetic image size in px (default: the generator\'s)')
    p.add_argument('--repeats', type=int, default=400,
                   help='random pose splits per candidate in the search (default: 400, the paper)')
    p.add_argument('--per-class', type=int, default=3,
                   help='held-out poses per class put on the stage (default: 3)')
    p.add_argument('--jobs', type=jobs_type, default=2, help='worker processes (default: 2)')
    p.add_argument('--seed', type=int, default=0,
                   help='seed of the dataset, the search and the stage camera\'s noise (default: 0)')
    p.add_argument('--domain-id', type=int, default=None,
                   help='ROS_DOMAIN_ID of the demo graph (default: $ROS_DOMAIN_ID, else 42)')
    p.add_argument('--fresh', action='store_true', help='redo the dataset and the training')
    return p


# ----------------------------------------------------------------------------- offline part
def _dataset(out: Path, args) -> Path:
    from lightstage_physics import synth

    capture = out / 'capture'
    if (capture / 'rig.yaml').is_file() and not args.fresh:
        _say(f'dataset: reusing {capture}')
        return capture
    kwargs = {'n_jobs': args.jobs, 'seed': args.seed, 'overwrite': True}
    if args.size:
        kwargs['image_size'] = args.size
    _say('dataset: synthesising relightable models (5 fruit types x real/fake, 32 LEDs each)...')
    t0 = time.perf_counter()
    synth.generate(capture, **kwargs)
    _say(f'dataset: {capture} written in {time.perf_counter() - t0:.0f} s')
    return capture


def _split_by_instance(modelset):
    """Train on every physical sample but the last of each class; hold that one out."""
    import numpy as np

    last = np.zeros(len(modelset), dtype=bool)
    for c in range(modelset.n_classes):
        in_class = modelset.labels == c
        last |= in_class & (modelset.instance == modelset.instance[in_class].max())
    return np.flatnonzero(~last), np.flatnonzero(last)


def _train(out: Path, capture: Path, args) -> tuple[dict, list[str]]:
    from dataclasses import replace

    from lightstage_physics.capture_format import load_capture
    from mux_trainer.baselines import NaiveClassifier
    from mux_trainer.calibration import calibrate_pattern_model
    from mux_trainer.greedy import GreedyPatternSelector
    from mux_trainer.search_params import Execution, Rendering, SplitScoring

    modelset = load_capture(capture, downscale_to=120)
    train_idx, test_idx = _split_by_instance(modelset)
    held_out = [modelset.sample_names[i] for i in test_idx]
    artifacts = {'greedy': out / f'greedy_{NOISE}.npz', 'naive': out / f'naive_{NOISE}.npz',
                 'learned': out / f'learned_{NOISE}.npz'}
    summary_path = out / 'training.json'
    if all(p.is_file() for p in artifacts.values()) and summary_path.is_file() and not args.fresh:
        _say(f'training: reusing {", ".join(str(p) for p in artifacts.values())}')
        return json.loads(summary_path.read_text()), held_out
    train = modelset.subset(train_idx)
    n_samples = len({name.rsplit('/', 1)[0] for name in train.sample_names})
    _say(f'training on {len(train)} models ({n_samples} physical samples, {train.n_classes} classes); '
         f'{len(test_idx)} models of unseen samples held out for the stage')
    summary = {}
    common = dict(rendering=Rendering(noise=NOISE), scoring=SplitScoring(n_repeats=args.repeats),
                  seed=args.seed, execution=Execution(n_jobs=args.jobs, progress=True))
    for name, model in (('greedy', GreedyPatternSelector(**common)),
                        ('naive', NaiveClassifier(**common))):
        t0 = time.perf_counter()
        model.fit(train)
        # calibrated probabilities and the anytime rule, as `lightstage train` fits them
        confidence = calibrate_pattern_model(model)
        seconds = time.perf_counter() - t0
        replace(model.to_artifact(provenance={'capture': str(capture.resolve()),
                                              'train_seconds': seconds,
                                              'demo_held_out_instance': 'last per class'}),
                confidence=confidence).save(artifacts[name])
        per_pattern = int(model.images_per_pattern)
        best_images = int(model.best_n_patterns_) * per_pattern
        summary[name] = {'artifact': str(artifacts[name]), 'train_seconds': seconds,
                         'best_n_images': best_images,
                         'patterns': model.patterns_.astype(int).tolist(),
                         'split_accuracy_by_images': {str(k * per_pattern): float(v) for k, v
                                                      in model.accuracy_by_images_.items()}}
        _say(f'training: {name}: {seconds:.0f} s, split accuracy by image count '
             + ', '.join(f'{k}: {100 * v:.1f} %' for k, v in summary[name]['split_accuracy_by_images'].items()))
        _say(f'  calibrated: anytime stop at {100 * confidence.stop_probability:.3g} % '
             f'(held-out answers: {100 * confidence.estimate["anytime_accuracy"]:.1f} % at a mean '
             f'of {confidence.estimate["anytime_mean_images"]:.1f} of '
             f'{confidence.estimate["full_images"]} images)')
        if name == 'greedy':
            for j in range(model.patterns_.shape[1]):
                lit = [s for s in range(model.patterns_.shape[0]) if model.patterns_[s, j] > 0.5]
                _say(f'  pattern {j + 1}: sites {lit} lit, each colour in turn (4 images)')
    summary['learned'] = _train_learned(train, artifacts['learned'], capture, args)
    summary_path.write_text(json.dumps(summary, indent=2))
    return summary, held_out


# The demo's learned schedule: 8 exposures (half of greedy's 16), the default's starts
# without gradient steps (`learned_schedule`), a quarter of its inner pose splits
# (`LearnedIlluminationClassifier`'s defaults)
LEARNED_SCHEDULE = dict(n_repeats=100)
LEARNED_EXPOSURES = 8


def _train_learned(train, artifact: Path, capture: Path, args) -> dict:
    from mux_trainer.learned_method import (build_learned, describe_choice, learned_artifact,
                                            pattern_levels)

    model = build_learned(LEARNED_EXPOSURES, noise=NOISE, seed=args.seed, **LEARNED_SCHEDULE)
    t0 = time.perf_counter()
    model.fit(train)
    # JAX's threads now exist; the graph's nodes start through subprocess, whose fork is
    # followed by exec at once (in C, no Python runs between them): JAX's warning about
    # forking a multithreaded process does not apply to it
    warnings.filterwarnings('ignore', message=r'os\.fork\(\) was called', category=RuntimeWarning)
    seconds = time.perf_counter() - t0
    learned_artifact(model, provenance={'capture': str(capture.resolve()), 'train_seconds': seconds,
                                        'demo_held_out_instance': 'last per class'}
                     ).save(artifact)
    k = int(model.best_n_patterns_)
    accuracy = float(model.accuracy_by_images_[k])
    _say(f'training: learned: {seconds:.0f} s, {k} graded patterns (kept {describe_choice(model.chosen_, model.descent.max_steps)}; '
         f'inner split accuracy {100 * accuracy:.1f} %)')
    return {'artifact': str(artifact), 'train_seconds': seconds, 'best_n_images': k,
            'patterns': pattern_levels(model.patterns_),
            'inner_split_accuracy_by_images': {str(k): accuracy}, 'chosen': model.chosen_}


def _choose_on_stage(held_out: list[str], per_class: int) -> list[str]:
    by_class: dict[str, list[str]] = {}
    for name in held_out:
        by_class.setdefault(name.split('/')[0], []).append(name)
    return [n for names in by_class.values() for n in names[:per_class]]


# ----------------------------------------------------------------------------- on the stage
# A request sent while a service's reply path is still matching can be lost: both calls
# below are resent after their timeout (both are idempotent).
def _set_parameter(graph, node: str, name: str, value: str) -> None:
    from lightstage_graph.graph_client import parameter_msgs
    from rcl_interfaces.srv import SetParameters

    request = SetParameters.Request(parameters=parameter_msgs({name: value}))
    result = graph.call(SetParameters, f'/{node}/set_parameters', request, timeout_s=10.0,
                        attempts=3).results[0]
    if not result.successful:
        raise RuntimeError(f'{node} refused {name}={value!r}: {result.reason}')


def _classify(graph, max_images: int, target_probability: float = 0.0):
    from lightstage_interfaces.srv import Classify

    request = Classify.Request(max_images=max_images, timeout_s=10.0,
                               target_probability=target_probability)
    return graph.call(Classify, CLASSIFY_SERVICE, request, timeout_s=15.0, attempts=3)


def _params_file(path: Path, sections: dict) -> Path:
    """A ROS params YAML: {node: {parameter: value}}."""
    import yaml

    path.write_text(yaml.safe_dump({node: {'ros__parameters': values}
                                    for node, values in sections.items()}, sort_keys=False))
    return path


# graded levels (pwm_bits 8) for the learned patterns; on/off ones light the same
SIM_DRIVER = {'port': 'sim://?pwm_bits=8'}
STAGE_PARAMS = 'stage_params.yaml'  # the demo's stage for `lightstage up` (the README's)


def _write_params(out: Path, capture: Path, artifact: str, first_sample: str,
                  recorder: dict, seed: int) -> Path:
    return _params_file(out / 'demo_params.yaml', {
        'driver': SIM_DRIVER,
        # a seeded camera: the same demo gives the same frames, so the same figures
        'camera': {'backend': 'sim', 'capture_dir': str(capture.resolve()),
                   'sample': first_sample, 'noise': 'auto', 'seed': seed},
        'classifier': {'artifact_path': str(Path(artifact).resolve())},
        RECORDER: recorder,
    })


def write_stage_params(out: Path, capture: Path, artifact: str, sample: str) -> Path:
    """OUT/stage_params.yaml: the demo's stage for `lightstage up driver camera classifier
    acquisition --params` (the README's next step): the simulated firmware with graded
    levels, the simulated camera on the demo's capture with `sample` (a held-out one) on the
    stage and fresh noise, the classifier with `artifact`. No recorder section: `lightstage up`
    records to out/bags/ (or --no-record), never over the demo's own bag."""
    return _params_file(out / STAGE_PARAMS, {
        'driver': SIM_DRIVER,
        'camera': {'backend': 'sim', 'capture_dir': str(capture.resolve()), 'sample': sample,
                   'noise': 'auto'},
        'classifier': {'artifact_path': str(Path(artifact).resolve())},
    })


def replay_commands(bag: Path, artifact: str, out: Path, domain_id: int) -> list[list[str]]:
    """The two commands (two terminals) that replay the stage session's /illumination and
    /camera/image_raw from `bag` into a classifier that only observes, with `artifact`: it publishes
    the recorded labels of the calls made with that artifact again on /lightstage/result."""
    params = _params_file(out / 'replay_params.yaml', {
        'classifier': {'artifact_path': str(Path(artifact).resolve()), 'classify_observed': True}})
    domain = ['--domain-id', str(domain_id)]
    return [['lightstage', 'up', 'classifier', '--params', str(params), *domain],
            ['lightstage', 'play', str(bag), '--topics', ILLUMINATION_TOPIC, resolved(IMAGE_TOPIC),
             '--wait-for', ILLUMINATION_TOPIC, resolved(IMAGE_TOPIC), '--delay-s', '1', *domain]]


def _on_stage(out: Path, capture: Path, summary: dict, samples: list[str], domain_id: int,
              recorder: dict | None = None, seed: int = 0) -> dict:
    """Classify `samples` on the stage with each method of `summary`, recorded into the bag
    OUT/BAG (`recorder`: more parameters of the recorder, e.g. max_bag_size_bytes)."""
    import shutil

    from lightstage_bringup.launcher import NODE_REGISTRY, GraphWatcher, node_command
    from lightstage_bringup.supervisor import ProcessSpec, Supervisor
    from lightstage_graph.graph_client import GraphClient

    bag = out / BAG
    if bag.is_dir():
        shutil.rmtree(bag)  # the previous demo's: OUT is the demo's own working folder
    params = _write_params(out, capture, summary['greedy']['artifact'], samples[0],
                           {'output_dir': str(bag.resolve()), **(recorder or {})}, seed)
    env = ros_environment(domain_id)
    log_dir = out / 'logs'
    results = {}
    names = [*DEFAULT_NODES, RECORDER]  # driver, camera, classifier and the recorder
    with open(os.devnull, 'w') as quiet, \
            Supervisor(stdout=quiet, stderr=quiet, log_dir=log_dir) as supervisor:
        t0 = time.monotonic()
        for name in names:
            supervisor.start(ProcessSpec(name, node_command(NODE_REGISTRY[name].module, name, params), env))
        with GraphWatcher(domain_id) as graph:
            missing, dead = graph.wait_for(names, 60.0, supervisor)
        if missing or dead:
            raise RuntimeError(f'the graph did not come up (missing {missing}, died {dead}); '
                               f'see the node logs in {log_dir}')
        _say(f'graph up in {time.monotonic() - t0:.1f} s (ROS_DOMAIN_ID={domain_id}): driver on the '
             f'simulated firmware, simulated camera, classifier, recorder; node logs in {log_dir}')
        with GraphClient(domain_id, 'lightstage_demo') as graph:
            graph.wait_for_subscriptions(RECORDER, RECORDED, 30.0)
            calibrated = []
            for method in summary:
                results[method] = _stage_pass(graph, method, summary, samples)
                if results[method] and results[method][0]['calibrated']:
                    calibrated.append(method)
            if calibrated:
                # the same samples with every exposure, beside the anytime calls; not
                # recorded (the bag replays the calls that decided by the trained rule)
                supervisor.stop(RECORDER)
                for method in calibrated:
                    results[f'{method}, every exposure'] = _stage_pass(
                        graph, method, summary, samples, target_probability=1.0,
                        name=f'{method}, every exposure')
    # leaving the Supervisor stopped the recorder with SIGINT: the bag is closed
    _report_bag(bag, summary['greedy']['artifact'], out, domain_id)
    return results


def _stage_pass(graph, method: str, summary: dict, samples: list[str],
                target_probability: float = 0.0, name: str | None = None) -> list[dict]:
    """Classify each sample once with `method`'s artifact (at most its best image count);
    one row per call."""
    _set_parameter(graph, CLASSIFIER_NODE, 'artifact_path', summary[method]['artifact'])
    rows = []
    for sample in samples:
        _set_parameter(graph, CAMERA_NODE, 'sample', sample)
        r = _classify(graph, summary[method]['best_n_images'], target_probability)
        if not r.success:
            raise RuntimeError(f'classify failed for {sample}: {r.message}')
        rows.append({'sample': sample, 'true': sample.split('/')[0], 'label': r.label,
                     'images_used': int(r.images_used), 'images_budget': int(r.images_budget),
                     'decision': r.decision, 'calibrated': bool(r.calibrated),
                     'probability': max(r.probabilities) if len(r.probabilities) else None,
                     'acquisition_ms': float(r.acquisition_ms),
                     'compute_ms': float(r.compute_ms)})
    correct = sum(row['true'] == row['label'] for row in rows)
    _say(f'{name or method}: {correct}/{len(rows)} unseen samples right on the stage')
    return rows


def _report_bag(bag: Path, artifact: str, out: Path, domain_id: int) -> None:
    """Say what the bag holds and how to replay it; RuntimeError if it is not complete."""
    import shlex

    from lightstage_recording import BagError, BagReader, format_size

    try:
        info = BagReader(bag).info(verify=True)
    except BagError as exc:
        raise RuntimeError(f'the recorder left no readable bag: {exc}; see {out / "logs"}') from None
    if not info.complete:
        raise RuntimeError(f'the bag {bag} is incomplete: {"; ".join(info.problems)}; see '
                           f'{out / "logs" / (RECORDER + ".log")}')
    _say(f'stage session recorded: {bag} ({info.message_count} messages, '
         f'{format_size(info.size_bytes)}; `lightstage bag info {bag}`)')
    _say('replay its greedy calls into a classifier that only observes, which gives their '
         'labels again (two terminals):')
    for command in replay_commands(bag, artifact, out, domain_id):
        _say('  ' + shlex.join(command))


def _report(results: dict, summary: dict) -> dict:
    import numpy as np

    report = {}
    print()
    print('On the simulated stage, physical samples never seen in training (noise Sigma3);')
    print('anytime: each object stops at the first pattern column whose top class reaches the')
    print('trained target; "every exposure" takes the whole budget. Means per object:')
    print(f'  {"method":<24} {"accuracy":>9} {"exposures":>10} {"acquisition ms":>15} '
          f'{"compute ms":>11} {"unsure":>7} {"unknown":>8}')
    for method, rows in results.items():
        accuracy = float(np.mean([r['true'] == r['label'] for r in rows]))
        acq = float(np.mean([r['acquisition_ms'] for r in rows]))
        comp = float(np.mean([r['compute_ms'] for r in rows]))
        images = float(np.mean([r['images_used'] for r in rows]))
        unsure = sum(r.get('decision') == UNSURE for r in rows)
        unknown = sum(r.get('decision') == UNKNOWN for r in rows)
        budget = rows[0].get('images_budget') or rows[0]['images_used']
        base = method.split(',')[0]
        report[method] = {'accuracy': accuracy, 'images_used_mean': images,
                          'images_budget': budget, 'acquisition_ms_mean': acq,
                          'compute_ms_mean': comp, 'unsure': unsure, 'unknown': unknown,
                          'train_seconds': summary[base]['train_seconds'], 'calls': rows}
        print(f'  {method:<24} {100 * accuracy:8.1f} % {images:>5.1f} of {budget:<2d} {acq:>15.1f} '
              f'{comp:>11.1f} {unsure:>7d} {unknown:>8d}')
    print()
    return report


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(sys.argv[1:] if argv is None else argv)
    for name in ('repeats', 'per_class', 'jobs'):
        if getattr(args, name) < 1:
            print(f'lightstage demo: --{name.replace("_", "-")} must be >= 1', file=sys.stderr)
            return 2
    domain_id = args.domain_id
    if domain_id is None:
        domain_id = int(os.environ.get('ROS_DOMAIN_ID') or 42)
    try:
        apply_ros_environment(domain_id)  # before rclpy loads: LOCALHOST discovery, the profile
    except ValueError as exc:
        print(f'lightstage demo: {exc}', file=sys.stderr)
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    try:
        capture = _dataset(out, args)
        summary, held_out = _train(out, capture, args)
        samples = _choose_on_stage(held_out, args.per_class)
        stage_params = write_stage_params(out, capture, summary['greedy']['artifact'], samples[0])
        results = _on_stage(out, capture, summary, samples, domain_id, seed=args.seed)
    except (RuntimeError, ValueError, OSError) as exc:  # a GraphTimeout is an OSError
        print(f'lightstage demo: {exc}', file=sys.stderr)
        return 1
    report = _report(results, summary)
    path = out / 'demo_results.json'
    path.write_text(json.dumps({'noise': NOISE, 'training': summary, 'on_stage': report}, indent=2))
    _say(f'done in {time.perf_counter() - t0:.0f} s; results in {path}')
    _say(f'the demo\'s stage, to classify on yourself (README, "On the demo\'s stage"): '
         f'lightstage up driver camera classifier acquisition --params {stage_params}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
