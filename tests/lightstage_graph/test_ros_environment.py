"""The ROS environment module, and that ROS processes started with it stay on loopback:
checked on the sockets they bind (/proc) and, where strace is available, on the
addresses they actually send to."""
import os
import re
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET

import pytest

from lightstage_graph import ros_env
from helpers.proc_sockets import (InetSocket, ephemeral_port_low, listening_beyond_loopback,
                          parse_address, parse_proc_net, sockets_of)
from helpers.ros import running_nodes
from helpers.suite import GraphClient, fresh_domain_id

pytestmark = pytest.mark.process

DRIVER = {'driver': 'ros_fake_driver_node'}
NS = '{http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles}'


# -- ros_env --------------------------------------------------------------------------
def test_ros_environment_forces_localhost_and_sets_domain_without_touching_the_base():
    base = {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET', 'ROS_STATIC_PEERS': '10.0.0.7',
            'ROS_DOMAIN_ID': '5', 'PATH': '/bin'}
    env = ros_env.ros_environment(17, base=base)
    assert env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
    assert 'ROS_STATIC_PEERS' not in env
    assert env['ROS_DOMAIN_ID'] == '17' and env['PATH'] == '/bin'
    assert env['RMW_IMPLEMENTATION'] == 'rmw_fastrtps_cpp'
    assert env['FASTRTPS_DEFAULT_PROFILES_FILE'] == str(ros_env.fastdds_profile_path())
    assert base['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'SUBNET'  # a copy, not the input
    # no explicit id: the base's is kept; a profile the user chose is kept
    env = ros_env.ros_environment(None, base={'ROS_DOMAIN_ID': '5', 'FASTRTPS_DEFAULT_PROFILES_FILE': '/my.xml'})
    assert env['ROS_DOMAIN_ID'] == '5' and env['FASTRTPS_DEFAULT_PROFILES_FILE'] == '/my.xml'


@pytest.mark.parametrize('bad', [-1, 233])
def test_ros_environment_rejects_out_of_range_domain_ids(bad):
    with pytest.raises(ValueError, match=r'out of range: use 0\.\.232'):
        ros_env.ros_environment(bad, base={})


@pytest.fixture
def saved_environ():
    """Restore this process's whole environment after the test (apply_* changes it)."""
    saved = dict(os.environ)
    yield
    os.environ.clear()
    os.environ.update(saved)


def test_apply_ros_environment_updates_this_process(monkeypatch, saved_environ):
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'SUBNET')
    monkeypatch.setenv('ROS_DOMAIN_ID', '3')
    ros_env.apply_ros_environment(9)
    assert os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
    assert os.environ['ROS_DOMAIN_ID'] == '9'


def test_apply_ros_environment_drops_static_peers(monkeypatch, saved_environ):
    monkeypatch.setenv('ROS_STATIC_PEERS', '10.0.0.7')
    ros_env.apply_ros_environment(9)
    assert 'ROS_STATIC_PEERS' not in os.environ


def test_fastdds_profile_has_the_large_shared_memory_segment():
    root = ET.parse(ros_env.fastdds_profile_path()).getroot()
    shm = [t for t in root.iter(f'{NS}transport_descriptor') if t.findtext(f'{NS}type') == 'SHM']
    assert len(shm) == 1
    assert int(shm[0].findtext(f'{NS}segment_size')) == 16 * 1024 * 1024
    assert int(shm[0].findtext(f'{NS}maxMessageSize')) == 4 * 1024 * 1024
    assert root.find(f'.//{NS}participant[@is_default_profile="true"]') is not None


