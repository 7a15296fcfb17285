"""The recorder and player processes on their own: a recorder killed mid-recording, latched
(transient-local) topics through record and replay, and the command-line errors."""
import signal
import subprocess
import threading

import pytest

from lightstage_recording import BagError, BagReader
from lightstage_bringup.launcher import node_command
from lightstage_graph.ros_env import ros_environment
from helpers.recording import illumination, recover
from helpers.suite import GraphClient, fresh_domain_id, lightstage_command, write_params

pytestmark = [pytest.mark.ros, pytest.mark.process]


def _readable(bag, topic):
    try:
        return sum(1 for _ in BagReader(bag).messages([topic]))
    except BagError:  # nothing written yet
        return 0


def test_killed_recorder_bag_is_readable_and_replay_keeps_the_recorded_qos(tmp_path):
    from lightstage_interfaces.msg import IlluminationState
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from rclpy.serialization import deserialize_message
    from std_msgs.msg import String
    domain_id = fresh_domain_id()
    bag = tmp_path / 'killed'
    params = write_params(tmp_path / 'params.yaml', {
        # split into small files: a killed recorder's closed files and its file in progress
        'recorder': {'output_dir': str(bag), 'flush_period_s': 0.1, 'max_bag_size_bytes': 4096,
                     'topics': ['/stage_status', '/illumination'], 'include_regex': '^/late_'},
        'player': {'bag': str(tmp_path / 'fixed'), 'loop': True, 'rate': 5.0,
                   'topics': ['/stage_status', '/illumination']}})
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    client = GraphClient(domain_id)
    try:
        status = client.node.create_publisher(String, '/stage_status', latched)
        states = client.node.create_publisher(IlluminationState, '/illumination', 100)
        status.publish(String(data='stage ready'))  # before the recorder exists
        recorder = subprocess.Popen(node_command('lightstage_recording.recorder_node', 'recorder', params),
                                    env=ros_environment(domain_id), stdout=subprocess.PIPE,
                                    stderr=subprocess.STDOUT, text=True)
        try:
            client.spin_until(lambda: states.get_subscription_count() > 0
                              and status.get_subscription_count() > 0, 30.0,
                              'the recorder to subscribe')
            for i in range(30):
                states.publish(illumination(request_id=i, index=0, count=1, seq=i))
            # a topic that appears while recording is picked up (include_regex takes it)
            late = client.node.create_publisher(String, '/late_topic', 10)
            client.spin_until(lambda: late.get_subscription_count() > 0, 30.0,
                              'the recorder to find /late_topic')
            late.publish(String(data='late'))
            client.spin_until(lambda: _readable(bag, '/illumination') >= 30
                              and _readable(bag, '/late_topic') >= 1, 20.0,
                              'the recorder to flush 30 + 1 messages')
        finally:
            recorder.kill()  # SIGKILL: no summary, no footer, no metadata.yaml
            recorder.communicate(timeout=30)
        reader = BagReader(bag)
        info = reader.info()
        assert not info.complete and not info.has_metadata_yaml
        assert len(info.files) > 1 and info.files[0].name == 'killed_0.mcap'
        assert any('no metadata.yaml' in p for p in info.problems)
        got = [deserialize_message(m.data, IlluminationState).request_id
               for m in reader.messages(['/illumination'])]
        assert got == list(range(30))
        assert set(info.topics) >= {'/stage_status', '/illumination', '/late_topic'}
        assert '/rosout' not in info.topics  # neither named nor matching include_regex
        (ready,) = reader.messages(['/stage_status'])  # latched before the recorder started
        assert deserialize_message(ready.data, String).data == 'stage ready'
        (q,) = info.topics['/stage_status'].offered_qos
        assert (q.reliability, q.durability) == ('reliable', 'transient_local')
        fixed = recover(bag, tmp_path / 'fixed')
        assert fixed.complete and fixed.message_count == info.message_count

        # replay: the player's publishers offer what was recorded; a late subscriber of the
        # latched topic still gets its message
        player = subprocess.Popen(node_command('lightstage_recording.player_node', 'player', params),
                                  env=ros_environment(domain_id), stdout=subprocess.PIPE,
                                  stderr=subprocess.STDOUT, text=True)
        try:
            def offered(topic):
                return [i.qos_profile for i in client.node.get_publishers_info_by_topic(topic)
                        if i.node_name == 'player']
            client.spin_until(lambda: offered('/stage_status') and offered('/illumination'), 30.0,
                              'the player\'s publishers')
            assert offered('/stage_status')[0].durability == DurabilityPolicy.TRANSIENT_LOCAL
            assert offered('/illumination')[0].durability == DurabilityPolicy.VOLATILE
            assert offered('/illumination')[0].reliability == ReliabilityPolicy.RELIABLE
            late = []
            client.node.create_subscription(String, '/stage_status', late.append, latched)
            client.spin_until(lambda: late, 20.0, 'the latched status from the player')
            assert late[0].data == 'stage ready'
        finally:
            player.send_signal(signal.SIGINT)
            out, _ = player.communicate(timeout=30)
        assert player.returncode == 0, out
        assert 'played ' in out
    finally:
        client.close()


