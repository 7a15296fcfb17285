"""A params YAML with a syntax error, a value out of range, an
integer where a float belongs, an unknown name -- each a message naming the parameter (and
the line), never an rclpy traceback; integers are taken for float parameters."""
import os
import subprocess
import sys

import pytest
from lightstage_camera.camera_node import PARAMETERS as CAMERA
from lightstage_graph.params import ParameterError, check_values, read_params_file
from mux_classifier.classifier_node import PARAMETERS as CLASSIFIER

from helpers.suite import REPO, fresh_domain_id

pytestmark = pytest.mark.process


@pytest.mark.parametrize('table, values, message', [
    (CLASSIFIER, {'timeout_s': 1.0e9}, 'timeout_s: 1000000000.0 is out of range: give a number in '
                                       '0.1 .. 600'),
    (CAMERA, {'dimmer': -1.0}, 'dimmer: -1.0 is out of range: give a number in 0.001 .. 10'),
    (CAMERA, {'exposure_us': 1.0e12}, 'exposure_us: 1000000000000.0 is out of range: give a '
                                      'number in 1 .. 10000000'),
    (CAMERA, {'seed': 'abc'}, "seed: must be a whole number in -1 .. 2147483647, got 'abc'"),
    (CAMERA, {'frame_id': 5}, 'frame_id: must be a string (quote it in YAML)'),
    (CAMERA, {'exposure': 30000}, 'exposure: node has no such parameter (did you mean '
                                  'exposure_us?)'),
    (CLASSIFIER, {'artefact_path': 'a.npz'}, 'did you mean artifact_path?'),
])
def test_bad_values_and_unknown_names_are_named(table, values, message):
    with pytest.raises(ParameterError) as exc:
        check_values(table, values)
    assert message in str(exc.value)


def test_every_problem_is_named_at_once():
    with pytest.raises(ParameterError) as exc:
        check_values(CAMERA, {'dimmer': -1.0, 'exposure_us': 1e12, 'typo': 1}, "node 'camera'")
    text = str(exc.value)
    assert text.startswith("node 'camera': cannot start with these parameters")
    assert all(name in text for name in ('dimmer:', 'exposure_us:', 'typo:'))


def test_integers_are_taken_for_float_parameters_and_ros_own_names_pass():
    checked = check_values(CAMERA, {'exposure_us': 30000, 'dimmer': 1, 'use_sim_time': False,
                                    'qos_overrides./illumination.subscription.depth': 5})
    assert checked['exposure_us'] == 30000.0 and type(checked['exposure_us']) is float
    assert type(checked['dimmer']) is float


def test_a_yaml_syntax_error_names_the_file_and_line(tmp_path):
    path = tmp_path / 'p.yaml'
    path.write_text('camera:\n  ros__parameters:\n    dimmer: [0.45\n    seed: 1\n')
    with pytest.raises(ValueError, match=rf'params file {path}: not valid YAML at line \d+'):
        read_params_file(path)
    path.write_text('camera:\n  ros__parameters: 5\n')
    with pytest.raises(ValueError, match='camera.ros__parameters must map names to values'):
        read_params_file(path)


@pytest.mark.ros
def test_the_camera_node_takes_an_integer_exposure_and_refuses_a_bad_dimmer():
    """`exposure_us: 30000` (as docs/CAMERAS.md writes it) gave InvalidParameterTypeException."""
    import rclpy
    from lightstage_camera.camera_node import CameraNode
    from rclpy.context import Context
    from rclpy.parameter import Parameter
    context = Context()
    rclpy.init(context=context, domain_id=fresh_domain_id())
    try:
        node = CameraNode(context=context, parameter_overrides=[
            Parameter('exposure_us', value=30000), Parameter('backend', value='sim')])
        assert node.p('exposure_us') == 30000.0
        node.destroy_node()
        with pytest.raises(ParameterError, match=r"dimmer: -1.0 is out of range"):
            CameraNode(context=context, parameter_overrides=[Parameter('dimmer', value=-1.0)])
        with pytest.raises(ParameterError, match=r'exposur: .*did you mean exposure_us\?'):
            CameraNode(context=context, parameter_overrides=[Parameter('exposur', value=1.0)])
    finally:
        rclpy.shutdown(context=context)


@pytest.mark.ros
@pytest.mark.parametrize('yaml_text, message', [
    ('camera:\n  ros__parameters:\n    dimmer: [0.45\n', 'not valid YAML at line'),
    ('camera:\n  ros__parameters:\n    dimmer: -1.0\n', 'dimmer: -1.0 is out of range'),
])
def test_a_node_started_with_a_bad_params_file_says_what_is_wrong_without_a_traceback(
        tmp_path, yaml_text, message):
    path = tmp_path / 'p.yaml'
    path.write_text(yaml_text)
    done = subprocess.run([sys.executable, '-c', 'import sys; from lightstage_camera.camera_node '
                           'import main; sys.exit(main())', '--ros-args', '--params-file', str(path)],
                          capture_output=True, text=True, timeout=120,
                          env={**os.environ, 'ROS_DOMAIN_ID': str(fresh_domain_id())})
    assert done.returncode == 1
    assert message in done.stderr and 'Traceback' not in done.stderr, done.stderr


def test_lightstage_up_refuses_a_params_file_with_a_syntax_error(tmp_path, capsys):
    from lightstage_bringup.launcher import EXIT_USAGE, main
    path = tmp_path / 'p.yaml'
    path.write_text('camera:\n  ros__parameters:\n    dimmer: [0.45\n')
    assert main(['camera', '--no-record', '--params', str(path)]) == EXIT_USAGE
    assert 'not valid YAML at line' in capsys.readouterr().err


def test_the_parameter_tables_of_docs_nodes_md_are_those_the_nodes_declare():
    """docs/NODES.md's tables are generated from every node's PARAMETERS; they must not drift."""
    done = subprocess.run([sys.executable, str(REPO / 'scripts' / 'node_parameters_doc.py'),
                           '--check', '--doc', str(REPO / 'docs' / 'NODES.md')],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
