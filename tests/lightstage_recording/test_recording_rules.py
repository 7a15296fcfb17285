"""Which topics are recorded / played and with which QoS (no graph)."""
import pytest

from lightstage_recording import QosProfile
from lightstage_recording.recording import (TopicSelector, is_hidden, playback_delay_s, playback_qos,
                                          select_play_topics, subscription_qos)

pytestmark = pytest.mark.process

IMG = 'sensor_msgs/msg/Image'
EVENT = 'lightstage_interfaces/srv/Classify_Event'


def test_default_selection_takes_topics_and_service_events_not_other_hidden_topics():
    s = TopicSelector()
    assert s.wants('/image_raw', IMG)
    assert s.wants('/lightstage/classify/_service_event', EVENT)
    assert not s.wants('/lightstage/train/_action/feedback', 'lightstage_interfaces/action/Train_FeedbackMessage')
    assert TopicSelector(hidden=True).wants('/lightstage/train/_action/status', 'action_msgs/msg/GoalStatusArray')
    assert not TopicSelector(services=False).wants('/lightstage/classify/_service_event', EVENT)
    assert is_hidden('/a/_b') and not is_hidden('/a/b_')


def test_named_topics_regex_and_exclude():
    s = TopicSelector(topics=('/image_raw', '/lightstage/classify/_service_event'))
    assert s.wants('/image_raw', IMG) and not s.wants('/illumination', 'x/msg/Y')
    assert s.wants('/lightstage/classify/_service_event', EVENT)
    s = TopicSelector(include='^/lightstage/')
    assert s.wants('/lightstage/result', 'x/msg/Y') and not s.wants('/image_raw', IMG)
    s = TopicSelector(topics=('/image_raw',), include='result$')
    assert s.wants('/image_raw', IMG) and s.wants('/lightstage/result', 'x/msg/Y')
    s = TopicSelector(exclude='^/(rosout|parameter_events)$|_service_event$')
    assert not s.wants('/rosout', 'rcl_interfaces/msg/Log')
    assert not s.wants('/lightstage/classify/_service_event', EVENT)
    assert s.wants('/illumination', 'x/msg/Y')


def test_bad_selection_is_a_clear_error():
    with pytest.raises(ValueError, match=r"include_regex '\(unclosed' is not a valid regular"):
        TopicSelector(include='(unclosed')
    with pytest.raises(ValueError, match="leading /"):
        TopicSelector(topics=('image_raw',))


def test_subscription_qos_matches_what_every_publisher_offers():
    rel, be = QosProfile(history='unknown', depth=0), QosProfile(reliability='best_effort')
    latched = QosProfile(durability='transient_local')
    q = subscription_qos([rel, rel], 100)
    assert (q.reliability, q.durability, q.history, q.depth) == ('reliable', 'volatile', 'keep_last', 100)
    assert subscription_qos([rel, be], 10).reliability == 'best_effort'
    assert subscription_qos([latched], 10).durability == 'transient_local'
    assert subscription_qos([latched, rel], 10).durability == 'volatile'


def test_playback_qos_is_the_recorded_one():
    latched = QosProfile(history='unknown', depth=0, durability='transient_local')
    q = playback_qos([latched], 50)
    assert (q.reliability, q.durability, q.history, q.depth) == ('reliable', 'transient_local', 'keep_last', 50)
    assert playback_qos([QosProfile(depth=7)], 50).depth == 7
    assert playback_qos([], 20) == QosProfile(depth=20)
    assert playback_qos([QosProfile(reliability='best_effort'), QosProfile()], 5).reliability == 'best_effort'


def test_play_topic_selection_and_timing():
    available = ['/illumination', '/image_raw', '/rosout', '/parameter_events',
                 '/lightstage/classify/_service_event']
    assert select_play_topics(available, None) == ['/illumination', '/image_raw']
    assert select_play_topics(available, ['/rosout']) == ['/rosout']
    with pytest.raises(ValueError, match='no topic /nope; it has: '):
        select_play_topics(available, ['/nope'])
    assert playback_delay_s(3_000_000_000, 1_000_000_000, 2.0) == 1.0
    assert playback_delay_s(500, 1_000, 1.0) == 0.0


def test_the_recording_cores_do_not_import_rclpy():
    import subprocess
    import sys
    code = ('import sys, lightstage_recording, lightstage_recording.recording, '
            'lightstage_recording.msg_definitions, mux_classifier.observe; '
            'assert "rclpy" not in sys.modules, sorted(m for m in sys.modules if "rclpy" in m)')
    p = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
