"""The classifier node: ``/lightstage/classify`` lights the learned patterns and classifies.

One call: the artifact's first k LED patterns go to the driver (``/lightstage/apply_patterns``,
one trigger each, exposure and gain of the noise setting the artifact was trained for); the
``camera/image_raw`` frames whose header stamps equal the returned trigger stamps are collected
in pattern order; the artifact's classifier for k images predicts; the answer also goes
out on ``/lightstage/result``. The work itself is `inference.classify_on_stage`.

With ``classify_observed`` the node also classifies sequences it only sees: a complete
trigger request on ``/illumination`` that lit the artifact's first k patterns (lit by another
client, or replayed from a bag) is matched to its images by stamp and classified; the result
goes out on ``/lightstage/result`` (`observe.SequenceObserver`; its own service calls are not
classified twice). ``service_introspection`` publishes the Classify calls on
``/lightstage/classify/_service_event`` so that recordings hold them.

Concurrency: the stage lights one sequence at a time, so calls take turns in a FIFO
(`stage_queue.StageQueue`) served by one worker thread; the service handler is a coroutine
that submits its call and awaits the outcome without holding the executor. The driver's
replies, the camera's parameter answers and the images are therefore always handled, at
any number of concurrent calls (when every executor thread waited for the stage, four calls
at once all failed). A call that cannot be served within its time limit is refused at once
with the reason. Observed sequences are classified on a worker thread of their own
(`observe.SequenceObserver`).

No callback blocks, so one executor thread serves them all, in arrival order. rclpy 7.1's
MultiThreadedExecutor handed each image to its threads 10 to 25 times (the subscription
stays ready until a thread has taken the message; every extra handler finds nothing): at a
replay's 44 images/s that kept a core busy, the images waited behind the empty handlers
longer than the reader's queue holds, and an observing classifier lost 1 to 13 of a demo
replay's 30 sequences in about half the replays. With one thread: one handler per image,
none lost (docs/NODES.md, "Observing mode").
"""
from __future__ import annotations

import sys
import threading
import time
import traceback

import numpy as np
from lightstage_graph.awaitable import executor_future
from lightstage_graph.diagnostics import ERROR, OK, DiagnosticsPublisher, Report
from lightstage_graph.errors import StageError
from lightstage_graph.links import ReaderMatch
from lightstage_graph.names import (CAMERA_NODE, CLASSIFIER_NODE, CLASSIFY_SERVICE,
                                    ILLUMINATION_TOPIC, RESULT_TOPIC)
from lightstage_graph.params import boolean, declare_parameters, floating, integer, string
from lightstage_graph.qos import ILLUMINATION_QOS, QUEUED_SERVICE_QOS
from lightstage_graph.spin import init_node, spin_until_stopped
from lightstage_graph.stage_client import StageClient
from lightstage_graph.stamps import ns_to_stamp, stamp_to_ns
from lightstage_interfaces.msg import ClassificationResult, IlluminationState
from lightstage_interfaces.srv import Classify
from rcl_interfaces.msg import SetParametersResult
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.qos import qos_profile_services_default
from rclpy.service_introspection import ServiceIntrospectionState

from .classify_request import TIMEOUT_MAX_S, TIMEOUT_MIN_S, request_timeout_s
from .inference import AcquisitionPlan, InferenceError, classify_on_stage
from .artifact import ArtifactError, TrainedArtifact, check_dimmer
from .observe import SequenceObserver, TriggerState
from .stage_queue import StageBusy, StageQueue

START_HINT = 'lightstage up driver camera classifier'
# the camera's parameter service answers in ms when the camera is up, in seconds on a machine
# loaded far beyond its cores: the query may take this long, or half the call's time if more
CAMERA_QUERY_S = 2.0
# unclaimed images kept per image of the artifact's longest sequence: a sequence's images
# come before its last trigger state is seen, and the next one's may follow at once
BUFFERED_SEQUENCES = 2

