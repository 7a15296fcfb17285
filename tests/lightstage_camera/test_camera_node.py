"""The camera node in this process: stamped frames per trigger, run-time samples, error state."""
import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticStatus
from lightstage_camera.sim_camera import SimCamera

from helpers.suite import fresh_domain_id

pytestmark = [pytest.mark.ros, pytest.mark.process]
OK, ERROR = DiagnosticStatus.OK, DiagnosticStatus.ERROR


class CameraHarness:
    """A CameraNode and a test node (publishing /illumination, listening to camera/image_raw,
    camera/frame_lost and
    /diagnostics) in one context of their own."""

    def __init__(self, **params):
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from lightstage_camera.camera_node import CameraNode
        from lightstage_graph.names import FRAME_LOST_TOPIC, ILLUMINATION_TOPIC, IMAGE_TOPIC
        from lightstage_graph.qos import ILLUMINATION_QOS, IMAGE_QOS
        from lightstage_interfaces.msg import FrameLost, IlluminationState
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.parameter import Parameter
        from sensor_msgs.msg import Image
        self.context = Context()
        rclpy.init(context=self.context, domain_id=fresh_domain_id())
        overrides = [Parameter(k, value=v) for k, v in params.items()]
        self.camera = CameraNode(context=self.context, parameter_overrides=overrides)
        self.node = rclpy.create_node('camera_test', context=self.context)
        self.images, self.lost, self.diagnostics = [], [], []
        self.pub = self.node.create_publisher(IlluminationState, ILLUMINATION_TOPIC, ILLUMINATION_QOS)
        self.node.create_subscription(Image, IMAGE_TOPIC, self.images.append, IMAGE_QOS)
        self.node.create_subscription(FrameLost, FRAME_LOST_TOPIC, self.lost.append, IMAGE_QOS)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self.diagnostics.append, 10)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.camera)
        self.executor.add_node(self.node)
        self.spin_until(lambda: self.pub.get_subscription_count() > 0
                        and self.camera._image_pub.get_subscription_count() > 0
                        and self.camera._lost_pub.get_subscription_count() > 0)

    def spin_until(self, done, timeout_s=10.0):
        import time
        end = time.monotonic() + timeout_s
        while not done() and time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.02)
        return done()

    def trigger(self, sequence, stamp_ns, leds, exposure_us=22500, gain_db=17.5):
        from lightstage_interfaces.msg import IlluminationState
        msg = IlluminationState(sequence=sequence, exposure_us=exposure_us, gain_db=gain_db,
                                intensities=np.asarray(leds, np.float32))
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
        self.pub.publish(msg)

    def set(self, **values):
        from rclpy.parameter import Parameter
        return self.camera.set_parameters([Parameter(k, value=v) for k, v in values.items()])

    def last_status(self):
        self.diagnostics.clear()
        self.spin_until(lambda: self.diagnostics)
        return self.diagnostics[-1].status[0]

    def close(self):
        import rclpy
        self.camera.destroy_node()
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)


@pytest.fixture
def harness_factory():
    made = []

    def make(**params):
        made.append(CameraHarness(diagnostics_period_s=0.2, **params))
        return made[-1]

    yield make
    for h in made:
        h.close()


def test_one_mono16_frame_per_trigger_stamped_with_the_trigger(harness_factory, stage_capture,
                                                                stage_modelset):
    h = harness_factory(capture_dir=str(stage_capture), sample='banana-real/s0/p01', noise='none',
                        frame_id='stage_cam')
    reference = SimCamera(stage_modelset, sample='banana-real/s0/p01', noise='none')
    rng = np.random.default_rng(0)
    sent = []
    for i in range(3):
        leds = (rng.random(32) > 0.6).astype(np.float32)
        stamp = 1_763_000_000_000_000_000 + 7_919 * i
        h.trigger(40 + i, stamp, leds)
        sent.append((stamp, leds))
    assert h.spin_until(lambda: len(h.images) == 3)
    for (stamp, leds), msg in zip(sent, h.images):
        assert msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec == stamp
        assert msg.header.frame_id == 'stage_cam'
        assert (msg.encoding, msg.height, msg.width, msg.step) == ('mono16', 120, 120, 240)
        image = np.frombuffer(bytes(msg.data), '<u2').reshape(120, 120)
        np.testing.assert_array_equal(image, reference.capture(leds, 22500, 17.5))
    status = h.last_status()
    assert status.level == OK and 'banana-real/s0/p01' in status.message
    assert {kv.key: kv.value for kv in status.values}['images_published'] == '3'


