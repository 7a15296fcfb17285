"""`lightstage classify`: classify the sample on the stage through ``/lightstage/classify``.

Exit codes: 0 classified; 1 the classifier answered with an error (printed); 2 bad
arguments; 3 the service is not available or did not answer in time, or the call ran past
its overall limit (--wait-s + the classification's limit + 30 s; the answer, once printed,
is followed by at most 10 s of teardown). Every call ends, with a message saying why.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys

from lightstage_graph.names import CLASSIFY_SERVICE
from lightstage_graph.ros_env import apply_ros_environment

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_UNAVAILABLE = 0, 1, 2, 3
# beyond --wait-s and the classification's own limit: starting and stopping the ROS client
# (a participant takes a few seconds to come up on a loaded machine, 12 started at once)
SETUP_S = 30.0
TEARDOWN_S = 10.0


def _parser() -> argparse.ArgumentParser:
    from mux_classifier.classify_request import TIMEOUT_MAX_S, TIMEOUT_MIN_S
    p = argparse.ArgumentParser(
        prog='lightstage classify',
        description='Classify the sample on the stage: the classifier node lights its learned '
                    'patterns, collects the images and answers with a label.',
        epilog='exit codes: 0 classified, 1 the classifier reported an error, 2 bad arguments, '
               '3 the service is not available / did not answer')
    p.add_argument('--max-images', type=int, default=0,
                   help='use at most this many learned patterns (default 0: all the classifier has)')
    p.add_argument('--timeout-s', type=float, default=0.0,
                   help=f'time limit of the classification [s], {TIMEOUT_MIN_S:g} to '
                        f'{TIMEOUT_MAX_S:g} (default 0: the node\'s timeout_s)')
    p.add_argument('--target-probability', type=float, default=0.0,
                   help='stop after the first pattern column at which the top class reaches '
                        'this calibrated probability, 0 to 1 (default 0: the classifier\'s own '
                        'rule; 1: every image). An uncalibrated classifier takes every image')
    p.add_argument('--wait-s', type=float, default=5.0,
                   help='how long to wait for the classify service to appear [s] (default 5)')
    p.add_argument('--domain-id', type=int, default=None,
                   help='ROS_DOMAIN_ID of the graph (default: $ROS_DOMAIN_ID or 0)')
    p.add_argument('--json', action='store_true', help='print the answer as one JSON object')
    return p


def _timing(answer: dict) -> str:
    budget = answer.get('images_budget') or answer['images_used']
    return (f'{answer["images_used"]} of {budget} exposures, acquisition '
            f'{answer["acquisition_ms"]:.1f} ms, compute {answer["compute_ms"]:.1f} ms')


def format_answer(answer: dict) -> str:
    """Human-readable answer in plain words: the decision (accepted with its probability, not
    sure, unknown; or the label of an uncalibrated classifier), the exposures it took and the
    timings, then each class best first with its probability and score."""
    if not answer['success']:
        return f'classification failed: {answer["message"]}'
    probabilities = answer.get('probabilities') or []
    names, scores = answer['class_names'], answer['scores']
    if not probabilities:
        lines = [f'label: {answer["label"]}  (uncalibrated classifier: scores only; '
                 f'{_timing(answer)})']
        ranked = sorted(zip(names, scores), key=lambda cs: -cs[1])
        width = max((len(c) for c, _ in ranked), default=0)
        return '\n'.join(lines + [f'  {c:<{width}}  {s:+.3f}' for c, s in ranked])
    ranked = sorted(zip(names, probabilities, scores), key=lambda cps: -cps[1])
    decision = answer.get('decision', 'accepted')
    if decision == 'unsure':
        top = ', '.join(f'{c} {100 * p:.1f} %' for c, p, _ in ranked[:2])
        head = f'not sure: {top}: look again or ask a person ({_timing(answer)})'
    elif decision == 'unknown':
        c, p, _ = ranked[0]
        novelty = math.nan if answer.get('novelty') is None else float(answer['novelty'])
        head = (f'unknown: unlike every trained class (novelty {novelty:.2f}); '
                f'nearest {c} {100 * p:.1f} % ({_timing(answer)})')
    else:
        head = (f'label: {answer["label"]}, {100 * ranked[0][1]:.1f} % (accepted; '
                f'{_timing(answer)})')
    width = max((len(c) for c, _, _ in ranked), default=0)
    return '\n'.join([head] + [f'  {c:<{width}}  {100 * p:5.1f} %  (score {s:+.3f})'
                                for c, p, s in ranked])


def main(argv: list[str] | None = None) -> int:
    from mux_classifier.classify_request import (TIMEOUT_MAX_S, request_max_images,
                                                 request_timeout_s)
    args = _parser().parse_args(sys.argv[1:] if argv is None else argv)
    try:
        # the node's own request checks, so that the answer is a usage error, not a refusal
        request_max_images(args.max_images, '--max-images')
        request_timeout_s(args.timeout_s, name='--timeout-s')
        if not (math.isfinite(args.target_probability) and 0.0 <= args.target_probability <= 1.0):
            raise ValueError('--target-probability must be a number from 0 (the classifier\'s '
                             'own rule) to 1 (every image); got '
                             f'{args.target_probability!r}')
        if not (math.isfinite(args.wait_s) and args.wait_s >= 0):
            raise ValueError(f'--wait-s must be a finite number of seconds >= 0; got {args.wait_s!r}')
        apply_ros_environment(args.domain_id)  # before rclpy is imported: LOCALHOST discovery
    except ValueError as exc:
        print(f'lightstage classify: {exc}', file=sys.stderr)
        return EXIT_USAGE

    from lightstage_graph.deadline import ExitDeadline
    from lightstage_graph.graph_client import GraphClient, GraphTimeout
    from lightstage_interfaces.srv import Classify

    # the node enforces the timeout; sent 0, its own default is at most TIMEOUT_MAX_S
    limit_s = (args.timeout_s if args.timeout_s > 0 else TIMEOUT_MAX_S) + 5.0
    request = Classify.Request(max_images=args.max_images, timeout_s=args.timeout_s,
                               target_probability=args.target_probability)
    # Every wait below is bounded; the deadline bounds what no timeout reaches (creating and
    # destroying the DDS participant): the whole call, then the teardown once answered.
    with ExitDeadline(args.wait_s + limit_s + SETUP_S, 'lightstage classify', EXIT_UNAVAILABLE,
                      phase='setting up its ROS client') as deadline:
        graph = GraphClient(args.domain_id, f'lightstage_classify_cli_{os.getpid()}')
        try:
            deadline.phase = f'waiting for {CLASSIFY_SERVICE} and its answer'
            try:
                r = graph.call(Classify, CLASSIFY_SERVICE, request, timeout_s=limit_s,
                               wait_s=args.wait_s, hint='start the graph with `lightstage up` '
                                                        '(driver camera classifier) in the same domain')
            except GraphTimeout as exc:
                print(f'lightstage classify: {exc}', file=sys.stderr, flush=True)
                code = EXIT_UNAVAILABLE
            else:
                code = _print_answer(r, args.json)
            # the answer is out before the participant is destroyed: a teardown that hangs
            # cannot swallow it, and ends after TEARDOWN_S with the answer's exit code
            deadline.phase = 'shutting down its ROS client (the answer above is complete)'
            deadline.restart(TEARDOWN_S, code)
        finally:
            graph.close()
    return code


def _print_answer(r, as_json: bool) -> int:
    """Print a Classify response (JSON, or the human-readable answer); its exit code."""
    answer = {'success': bool(r.success), 'message': r.message, 'label': r.label,
              'class_names': list(r.class_names), 'scores': [float(s) for s in r.scores],
              'images_used': int(r.images_used), 'acquisition_ms': float(r.acquisition_ms),
              'compute_ms': float(r.compute_ms),
              'probabilities': [float(p) for p in r.probabilities], 'decision': r.decision,
              'novelty': float(r.novelty) if math.isfinite(r.novelty) else None,
              'images_budget': int(r.images_budget), 'calibrated': bool(r.calibrated)}
    if as_json:
        print(json.dumps(answer), flush=True)
    else:
        print(format_answer(answer), file=sys.stdout if answer['success'] else sys.stderr, flush=True)
    return EXIT_OK if answer['success'] else EXIT_FAILED


if __name__ == '__main__':
    sys.exit(main())
