"""A bag recorded before the camera topics moved (its images on /image_raw) replays into the
current graph on camera/image_raw: the player honours ROS remapping rules, as
docs/RECORDING.md tells (`lightstage play --remap`, or the player node's `--ros-args -r`)."""
import subprocess
import sys

import pytest
from rclpy.serialization import serialize_message
from sensor_msgs.msg import Image

import lightstage_recording as lr
from lightstage_graph.names import IMAGE_TOPIC, resolved
from lightstage_graph.qos import IMAGE_QOS
from lightstage_graph.ros_env import ros_environment
from helpers.recording import image
from helpers.suite import GraphClient, fresh_domain_id, lightstage_command

pytestmark = [pytest.mark.ros, pytest.mark.process]

OLD_IMAGE_TOPIC = '/image_raw'   # where the camera published before
T0 = 1_700_000_000_000_000_000


@pytest.fixture
def old_bag(tmp_path):
    """Three images on /image_raw, as a bag of the old graph holds them."""
    bag = tmp_path / 'old_session'
    writer = lr.BagWriter(bag)
    writer.add_topic(OLD_IMAGE_TOPIC, 'sensor_msgs/msg/Image', [lr.QosProfile(history='unknown', depth=0)])
    sent = [serialize_message(image(seed=i)) for i in range(3)]
    for i, data in enumerate(sent):
        writer.write(OLD_IMAGE_TOPIC, data, T0 + i * 10_000_000)
    writer.close()
    return bag, sent


def _play(command, domain_id):
    """Run the player `command` with a client listening on both image topics; what arrived
    on each."""
    client = GraphClient(domain_id)
    received = {resolved(IMAGE_TOPIC): [], OLD_IMAGE_TOPIC: []}
    for topic, got in received.items():
        client.node.create_subscription(Image, topic, got.append, IMAGE_QOS, raw=True)
    try:
        p = subprocess.Popen(command, env=ros_environment(domain_id), stdout=subprocess.PIPE,
                             stderr=subprocess.STDOUT, text=True)
        try:
            client.spin_until(lambda: p.poll() is not None, 60.0, 'the player to end')
            client.spin_until(lambda: len(received[resolved(IMAGE_TOPIC)]) >= 3, 10.0,
                              'the three images')
        finally:
            if p.poll() is None:
                p.kill()
        output = p.stdout.read()
        assert p.returncode == 0, output
        client.spin_for(0.3)
    finally:
        client.close()
    return received


def test_lightstage_play_remaps_an_old_bags_image_topic(old_bag):
    bag, sent = old_bag
    domain_id = fresh_domain_id()
    received = _play(lightstage_command('play', str(bag), '--wait-for', OLD_IMAGE_TOPIC,
                                        '--delay-s', '0.5', '--domain-id', str(domain_id),
                                        '--remap', f'{OLD_IMAGE_TOPIC}:={resolved(IMAGE_TOPIC)}'),
                     domain_id)
    assert received[resolved(IMAGE_TOPIC)] == sent   # the recorded bytes, in order
    assert received[OLD_IMAGE_TOPIC] == []


def test_the_player_node_takes_ros_remapping_rules(old_bag):
    bag, sent = old_bag
    domain_id = fresh_domain_id()
    received = _play([sys.executable, '-m', 'lightstage_recording.player_node', '--ros-args',
                      '-p', f'bag:={bag}', '-p', f'wait_for_subscribers:=[{OLD_IMAGE_TOPIC}]',
                      '-p', 'delay_s:=0.5', '-r', f'{OLD_IMAGE_TOPIC}:={resolved(IMAGE_TOPIC)}'],
                     domain_id)
    assert received[resolved(IMAGE_TOPIC)] == sent
    assert received[OLD_IMAGE_TOPIC] == []