PARAMETERS = {
    'artifact_path': ('', string(
        'trained classifier (.npz written by `lightstage train`); settable at run time (a file '
        'that does not load is rejected and the old one kept)')),
    'timeout_s': (10.0, floating('default time limit of one classification (driver + images) [s]; '
                                 'a request\'s timeout_s other than 0 overrides it', TIMEOUT_MIN_S,
                                 TIMEOUT_MAX_S)),
    'camera_bit_depth': (10, integer('significant bits of the camera\'s mono16 images '
                                     '(10: gray level = value >> 6)', 8, 16)),
    'image_buffer': (64, integer('images kept while waiting for their trigger stamps', 8, 1024,
                                 read_only=True)),
    'service_introspection': (True, boolean(
        'publish the Classify calls (request and response contents) on '
        '/lightstage/classify/_service_event, so that recordings hold them', read_only=True)),
    'camera_node': (CAMERA_NODE, string(
        'the camera node whose dimmer is checked against the classifier\'s before each '
        'classification (a sim camera at another dimmer would classify wrong silently)',
        read_only=True)),
    'diagnostics_period_s': (1.0, floating('/diagnostics period [s] (the classifier loaded: '
                                           'its classes, image counts and inner estimate)', 0.1,
                                           60.0, read_only=True)),
    'classify_observed': (False, boolean(
        'also classify trigger sequences seen on /illumination that light the artifact\'s first '
        'k patterns (another client\'s, or a replayed bag\'s) and publish them on '
        '/lightstage/result', read_only=True)),
}


