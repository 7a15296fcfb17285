"""The stage as one client: light LED patterns through the driver, one camera trigger each,
and collect the camera frames of those triggers, matched by stamp (`frames.ImageMatcher`); a
frame the camera reports lost (camera/frame_lost) ends the collection at once with its reason.

The classifier and the acquisition node both drive the stage this way:

    self.stage = StageClient(self, image_buffer=64, callback_group=group,
                             start_hint='lightstage up driver camera classifier')
    self.stage.wait_ready(timeout_s)                       # driver service + camera publisher
    stamps, sequences = self.stage.apply(patterns, exposure_us, gain_db, timeout_s)
    frames = self.stage.grab(patterns, exposure_us, gain_db, timeout_s)  # apply + collect
    settings = self.stage.camera_parameters(('backend', 'dimmer'), timeout_s)  # or None

Calls block (they wait for the driver's reply and the images): make them from a thread that
is not one of the executor's (a worker, or an executor with threads to spare), with the
node spun by a multi-threaded executor; the clients go in the `callback_group` given (a
reentrant one). The image and lost-frame subscriptions have a mutually exclusive group of
their own: images are handled one at a time, in the order they arrive, which is what lets
`ImageMatcher.collect(..., since_ns=...)` tell from a later image that a missing one will
not come (the classifier's observing mode). Every failure is a
`StageError` saying which part of the stage is missing or failed and what to do.
"""
from __future__ import annotations

import threading
import time

import numpy as np
from lightstage_interfaces.msg import FrameLost, Pattern
from lightstage_interfaces.srv import ApplyPatterns
from rcl_interfaces.msg import ParameterType
from rcl_interfaces.srv import GetParameters
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.qos import QoSProfile
from rclpy.parameter import parameter_value_to_python
from sensor_msgs.msg import Image

from .errors import StageError
from .frames import ImageMatcher
from .limits import gain_db_fields
from .names import APPLY_PATTERNS_SERVICE, CAMERA_NODE, FRAME_LOST_TOPIC, IMAGE_TOPIC
from .qos import IMAGE_QOS, service_client
from .stamps import stamp_to_ns


class StageClient:
    def __init__(self, node, *, image_buffer: int, callback_group=None, start_hint: str = '',
                 camera_node: str = CAMERA_NODE):
        self.matcher = ImageMatcher(image_buffer, clock=lambda: node.get_clock().now().nanoseconds)
        self._start = f'`{start_hint}`' if start_hint else 'the driver and the camera'
        self._apply_client = service_client(node, ApplyPatterns, APPLY_PATTERNS_SERVICE,
                                             callback_group=callback_group)
        images = MutuallyExclusiveCallbackGroup()  # in arrival order, one at a time
        # the reader keeps up to image_buffer images the executor has not taken yet (IMAGE_QOS's
        # 32 is one sequence): a node held up for a moment loses none (depth is not matched
        # against the publisher's; unused depth costs nothing)
        depth = max(IMAGE_QOS.depth, int(image_buffer))
        self._image_sub = node.create_subscription(
            Image, IMAGE_TOPIC, self.matcher.add_message,
            QoSProfile(history=IMAGE_QOS.history, depth=depth, reliability=IMAGE_QOS.reliability,
                       durability=IMAGE_QOS.durability), callback_group=images)
        # the camera's notice that a trigger's frame will not come: `collect` fails at once
        self._lost_sub = node.create_subscription(FrameLost, FRAME_LOST_TOPIC,
                                                  self.matcher.add_lost_message, IMAGE_QOS,
                                                  callback_group=images)
        self._camera_params = service_client(node, GetParameters, f'{camera_node}/get_parameters',
                                              callback_group=callback_group)

    def wait_ready(self, timeout_s: float) -> None:
        """Driver service and camera publisher present within `timeout_s`, or StageError."""
        deadline = time.monotonic() + timeout_s
        if not self._apply_client.wait_for_service(timeout_sec=timeout_s):
            raise StageError(
                f'the light stage driver\'s service {APPLY_PATTERNS_SERVICE} is not available '
                f'(waited {timeout_s:g} s); start the driver, e.g. {self._start}, and check '
                'its /diagnostics')
        # Images published before the camera's publisher has matched this subscription are
        # lost (reliable, volatile): right after start-up, wait for the match, not the graph.
        while self._image_sub.get_publisher_count() == 0:
            if time.monotonic() >= deadline:
                raise StageError(f'no camera is publishing {IMAGE_TOPIC} to this node; start the '
                                 f'camera ({self._start}) and check its /diagnostics')
            time.sleep(0.01)

    def apply(self, led_patterns: np.ndarray, exposure_us: int, gain_db: float,
              timeout_s: float) -> tuple[list[int], list[int]]:
        """Light the columns of `led_patterns` (32, k), one trigger each; the trigger stamps
        (ns) and sequence numbers the driver reports, within `timeout_s`."""
        patterns = np.asarray(led_patterns, dtype=np.float32)
        k = patterns.shape[1]
        request = ApplyPatterns.Request(trigger=True)
        for column in patterns.T:
            request.patterns.append(Pattern(intensities=column, exposure_us=int(exposure_us),
                                            **gain_db_fields(gain_db)))
        done = threading.Event()
        future = self._apply_client.call_async(request)
        future.add_done_callback(lambda _f: done.set())
        if not done.wait(max(0.0, timeout_s)):
            self._apply_client.remove_pending_request(future)
            raise StageError(f'the driver did not answer {APPLY_PATTERNS_SERVICE} within '
                             f'{timeout_s:g} s ({k} patterns); is it running? check its log and '
                             '/diagnostics')
        response = future.result()
        if response is None or not response.success:
            reason = response.message if response is not None else future.exception()
            raise StageError(f'the driver did not apply the patterns: {reason}')
        stamps = [stamp_to_ns(t) for t in response.trigger_stamps]
        if len(stamps) != k:
            raise StageError(f'asked for {k} triggers but the driver reported {len(stamps)}; '
                             'check the driver\'s log')
        return stamps, [int(s) for s in response.sequences]

    def grab(self, led_patterns: np.ndarray, exposure_us: int, gain_db: float,
             timeout_s: float) -> list[np.ndarray]:
        """`apply`, then the k mono16 frames of those triggers in pattern order; `timeout_s`
        bounds each of the two waits."""
        stamps, sequences = self.apply(led_patterns, exposure_us, gain_db, timeout_s)
        frames, _ = self.matcher.collect(stamps, timeout_s, sequences)
        return frames

    def camera_parameters(self, names, timeout_s: float) -> dict | None:
        """The camera node's current values of `names` ({name: value}; a name the camera does
        not declare is left out), or None if its parameter service did not answer within
        `timeout_s`: a check that needs them then cannot be made."""
        if not self._camera_params.wait_for_service(timeout_sec=max(0.0, timeout_s)):
            return None
        done = threading.Event()
        future = self._camera_params.call_async(GetParameters.Request(names=list(names)))
        future.add_done_callback(lambda _f: done.set())
        if not done.wait(max(0.0, timeout_s)) or future.result() is None:
            self._camera_params.remove_pending_request(future)
            return None
        return {name: parameter_value_to_python(value)
                for name, value in zip(names, future.result().values)
                if value.type != ParameterType.PARAMETER_NOT_SET}
