"""The trainer node: the Train action (`/lightstage/train`) around `training.train_from_capture`.

One goal at a time (a second is rejected while one runs: the search uses every core it is
given). Feedback is sent when each pattern column starts, before each round of its
candidates' scoring tasks (one per worker) and when it is chosen (the learned method: when
each of its starts is begun and scored, greedy's progress while its start is made, each
gradient snapshot); a cancel request stops the search at the next of these.
Empty/zero goal fields take the
paper's defaults (greedy, per-colour, Sigma3, 8 columns, 400 splits); the `inner_groups`
parameter says what the inner splits hold out (default auto: whole physical samples where
the capture has two or more of every class), and the result's message gives the inner
estimate and how it was made. With the
`dask_scheduler` parameter set, the candidates are evaluated on that Dask cluster; a
scheduler that cannot be reached or is lost aborts the goal with the reason.
"""
from __future__ import annotations

import sys
import threading
import time

from lightstage_physics.workers import usable_cores
from lightstage_graph.leds import n_site_subsets
from lightstage_graph.names import TRAINER_NODE, TRAIN_ACTION
from lightstage_graph.params import boolean, declare_parameters, floating, integer, string
from mux_classifier.features import DEFAULT_EXTRACTOR, EXTRACTORS
from lightstage_graph.spin import init_node, spin_until_stopped
from lightstage_interfaces.action import Train
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node

from .cluster import DEFAULT_TIMEOUT_S
from .greedy import REFINE_TOP
from .learned_method import progress_text
from .learned_schedule import DEFAULT_STEPS, MAX_STEPS
from .splits import INNER_GROUPS, describe_inner
from .training import METHODS, train_from_capture

SITE_CANDIDATES = n_site_subsets()  # per-colour mode: patterns with 1..7 of 8 sites lit
MAX_JOBS = 256


PARAMETERS = {
    # 1..256: a range cannot hold -1 ("all cores") without 0, which means nothing to
    # joblib; the default is all the cores this process may use
    'n_jobs': (min(usable_cores(), MAX_JOBS), integer(
        'joblib worker processes for candidate evaluation (default: the cores this '
        'process may use)', 1, MAX_JOBS)),
    'refine_top': (REFINE_TOP, integer(
        'greedy: candidates per column re-scored with the exact linear SVM after the '
        'ridge screen (0 = the screen picks)', 0, SITE_CANDIDATES)),
    'features': (DEFAULT_EXTRACTOR, string(
        'feature extractor the search scores with and the trained classifier uses: '
        'hog_grid (the paper\'s), intensity_stats (objects placed any way), pooled_hog, '
        'pooled_hog_stats or pose_hog (docs/SEARCH.md); a bad name aborts the goal',
        constraints=', '.join(n for n, c in EXTRACTORS.items() if c.searchable))),
    'method': ('greedy', string(
        'method of a goal whose method field is empty: greedy (the paper\'s search), '
        'snr_optimal, naive or learned (LED levels and a classifier trained end to end, '
        'max_images exposures; docs/LEARNED.md); a bad name aborts the goal',
        constraints=', '.join(METHODS))),
    'learned_steps': (DEFAULT_STEPS, integer(
        'learned: gradient steps on the LED levels from each start descended (the random '
        'one, greedy\'s columns and the best raking split); 0: the starts alone', 0, MAX_STEPS)),
    'inner_groups': ('auto', string(
        'what the inner splits that choose and score every method hold out: instances '
        '(whole physical samples: an estimate for objects never seen in training), poses '
        '(the paper\'s rule: it holds only for the objects trained on) or auto (physical '
        'samples where the capture has two or more of every class, else poses); a bad '
        'value aborts the goal', constraints=', '.join(INNER_GROUPS))),
    'learned_binary': (False, boolean(
        'learned: on/off LED levels (boards with pwm_bits 0) instead of graded ones')),
    'dask_scheduler': ('', string(
        'address of an existing Dask scheduler to evaluate the candidates on, e.g. '
        'tcp://HOST:8786 (empty = locally, with n_jobs processes); same results')),
    'dask_timeout_s': (DEFAULT_TIMEOUT_S, floating(
        'a goal aborts when the Dask scheduler cannot be reached, or has no connection '
        'or no workers, for this long', 1.0, 3600.0)),
}


class _Cancelled(Exception):
    pass


class _Stopping(Exception):
    pass


def goal_options(goal, n_jobs: int, refine_top: int = REFINE_TOP,
                 features: str = DEFAULT_EXTRACTOR) -> dict:
    """Train goal fields -> `train_from_capture` options, with the documented defaults."""
    return dict(method=goal.method or 'greedy', mode=goal.mode or 'per_colour',
                noise=goal.noise or 'sigma3', max_images=int(goal.max_images) or 8,
                repeats=int(goal.repeats) or 400, seed=int(goal.seed), n_jobs=n_jobs,
                refine_top=refine_top, features=features)


