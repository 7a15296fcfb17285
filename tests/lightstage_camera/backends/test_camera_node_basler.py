"""The camera node with backend basler in this process: parameters, a missing camera fixed
at run time, camera_info_url checks (emulated camera, emulation transport layer only)."""

import pytest

from helpers.emulated_cameras import PYLON_TIMEOUT
from helpers.suite import fresh_domain_id

pytestmark = [pytest.mark.ros, pytest.mark.usefixtures('private_network'), PYLON_TIMEOUT, pytest.mark.process]


@pytest.fixture
def node():
    import rclpy
    from lightstage_camera.camera_node import CameraNode
    from rclpy.context import Context
    from rclpy.parameter import Parameter
    context = Context()
    rclpy.init(context=context, domain_id=fresh_domain_id())
    overrides = [Parameter(k, value=v) for k, v in {
        'backend': 'basler', 'transport_layer': 'BaslerCamEmu', 'serial_number': '4711-0000',
        'trigger_source': 'Software', 'pixel_format': 'Mono12', 'reopen_period_s': 0.2}.items()]
    camera = CameraNode(context=context, parameter_overrides=overrides)
    yield camera
    camera.destroy_node()
    rclpy.shutdown(context=context)


def set_(node, **values):
    from rclpy.parameter import Parameter
    return node.set_parameters([Parameter(k, value=v) for k, v in values.items()])


def test_parameters_have_units_and_ranges_and_a_missing_camera_is_fixed_at_run_time(node, tmp_path):
    descriptors = {d.name: d for d in node.describe_parameters(
        ['exposure_us', 'gain_db', 'trigger_source', 'pixel_format', 'frame_timeout_s'])}
    assert (descriptors['exposure_us'].floating_point_range[0].from_value,
            descriptors['exposure_us'].floating_point_range[0].to_value) == (1.0, 10_000_000.0)
    assert descriptors['gain_db'].floating_point_range[0].to_value == 48.0
    assert 'Line1' in descriptors['trigger_source'].additional_constraints
    assert 'Mono12' in descriptors['pixel_format'].additional_constraints
    assert not node.backend.status().ok
    assert 'no Basler camera with serial number 4711-0000' in node.backend.status().message
    (ok,) = set_(node, serial_number='0815-0001')
    assert ok.successful
    status = node.backend.status()
    assert status.ok and status.values['serial'] == '0815-0001' and status.values['bit_depth'] == 12
    (bad,) = set_(node, pixel_format='Mono14')
    assert not bad.successful and 'pixel_format one of' in bad.reason
    (bad,) = set_(node, camera_features='ImageFileMode On')
    assert not bad.successful and 'is not Name=Value' in bad.reason
    not_yaml = tmp_path / 'x.yaml'
    not_yaml.write_text('just text')
    (bad,) = set_(node, camera_info_url=str(not_yaml))
    assert not bad.successful and 'is not a camera calibration' in bad.reason
    (live,) = set_(node, gain_db=6.0)
    assert live.successful and node.backend.gain_db == 6.0
    assert node.backend.status().ok   # exposure and gain apply without reopening


def test_sim_parameters_are_refused_on_a_real_camera_with_the_reason(node):
    (bad,) = set_(node, dimmer=0.3)
    assert not bad.successful
    assert bad.reason == ('dimmer: used only by the sim backend, and this camera node runs the '
                          'basler backend (backend is chosen at start-up)')
    (ok,) = set_(node, gain_db=20.0)
    assert ok.successful
