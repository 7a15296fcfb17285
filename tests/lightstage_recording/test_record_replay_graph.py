"""End to end: record a graph that classifies on the simulated stage, then replay the bag's
/illumination and /camera/image_raw into a fresh classifier that only observes, and get the same
labels.

Every node runs in its own process with LOCALHOST discovery in a domain id of this test's own
(`lightstage_graph.ros_env`); the test talks to them from an in-process client.
"""
import io
import signal
import subprocess

import numpy as np
import pytest
from rclpy.serialization import deserialize_message

from lightstage_recording import BagReader, msg_definitions
from lightstage_graph.ros_env import ros_environment
from lightstage_bringup.supervisor import Supervisor
from helpers.recording import assert_replayed_results_match, bag_results, replay_into_observing_classifier
from helpers.suite import (GraphClient, fresh_domain_id, lightstage_command, stage_graph_params, start_nodes,
                           write_params)

pytestmark = [pytest.mark.ros, pytest.mark.process]

SAMPLES = ['banana-fake/s0/p01', 'orange-real/s1/p02', 'banana-real/s1/p00', 'orange-fake/s0/p00']
RECORDED = ['/illumination', '/camera/image_raw', '/lightstage/result',
            '/lightstage/classify/_service_event', '/lightstage/apply_patterns/_service_event']


@pytest.fixture(scope='module')
def session(stage_capture, stage_calibrated_artifact_path, tmp_path_factory):
    """Record a graph (driver on the sim firmware, sim camera, classifier) classifying four
    samples; the classifier also observes, so a sequence classified twice would show. The
    classifier is calibrated: its calls are anytime, one pattern column per driver request,
    stopping where its rule says."""
    stage_artifact_path = stage_calibrated_artifact_path
    tmp = tmp_path_factory.mktemp('session')
    bag = tmp / 'session'
    domain_id = fresh_domain_id()
    params = write_params(tmp / 'params.yaml', stage_graph_params(
        stage_capture, SAMPLES[0], 3,
        classifier={'artifact_path': str(stage_artifact_path), 'classify_observed': True}))
    from lightstage_interfaces.msg import ClassificationResult
    from lightstage_interfaces.srv import Classify
    client = GraphClient(domain_id)
    live = []
    client.node.create_subscription(ClassificationResult, '/lightstage/result', live.append, 10)
    out = io.StringIO()
    answers = []
    try:
        with Supervisor(stdout=out, stderr=out, sigint_timeout_s=5.0) as supervisor:
            start_nodes(supervisor, client, ['driver', 'camera', 'classifier'], domain_id, params)
            recorder = subprocess.Popen(lightstage_command('record', '-o', str(bag), '--domain-id', str(domain_id)),
                                        env=ros_environment(domain_id), stdout=subprocess.PIPE,
                                        stderr=subprocess.STDOUT, text=True)
            try:
                client.spin_until(lambda: all(client.subscribed_by(t, 'recorder') for t in RECORDED),
                                  30.0, f'the recorder to subscribe to {RECORDED}')
                # the publishers match the recorder's new subscriptions a little after this
                # process sees them: a first call whose start may be missing from the bag
                warm_up = client.call(Classify, '/lightstage/classify', Classify.Request(max_images=4))
                assert warm_up.success, warm_up.message
                for i, sample in enumerate(SAMPLES):
                    (ok,) = client.set_parameters('camera', sample=sample)
                    assert ok.successful, ok.reason
                    r = client.call(Classify, '/lightstage/classify',
                                    Classify.Request(max_images=8 if i % 2 == 0 else 4, timeout_s=10.0))
                    assert r.success, r.message
                    answers.append(r)
                client.spin_until(lambda: len(live) >= len(SAMPLES) + 1, 10.0, 'the live results')
            finally:
                recorder.send_signal(signal.SIGTERM)
                report, _ = recorder.communicate(timeout=60)
    finally:
        client.close()
    assert recorder.returncode == 0, report + out.getvalue()
    return {'bag': bag, 'answers': answers, 'live': live[1:], 'report': report, 'log': out.getvalue()}


def _stamp(msg):
    return msg.header.stamp.sec, msg.header.stamp.nanosec


def _counted(bag, n=len(SAMPLES)):
    """The results of the counted calls: the bag's last n."""
    return bag_results(bag)[-n:]


