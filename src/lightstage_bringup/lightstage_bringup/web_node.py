"""`lightstage web`'s ROS side: a node that hands what the graph says to the page's
`PageState` and serves the page's calls (Classify, CaptureModel, CalibrateNoise) to the graph.

rclpy spins in a thread of its own; the web server (`web_app`, aiohttp) runs on the asyncio
loop of the main thread. rclpy futures are handed to the loop with `call_soon_threadsafe`.
Started by `web_cli.main` after the ROS environment is set (LOCALHOST discovery).
"""
from __future__ import annotations

import asyncio
import math
import threading

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from lightstage_graph.frames import image_from_buffer
from lightstage_graph.limits import gain_db_fields
from lightstage_graph.names import (CALIBRATE_ACTION, CAPTURE_ACTION, CLASSIFY_SERVICE,
                                    DIAGNOSTICS_TOPIC, FRAME_LOST_TOPIC, ILLUMINATION_TOPIC,
                                    IMAGE_TOPIC, RESULT_TOPIC)
from lightstage_graph.qos import ILLUMINATION_QOS, IMAGE_QOS
from lightstage_graph.stamps import stamp_to_ns
from lightstage_interfaces.action import CalibrateNoise, CaptureModel
from lightstage_interfaces.msg import ClassificationResult, FrameLost, IlluminationState
from lightstage_interfaces.srv import Classify
from rclpy.action import ActionClient
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from sensor_msgs.msg import Image

from lightstage_bringup.web_app import GraphUnavailable
from lightstage_bringup.web_state import (Illumination, PageState, calibrate_progress,
                                          capture_progress)

WEB_NODE = 'web'
GOAL_ANSWER_S = 10.0   # an action server answers a goal (accept / refuse) within this
START_HINT = {'classify': 'start it with `lightstage up driver camera classifier`',
              'capture': 'start it with `lightstage up driver camera acquisition`',
              'calibrate': 'start it with `lightstage up driver camera acquisition`'}