# -- the socket inspection itself ---------------------------------------------------
def test_proc_net_addresses_are_decoded():
    assert parse_address('0100007F:1B58') == (parse_address('0100007F:0000')[0], 7000)
    assert str(parse_address('0100007F:1B58')[0]) == '127.0.0.1'
    assert str(parse_address('020200C0:93A4')[0]) == '192.0.2.2'
    assert str(parse_address('00000000000000000000000001000000:0016')[0]) == '::1'
    table = parse_proc_net(
        '  sl  local_address rem_address   st tx_queue rx_queue tr tm->when retrnsmt   uid  timeout inode\n'
        '   1: 00000000:5492 00000000:0000 07 00000000:00000000 00:00000000 00000000     0        0 111 2\n'
        '   2: 0100007F:5493 00000000:0000 07 00000000:00000000 00:00000000 00000000     0        0 112 2\n'
        '   3: 020200C0:93A4 00000000:0000 07 00000000:00000000 00:00000000 00000000     0        0 113 2\n',
        'udp')
    bad = listening_beyond_loopback(list(table.values()), ephemeral_low=32768)
    assert [str(s) for s in bad] == ['udp 0.0.0.0:21650']  # 113 is an ephemeral send socket
    listen = InetSocket('tcp', parse_address('00000000:C350')[0], 50000, '0A')
    assert listening_beyond_loopback([listen], 32768) == [listen]


def test_sockets_of_finds_a_socket_this_test_binds():
    import socket
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(('127.0.0.1', 0))
        port = s.getsockname()[1]
        mine = [x for x in sockets_of(os.getpid()) if x.port == port]
    assert len(mine) == 1 and mine[0].loopback and mine[0].proto == 'udp'


# -- ROS processes -------------------------------------------------------------------
def _profile_without_whitelist(tmp_path):
    """The project's profile with the loopback whitelist taken out (the state before it was
    added): the negative control that shows the socket check can fail."""
    text = re.sub(r'<interfaceWhiteList>.*?</interfaceWhiteList>', '',
                  ros_env.fastdds_profile_path().read_text(), flags=re.S)
    assert '<type>UDPv4</type>' in text and 'interfaceWhiteList>' not in text
    path = tmp_path / 'profile_no_whitelist.xml'
    path.write_text(text)
    return str(path)


def _driver_sockets(domain_id: int, **env_overrides):
    with running_nodes(DRIVER, domain_id, **env_overrides) as sup:
        sockets = sockets_of(sup['driver'].pid)
    rtps_ports = [s for s in sockets if 7400 + 250 * domain_id <= s.port < 7400 + 250 * (domain_id + 1)]
    assert rtps_ports, f'no DDS ports found among {[str(s) for s in sockets]}: nothing was checked'
    return sockets


@pytest.mark.ros
def test_ros_node_process_binds_no_port_beyond_loopback():
    sockets = _driver_sockets(fresh_domain_id())
    bad = listening_beyond_loopback(sockets, ephemeral_port_low())
    assert not bad, f'listening beyond loopback: {[str(s) for s in bad]}'


@pytest.mark.ros
def test_socket_check_flags_a_profile_without_the_loopback_whitelist(tmp_path):
    sockets = _driver_sockets(fresh_domain_id(),
                              FASTRTPS_DEFAULT_PROFILES_FILE=_profile_without_whitelist(tmp_path))
    bad = listening_beyond_loopback(sockets, ephemeral_port_low())
    assert bad and all(str(s.address) == '0.0.0.0' for s in bad), [str(s) for s in sockets]


def _strace_works() -> bool:
    if shutil.which('strace') is None:
        return False
    return subprocess.run(['strace', '-qq', '-o', '/dev/null', 'true'], capture_output=True).returncode == 0


