"""`lightstage web`'s ROS side: a node that hands what the graph says to the page's
`PageState` and serves the page's calls (Classify, CaptureModel, CalibrateNoise) to the graph.

rclpy spins in a thread of its own; the web server (`web_app`, aiohttp) runs on the asyncio
loop of the main thread. rclpy futures are handed to the loop with `call_soon_threadsafe`.
Started by `web_cli.main` after the ROS environment is set (LOCALHOST discovery).

Every second the node looks at the graph: which of the stage's nodes are in it, the lifecycle
state of those that have one (the driver), and which action goals the acquisition node lists
as active; the page's state ages its diagnostics then too. A job's action server that stops
being there ends the job as failed (`lightstage_graph.goal_watch.ServerWatch`, the rule the
CLI uses too).
"""
from __future__ import annotations

import asyncio
import math
import threading
import time

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from lightstage_graph.frames import image_from_buffer
from lightstage_graph.limits import gain_db_fields
from lightstage_graph.names import (CALIBRATE_ACTION, CAPTURE_ACTION, CLASSIFY_SERVICE,
                                    DIAGNOSTICS_TOPIC, FRAME_LOST_TOPIC, ILLUMINATION_TOPIC,
                                    IMAGE_TOPIC, RESULT_TOPIC)
from lightstage_graph.qos import ILLUMINATION_QOS, IMAGE_QOS, service_client
from lightstage_graph.stamps import stamp_to_ns
from lightstage_interfaces.action import CalibrateNoise, CaptureModel
from lightstage_interfaces.msg import ClassificationResult, FrameLost, IlluminationState
from lightstage_interfaces.srv import Classify
from rclpy.action import ActionClient
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from sensor_msgs.msg import Image

from lightstage_bringup.web_app import GraphUnavailable
from lightstage_graph.goal_watch import ServerWatch
from lightstage_bringup.web_state import (Illumination, PageState, calibrate_progress,
                                          capture_progress)

WEB_NODE = 'web'
GOAL_ANSWER_S = 10.0   # an action server answers a goal (accept / refuse) within this
CANCEL_ANSWER_S = 10.0  # ... and a cancel request within this
STATE_ANSWER_S = 3.0   # a lifecycle node answers get_state within this, or is asked again
SERVER_GRACE_S = 3.0   # a job's action server gone for longer than this: the job failed
WATCHED_NODES = ('driver', 'camera', 'classifier', 'acquisition')
ACTIVATABLE = ('driver',)   # lifecycle nodes the page may configure + activate (arming the
                            # stage's link: no light until a pattern is asked for)