def test_sample_changes_at_run_time_and_unknown_samples_are_rejected(harness_factory, stage_capture,
                                                                     stage_modelset):
    h = harness_factory(capture_dir=str(stage_capture), sample=0, noise='none')
    (ok,) = h.set(sample='orange-fake/s1/p02')
    assert ok.successful
    (bad,) = h.set(sample='orange-fake/s7/p02')
    assert not bad.successful and 'unknown sample' in bad.reason
    assert h.camera.get_parameter('sample').value == 'orange-fake/s1/p02'
    (bad_noise,) = h.set(noise='loud')
    assert not bad_noise.successful and 'unknown noise setting' in bad_noise.reason
    leds = np.ones(32, np.float32)
    h.trigger(1, 5_000_000_000, leds)
    assert h.spin_until(lambda: len(h.images) == 1)
    expected = SimCamera(stage_modelset, sample='orange-fake/s1/p02', noise='none').capture(leds, 22500)
    np.testing.assert_array_equal(np.frombuffer(bytes(h.images[0].data), '<u2').reshape(120, 120), expected)


def test_real_camera_parameters_are_refused_on_the_sim_backend_with_the_reason(harness_factory,
                                                                              stage_capture):
    """A GenICam setting on the sim camera was answered successful and ignored."""
    h = harness_factory(capture_dir=str(stage_capture), sample=0, noise='none')
    from rclpy.parameter import Parameter
    for values in ({'camera_features': 'ExposureAuto=Off'}, {'serial_number': '4711'},
                   {'gain_db': 20.0}, {'pixel_format': 'Mono12', 'sample': 'orange-fake/s1/p02'}):
        bad = h.camera.set_parameters_atomically([Parameter(k, value=v) for k, v in values.items()])
        assert not bad.successful, values
        assert 'used only by the real-camera backends (basler, aravis)' in bad.reason
        assert 'runs the sim backend' in bad.reason and min(values) in bad.reason
    assert h.camera.get_parameter('camera_features').value == ''
    assert str(h.camera.get_parameter('sample').value) == '0'  # refused together, nothing changed
    ok = h.camera.set_parameters_atomically([Parameter('sample', value='orange-fake/s1/p02'),
                                             Parameter('frame_id', value='stage_cam')])
    assert ok.successful, ok.reason  # frame_id: both kinds use it


def test_a_missing_capture_leaves_the_node_up_reporting_the_error(harness_factory, stage_capture,
                                                                  tmp_path):
    missing = tmp_path / 'no_capture'
    h = harness_factory(capture_dir=str(missing))
    status = h.last_status()
    assert status.level == ERROR and str(missing) in status.message
    h.trigger(1, 1_000_000_000, np.ones(32))
    # no image, but at once the notice that this trigger's frame will not come, and why
    assert h.spin_until(lambda: h.lost)
    assert not h.images
    (lost,) = h.lost
    assert (lost.header.stamp.sec, lost.header.stamp.nanosec, lost.sequence) == (1, 0, 1)
    assert lost.reason.startswith('camera not ready') and str(missing) in lost.reason
    values = {kv.key: kv.value for kv in h.last_status().values}
    assert values['triggers_dropped'] == '1'
    # fixing the parameter brings the camera up without a restart
    (ok,) = h.set(capture_dir=str(stage_capture))
    assert ok.successful, ok.reason
    assert h.last_status().level == OK
    h.trigger(2, 2_000_000_000, np.ones(32))
    assert h.spin_until(lambda: len(h.images) == 1)
    (bad,) = h.set(capture_dir=str(missing))
    assert not bad.successful and 'not a directory' in bad.reason
    assert h.last_status().level == OK  # the working capture was kept


def test_an_unknown_start_sample_is_reported_and_fixing_it_starts_the_camera(harness_factory,
                                                                             stage_capture):
    h = harness_factory(capture_dir=str(stage_capture), sample='kiwi-real/s0/p00')
    status = h.last_status()
    assert status.level == ERROR and "unknown sample 'kiwi-real/s0/p00'" in status.message
    (ok,) = h.set(sample='banana-fake/s1/p01')  # accepted while down, and retried
    assert ok.successful
    status = h.last_status()
    assert status.level == OK and 'banana-fake/s1/p01' in status.message
    h.trigger(1, 3_000_000_000, np.ones(32))
    assert h.spin_until(lambda: len(h.images) == 1)


def test_exposure_scales_light_changes_at_run_time(harness_factory, stage_capture, stage_modelset):
    h = harness_factory(capture_dir=str(stage_capture), sample=0, noise='none')
    leds = np.full(32, 0.5, np.float32)
    h.trigger(1, 5_000_000_000, leds, exposure_us=11250)
    assert h.spin_until(lambda: len(h.images) == 1)
    (ok,) = h.set(exposure_scales_light=True)
    assert ok.successful
    h.trigger(2, 6_000_000_000, leds, exposure_us=11250)
    assert h.spin_until(lambda: len(h.images) == 2)
    frames = [np.frombuffer(bytes(m.data), '<u2').reshape(120, 120) for m in h.images]
    for scales, frame in zip((False, True), frames):
        expected = SimCamera(stage_modelset, sample=0, noise='none',
                             exposure_scales_light=scales).capture(leds, 11250, 17.5)
        np.testing.assert_array_equal(frame, expected)
    assert not np.array_equal(frames[0], frames[1])