def json_safe(value):
    """Message field values as JSON takes them (NaN / inf -> None, arrays -> lists)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, (list, tuple)) or hasattr(value, 'tolist'):
        return [json_safe(v) for v in (value.tolist() if hasattr(value, 'tolist') else value)]
    return value


def message_dict(msg) -> dict:
    return {name: json_safe(getattr(msg, name)) for name in msg.get_fields_and_field_types()}


def _level(level) -> int:
    """DiagnosticStatus.level is a ROS byte: bytes of length 1 in rclpy."""
    return level[0] if isinstance(level, (bytes, bytearray)) else int(level)


class WebBridge(Node):
    """The page's participant in the graph."""

    def __init__(self, state: PageState, node_name: str = WEB_NODE, **kwargs):
        super().__init__(node_name, **kwargs)
        self.state = state
        self.loop: asyncio.AbstractEventLoop | None = None
        # the two inputs a classification's pictures need, shown as links once matched
        self.inputs = {
            'driver': self.create_subscription(IlluminationState, ILLUMINATION_TOPIC,
                                               self._on_illumination, ILLUMINATION_QOS),
            'camera': self.create_subscription(Image, IMAGE_TOPIC, self._on_image, IMAGE_QOS)}
        self.create_subscription(FrameLost, FRAME_LOST_TOPIC, self._on_frame_lost, IMAGE_QOS)
        self.create_subscription(ClassificationResult, RESULT_TOPIC, self._on_result, 10)
        self.create_subscription(DiagnosticArray, DIAGNOSTICS_TOPIC, self._on_diagnostics, 10)
        self.classify_client = self.create_client(Classify, CLASSIFY_SERVICE)
        self.actions = {kind: (ActionClient(self, action, name), action, name) for kind, action, name in
                        (('capture', CaptureModel, CAPTURE_ACTION),
                         ('calibrate', CalibrateNoise, CALIBRATE_ACTION))}
        self._goal_handle = None
        self.create_timer(1.0, self._check_links)

    # ------------------------------------------------------------------ graph -> page
    def _on_illumination(self, msg: IlluminationState) -> None:
        self.state.on_illumination(Illumination(
            int(msg.sequence), stamp_to_ns(msg.header.stamp), int(msg.request_id),
            int(msg.index_in_request), int(msg.count_in_request),
            [float(v) for v in msg.intensities], int(msg.exposure_us), float(msg.gain_db)))

    def _on_image(self, msg: Image) -> None:
        try:
            pixels = image_from_buffer(msg.data, msg.height, msg.width, msg.step, msg.encoding,
                                       bool(msg.is_bigendian))
        except ValueError as exc:
            self.state.event('error', 'camera', f'image not shown: {exc}')
            return
        self.state.on_image(stamp_to_ns(msg.header.stamp), pixels)

    def _on_frame_lost(self, msg: FrameLost) -> None:
        self.state.on_frame_lost(int(msg.sequence), stamp_to_ns(msg.header.stamp), msg.reason)

    def _on_result(self, msg: ClassificationResult) -> None:
        self.state.on_result({'label': msg.label, 'class_names': list(msg.class_names),
                              'scores': json_safe([float(s) for s in msg.scores]),
                              'images_used': int(msg.images_used),
                              'sequences': [int(s) for s in msg.sequences],
                              'acquisition_ms': float(msg.acquisition_ms),
                              'compute_ms': float(msg.compute_ms),
                              'stamp_ns': stamp_to_ns(msg.header.stamp)})

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        self.state.on_diagnostics([
            {'name': s.name, 'level': _level(s.level), 'message': s.message,
             'hardware_id': s.hardware_id, 'values': {kv.key: kv.value for kv in s.values}}
            for s in msg.status])

    def _check_links(self) -> None:
        self.state.set_connected('classify', self.classify_client.service_is_ready())
        for kind, (client, _, _) in self.actions.items():
            self.state.set_connected(kind, client.server_is_ready())
        # a publisher matched, not only seen in the graph: what it sends from now on arrives
        for kind, subscription in self.inputs.items():
            self.state.set_connected(kind, subscription.get_publisher_count() > 0)

    # ------------------------------------------------------------------ page -> graph
    def _awaitable(self, future) -> asyncio.Future:
        """An rclpy future as an asyncio future of this loop."""
        loop = self.loop
        result = loop.create_future()

        def settle(done):
            if result.done():
                return
            exc = done.exception()
            if exc is not None:
                result.set_exception(exc)
            else:
                result.set_result(done.result())

        future.add_done_callback(lambda done: loop.call_soon_threadsafe(settle, done))
        return result

    def _unavailable(self, what: str, name: str, kind: str) -> GraphUnavailable:
        return GraphUnavailable(f'the {what} {name} is not available '
                                f'(ROS_DOMAIN_ID={self.context.get_domain_id()}); '
                                f'{START_HINT[kind]} in the same domain')

    async def classify(self, max_images: int, timeout_s: float) -> dict:
        from mux_classifier.classify_request import TIMEOUT_MAX_S
        if not self.classify_client.service_is_ready():
            raise self._unavailable('service', CLASSIFY_SERVICE, 'classify')
        future = self.classify_client.call_async(Classify.Request(max_images=max_images,
                                                                  timeout_s=timeout_s))
        limit_s = (timeout_s if timeout_s > 0 else TIMEOUT_MAX_S) + 5.0
        try:
            r = await asyncio.wait_for(self._awaitable(future), limit_s)
        except asyncio.TimeoutError:
            self.classify_client.remove_pending_request(future)
            return {'success': False, 'message': f'no answer from {CLASSIFY_SERVICE} within '
                                                 f'{limit_s:g} s', 'label': '', 'class_names': [],
                    'scores': [], 'images_used': 0, 'acquisition_ms': 0.0, 'compute_ms': 0.0}
        return message_dict(r)

    async def start_job(self, kind: str, goal: dict) -> None:
        client, action, name = self.actions[kind]
        if not client.server_is_ready():
            raise self._unavailable('action', name, kind)
        job = self.state.start_job(kind, goal)   # refuses a second one (409)
        fields = {**{k: (math.nan if v is None else v) for k, v in goal.items()},
                  **gain_db_fields(goal['gain_db'])}
        progress = capture_progress if kind == 'capture' else calibrate_progress

        def on_feedback(message):
            f = message.feedback
            text, fraction = progress(**{k: getattr(f, k) for k in f.get_fields_and_field_types()})
            self.state.update_job(job, progress=text, fraction=fraction)

        send = client.send_goal_async(action.Goal(**fields), feedback_callback=on_feedback)
        try:
            handle = await asyncio.wait_for(self._awaitable(send), GOAL_ANSWER_S)
        except asyncio.TimeoutError:
            self.state.update_job(job, state='failed',
                                  message=f'{name} did not answer the goal in '
                                          f'{GOAL_ANSWER_S:g} s')
            return
        if not handle.accepted:
            self.state.update_job(job, state='failed',
                                  message=f'{name} refused the goal: another capture '
                                          'or calibration is running on the stage; try again when '
                                          'it is done')
            return
        self._goal_handle = handle
        self.state.update_job(job, state='running')
        asyncio.get_running_loop().create_task(self._finish(job, handle))

    async def _finish(self, job, handle) -> None:
        from action_msgs.msg import GoalStatus
        try:
            answer = await self._awaitable(handle.get_result_async())
        except Exception as exc:  # noqa: BLE001 (the job says what happened, the page goes on)
            self.state.update_job(job, state='failed', message=f'no result: {exc}')
            return
        finally:
            self._goal_handle = None
        states = {GoalStatus.STATUS_SUCCEEDED: 'succeeded', GoalStatus.STATUS_CANCELED: 'canceled'}
        result = message_dict(answer.result)
        done = answer.status == GoalStatus.STATUS_SUCCEEDED
        self.state.update_job(job, state=states.get(answer.status, 'failed'),
                              message=result.get('message', ''), result=result,
                              # a failed job keeps where it stopped
                              progress='' if done else job.progress,
                              fraction=1.0 if done else job.fraction)

    async def cancel_job(self) -> bool:
        job, handle = self.state.running_job(), self._goal_handle
        if job is None or handle is None:
            return False
        self.state.update_job(job, state='cancelling')
        await self._awaitable(handle.cancel_goal_async())
        return True


def spin_in_thread(node: Node) -> tuple[SingleThreadedExecutor, threading.Thread]:
    executor = SingleThreadedExecutor()
    executor.add_node(node)

    def spin():
        try:
            executor.spin()
        except Exception:  # noqa: BLE001 (shutting down: the context went away under the spin)
            if rclpy.ok():
                raise

    thread = threading.Thread(target=spin, name='rclpy', daemon=True)
    thread.start()
    return executor, thread
