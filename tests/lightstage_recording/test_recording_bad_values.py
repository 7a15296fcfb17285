"""`bag info` into a closed pipe, and --remap rules the
bag cannot be played with, refused naming the rule before any node exists."""
import os
import subprocess
import sys

import pytest
from lightstage_recording.player_node import PlayerError, check_remaps

from helpers.suite import REPO

pytestmark = pytest.mark.process

BAG = REPO / 'bags' / 'sim_session'
TYPES = {'/illumination': 'lightstage_interfaces/msg/IlluminationState',
         '/camera/image_raw': 'sensor_msgs/msg/Image',
         '/image_raw': 'sensor_msgs/msg/Image',
         '/rosout': 'rcl_interfaces/msg/Log'}
PLAYED = ['/illumination', '/camera/image_raw', '/image_raw']


@pytest.mark.parametrize('json_flag', [[], ['--json']])
def test_bag_info_into_a_closed_pipe_ends_quietly(json_flag):
    """`lightstage bag info BAG | head -1` ended in a BrokenPipeError traceback. The pipe's
    reader is closed before the command writes, so every write meets a closed pipe."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        done = subprocess.run([sys.executable, '-c', 'import sys; from lightstage_recording.bag_cli '
                               'import bag_main; sys.exit(bag_main())', 'info', str(BAG), *json_flag],
                              stdout=write_end, stderr=subprocess.PIPE, text=True, timeout=120)
    finally:
        os.close(write_end)
    assert 'Traceback' not in done.stderr and 'BrokenPipeError' not in done.stderr, done.stderr
    assert done.returncode == 0


@pytest.mark.parametrize('rules, message', [
    (['/illumination:=/bad topic!!'], "'/bad topic!!' is not a ROS topic name"),
    (['/nope:=/x'], 'the bag has no topic /nope'),
    (['/illuminatoin:=/x'], 'did you mean /illumination?'),
    (['/illumination:=/a', '/illumination:=/b'], '/illumination is already remapped to /a'),
    (['/image_raw:=/camera/image_raw'], '/camera/image_raw and /image_raw would both be published '
                                        'on /camera/image_raw'),
    (['/illumination:=/rosout'], 'onto /rosout, which carries rcl_interfaces/msg/Log'),
    (['/illumination:=/parameter_events'], 'which carries rcl_interfaces/msg/ParameterEvent'),
    (['/camera/image_raw:=/cam', '/illumination:=/camera/image_raw'],
     '/illumination (lightstage_interfaces/msg/IlluminationState) onto /camera/image_raw, which '
     'carries sensor_msgs/msg/Image'),
])
def test_remaps_the_bag_cannot_be_played_with_are_refused_naming_the_rule(rules, message):
    with pytest.raises(PlayerError) as exc:
        check_remaps(rules, TYPES, PLAYED)
    assert message in str(exc.value)


def test_good_remaps_give_where_each_topic_goes():
    assert check_remaps(['/image_raw:=/cam2', '/illumination:=lights'], TYPES, PLAYED) == {
        '/illumination': '/lights', '/camera/image_raw': '/camera/image_raw',
        '/image_raw': '/cam2'}


def test_a_remap_of_a_topic_that_is_not_played_is_refused():
    with pytest.raises(PlayerError, match=r'/rosout is not played .* add it to --topics'):
        check_remaps(['/rosout:=/r'], TYPES, PLAYED)


def test_lightstage_play_refuses_a_bad_remap_before_starting_ros(capsys):
    from lightstage_recording.bag_cli import play_main
    assert play_main([str(BAG), '--remap', '/illumination:=/bad topic!!']) == 2
    err = capsys.readouterr().err
    assert "lightstage play: --remap '/illumination:=/bad topic!!'" in err and 'Traceback' not in err