def test_command_line_errors_say_what_to_do(tmp_path):
    domain_id = fresh_domain_id()
    env = ros_environment(domain_id)
    # a bag to play: two illumination states
    from lightstage_recording import BagWriter
    from rclpy.serialization import serialize_message
    with BagWriter(tmp_path / 'small') as w:
        w.add_topic('/illumination', 'lightstage_interfaces/msg/IlluminationState')
        for i in range(2):
            w.write('/illumination', serialize_message(illumination(seq=i)), 1_000_000_000 * (i + 1))

    def run(*args, timeout=60):
        return subprocess.run(lightstage_command(*args, '--domain-id', str(domain_id)), env=env,
                              capture_output=True, text=True, timeout=timeout)

    p = run('play', str(tmp_path / 'small'), '--topics', '/nope')
    assert p.returncode == 2 and 'the bag has no topic /nope; it has: /illumination' in p.stderr
    p = run('play', str(tmp_path / 'missing'))
    assert p.returncode == 2 and 'does not exist' in p.stderr
    p = run('play', str(tmp_path / 'small'), '--wait-for', '/illumination', '--wait-timeout-s', '0.5')
    assert p.returncode == 1 and 'no subscriber matched /illumination within 0.5 s' in p.stderr
    p = run('play', str(tmp_path / 'small'), '--rate', '0')
    assert p.returncode == 2 and '--rate' in p.stderr
    p = run('record', '-o', str(tmp_path / 'small'))
    assert p.returncode == 2 and 'already exists' in p.stderr
    p = run('record', '-o', str(tmp_path / 'new'), '-x', '(unclosed')
    assert p.returncode == 2 and 'not a valid regular expression' in p.stderr
    p = run('record', '-o', str(tmp_path / 'new'), '-b', '100')
    assert p.returncode == 2 and '--max-bag-size-bytes must be 0 (no limit) or >= 1024' in p.stderr
    assert not (tmp_path / 'new').exists()


def test_record_splits_by_duration_and_keeps_the_newest_files(tmp_path):
    """`lightstage record -d S --max-bag-files N`: the options reach the recorder node."""
    from lightstage_interfaces.msg import IlluminationState
    import yaml
    domain_id = fresh_domain_id()
    bag = tmp_path / 'rolling'
    client = GraphClient(domain_id)
    try:
        pub = client.node.create_publisher(IlluminationState, '/illumination', 100)
        recorder = subprocess.Popen(
            lightstage_command('record', '/illumination', '-o', str(bag), '-d', '0.5',
                               '--max-bag-files', '2', '--domain-id', str(domain_id)),
            env=ros_environment(domain_id), stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
            text=True)
        lines, deleted = [], threading.Event()

        def read_output():
            for line in recorder.stdout:
                lines.append(line)
                if 'deleted' in line and 'to keep max_bag_files 2' in line:
                    deleted.set()
        reader = threading.Thread(target=read_output, daemon=True)
        reader.start()
        try:
            client.spin_until(lambda: pub.get_subscription_count() > 0, 30.0,
                              'the recorder to subscribe')
            # about 20 Hz (the log times must span several 0.5 s files), until the recorder
            # says it deleted a file to keep 2
            published = 0
            while not deleted.is_set():
                assert published < 2000, f'no file deleted after {published} messages:\n{"".join(lines)}'
                pub.publish(illumination(seq=published))
                published += 1
                client.spin_for(0.05)
        finally:
            recorder.send_signal(signal.SIGINT)
            recorder.wait(timeout=60)
            reader.join(timeout=10)
    finally:
        client.close()
    report = ''.join(lines)
    assert recorder.returncode == 0, report
    meta = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert len(meta['relative_file_paths']) == 2 == len(list(bag.glob('*.mcap')))
    assert 'were deleted to keep max_bag_files 2' in meta['custom_data']['deleted_files']
    assert 'not kept: ' in report and 'in 2 files)' in report, report
    held = BagReader(bag).info(verify=True)
    assert held.complete and 0 < held.message_count < published
