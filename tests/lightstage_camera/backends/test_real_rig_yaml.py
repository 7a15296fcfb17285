"""The shipped real-rig YAML names only parameters the nodes declare, with their types."""
import yaml

from helpers.suite import REPO

REAL_RIG = REPO / 'src' / 'lightstage_bringup' / 'config' / 'real_rig.yaml'


def test_every_parameter_of_the_real_rig_yaml_is_declared_with_its_type():
    from lightstage_camera.acquisition_node import PARAMETERS as ACQUISITION
    from lightstage_camera.camera_node import BACKENDS, PARAMETERS as CAMERA, TRIGGER_SOURCES
    from lightstage_driver.driver_node import PARAMETERS as DRIVER
    from mux_classifier.classifier_node import PARAMETERS as CLASSIFIER
    declared = {'driver': DRIVER, 'camera': CAMERA, 'classifier': CLASSIFIER, 'acquisition': ACQUISITION}
    data = yaml.safe_load(REAL_RIG.read_text())
    assert set(data) <= set(declared)
    for node, section in data.items():
        for name, value in section['ros__parameters'].items():
            assert name in declared[node], f'{node}.{name} is not a parameter of the {node} node'
            default = declared[node][name][0]
            assert type(value) is type(default), f'{node}.{name}: {value!r} is not a {type(default).__name__}'
    camera = data['camera']['ros__parameters']
    assert camera['backend'] in BACKENDS and camera['trigger_source'] in TRIGGER_SOURCES