def test_sigterm_closes_a_complete_bag_and_reports_it(session):
    from lightstage_interfaces.msg import IlluminationState
    from sensor_msgs.msg import Image
    bag, report = session['bag'], session['report']
    assert 'recorded ' in report and str(bag) in report and '/camera/image_raw: ' in report, report
    info = BagReader(bag).info(verify=True)
    assert info.complete and not info.problems and info.has_metadata_yaml
    counts = {t.name: t.count for t in info.topics.values()}
    calls = len(SAMPLES) + 1  # with the warm-up, which may be partly missing
    n_images = sum(a.images_used for a in session['answers'])
    assert n_images <= counts['/illumination'] <= n_images + 4
    assert n_images <= counts['/camera/image_raw'] <= n_images + 4
    # one result per call: the observing mode did not classify the node's own calls again
    assert len(SAMPLES) <= counts['/lightstage/result'] <= calls
    # request received + response sent per call, for both services (an anytime call asks
    # the driver once per pattern column it takes: 4 images each)
    assert 2 * len(SAMPLES) <= counts['/lightstage/classify/_service_event'] <= 2 * calls
    columns = sum(a.images_used // 4 for a in session['answers'])
    assert 2 * columns <= counts['/lightstage/apply_patterns/_service_event'] <= 2 * columns + 4
    # every trigger and image of the counted calls is in the bag
    reader = BagReader(bag)
    triggers = {t.sequence: _stamp(t) for t in (deserialize_message(m.data, IlluminationState)
                                               for m in reader.messages(['/illumination']))}
    images = {_stamp(deserialize_message(m.data, Image)) for m in reader.messages(['/camera/image_raw'])}
    for r in _counted(bag):
        assert all(s in triggers and triggers[s] in images for s in r.sequences), r.sequences
    for t in info.topics.values():
        # the hash the graph announced is the one of the installed interface files
        assert t.type_hash == msg_definitions.type_hash(t.type), t.name
        assert t.offered_qos, t.name
    (q,) = info.topics['/illumination'].offered_qos
    assert (q.reliability, q.durability) == ('reliable', 'volatile')
    assert 'classified an observed sequence' not in session['log']


def test_the_bag_holds_the_service_calls_and_the_results(session):
    from lightstage_interfaces.srv import Classify
    bag, answers = session['bag'], session['answers']
    recorded = _counted(bag)
    assert [r.label for r in recorded] == [a.label for a in answers]
    assert [r.label for r in session['live']] == [a.label for a in answers]
    events = [deserialize_message(m.data, Classify.Event)
              for m in BagReader(bag).messages(['/lightstage/classify/_service_event'])]
    requests = [e.request[0] for e in events if e.info.event_type == 1]
    responses = [e.response[0] for e in events if e.info.event_type == 2]
    assert [q.max_images for q in requests[-4:]] == [8, 4, 8, 4]
    assert [(p.label, p.images_used) for p in responses[-4:]] == [(a.label, a.images_used) for a in answers]
    np.testing.assert_allclose([list(p.scores) for p in responses[-4:]], [list(a.scores) for a in answers])


def test_replay_into_an_observing_classifier_reproduces_the_labels(
        session, stage_calibrated_artifact_path, tmp_path):
    """The same labels, decisions and image counts: the observer decides each anytime
    sequence column by column with the artifact's rule, as the live calls did."""
    from lightstage_interfaces.msg import IlluminationState
    from sensor_msgs.msg import Image
    bag = session['bag']
    recorded = _counted(bag)
    # play from just before the first message of the counted calls (--start-offset-s):
    # halfway between it and the last message of the warm-up before it. Messages are told
    # apart by header stamp (an image carries its trigger's), not by topic: log times are
    # the recorder's receive times, and an image can be logged before its trigger state
    reader = BagReader(bag)
    counted = {s for r in recorded for s in r.sequences}
    triggers = [deserialize_message(m.data, IlluminationState)
                for m in reader.messages(['/illumination'])]
    counted_stamps = {_stamp(t) for t in triggers if t.sequence in counted}
    log_times = {True: [], False: []}  # counted or not -> log times
    for m in reader.messages(['/illumination', '/camera/image_raw']):
        kind = IlluminationState if m.topic == '/illumination' else Image
        log_times[_stamp(deserialize_message(m.data, kind)) in counted_stamps].append(m.log_time_ns)
    first_ns = min(log_times[True])
    before = [t for t in log_times[False] if t < first_ns]
    start_ns = (first_ns + max(before)) // 2 if before else first_ns
    offset_s = max(0.0, (start_ns - reader.info().start_ns) / 1e9)
    assert not [t for t in log_times[False] if t > start_ns]  # the warm-up is over by then
    n_played = 2 * sum(r.images_used for r in recorded)
    replayed, p = replay_into_observing_classifier(bag, stage_calibrated_artifact_path, tmp_path,
                                                   len(recorded),
                                                   '--start-offset-s', f'{offset_s:.6f}', '--rate', '4')
    assert f'played {n_played} messages on 2 topics' in p.stdout, p.stdout
    for r, again in assert_replayed_results_match(recorded, replayed, rtol=1e-5, atol=1e-6):
        assert again.header.stamp == r.header.stamp
        assert again.decision == r.decision
        assert r.calibrated and again.calibrated and len(r.probabilities) == 4
        np.testing.assert_allclose(again.probabilities, r.probabilities, rtol=1e-5, atol=1e-6)


def test_the_recording_exported_opens_in_rosbags_and_mcap_ros2(session, tmp_path):
    """A bag `lightstage record` wrote with its defaults, exported: rosbags' AnyReader and
    mcap_ros2 decode every message (service events included) as rclpy does, rosbags-convert
    converts it."""
    import sys
    from pathlib import Path

    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from rosbags.highlevel import AnyReader
    from test_reader_recipes import _check
    bag, dst = session['bag'], tmp_path / 'export'
    p = subprocess.run(lightstage_command('bag', 'export', str(bag), '-o', str(dst)),
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stdout + p.stderr
    info = BagReader(bag).info()
    events = sum(t.count for t in info.topics.values() if t.is_service_event)
    assert events >= 4 * len(SAMPLES)
    with AnyReader([dst]) as reader:
        decoded = [(c.topic, t, reader.deserialize(raw, c.msgtype)) for c, t, raw in reader.messages()]
    assert len(decoded) == info.message_count and _check(decoded, bag) == events
    decoded = []
    for path in BagReader(dst).files:
        with open(path, 'rb') as f:
            decoded += [(c.topic, m.log_time, msg) for _, c, m, msg in make_reader(
                f, decoder_factories=[DecoderFactory()]).iter_decoded_messages()]
    assert len(decoded) == info.message_count and _check(decoded, bag) == events
    convert = Path(sys.executable).with_name('rosbags-convert')
    p = subprocess.run([str(convert), '--src', str(dst), '--dst', str(tmp_path / 'x.bag')],
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stdout + p.stderr


def test_a_recorder_stopped_mid_session_reports_what_it_lost(stage_capture, stage_artifact_path,
                                                            tmp_path):
    """The probe: the recorder stopped (SIGSTOP) while 12 calls of 8 images run (more than the
    camera publisher's keep-last 32 and what the transport buffers), then continued:
    the images, triggers and service events it never got are named, with counts, in its report
    and by `bag info`, and the counts are the bag's own (what the calls used minus what it
    holds)."""
    import json
    from lightstage_interfaces.srv import Classify
    bag = tmp_path / 'paused'
    domain_id = fresh_domain_id()
    params = write_params(tmp_path / 'params.yaml', stage_graph_params(
        stage_capture, SAMPLES[0], 3, artifact=stage_artifact_path))
    client = GraphClient(domain_id)
    out = io.StringIO()
    answers = []
    try:
        with Supervisor(stdout=out, stderr=out, sigint_timeout_s=5.0) as supervisor:
            start_nodes(supervisor, client, ['driver', 'camera', 'classifier'], domain_id, params)
            recorder = subprocess.Popen(lightstage_command('record', '-o', str(bag), '--domain-id',
                                                           str(domain_id)),
                                        env=ros_environment(domain_id), stdout=subprocess.PIPE,
                                        stderr=subprocess.STDOUT, text=True)
            try:
                client.spin_until(lambda: all(client.subscribed_by(t, 'recorder') for t in RECORDED),
                                  30.0, f'the recorder to subscribe to {RECORDED}')
                warm_up = client.call(Classify, '/lightstage/classify', Classify.Request(max_images=4))
                assert warm_up.success, warm_up.message
                recorder.send_signal(signal.SIGSTOP)
                try:
                    for _ in range(12):
                        r = client.call(Classify, '/lightstage/classify',
                                        Classify.Request(max_images=8, timeout_s=10.0))
                        assert r.success, r.message
                        answers.append(r)
                finally:
                    recorder.send_signal(signal.SIGCONT)
                # one call with the recorder running again: what it lost lies between
                # messages it holds, where the sequence numbers show it
                r = client.call(Classify, '/lightstage/classify', Classify.Request(max_images=4))
                assert r.success, r.message
                answers.append(r)
            finally:
                recorder.send_signal(signal.SIGTERM)
                report, _ = recorder.communicate(timeout=60)
    finally:
        client.close()
    assert recorder.returncode == 0, report + out.getvalue()
    assert '/rosout' not in report.split('LOST WHILE RECORDING')[-1], report  # several publishers
    info = BagReader(bag).info(verify=True)
    used = 4 + sum(a.images_used for a in answers)
    images = info.topics['/camera/image_raw'].count
    lost = info.losses.gaps.get('/camera/image_raw', (0, 0))[0]
    assert lost > 0, f'the stopped recorder lost no image ({images} of {used}): {report}'
    # the first and last images of the session may be missing without a gap showing (the
    # warm-up's before the camera matched the recorder, the last call's after it closed)
    assert images + lost <= used, (images, lost, used)
    assert f'/camera/image_raw: {lost} of {images + lost} messages missing' in report, report
    p = subprocess.run(lightstage_command('bag', 'info', str(bag)), capture_output=True, text=True,
                       timeout=120)
    assert 'LOST WHILE RECORDING' in p.stdout, p.stdout
    assert f'/camera/image_raw: {lost} of {images + lost} messages missing' in p.stdout, p.stdout
    doc = json.loads(subprocess.run(lightstage_command('bag', 'info', '--json', str(bag)),
                                    capture_output=True, text=True, timeout=120).stdout)
    assert doc['lost_while_recording']['sequence_gaps']['/camera/image_raw']['missing'] == lost