class ClassifierNode(Node):
    def __init__(self, node_name: str = CLASSIFIER_NODE, **kwargs):
        super().__init__(node_name, **kwargs)
        self.p = declare_parameters(self, PARAMETERS)
        self.artifact: TrainedArtifact | None = None
        self.artifact_error = ''
        self.artifact_path = ''
        group = ReentrantCallbackGroup()
        self.stage = StageClient(self, image_buffer=self.p('image_buffer'), callback_group=group,
                                 start_hint=START_HINT, camera_node=self.p('camera_node'))
        self.diagnostics = DiagnosticsPublisher(self, 'model', self._classifier_status,
                                                self.p('diagnostics_period_s'))
        self._load_artifact(self.p('artifact_path'))
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._busy = threading.Lock()  # held by the queue's worker while it uses the stage
        self.queue = StageQueue(name='classify-stage')
        self._result_pub = self.create_publisher(ClassificationResult, RESULT_TOPIC, 10)
        self._result_readers = ReaderMatch(self, self._result_pub)  # a recorder just started
        # a burst of calls waits in the service's queue until the executor takes them; the
        # default depth (10) would drop the oldest of a larger burst unanswered
        service = self.create_service(Classify, CLASSIFY_SERVICE, self._on_classify,
                                      qos_profile=QUEUED_SERVICE_QOS, callback_group=group)
        if self.p('service_introspection'):
            service.configure_introspection(self.get_clock(), qos_profile_services_default,
                                            ServiceIntrospectionState.CONTENTS)
        self.observer = None
        if self.p('classify_observed'):
            self.observer = SequenceObserver(
                lambda: self.artifact, self.stage.matcher, self._on_observed, stage_busy=self._busy,
                timeout_s=lambda: float(self.p('timeout_s')),
                bit_depth=lambda: int(self.p('camera_bit_depth')),
                on_error=lambda m: self.get_logger().warning(m))
            # in order, one at a time: the assembler sees each request's states as sent
            self.create_subscription(IlluminationState, ILLUMINATION_TOPIC, self._on_illumination,
                                     ILLUMINATION_QOS, callback_group=MutuallyExclusiveCallbackGroup())

    def destroy_node(self) -> None:
        if getattr(self, 'queue', None) is not None:
            self.queue.close()  # waiting calls are refused; the one on the stage finishes
        if getattr(self, 'observer', None) is not None:
            self.observer.close()  # its worker thread ends before the node goes
        super().destroy_node()

    # ------------------------------------------------------------------ artifact
    @staticmethod
    def _read(path: str) -> TrainedArtifact:
        """The artifact at ``path``, ready to classify; any failure is an ArtifactError (the
        node stays up and keeps the classifier it has)."""
        if not str(path).strip():
            raise ArtifactError('artifact_path is empty; set it to a classifier file written by '
                                '`lightstage train` (a .npz)')
        try:
            artifact = TrainedArtifact.load(path)
            # first use of the HOG/linear code costs tens of ms: pay it now, not in a request
            size = artifact.hog_config.image_size
            artifact.predict_stack(np.zeros((artifact.n_images[-1], size, size), np.float32))
        except ArtifactError:
            raise
        except Exception as exc:  # last resort: a bad file never takes the node down
            raise ArtifactError(f'{path!r} cannot be used as a classifier ({type(exc).__name__}: '
                                f'{exc}); retrain to get a new file') from exc
        return artifact

    def _use(self, path: str, artifact: TrainedArtifact) -> None:
        # the buffer holds what the artifact's sequences need, whatever image_buffer says
        self.stage.matcher.set_capacity(max(int(self.p('image_buffer')),
                                            BUFFERED_SEQUENCES * max(artifact.n_images)))
        self.artifact, self.artifact_error = artifact, ''
        self.artifact_path = str(path)
        self.get_logger().info(f'loaded {path}: {artifact.describe()}')
        self.diagnostics.publish()

    def _classifier_status(self) -> Report:
        """The /diagnostics status: the classifier loaded (its description, the inner
        estimate and what its inner splits held out: physical samples, an estimate for
        objects never seen, or poses, one for the objects trained on), or why none is."""
        artifact = self.artifact
        if artifact is None:
            return Report(ERROR, self.artifact_error or 'no classifier loaded',
                          {'artifact_path': str(self.p('artifact_path'))})
        values = {'artifact_path': self.artifact_path,
                  'classes': ', '.join(artifact.class_names),
                  'method': str(artifact.provenance.get('method', '')),
                  'image_counts': ', '.join(str(n) for n in artifact.n_images),
                  'calibrated': str(artifact.confidence is not None).lower()}
        inner = artifact.provenance.get('inner_estimate')
        if not isinstance(inner, dict):   # older files, or a provenance written by hand
            inner = {}
        number = {key: inner[key] for key in ('accuracy', 'search_accuracy', 'selection_optimism')
                  if isinstance(inner.get(key), (int, float))}
        if 'accuracy' in number:
            values['inner_estimate_percent'] = f"{100 * number['accuracy']:.1f}"
            values['inner_estimate_held_out'] = str(inner.get('held_out', 'poses'))
            if 'search_accuracy' in number and 'selection_optimism' in number:
                values['inner_split_accuracy_percent'] = f"{100 * number['search_accuracy']:.1f}"
                values['selection_optimism_points'] = f"{100 * number['selection_optimism']:.1f}"
        return Report(OK, artifact.describe(), values)

    def _load_artifact(self, path: str) -> None:
        try:
            artifact = self._read(path)
        except ArtifactError as exc:
            self.artifact = None
            self.artifact_error = f'no classifier loaded: {exc}'
            self.get_logger().error(self.artifact_error)
            return
        self._use(path, artifact)

    def _on_set_parameters(self, params) -> SetParametersResult:
        for param in params:
            if param.name == 'artifact_path':
                try:
                    artifact = self._read(param.value)
                except ArtifactError as exc:
                    kept = ('the loaded classifier stays' if self.artifact is not None
                            else 'still no classifier loaded')
                    self.get_logger().warning(f'artifact_path {param.value!r} rejected ({kept}): {exc}')
                    return SetParametersResult(successful=False, reason=str(exc))
                self._use(param.value, artifact)
        return SetParametersResult(successful=True)

    # ------------------------------------------------------------------ driver
    def _apply(self, plan: AcquisitionPlan, timeout_s: float):
        deadline = time.monotonic() + timeout_s
        self.stage.wait_ready(timeout_s)
        stamps, sequences = self.stage.apply(plan.led_patterns, plan.exposure_us, plan.gain_db,
                                             deadline - time.monotonic())
        if self.observer is not None and stamps:
            self.observer.mark_own(stamps[0])  # lit by this call: not to be classified twice
        return stamps, sequences

    def _check_camera(self, artifact: TrainedArtifact, timeout_s: float) -> None:
        """DimmerMismatch if a sim camera renders at another dimmer than the classifier was
        trained with (a real camera has no dimmer). The check fails closed: a camera node that
        does not answer (stopped, hung, not running, another name) refuses the call, since
        an unchecked sim camera at another dimmer would classify wrong silently."""
        settings = self.stage.camera_parameters(('backend', 'dimmer'), timeout_s)
        if settings is None:
            camera = self.p('camera_node')
            raise InferenceError(
                f'not classifying: the camera node {camera!r} did not answer a parameter query '
                f'within {timeout_s:.1f} s, so its dimmer cannot be checked against the '
                f'classifier\'s ({artifact.dimmer:g}; a sim camera at another dimmer classifies '
                f'wrong silently). Is the camera running and not stopped or hung (`ros2 node '
                f'list`, its log)? If the camera node has another name, set the classifier\'s '
                f'camera_node parameter to it')
        if settings.get('backend') == 'sim' and 'dimmer' in settings:
            check_dimmer(artifact.dimmer, settings['dimmer'])

    # ------------------------------------------------------------------ service
    async def _on_classify(self, request: Classify.Request, response: Classify.Response):
        """Check the request, queue it for the stage and await its turn and outcome; the
        executor thread is free meanwhile."""
        try:
            try:
                timeout_s = request_timeout_s(request.timeout_s, self.p('timeout_s'))
            except ValueError as exc:
                return self._failed(response, str(exc))
            if self.artifact is None:
                return self._failed(response, self.artifact_error)
            try:
                outcome = self.queue.submit(lambda remaining_s: self._serve(request, remaining_s),
                                            timeout_s)
            except StageBusy as exc:
                return self._failed(response, str(exc))
            answer = await executor_future(self, outcome)
            try:
                return answer.result()
            except StageBusy as exc:  # its turn came too late
                return self._failed(response, str(exc))
        except Exception as exc:  # noqa: BLE001 - last resort: the service answers every request
            return self._unexpected(exc)

    def _unexpected(self, exc: BaseException) -> Classify.Response:
        self.get_logger().error('classify failed unexpectedly: '
                                + ''.join(traceback.format_exception(exc)))
        return Classify.Response(
            success=False, message=f'the classifier failed unexpectedly ({type(exc).__name__}: '
                                   f'{exc}); this is a bug: report it with the node\'s log')

    @staticmethod
    def _failed(response: Classify.Response, message: str) -> Classify.Response:
        response.success = False
        response.message = message
        return response

    def _serve(self, request: Classify.Request, remaining_s: float) -> Classify.Response:
        """One call on the stage (the queue's worker thread), within `remaining_s`."""
        response = Classify.Response(success=False)
        artifact = self.artifact
        if artifact is None:
            return self._failed(response, self.artifact_error)
        deadline = time.monotonic() + remaining_s
        with self._busy:
            try:
                target = artifact.check_target_probability(float(request.target_probability))
                # driver and camera there (the clearest errors first), dimmer checked, then light
                self.stage.wait_ready(remaining_s)
                left_s = deadline - time.monotonic()
                self._check_camera(artifact, min(left_s, max(CAMERA_QUERY_S, left_s / 2)))
                left_s = deadline - time.monotonic()
                if left_s <= 0:
                    raise InferenceError(f'the time limit ({remaining_s:.2f} s left when the '
                                         'stage was free) ran out while checking the stage; '
                                         'give a longer timeout_s')
                result = classify_on_stage(artifact, self._apply, self.stage.matcher,
                                           max_images=request.max_images, timeout_s=left_s,
                                           bit_depth=self.p('camera_bit_depth'),
                                           target_probability=target)
            except (StageError, ArtifactError) as exc:  # InferenceError, MissingImagesError, DimmerMismatch
                self.get_logger().warning(f'classify failed: {exc}')
                return self._failed(response, str(exc))
        response.success = True
        response.message = f'{result.label} ({result.decision}) from {result.images_used} of ' \
                           f'{result.images_budget} images'
        _fill(response, result)
        self._publish_result(result)
        self.get_logger().info(f'classified: {result.label}, {result.decision} '
                               f'({result.images_used} of {result.images_budget} images, '
                               f'acquisition {result.acquisition_ms:.1f} ms, compute '
                               f'{result.compute_ms:.1f} ms)')
        return response

    # ------------------------------------------------------------------ observing
    def _on_illumination(self, msg: IlluminationState) -> None:
        self.observer.on_trigger(TriggerState(
            request_id=int(msg.request_id), index=int(msg.index_in_request),
            count=int(msg.count_in_request), intensities=np.asarray(msg.intensities),
            stamp_ns=stamp_to_ns(msg.header.stamp), sequence=int(msg.sequence),
            arrival_ns=self.get_clock().now().nanoseconds, source=msg.header.frame_id))

    def _on_observed(self, result) -> None:
        self._publish_result(result)
        self.get_logger().info(f'classified an observed sequence: {result.label} '
                               f'({result.images_used} images, compute {result.compute_ms:.1f} ms)')

    def _publish_result(self, result) -> None:
        msg = ClassificationResult()
        msg.header.stamp = ns_to_stamp(result.first_stamp_ns)
        _fill(msg, result)
        msg.sequences = [int(s) for s in result.sequences]
        self._result_readers.wait()
        self._result_pub.publish(msg)


def _fill(msg, result) -> None:
    """The answer's fields a Classify response and a ClassificationResult share."""
    msg.label = result.label
    msg.class_names = list(result.class_names)
    msg.scores = [float(s) for s in result.scores]
    msg.images_used = int(result.images_used)
    msg.acquisition_ms = float(result.acquisition_ms)
    msg.compute_ms = float(result.compute_ms)
    msg.probabilities = [float(p) for p in result.probabilities]
    msg.decision = str(result.decision)
    msg.novelty = float(result.novelty)
    msg.images_budget = int(result.images_budget or result.images_used)
    msg.calibrated = bool(result.calibrated)


def main(argv: list[str] | None = None) -> int:
    init_node(sys.argv if argv is None else argv)
    return spin_until_stopped(ClassifierNode())


if __name__ == '__main__':
    sys.exit(main())