LIFECYCLE_STATES = {1: 'unconfigured', 2: 'inactive', 3: 'active', 4: 'finalized'}
# the acquisition node's settings a goal field of 0 / null stands for, shown on the page
ACQUISITION_DEFAULTS = ('exposure_us', 'gain_db', 'frames_averaged', 'calibration_exposure_us',
                        'calibration_gain_db', 'calibration_frames', 'calibration_levels')
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
        self.classify_client = service_client(self, Classify, CLASSIFY_SERVICE)
        self.actions = {kind: (ActionClient(self, action, name), action, name) for kind, action, name in
                        (('capture', CaptureModel, CAPTURE_ACTION),
                         ('calibrate', CalibrateNoise, CALIBRATE_ACTION))}
        self._goal_handle = None
        self.server_ready = {kind: False for kind in self.actions}
        self._active_goals: dict[str, list[str]] = {kind: [] for kind in self.actions}
        from action_msgs.msg import GoalStatusArray
        from action_msgs.srv import CancelGoal
        from lifecycle_msgs.srv import ChangeState, GetState
        from rclpy.qos import qos_profile_action_status_default
        self._cancel_clients = {}
        for kind, (_, _, name) in self.actions.items():
            self.create_subscription(GoalStatusArray, f'{name}/_action/status',
                                     lambda msg, kind=kind: self._on_status(kind, msg),
                                     qos_profile_action_status_default)
            self._cancel_clients[kind] = service_client(self, CancelGoal, f'{name}/_action/cancel_goal')
        self._lifecycle = {name: (service_client(self, GetState, f'/{name}/get_state'),
                                  service_client(self, ChangeState, f'/{name}/change_state'))
                           for name in WATCHED_NODES}
        self._state_pending: dict[str, object] = {}
        from rcl_interfaces.srv import GetParameters
        self._acquisition_params = service_client(self, GetParameters, '/acquisition/get_parameters')
        self._defaults_pending = None
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
                              'probabilities': json_safe([float(p) for p in msg.probabilities]),
                              'decision': msg.decision,
                              'novelty': json_safe(float(msg.novelty)),
                              'images_budget': int(msg.images_budget),
                              'calibrated': bool(msg.calibrated),
                              'stamp_ns': stamp_to_ns(msg.header.stamp)})

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        self.state.on_diagnostics([
            {'name': s.name, 'level': _level(s.level), 'message': s.message,
             'hardware_id': s.hardware_id, 'values': {kv.key: kv.value for kv in s.values}}
            for s in msg.status])

    def _on_status(self, kind: str, msg) -> None:
        from action_msgs.msg import GoalStatus
        active = (GoalStatus.STATUS_ACCEPTED, GoalStatus.STATUS_EXECUTING, GoalStatus.STATUS_CANCELING)
        self._active_goals[kind] = [bytes(s.goal_info.goal_id.uuid).hex() for s in msg.status_list
                                    if s.status in active]

    def _check_links(self) -> None:
        self.state.set_connected('classify', self.classify_client.service_is_ready())
        for kind, (client, _, _) in self.actions.items():
            ready = client.server_is_ready()
            self.server_ready[kind] = ready
            self.state.set_connected(kind, ready)
            self.state.on_active_goals(kind, self._active_goals[kind] if ready else [])
        # a publisher matched, not only seen in the graph: what it sends from now on arrives
        for kind, subscription in self.inputs.items():
            self.state.set_connected(kind, subscription.get_publisher_count() > 0)
        self._check_nodes()
        self.state.tick()

    def _check_nodes(self) -> None:
        """Each stage node in the graph or not; a lifecycle node's state asked each second."""
        from lifecycle_msgs.srv import GetState
        present = {name for name, namespace in self.get_node_names_and_namespaces()
                   if namespace == '/'}
        if 'acquisition' not in present:
            self._defaults_pending = None
        elif self._defaults_pending is None and self._acquisition_params.service_is_ready():
            self._ask_defaults()
        for name in WATCHED_NODES:
            get_state = self._lifecycle[name][0]
            pending = self._state_pending.get(name)
            if pending is not None and not pending[0].done():
                if name in present and time.monotonic() - pending[1] < STATE_ANSWER_S:
                    continue
                get_state.remove_pending_request(pending[0])   # a node gone mid-call answers never
                if name in present:   # there but silent (frozen, or its executor stuck)
                    self.state.set_node(name, 'not answering', lifecycle=True)
            self._state_pending.pop(name, None)
            if name not in present:
                self.state.set_node(name, 'stopped')
                continue
            if not get_state.service_is_ready():
                self.state.set_node(name, 'running')
                continue
            future = get_state.call_async(GetState.Request())
            self._state_pending[name] = (future, time.monotonic())

            def answered(done, name=name):
                if done.exception() is None and done.result() is not None:
                    label = LIFECYCLE_STATES.get(done.result().current_state.id,
                                                 done.result().current_state.label)
                    self.state.set_node(name, label, lifecycle=True)
            future.add_done_callback(answered)

    def _ask_defaults(self) -> None:
        """The acquisition node's settings (asked once each time it appears)."""
        from rcl_interfaces.srv import GetParameters
        future = self._acquisition_params.call_async(GetParameters.Request(names=list(ACQUISITION_DEFAULTS)))
        self._defaults_pending = future

        def answered(done):
            if done.exception() is not None or done.result() is None:
                self._defaults_pending = None   # asked again next second
                return
            values = {}
            for name, value in zip(ACQUISITION_DEFAULTS, done.result().values):
                got = {2: value.integer_value, 3: value.double_value}.get(value.type)
                if got is not None:
                    values[name] = got
            self.state.set_defaults(values)
        future.add_done_callback(answered)

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
        self.state.update_job(job, state='running', goal_id=bytes(handle.goal_id.uuid).hex())
        asyncio.get_running_loop().create_task(self._finish(job, handle))

    async def _server_lost(self, kind: str) -> float:
        """Returns once the action server of `kind` has been gone past SERVER_GRACE_S: how
        long it has been gone [s]."""
        watch = ServerWatch(grace_s=SERVER_GRACE_S)
        while not watch.observe(self.server_ready[kind]):
            await asyncio.sleep(0.25)
        return watch.lost_for_s

    async def _finish(self, job, handle) -> None:
        from action_msgs.msg import GoalStatus
        name = self.actions[job.kind][2]
        result = self._awaitable(handle.get_result_async())
        lost = asyncio.ensure_future(self._server_lost(job.kind))
        try:
            await asyncio.wait({result, lost}, return_when=asyncio.FIRST_COMPLETED)
            if not result.done():
                result.cancel()
                self.state.update_job(job, state='failed',
                                      message=f'{name} went away during the {job.kind} (gone for '
                                              f'{lost.result():.1f} s): the node stopped or crashed; '
                                              f'start it again and start the {job.kind} again')
                return
            answer = result.result()
        except Exception as exc:  # noqa: BLE001 (the job says what happened, the page goes on)
            self.state.update_job(job, state='failed', message=f'no result: {exc}')
            return
        finally:
            lost.cancel()
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
        """Ask the node to cancel the running job (this page's, or one it found running). The
        job then ends when the node says so, or fails when the node is gone."""
        from action_msgs.srv import CancelGoal
        from unique_identifier_msgs.msg import UUID
        job, handle = self.state.running_job(), self._goal_handle
        if job is None:
            return False
        if job.known and handle is None:
            return False   # not yet accepted: nothing to cancel on the node
        self.state.update_job(job, state='cancelling')
        if job.known:
            future = handle.cancel_goal_async()
        else:
            request = CancelGoal.Request()
            request.goal_info.goal_id = UUID(uuid=list(bytes.fromhex(job.goal_id)))
            future = self._cancel_clients[job.kind].call_async(request)
        try:
            await asyncio.wait_for(self._awaitable(future), CANCEL_ANSWER_S)
        except asyncio.TimeoutError:
            if job.state == 'cancelling':
                self.state.update_job(job, state='running', message=f'the node did not answer the '
                                      f'cancel request in {CANCEL_ANSWER_S:g} s; it goes on')
        return True

    async def activate(self, node: str) -> str:
        """Configure (if unconfigured) and activate the lifecycle node `node`; its state after."""
        from lifecycle_msgs.msg import Transition
        from lifecycle_msgs.srv import ChangeState, GetState
        from lightstage_bringup.web_state import RequestError
        if node not in ACTIVATABLE:
            raise RequestError(f'the page activates only {", ".join(ACTIVATABLE)}; not {node!r}',
                               status=404)
        get_state, change_state = self._lifecycle[node]
        if not get_state.service_is_ready():
            raise GraphUnavailable(f'the {node} node is not running (ROS_DOMAIN_ID='
                                   f'{self.context.get_domain_id()}); start it with `lightstage up '
                                   f'{node}` in the same domain')

        async def current() -> str:
            answer = await asyncio.wait_for(self._awaitable(get_state.call_async(GetState.Request())), 10.0)
            return LIFECYCLE_STATES.get(answer.current_state.id, answer.current_state.label)

        steps = {'unconfigured': (Transition.TRANSITION_CONFIGURE, 'configure'),
                 'inactive': (Transition.TRANSITION_ACTIVATE, 'activate')}
        now = await current()
        while now in steps:
            transition, word = steps[now]
            answer = await asyncio.wait_for(self._awaitable(change_state.call_async(
                ChangeState.Request(transition=Transition(id=transition)))), 30.0)
            after = await current()
            if not answer.success or after == now:
                raise RequestError(f'the {node} node refused to {word} (it is {after}); its '
                                   f'/diagnostics say why', status=409)
            now = after
        self.state.set_node(node, now, lifecycle=True)
        if now != 'active':
            raise RequestError(f'the {node} node is {now}: it cannot be activated from there; '
                               f'restart it', status=409)
        return now


def spin_in_thread(node: Node) -> tuple[SingleThreadedExecutor, threading.Thread]:
    executor = SingleThreadedExecutor()
    executor.add_node(node)

    def spin():
        try:
            executor.spin()
        except Exception:  # shutting down: the context went away under the spin
            if rclpy.ok():
                raise

    thread = threading.Thread(target=spin, name='rclpy', daemon=True)
    thread.start()
    return executor, thread