@pytest.mark.ros
@pytest.mark.skipif(not _strace_works(), reason='strace missing or ptrace not permitted')
def test_ros_node_process_sends_only_to_loopback(tmp_path):
    """Every datagram the node process sends (discovery, service replies, topic data) goes
    to a loopback address: traced with strace during a service exchange."""
    from lightstage_interfaces.srv import ApplyPatterns
    from lightstage_interfaces.msg import Pattern
    trace = tmp_path / 'strace.txt'
    wrap = ['strace', '-f', '-qq', '-e', 'trace=sendto,sendmsg,sendmmsg,connect', '-o', str(trace)]
    domain_id = fresh_domain_id()
    with running_nodes(DRIVER, domain_id, wrap=wrap):
        c = GraphClient(domain_id)
        try:
            cli = c.node.create_client(ApplyPatterns, '/lightstage/apply_patterns')
            c.spin_until(cli.service_is_ready, 20, 'the driver service')
            c.call_until_answered(cli, ApplyPatterns.Request(patterns=[Pattern()], trigger=False))
            resp = c.result(cli.call_async(ApplyPatterns.Request(patterns=[Pattern()] * 4, trigger=True)), 20)
            assert resp.success and len(resp.sequences) == 4
        finally:
            c.close()
    text = trace.read_text()
    v4 = re.findall(r'sa_family=AF_INET, sin_port=htons\(\d+\), sin_addr=inet_addr\("([\d.]+)"\)', text)
    v6 = re.findall(r'sa_family=AF_INET6, sin6_port=htons\(\d+\), sin6_flowinfo=[^,]+, inet_pton\(AF_INET6, "([^"]+)"', text)
    print(f'{len(v4)} IPv4 and {len(v6)} IPv6 sends traced')
    assert len(v4) + len(v6) > 20, f'too few sends traced to judge:\n{text[:2000]}'
    assert {a for a in v4 if not a.startswith('127.')} == set()
    assert {a for a in v6 if a != '::1'} == set()


# -- the environment a node applies itself, and the setup file's commands -------------
def test_the_install_prefix_goes_first_on_ament_prefix_path_once():
    prefix = ros_env.ament_prefix()
    assert prefix is not None, 'lightstage_graph runs from an install with an ament index marker'
    env = ros_env.ros_environment(None, base={'AMENT_PREFIX_PATH': '/opt/ros/jazzy'})
    assert env['AMENT_PREFIX_PATH'] == f'{prefix}{os.pathsep}/opt/ros/jazzy'
    again = ros_env.ros_environment(None, base=env)
    assert again['AMENT_PREFIX_PATH'] == env['AMENT_PREFIX_PATH']


def test_a_node_started_without_the_environment_applies_it_and_says_what_it_set(monkeypatch, saved_environ):
    for name in ('ROS_AUTOMATIC_DISCOVERY_RANGE', 'FASTRTPS_DEFAULT_PROFILES_FILE', 'AMENT_PREFIX_PATH'):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv('ROS_STATIC_PEERS', '10.0.0.7')
    message = ros_env.apply_node_environment()
    assert os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST' and 'ROS_STATIC_PEERS' not in os.environ
    assert 'ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST (was unset)' in message
    assert f'FASTRTPS_DEFAULT_PROFILES_FILE={ros_env.fastdds_profile_path()} (was unset)' in message
    assert 'unset ROS_STATIC_PEERS (was 10.0.0.7)' in message
    assert ros_env.apply_node_environment() is None  # already the project's: nothing to say


def test_shell_commands_turn_an_environment_into_the_projects():
    base = {'PATH': '/bin', 'ROS_STATIC_PEERS': '10.0.0.7', 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET',
            'FASTRTPS_DEFAULT_PROFILES_FILE': "/my profiles/it's.xml"}
    out = subprocess.run(['sh', '-c', ros_env.shell_commands(base) + 'env'], env=base,
                         capture_output=True, text=True, check=True).stdout
    env = dict(line.split('=', 1) for line in out.splitlines() if '=' in line)
    expected = ros_env.ros_environment(base=base)
    for name in ('ROS_AUTOMATIC_DISCOVERY_RANGE', 'FASTRTPS_DEFAULT_PROFILES_FILE', 'RMW_IMPLEMENTATION',
                 'AMENT_PREFIX_PATH'):
        assert env[name] == expected[name], name
    assert 'ROS_STATIC_PEERS' not in env and env['FASTRTPS_DEFAULT_PROFILES_FILE'] == "/my profiles/it's.xml"
    assert ros_env.shell_commands(expected) == ''


