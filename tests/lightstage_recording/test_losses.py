"""The recorder says what it lost: publisher sequence gaps on one-publisher topics and service
requests without response, counted the same way by the recorder's report (`Recording`) and by
`lightstage bag info` (`BagReader.info`), from the bag alone. No ROS graph."""
import json

import pytest
from rclpy.serialization import serialize_message

from lightstage_recording import BagReader, BagWriter, format_info
from lightstage_recording.losses import LossCounter, event_info
from lightstage_recording.qos import QosProfile
from lightstage_recording.recording import Recording
from helpers.recording import classify_event, illumination, image

pytestmark = pytest.mark.process

CLASSIFY = '/lightstage/classify/_service_event'
CLASSIFY_EVENT = 'lightstage_interfaces/srv/Classify_Event'


def _event(kind, sequence, gid=7):
    e = classify_event(kind)
    e.info.sequence_number = sequence
    e.info.client_gid = [gid] * 16
    return serialize_message(e)


@pytest.mark.parametrize('sequence,gid', [(0, 0), (4, 7), (2**40 + 3, 255), (-1, 1)])
def test_event_info_reads_what_rclpy_wrote(sequence, gid):
    for kind, event_type in (('request', 1), ('response', 2)):
        assert event_info(_event(kind, sequence, gid)) == (event_type, bytes([gid] * 16), sequence)
    assert event_info(serialize_message(illumination())[:20]) is None


def test_gaps_are_counted_on_one_publisher_topics_only():
    c = LossCounter()
    c.add_topic('/illumination', 'lightstage_interfaces/msg/IlluminationState', 1)
    c.add_topic('/rosout', 'rcl_interfaces/msg/Log', 3)
    c.add_topic('/parameter_events', 'rcl_interfaces/msg/ParameterEvent', 1)
    for seq in [5, 6, 9, 10, 12]:  # from 5 (joined late: no loss), 7, 8 and 11 lost
        c.message('/illumination', seq)
    for seq in [1, 1, 2, 9, 3]:
        c.message('/rosout', seq)
    # one publisher when it was found, a second one later: its jumps are no losses
    for seq in [1, 2, 7, 3, 8]:
        c.message('/parameter_events', seq)
    assert c.gaps == {'/illumination': (3, 5)}
    assert c.uncounted == ['/parameter_events', '/rosout']
    assert c.lines() == ['/illumination: 3 of 8 messages missing (publisher sequence numbers '
                         'skipped: sent, never recorded)']


def test_sequence_0_means_not_stored_and_is_not_a_gap():
    c = LossCounter()
    c.add_topic('/a', 'std_msgs/msg/String', 1)
    for seq in [0, 0, 0]:
        c.message('/a', seq)
    assert not c.lost_any


def test_a_request_without_response_and_a_response_without_request_are_counted():
    c = LossCounter()
    c.add_topic(CLASSIFY, CLASSIFY_EVENT, 1)
    events = [('request', 1), ('response', 1),   # a whole call
              ('response', 2),                   # its request was not recorded
              ('request', 3),                    # its response was not recorded
              ('request', 4), ('response', 4)]
    for i, (kind, call) in enumerate(events, start=1):
        c.message(CLASSIFY, i, _event(kind, call))
    assert c.unmatched == {CLASSIFY: (1, 1)}
    assert c.lines() == [f'{CLASSIFY}: 1 request without response, 1 response without request']
    # the same call number from another client is another call
    c2 = LossCounter()
    c2.add_topic(CLASSIFY, CLASSIFY_EVENT, 1)
    c2.message(CLASSIFY, 1, _event('request', 1, gid=1))
    c2.message(CLASSIFY, 2, _event('response', 1, gid=2))
    assert c2.unmatched == {CLASSIFY: (1, 1)}


def _record_with_a_pause(path):
    """What a recorder stopped for a while receives of 6 classify calls of 8 triggers each:
    the illumination and images of calls 3 and 4 (16 triggers), both events of call 3 and the
    response of call 4 never arrive (the probe: 16 of 48 images missing)."""
    rec = Recording(BagWriter(path))
    one = [QosProfile(reliability='reliable')]
    rec.add_topic('/illumination', 'lightstage_interfaces/msg/IlluminationState', one)
    rec.add_topic('/camera/image_raw', 'sensor_msgs/msg/Image', one)
    rec.add_topic(CLASSIFY, CLASSIFY_EVENT, one)
    t = 1_700_000_000_000_000_000
    ill, img = serialize_message(illumination()), serialize_message(image())
    trigger = event = 0
    lost_calls = {3: ('request', 'response'), 4: ('response',)}
    for call in range(1, 7):
        lost = lost_calls.get(call, ())
        event += 1
        if 'request' not in lost:
            rec.receive(CLASSIFY, _event('request', call), {'publication_sequence_number': event,
                                                            'received_timestamp': t + event})
        for _ in range(8):
            trigger += 1
            if call not in lost_calls:
                for topic, data in (('/illumination', ill), ('/camera/image_raw', img)):
                    rec.receive(topic, data, {'publication_sequence_number': trigger,
                                              'received_timestamp': t + 1000 * trigger})
        event += 1
        if 'response' not in lost:
            rec.receive(CLASSIFY, _event('response', call), {'publication_sequence_number': event,
                                                             'received_timestamp': t + 10**6 * event})
    return rec


def test_the_recorder_report_and_bag_info_say_what_was_lost(tmp_path):
    bag = tmp_path / 'paused'
    rec = _record_with_a_pause(bag)
    rec.close()
    report = rec.report(17.0)
    assert 'LOST WHILE RECORDING' in report, report
    assert '/camera/image_raw: 16 of 48 messages missing' in report, report
    assert '/illumination: 16 of 48 messages missing' in report, report
    assert f'{CLASSIFY}: 3 of 12 messages missing' in report, report
    assert f'{CLASSIFY}: 1 request without response' in report, report

    info = BagReader(bag).info(verify=True)
    assert info.losses.gaps == rec.losses.gaps == {'/illumination': (16, 32),
                                                   '/camera/image_raw': (16, 32), CLASSIFY: (3, 9)}
    assert info.losses.unmatched == rec.losses.unmatched == {CLASSIFY: (1, 0)}
    text = format_info(info)
    assert 'LOST WHILE RECORDING' in text and '/camera/image_raw: 16 of 48 messages missing' in text
    doc = json.loads(json.dumps(info.to_json()))['lost_while_recording']
    assert doc['sequence_gaps']['/camera/image_raw'] == {'missing': 16, 'received': 32}
    assert doc['unmatched_service_events'][CLASSIFY] == {'requests_without_response': 1,
                                                         'responses_without_request': 0}
    unverified = BagReader(bag).info(verify=False)
    assert unverified.losses is None
    assert 'Lost:              not counted' in format_info(unverified)


def test_a_recording_that_lost_nothing_says_nothing_of_losses(tmp_path):
    rec = Recording(BagWriter(tmp_path / 'whole'))
    rec.add_topic('/illumination', 'lightstage_interfaces/msg/IlluminationState', [QosProfile()])
    for seq in range(1, 6):
        rec.receive('/illumination', serialize_message(illumination()),
                    {'publication_sequence_number': seq, 'received_timestamp': 10**18 + seq})
    rec.close()
    assert 'LOST' not in rec.report(1.0)
    info = BagReader(tmp_path / 'whole').info(verify=True)
    assert not info.losses.lost_any and 'LOST' not in format_info(info)