class TrainerNode(Node):
    def __init__(self, node_name: str = TRAINER_NODE, **kwargs):
        super().__init__(node_name, **kwargs)
        self.p = declare_parameters(self, PARAMETERS)
        self._busy = threading.Lock()
        self._stopping = threading.Event()
        self._destroyed = False
        self._server = ActionServer(self, Train, TRAIN_ACTION, execute_callback=self._execute,
                                    goal_callback=self._on_goal, cancel_callback=self._on_cancel,
                                    callback_group=ReentrantCallbackGroup())

    def _on_goal(self, goal) -> GoalResponse:
        if not goal.capture_dir or not goal.output_path:
            self.get_logger().error('Train goal rejected: capture_dir and output_path are required')
            return GoalResponse.REJECT
        if self._busy.locked():
            self.get_logger().warning('Train goal rejected: a training run is in progress')
            return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    def destroy_node(self) -> None:
        self._stopping.set()
        self._destroyed = True
        super().destroy_node()

    def stop_work(self):
        """At the node's stop (`spin_until_stopped`): a running goal ends at its next progress
        event, aborted, no artifact written; returns whether no goal runs any more."""
        self._stopping.set()
        return lambda: not self._busy.locked()

    def _on_cancel(self, _goal_handle) -> CancelResponse:
        return CancelResponse.ACCEPT

    def _method_options(self, goal) -> dict:
        """The `method` parameter for a goal that names none; the learned method's options."""
        method = goal.method or str(self.p('method'))
        if method != 'learned':
            return {'method': method}
        return {'method': method, 'steps': int(self.p('learned_steps')),
                'binary': bool(self.p('learned_binary'))}

    def _execute(self, goal_handle):
        goal = goal_handle.request
        result = Train.Result()
        t0 = time.perf_counter()
        with self._busy:
            options = goal_options(goal, int(self.p('n_jobs')), int(self.p('refine_top')),
                                   str(self.p('features')))
            options.update(self._method_options(goal))
            options['inner_groups'] = str(self.p('inner_groups'))
            cluster = dict(dask_scheduler=str(self.p('dask_scheduler')).strip(),
                           dask_timeout_s=float(self.p('dask_timeout_s')))
            total = SITE_CANDIDATES if options['mode'] == 'per_colour' else 0
            best = [0.0]

            def on_event(event: dict) -> None:
                if self._stopping.is_set():
                    raise _Stopping()
                if goal_handle.is_cancel_requested:
                    raise _Cancelled()
                if event['event'] == 'candidates':   # greedy, within a column
                    goal_handle.publish_feedback(Train.Feedback(
                        column=event['column'], candidates_done=event['done'],
                        candidates_total=event['of'], best_accuracy=best[0],
                        stage=(f'column {event["column"]}: {event["done"]} of {event["of"]} '
                               'candidates scored')))
                    return
                if event['event'] not in ('column_start', 'column_done'):  # the learned method's
                    best[0] = event.get('best_accuracy', best[0])
                    goal_handle.publish_feedback(Train.Feedback(best_accuracy=best[0],
                                                                stage=progress_text(event)))
                    return
                done = event['event'] == 'column_done'
                if done:
                    best[0] = event['best_accuracy']
                goal_handle.publish_feedback(Train.Feedback(
                    column=event['column'], candidates_done=event.get('candidates', 0) if done else 0,
                    candidates_total=total, best_accuracy=best[0],
                    stage=(f'column {event["column"]} of at most {event["of"]}: '
                           + (f'accuracy {event["accuracy"]:.3f}' if done else 'searching'))))

            goal_handle.publish_feedback(Train.Feedback(stage='loading models'))
            where = f' on the Dask cluster {cluster["dask_scheduler"]}' if cluster['dask_scheduler'] else ''
            self.get_logger().info(f'training {options} on {goal.capture_dir}{where}')
            try:
                summary = train_from_capture(goal.capture_dir, goal.output_path,
                                             callback=on_event, **options, **cluster)
            except _Cancelled:
                goal_handle.canceled()
                result.message = ('canceled between rounds of candidates (learned: between '
                                  'starts or gradient steps); no artifact written')
                result.elapsed_s = time.perf_counter() - t0
                return result
            except _Stopping:
                result.message = 'aborted: the trainer node is stopping; no artifact written'
                result.elapsed_s = time.perf_counter() - t0
                self.get_logger().warning(result.message)
                if not self._destroyed:   # a goal longer than the stop's grace outlives its server
                    goal_handle.abort()
                return result
            except (ValueError, OSError) as exc:  # bad options, unreadable capture, unwritable
                # output, a Dask scheduler unreachable or lost (cluster.ClusterUnavailable)
                goal_handle.abort()
                result.message = f'training failed: {exc}'
                result.elapsed_s = time.perf_counter() - t0
                self.get_logger().error(result.message)
                return result
        accuracy = summary['accuracy_by_images']
        result.success = True
        result.artifact_path = summary['artifact']
        result.accuracy_by_images = [float(accuracy[k]) for k in sorted(accuracy, key=int)]
        result.elapsed_s = time.perf_counter() - t0
        per = int(summary.get('images_per_pattern', 1))
        columns = len(summary['patterns'][0]) if summary['patterns'] else 0
        inner = summary.get('inner_estimate')
        result.message = (f'{summary["method"]}: {columns} pattern column(s) of '
                          f'{per} exposure(s) each; best at {summary["best_n_images"]} '
                          f'column(s) = {summary["best_n_images"] * per} exposure(s)'
                          + (f'; {describe_inner(inner, inner["accuracy"])}' if inner else ''))
        goal_handle.succeed()
        self.get_logger().info(f'wrote {result.artifact_path} ({result.message})')
        return result


def main(argv: list[str] | None = None) -> int:
    init_node(sys.argv if argv is None else argv)
    return spin_until_stopped(TrainerNode(), MultiThreadedExecutor(num_threads=2))


if __name__ == '__main__':
    sys.exit(main())