@pytest.mark.skipif(os.environ.get('LIGHTSTAGE_TEST_NETNS') != 'private',
                    reason='not run by scripts/run_tests.sh in a private network namespace')
def test_the_suite_runs_where_no_packet_can_leave_the_machine():
    import errno
    import socket

    from helpers.suite import network_interfaces
    assert network_interfaces() == ['lo']
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        with pytest.raises(OSError) as excinfo:
            s.sendto(b'x', ('192.0.2.1', 9))  # TEST-NET-1: would need a route off the machine
    assert excinfo.value.errno == errno.ENETUNREACH


# -- the service reply writer's profile ------------------------------------------------
SERVICE_PROBE = '''
import sys, time
import rclpy
from rcl_interfaces.srv import GetParameters
rclpy.init()
node = rclpy.create_node('reply_profile_probe')
node.create_service(GetParameters, '/probe/echo', lambda request, response: response)
client = node.create_client(GetParameters, '/probe/echo')
deadline = time.monotonic() + float(sys.argv[1])
while not client.service_is_ready() and time.monotonic() < deadline:
    rclpy.spin_once(node, timeout_sec=0.05)
if not client.service_is_ready():
    print('not ready')
else:
    future = client.call_async(GetParameters.Request())
    rclpy.spin_until_future_complete(node, future, timeout_sec=10.0)
    print('answered' if future.done() else 'unanswered')
'''


def _probe_service(profile_path: str, wait_s: float) -> str:
    env = ros_env.ros_environment(fresh_domain_id())
    env['FASTRTPS_DEFAULT_PROFILES_FILE'] = profile_path
    result = subprocess.run([sys.executable, '-c', SERVICE_PROBE, str(wait_s)], env=env,
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    return result.stdout.strip()


def test_the_profile_gives_service_replies_two_seconds_to_find_their_client():
    root = ET.parse(ros_env.fastdds_profile_path()).getroot()
    writer = root.find(f'.//{NS}data_writer[@profile_name="service"]')
    blocking = writer.find(f'{NS}qos/{NS}reliability/{NS}max_blocking_time')
    assert int(blocking.findtext(f'{NS}sec')) >= 1


@pytest.mark.ros
def test_the_service_profile_is_the_one_rmw_gives_the_reply_writer(tmp_path):
    """Only if rmw_fastrtps takes the "service" profile for reply writers does its
    max_blocking_time count: put that profile's writer into a partition no client reads, and
    the service never becomes ready; with the profile as shipped, it answers."""
    shipped = ros_env.fastdds_profile_path()
    assert _probe_service(str(shipped), 10.0) == 'answered'
    text = shipped.read_text()
    moved = text.replace('<data_writer profile_name="service">\n      <qos>',
                         '<data_writer profile_name="service">\n      <qos><partition><names>'
                         '<name>nowhere</name></names></partition>', 1)
    assert moved != text
    path = tmp_path / 'service_writer_elsewhere.xml'
    path.write_text(moved)
    assert _probe_service(str(path), 3.0) == 'not ready'


# -- the suite's own domain ids ---------------------------------------------------------
def test_parallel_workers_draw_disjoint_domain_ids(monkeypatch):
    """Two pytest-xdist workers run tests at the same time: their ids never meet, and all
    are per-test ids (1..99, below the run's own 100..199)."""
    from helpers.suite import fresh_domain_id
    drawn = {}
    for worker in (0, 1):
        monkeypatch.setenv('PYTEST_XDIST_WORKER', f'gw{worker}')
        monkeypatch.setenv('PYTEST_XDIST_WORKER_COUNT', '2')
        drawn[worker] = {fresh_domain_id() for _ in range(200)}
    assert not drawn[0] & drawn[1]
    assert all(1 <= d <= 99 for ids in drawn.values() for d in ids)
    assert min(len(ids) for ids in drawn.values()) >= 40   # each worker still has many
