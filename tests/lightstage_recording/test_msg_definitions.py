"""Bag schemas from the installed interface files, as rosbag2 writes them (ros2msg), and
checked against an independent parser (rosbags) and the rclpy message classes."""
import pytest

from lightstage_recording import msg_definitions as md

pytestmark = pytest.mark.process

SEP = '=' * 80


def _own(type_name):
    return md.definition_text(type_name)


def test_image_definition_is_its_msg_then_each_dependency_once_depth_first():
    expected = (_own('sensor_msgs/msg/Image')
                + f'\n{SEP}\nMSG: std_msgs/Header\n' + _own('std_msgs/Header')
                + f'\n{SEP}\nMSG: builtin_interfaces/Time\n' + _own('builtin_interfaces/Time'))
    assert md.full_definition('sensor_msgs/msg/Image') == expected
    assert expected.startswith('# This message contains an uncompressed image')


def test_illumination_state_names_header_and_time_once():
    text = md.full_definition('lightstage_interfaces/msg/IlluminationState')
    assert text.count('MSG: std_msgs/Header\n') == 1
    assert text.count('MSG: builtin_interfaces/Time\n') == 1
    assert text.startswith(_own('lightstage_interfaces/msg/IlluminationState'))


def test_dependencies_follow_rosbag2s_rules():
    text = ('# a comment naming foo_msgs/Bar baz\n'
            'Header header\n'
            'uint8 CONSTANT = 3\n'
            'Pattern[] patterns\n'
            'other_pkg/Thing[<=4] things\n'
            'int32[5] numbers\n'
            'string<=8 short\n'
            'builtin_interfaces/Time stamp\n')
    assert md.dependencies(text, 'mine') == ['builtin_interfaces/Time', 'mine/Header',
                                             'mine/Pattern', 'other_pkg/Thing']


def test_service_event_definition_has_info_request_and_response():
    text = md.full_definition('lightstage_interfaces/srv/Classify_Event')
    first = text.split(SEP)[0]
    assert first.splitlines()[:3] == ['service_msgs/ServiceEventInfo info',
                                      'lightstage_interfaces/Classify_Request[<=1] request',
                                      'lightstage_interfaces/Classify_Response[<=1] response']
    for dep in ('lightstage_interfaces/Classify_Request', 'lightstage_interfaces/Classify_Response',
                'service_msgs/ServiceEventInfo', 'builtin_interfaces/Time'):
        assert text.count(f'MSG: {dep}\n') == 1, dep
    assert 'uint32 max_images' in text and 'string label' in text and '---' not in text


TYPES = ['lightstage_interfaces/msg/IlluminationState', 'lightstage_interfaces/msg/ClassificationResult',
         'sensor_msgs/msg/Image', 'diagnostic_msgs/msg/DiagnosticArray', 'rcl_interfaces/msg/Log',
         'rcl_interfaces/msg/ParameterEvent', 'lifecycle_msgs/msg/TransitionEvent',
         'lightstage_interfaces/srv/Classify_Event', 'lightstage_interfaces/srv/ApplyPatterns_Event']


@pytest.mark.parametrize('type_name', TYPES)
def test_rosbags_parses_each_definition_into_the_fields_of_the_rclpy_class(type_name):
    from lightstage_recording.bag_ros import message_class
    from rosbags.typesys import get_types_from_msg
    types = get_types_from_msg(md.full_definition(type_name), type_name)
    root = next(iter(types))  # rosbags keys srv types as pkg/srv/msg/Name: the root comes first
    fields = [name for name, _ in types[root][1]]
    assert fields == list(message_class(type_name).get_fields_and_field_types())


def test_type_hashes_come_from_the_installed_json_files():
    h = md.type_hash('sensor_msgs/msg/Image')
    assert h.startswith('RIHS01_') and len(h) == 7 + 64
    assert md.type_hash('lightstage_interfaces/srv/Classify_Event').startswith('RIHS01_')
    assert md.type_hash('lightstage_interfaces/srv/Classify_Event') != \
        md.type_hash('lightstage_interfaces/srv/Classify_Request')
    assert md.type_hash('no_such_pkg/msg/Nothing') == ''


def test_unknown_and_malformed_types_are_clear_errors():
    with pytest.raises(md.DefinitionNotFoundError, match='no_such_pkg/msg/Nothing.*install'):
        md.full_definition('no_such_pkg/msg/Nothing')
    with pytest.raises(ValueError, match='not a ROS type name'):
        md.split_type('just-a-name')
