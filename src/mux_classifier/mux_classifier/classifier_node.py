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

The service handler blocks while it waits for the driver and the images, so the node runs
in a MultiThreadedExecutor with one ReentrantCallbackGroup: images and the driver's reply
are handled by other threads meanwhile.
"""
from __future__ import annotations

import sys
import threading
import time
import traceback

import numpy as np
from lightstage_graph.errors import StageError
from lightstage_graph.names import (CAMERA_NODE, CLASSIFIER_NODE, CLASSIFY_SERVICE,
                                    ILLUMINATION_TOPIC, RESULT_TOPIC)
from lightstage_graph.params import boolean, declare_parameters, floating, integer, string
from lightstage_graph.qos import ILLUMINATION_QOS
from lightstage_graph.spin import init_node, spin_until_stopped
from lightstage_graph.stage_client import StageClient
from lightstage_graph.stamps import ns_to_stamp, stamp_to_ns
from lightstage_interfaces.msg import ClassificationResult, IlluminationState
from lightstage_interfaces.srv import Classify
from rcl_interfaces.msg import SetParametersResult
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from rclpy.qos import qos_profile_services_default
from rclpy.service_introspection import ServiceIntrospectionState

from .classify_request import TIMEOUT_MAX_S, TIMEOUT_MIN_S, request_timeout_s
from .inference import AcquisitionPlan, classify_on_stage
from .artifact import ArtifactError, TrainedArtifact, check_dimmer
from .observe import SequenceObserver, TriggerState

START_HINT = 'lightstage up driver camera classifier'
CAMERA_QUERY_S = 2.0  # the camera's parameter service answers in ms when the camera is up

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
        self._load_artifact(self.p('artifact_path'))
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._busy = threading.Lock()  # one classification at a time: they share the stage
        self._camera_answers = True  # until a parameter query of the camera goes unanswered
        group = ReentrantCallbackGroup()
        self.stage = StageClient(self, image_buffer=self.p('image_buffer'), callback_group=group,
                                 start_hint=START_HINT, camera_node=self.p('camera_node'))
        self._result_pub = self.create_publisher(ClassificationResult, RESULT_TOPIC, 10)
        service = self.create_service(Classify, CLASSIFY_SERVICE, self._on_classify,
                                      callback_group=group)
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
            self.create_subscription(IlluminationState, ILLUMINATION_TOPIC, self._on_illumination,
                                     ILLUMINATION_QOS, callback_group=group)

    def destroy_node(self) -> None:
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
        except Exception as exc:  # noqa: BLE001 - last resort: a bad file never takes the node down
            raise ArtifactError(f'{path!r} cannot be used as a classifier ({type(exc).__name__}: '
                                f'{exc}); retrain to get a new file') from exc
        return artifact

    def _use(self, path: str, artifact: TrainedArtifact) -> None:
        self.artifact, self.artifact_error = artifact, ''
        self.get_logger().info(f'loaded {path}: {artifact.describe()}')

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
        trained with (a real camera has no dimmer). A camera node that does not answer is not
        refused here: without it the images are missed, with their own error. After one miss
        the query waits briefly, so a camera without parameter services costs no latency."""
        if not self._camera_answers:
            timeout_s = min(timeout_s, 0.1)
        settings = self.stage.camera_parameters(('backend', 'dimmer'), timeout_s)
        if settings is None:
            if self._camera_answers:
                self.get_logger().warning(
                    f'the camera node {self.p("camera_node")!r} did not answer a parameter '
                    f'query within {timeout_s:g} s: its dimmer is not checked against the '
                    'classifier\'s')
            self._camera_answers = False
            return
        self._camera_answers = True
        if settings.get('backend') == 'sim' and 'dimmer' in settings:
            check_dimmer(artifact.dimmer, settings['dimmer'])

    # ------------------------------------------------------------------ service
    def _on_classify(self, request: Classify.Request, response: Classify.Response):
        try:
            return self._classify(request, response)
        except Exception as exc:  # noqa: BLE001 - last resort: the service answers every request
            self.get_logger().error(f'classify failed unexpectedly: {traceback.format_exc()}')
            return Classify.Response(
                success=False, message=f'the classifier failed unexpectedly ({type(exc).__name__}: '
                                       f'{exc}); this is a bug: report it with the node\'s log')

    def _classify(self, request: Classify.Request, response: Classify.Response):
        response.success = False
        try:
            timeout_s = request_timeout_s(request.timeout_s, self.p('timeout_s'))
        except ValueError as exc:
            response.message = str(exc)
            return response
        artifact = self.artifact
        if artifact is None:
            response.message = self.artifact_error
            return response
        start = time.monotonic()
        busy = (f'another classification kept the stage busy for {timeout_s:g} s (this '
                'request\'s time limit); try again, or give a longer timeout_s')
        if not self._busy.acquire(timeout=timeout_s):
            response.message = busy
            return response
        try:
            remaining_s = timeout_s - (time.monotonic() - start)
            if remaining_s <= 0:
                response.message = busy
                return response
            self._check_camera(artifact, min(CAMERA_QUERY_S, remaining_s))
            result = classify_on_stage(artifact, self._apply, self.stage.matcher,
                                       max_images=request.max_images, timeout_s=remaining_s,
                                       bit_depth=self.p('camera_bit_depth'))
        except (StageError, ArtifactError) as exc:  # InferenceError, MissingImagesError, DimmerMismatch
            response.message = str(exc)
            self.get_logger().warning(f'classify failed: {exc}')
            return response
        finally:
            self._busy.release()
        response.success = True
        response.message = f'{result.label} from {result.images_used} images'
        response.label = result.label
        response.class_names = list(result.class_names)
        response.scores = [float(s) for s in result.scores]
        response.images_used = result.images_used
        response.acquisition_ms = float(result.acquisition_ms)
        response.compute_ms = float(result.compute_ms)
        self._publish_result(result)
        self.get_logger().info(f'classified: {result.label} ({result.images_used} images, '
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
        msg.label = result.label
        msg.class_names = list(result.class_names)
        msg.scores = [float(s) for s in result.scores]
        msg.images_used = result.images_used
        msg.sequences = [int(s) for s in result.sequences]
        msg.acquisition_ms = float(result.acquisition_ms)
        msg.compute_ms = float(result.compute_ms)
        self._result_pub.publish(msg)


def main(argv: list[str] | None = None) -> int:
    init_node(sys.argv if argv is None else argv)
    return spin_until_stopped(ClassifierNode(), MultiThreadedExecutor(num_threads=4))


if __name__ == '__main__':
    sys.exit(main())
