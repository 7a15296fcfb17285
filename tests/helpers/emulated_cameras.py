"""Shared by the real-camera backend tests (tests/lightstage_camera/backends): the emulated
cameras' serials and served files, and the ROS client of the graph tests."""
import contextlib
import time

import numpy as np
import pytest
from lightstage_bringup.supervisor import Supervisor

from lightstage_graph.graph_client import GraphTimeout
from lightstage_graph.stamps import stamp_to_ns
from helpers.suite import GraphClient, fresh_domain_id, start_nodes

EMULATED_SERIALS = ('0815-0000', '0815-0001')   # PYLON_CAMEMU=2, set in conftest.py
# pylon runs a POSIX timer that signals SIGALRM to a handler it installs when a camera opens;
# pytest-timeout's signal method restores the handler it found before the test (none) after
# it, and pylon's next alarm then kills the run. The thread method leaves signals alone.
PYLON_TIMEOUT = pytest.mark.timeout(300, method='thread')


def write_served_images(folder, images) -> list:
    """16-bit TIFFs (pylon's own writer) that the emulator serves in sorted order, cycling."""
    from pypylon import pylon
    folder.mkdir(parents=True, exist_ok=True)
    for i, image in enumerate(images):
        pim = pylon.PylonImage()
        pim.AttachArray(np.ascontiguousarray(image, np.uint16), pylon.PixelType_Mono16)
        pim.Save(pylon.ImageFileFormat_Tiff, str(folder / f'{i:03d}.tiff'))
    return images


def emulator_features(folder) -> list[str]:
    """The emulator's image-file feature: serve the files in `folder`, no test pattern."""
    return [f'ImageFilename={folder}', 'ImageFileMode=On', 'TestImageSelector=Off']


class CameraGraphClient(GraphClient):
    """The test's participant: fires pattern sequences through the driver, collects the
    camera's images, camera_info, lost-frame notices and /diagnostics."""

    def __init__(self, domain_id):
        super().__init__(domain_id)
        from diagnostic_msgs.msg import DiagnosticArray
        from lightstage_graph.names import CAMERA_INFO_TOPIC, FRAME_LOST_TOPIC, IMAGE_TOPIC
        from lightstage_graph.qos import IMAGE_QOS
        from lightstage_interfaces.msg import FrameLost
        from sensor_msgs.msg import CameraInfo, Image
        self.images, self.infos, self.lost, self.diagnostics = [], [], [], []
        self.camera_subscriptions = [
            self.node.create_subscription(Image, IMAGE_TOPIC, self.images.append, IMAGE_QOS),
            self.node.create_subscription(FrameLost, FRAME_LOST_TOPIC, self.lost.append, IMAGE_QOS),
            self.node.create_subscription(CameraInfo, CAMERA_INFO_TOPIC, self.infos.append, IMAGE_QOS)]
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self.diagnostics.append, 50)
        from lightstage_interfaces.srv import ApplyPatterns
        # made now, so that the driver has discovered its reply reader by the first `fire`
        self.service(ApplyPatterns, '/lightstage/apply_patterns')

    def fire(self, n, exposure_us=2000):
        from lightstage_interfaces.msg import Pattern
        from lightstage_interfaces.srv import ApplyPatterns
        rng = np.random.default_rng(n)
        patterns = [Pattern(intensities=(rng.random(32) > 0.5).astype(np.float32),
                            exposure_us=exposure_us, gain_db=float('nan')) for _ in range(n)]
        response = self.call(ApplyPatterns, '/lightstage/apply_patterns',
                             ApplyPatterns.Request(patterns=patterns, trigger=True))
        assert response.success, response.message
        return [stamp_to_ns(s) for s in response.trigger_stamps], list(response.sequences)

    def camera_errors(self):
        return [kv.value for msg in self.diagnostics for st in msg.status
                if st.name.startswith('camera') for kv in st.values if kv.key == 'last_error']

    def wait_images_flow(self, timeout_s=30.0):
        """Until one trigger fired through the driver comes back as an image: the test's
        readers and the camera's reader of /illumination are matched (a writer drops what it
        publishes before it has discovered a reader, and the graph shows the reader earlier).
        Fires again every few seconds; the lists are cleared after."""
        self.spin_until(lambda: all(s.get_publisher_count() > 0 for s in self.camera_subscriptions),
                        timeout_s, "the camera's image, camera_info and frame_lost publishers")
        deadline = time.monotonic() + timeout_s
        while not self.images:
            if time.monotonic() >= deadline:
                raise AssertionError(f'no image for a trigger within {timeout_s:g} s; '
                                     f'camera errors: {self.camera_errors()[-3:]}')
            self.fire(1)
            with contextlib.suppress(GraphTimeout):
                self.spin_until(lambda: self.images, 3.0)
        self.spin_for(0.3)
        for received in (self.images, self.infos, self.lost):
            received.clear()

    def wait_camera_ready(self):
        from diagnostic_msgs.msg import DiagnosticStatus

        def ready():
            return any(st.name.startswith('camera') and st.level == DiagnosticStatus.OK
                       for msg in self.diagnostics[-5:] for st in msg.status)
        self.spin_until(ready, 30.0, lambda: f'the camera to be open: {self.camera_errors()[-1:]}')


@contextlib.contextmanager
def camera_graph(params):
    """The driver (Python firmware simulator) and the camera node of `params` as processes,
    and a CameraGraphClient once the camera listens to /illumination and says it is open."""
    domain_id = fresh_domain_id()
    client = CameraGraphClient(domain_id)
    try:
        with Supervisor(sigint_timeout_s=5.0) as supervisor:
            start_nodes(supervisor, client, ['driver', 'camera'], domain_id, params)  # and its links
            client.wait_camera_ready()
            client.wait_images_flow()
            yield client
    finally:
        client.close()
