"""The lifecycle driver node as a separate process, against the Python simulator on a pty."""
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from lightstage_graph.ros_env import ros_environment
from lightstage_driver.sim_backend import PythonSimBackend

from helpers.driver import child_pids, distinct_words, wait_until

pytestmark = [pytest.mark.ros, pytest.mark.process]

rclpy = pytest.importorskip('rclpy')
interfaces = pytest.importorskip('lightstage_interfaces.srv')
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus  # noqa: E402
from lifecycle_msgs.msg import Transition  # noqa: E402
from lifecycle_msgs.srv import ChangeState  # noqa: E402
from lightstage_interfaces.msg import IlluminationState, Pattern  # noqa: E402
from lightstage_interfaces.srv import ApplyPatterns  # noqa: E402

from helpers.suite import REPO, fresh_domain_id  # noqa: E402

SRC = REPO / 'src'


def start_node(port: str, name: str, *params: str, domain_id: int) -> subprocess.Popen:
    env = ros_environment(domain_id)
    env['PYTHONPATH'] = os.pathsep.join([str(SRC / 'lightstage_driver'), str(SRC / 'lightstage_bringup'),
                                         env.get('PYTHONPATH', '')])
    args = [sys.executable, '-m', 'lightstage_driver.driver_node', '--ros-args', '-r', f'__node:={name}',
            '-p', f'port:={port}', '-p', 'diagnostics_period_s:=0.2', '-p', 'timeout_ms:=100', '-p', 'connect_timeout_s:=0.5']
    for param in params:
        args += ['-p', param]
    return subprocess.Popen(args, env=env)


def stop_node(proc: subprocess.Popen) -> int:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            return proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
    return proc.wait()


class Client:
    """An rclpy context of its own on the node's domain, so tests never see each other's nodes."""

    def __init__(self, node_name: str, domain_id: int):
        from rclpy.executors import SingleThreadedExecutor
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = rclpy.create_node(f'driver_test_client_{node_name}', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.illumination: list[IlluminationState] = []
        self.diagnostics: list[DiagnosticArray] = []
        self.node.create_subscription(IlluminationState, '/illumination', self.illumination.append, 100)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self.diagnostics.append, 50)
        self.apply_client = self.node.create_client(ApplyPatterns, '/lightstage/apply_patterns')
        self.lifecycle = self.node.create_client(ChangeState, f'/{node_name}/change_state')

    def call(self, client, request, timeout_s=10.0, attempts=1):
        # service_is_ready() covers the request direction only: a reply sent before the
        # node's reply writer has matched this client is lost. Idempotent requests may be
        # resent (attempts > 1); the others wait the whole timeout once.
        assert client.wait_for_service(timeout_sec=20.0), 'service did not appear'
        for _ in range(attempts):
            future = client.call_async(request)
            self.executor.spin_until_future_complete(future, timeout_sec=timeout_s / attempts)
            if future.done():
                return future.result()
            client.remove_pending_request(future)
        raise AssertionError(f'no response in {timeout_s} s ({attempts} attempt(s))')

    def apply(self, patterns, trigger=True, exposure_us=1000):
        request = ApplyPatterns.Request(trigger=trigger)
        for pattern in patterns:
            msg = Pattern()
            msg.intensities = np.asarray(pattern, dtype=np.float32)
            msg.exposure_us = exposure_us
            msg.gain_db = 12.0
            request.patterns.append(msg)
        # setting LEDs without a trigger is idempotent: safe to resend
        return self.call(self.apply_client, request, attempts=1 if trigger else 3)

    def transition(self, transition_id):
        request = ChangeState.Request()
        request.transition.id = transition_id
        return self.call(self.lifecycle, request).success

    def spin_until(self, predicate, timeout_s=5.0):
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and not predicate():
            self.executor.spin_once(timeout_sec=0.05)
        return predicate()

    def wait_status(self, predicate, timeout_s=20.0):
        """The first /diagnostics status from now on with predicate(status, values) true, and its
        values (a key -> value dict); fails the test if none comes within timeout_s."""
        self.diagnostics.clear()
        found = []

        def check():
            for array in self.diagnostics:
                status = array.status[0]
                values = {kv.key: kv.value for kv in status.values}
                if predicate(status, values):
                    found.append((status, values))
                    return True
            return False
        def seen():
            return [{kv.key: kv.value for kv in a.status[0].values}.get('state') for a in self.diagnostics]
        assert self.spin_until(check, timeout_s), f'no such /diagnostics status within {timeout_s} s: {seen()}'
        return found[0]

    def wait_state(self, state, timeout_s=20.0):
        return self.wait_status(lambda status, values: values['state'] == state, timeout_s)

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()
        self.context.try_shutdown()


@pytest.fixture(scope='module')
def rig():
    backend = PythonSimBackend()
    backend.start()
    domain = fresh_domain_id()
    proc = start_node(backend.port, 'stage_driver_under_test', domain_id=domain)
    client = Client('stage_driver_under_test', domain)
    yield backend, proc, client
    client.close()
    stop_node(proc)
    backend.close()


def eye(*leds):
    pattern = np.zeros(32)
    pattern[list(leds)] = 1.0
    return pattern


ALL_ON = (1 << 32) - 1
ONE_SECOND_US = 1_000_000


def test_apply_triggers_stamps_and_publishes_illumination(rig):
    backend, proc, client = rig
    assert client.apply([eye(0)], trigger=False).success      # wait for the service; warm-up
    backend.reset_observations()
    client.illumination.clear()
    patterns = [eye(k * 4) for k in range(3)]
    before = time.time()
    response = client.apply(patterns, exposure_us=2000)
    assert response.success, response.message
    assert len(response.trigger_stamps) == 3 and len(response.sequences) == 3
    assert list(np.diff(response.sequences)) == [1, 1]
    stamps = [s.sec + s.nanosec * 1e-9 for s in response.trigger_stamps]
    assert before - 0.5 < stamps[0] < time.time() + 0.5
    assert np.diff(stamps) == pytest.approx([0.002, 0.002], abs=0.0015)  # exposure apart (gap 0)
    assert client.spin_until(lambda: len(client.illumination) == 3)
    for k, msg in enumerate(client.illumination):
        assert msg.sequence == response.sequences[k] and msg.request_id == response.request_id
        assert (msg.index_in_request, msg.count_in_request) == (k, 3)
        assert msg.header.stamp == response.trigger_stamps[k] and msg.header.frame_id == 'lightstage'
        assert np.array_equal(msg.intensities, eye(k * 4).astype(np.float32))
        assert msg.exposure_us == 2000 and msg.gain_db == pytest.approx(12.0)
    assert wait_until(lambda: len(backend.trigger_pulses()) == 3, 2.0)
    assert [w for w in distinct_words(backend) if w] == [1, 1 << 4, 1 << 8]


def test_bad_request_is_refused_and_nothing_is_sent(rig):
    backend, proc, client = rig
    backend.reset_observations()
    assert client.apply([eye(1)], trigger=True).success
    # the simulator reports the pulse and the dark word after the reply: let them in first
    assert wait_until(lambda: len(backend.trigger_pulses()) == 1 and backend.current_word() == 0, 5.0)
    backend.reset_observations()
    bad = eye(2)
    bad[6] = 1.7
    response = client.apply([eye(1), bad])
    assert not response.success
    assert 'patterns[1].intensities[6]: pattern 1, LED 6 (site 1, channel 2) is above 1: 1.7;' in response.message
    assert 'nothing was sent' in response.message
    response = client.apply([eye(1)], exposure_us=5)
    assert not response.success and 'patterns[0].exposure_us 5 us is outside' in response.message
    time.sleep(0.1)
    assert backend.led_words() == [] and backend.trigger_pulses() == []


def test_diagnostics_report_the_link(rig):
    backend, proc, client = rig
    client.diagnostics.clear()
    assert client.spin_until(lambda: len(client.diagnostics) >= 1)
    status = client.diagnostics[-1].status[0]
    values = {kv.key: kv.value for kv in status.values}
    assert status.level == b'\x00' and values['state'] == 'armed'
    assert values['firmware'] == 'lightstage-pysim' and status.hardware_id.startswith('lightstage-pysim')
    assert int(values['commands']) > 0 and 'crc_errors' in values and 'watchdog_trips' in values


def test_deactivate_darkens_and_refuses_then_activate_serves_again(rig):
    backend, proc, client = rig
    assert client.apply([eye(5, 6)], trigger=False).success
    assert wait_until(lambda: backend.current_word() == (1 << 5) | (1 << 6), 2.0)
    assert client.transition(Transition.TRANSITION_DEACTIVATE)
    assert wait_until(lambda: backend.current_word() == 0, 2.0)
    response = client.apply([eye(1)])
    assert not response.success and 'not active' in response.message
    assert client.transition(Transition.TRANSITION_ACTIVATE)
    assert client.apply([eye(1)]).success


def test_a_lost_port_is_reported_requests_fail_at_once_and_the_link_comes_back(rig):
    # for a port that is not the driver's own simulator (as a real serial
    # port): the firmware process is killed, its pty goes
    backend, proc, client = rig
    client.wait_state('armed')
    os.kill(backend.pid, signal.SIGKILL)
    status, values = client.wait_state('link down')      # the heartbeat noticed
    assert status.level == DiagnosticStatus.ERROR
    assert 'heartbeat failed' in status.message and 'went away' in status.message
    assert f'the driver tries to reopen {backend.port} every 1 s' in status.message
    response = client.apply([eye(3)])
    assert not response.success
    assert 'the link to the stage is down (heartbeat failed' in response.message   # the reason, at once
    assert 'nothing was sent' in response.message and 'tries to reopen' in response.message
    backend.restart()
    status, values = client.wait_state('armed', 30.0)
    assert int(values['reconnects']) >= 1
    response = client.apply([eye(3)])
    assert response.success, response.message
    assert wait_until(lambda: backend.current_word() == 0, 5.0)


def test_firmware_killed_mid_sequence_the_reply_says_the_leds_state_is_unknown(rig):
    # the reply said "LEDs switched off" while the driver could not switch
    # them off and the last latched word was all 32 LEDs on
    backend, proc, client = rig
    client.wait_state('armed')
    backend.reset_observations()
    request = ApplyPatterns.Request(trigger=True)
    for _ in range(4):
        request.patterns.append(Pattern(intensities=np.ones(32, dtype=np.float32), exposure_us=ONE_SECOND_US))
    future = client.apply_client.call_async(request)
    assert backend.wait_for(lambda words, pulses: bool(words) and words[-1].word == ALL_ON, 20.0)
    os.kill(backend.pid, signal.SIGKILL)                   # mid-sequence, all 32 LEDs lit
    client.executor.spin_until_future_complete(future, timeout_sec=30.0)
    assert future.done(), 'no reply'
    response = future.result()
    assert not response.success
    message = response.message
    assert 'went away' in message and 'LEDs switched off' not in message
    assert 'The board is unreachable, so the state of its LEDs is unknown' in message
    assert 'its watchdog (watchdog_ms = 1000)' in message
    assert 'the driver switches them off when it reconnects' in message
    assert 'trigger(s) happened and were published' in message
    status, values = client.wait_state('link down')
    assert status.level == DiagnosticStatus.ERROR and 'apply failed' in status.message
    backend.restart()
    client.wait_state('armed', 30.0)
    assert client.apply([eye(7)]).success


def test_the_drivers_own_simulator_killed_is_noticed_reported_and_restarted():
    # with port sim, the simulator child killed was never restarted and every
    # request waited 10-12 s for "driver did not answer"
    domain = fresh_domain_id()
    proc = start_node('sim', 'stage_driver_sim_killed', 'reconnect_period_s:=5.0', domain_id=domain)
    client = Client('stage_driver_sim_killed', domain)
    try:
        assert client.apply([eye(0)], trigger=False).success
        status, values = client.wait_state('armed')
        sims = child_pids(proc.pid, 'lightstage_driver.firmware_sim')
        assert sims == [int(values['simulator_pid'])]
        os.kill(sims[0], signal.SIGKILL)
        # the next request: a reply with the reason (the link down, or the port gone under it),
        # never a wait for a dead simulator
        response = client.apply([eye(1)])
        assert not response.success
        assert 'the link to the stage is down' in response.message or 'went away' in response.message
        response = client.apply([eye(1)])
        assert not response.success
        assert 'the link to the stage is down' in response.message
        assert 'the driver restarts its firmware simulator and reconnects every 5 s' in response.message
        status, values = client.wait_state('link down')
        assert status.level == DiagnosticStatus.ERROR
        status, values = client.wait_status(
            lambda status, values: values['state'] == 'armed' and values['simulator_restarts'] == '1', 60.0)
        restarted = int(values['simulator_pid'])
        assert restarted != sims[0] and restarted in child_pids(proc.pid)
        response = client.apply([eye(2)])
        assert response.success, response.message

        # inactive (no heartbeats), the simulator's exit alone is noticed
        assert client.transition(Transition.TRANSITION_DEACTIVATE)
        os.kill(restarted, signal.SIGKILL)
        status, values = client.wait_state('link down')
        assert 'the firmware simulator process ended (killed by SIGKILL)' in status.message
        assert client.transition(Transition.TRANSITION_ACTIVATE)
        status, values = client.wait_status(
            lambda status, values: values['state'] == 'armed' and values['simulator_restarts'] == '2', 60.0)
        assert client.apply([eye(3)]).success
    finally:
        client.close()
        assert stop_node(proc) == 0


def test_shutdown_switches_the_leds_off():
    backend = PythonSimBackend()
    backend.start()
    domain = fresh_domain_id()
    proc = start_node(backend.port, 'stage_driver_shutdown', domain_id=domain)
    client = Client('stage_driver_shutdown', domain)
    try:
        assert client.apply([eye(30, 31)], trigger=False).success
        assert wait_until(lambda: backend.current_word() == 3 << 30, 2.0), backend.led_words()
        assert stop_node(proc) == 0
        assert backend.current_word() == 0
    finally:
        client.close()
        stop_node(proc)
        backend.close()


def test_port_sim_starts_its_own_simulator():
    domain = fresh_domain_id()
    proc = start_node('sim://?pwm_bits=8', 'stage_driver_own_sim', domain_id=domain)
    client = Client('stage_driver_own_sim', domain)
    try:
        half = np.full(32, 0.25)
        response = client.apply([half, eye(2)], exposure_us=500)
        assert response.success, response.message
        assert len(response.trigger_stamps) == 2
        client.diagnostics.clear()
        assert client.spin_until(lambda: any(
            {kv.key: kv.value for kv in d.status[0].values}.get('pwm_bits') == '8' for d in client.diagnostics))
    finally:
        client.close()
        assert stop_node(proc) == 0


@pytest.mark.parametrize('port, params, reason', [
    ('/nonexistent/ttyACM9', (), '/nonexistent/ttyACM9 does not exist'),
    # these gave "Could not configure port: (25, 'Inappropriate ioctl for device')"
    ('/dev/null', (), '/dev/null is not a serial device'),
    ('REGULAR_FILE', (), 'is a regular file, not a serial device'),
    ('sim', ('sites:=6',), 'drives 8 sites x 4 channels, but this rig is configured as 6 x 4'),
    ('sim', ('heartbeat_period_s:=0.8',), 'heartbeat_period_s 0.8 is too long for watchdog_ms 1000'),
])
def test_a_configure_failure_leaves_the_node_up_unconfigured_with_the_reason(port, params, reason, tmp_path):
    if port == 'REGULAR_FILE':
        port = str(tmp_path / 'ttyACM0')
        Path(port).write_bytes(b'')
    domain = fresh_domain_id()
    proc = start_node(port, 'stage_driver_no_port', *params, domain_id=domain)
    client = Client('stage_driver_no_port', domain)
    try:
        assert client.spin_until(lambda: bool(client.diagnostics), 20.0)
        status = client.diagnostics[-1].status[0]
        assert status.level == DiagnosticStatus.ERROR
        assert 'unconfigured' in status.message and reason in status.message
        if 'serial device' in reason:      # and what to give instead
            assert 'usb:SERIAL' in status.message and '`sim`' in status.message
        response = client.apply([eye(0)])
        assert not response.success and 'not active' in response.message
        assert proc.poll() is None
    finally:
        client.close()
        assert stop_node(proc) == 0


def test_a_crashed_driver_does_not_leave_the_leds_on():
    backend = PythonSimBackend()
    backend.start()
    domain = fresh_domain_id()
    proc = start_node(backend.port, 'stage_driver_crash', 'watchdog_ms:=300', 'heartbeat_period_s:=0.1',
                      domain_id=domain)
    client = Client('stage_driver_crash', domain)
    try:
        assert client.apply([eye(12)], trigger=False).success
        time.sleep(0.6)                    # heartbeats keep the pattern lit past the watchdog time
        assert backend.current_word() == 1 << 12
        proc.kill()                        # no shutdown handler runs
        proc.wait()
        killed_at = time.monotonic()
        assert wait_until(lambda: backend.current_word() == 0, 2.0)
        assert time.monotonic() - killed_at < 0.3 + 0.3   # the firmware watchdog, not luck
    finally:
        client.close()
        stop_node(proc)
        backend.close()


def test_every_bad_request_field_is_refused_by_name_and_the_node_serves_on(rig):
    """NaN, infinite, negative, above-1 drives, exposures out of range, gains out of
    range, graded drives on this on/off board: each refused naming the field, nothing sent."""
    backend, proc, client = rig
    assert client.apply([eye(0)], trigger=False).success
    assert wait_until(lambda: backend.current_word() == 1, 2.0)    # its latch reported
    backend.reset_observations()

    def send(intensities=None, exposure_us=1000, gain_db=12.0):
        request = ApplyPatterns.Request(trigger=True)
        msg = Pattern()
        msg.intensities = np.asarray(eye(1) if intensities is None else intensities, dtype=np.float32)
        msg.exposure_us = exposure_us
        msg.gain_db = gain_db
        request.patterns.append(msg)
        return client.call(client.apply_client, request)

    def with_led(led, value):
        pattern = eye(1)
        pattern[led] = value
        return pattern

    cases = [(dict(intensities=with_led(3, np.nan)), 'patterns[0].intensities[3]: pattern 0, LED 3 (site 0, channel 3) is NaN'),
             (dict(intensities=with_led(4, np.inf)), 'patterns[0].intensities[4]: pattern 0, LED 4 (site 1, channel 0) is infinite'),
             (dict(intensities=with_led(5, -1.0)), 'patterns[0].intensities[5]: pattern 0, LED 5 (site 1, channel 1) is negative'),
             (dict(intensities=with_led(6, 3e38)), 'patterns[0].intensities[6]: pattern 0, LED 6 (site 1, channel 2) is above 1'),
             (dict(exposure_us=2**32 - 1), 'patterns[0].exposure_us 4294967295 us is outside the firmware range'),
             (dict(exposure_us=19), 'patterns[0].exposure_us 19 us is outside'),
             (dict(gain_db=float('inf')), 'patterns[0].gain_db = inf dB is out of range: give 0 .. 48 dB'),
             (dict(gain_db=-1.0), 'patterns[0].gain_db = -1.0 dB is out of range'),
             (dict(gain_db=3e38), 'dB is out of range: give 0 .. 48 dB'),
             (dict(intensities=with_led(9, 0.7)), 'is 0.699999988079071, a graded level, but the board')]
    for fields, expected in cases:
        response = send(**fields)
        assert not response.success and expected in response.message, (fields, response.message)
        assert 'nothing was sent' in response.message
    time.sleep(0.1)
    assert backend.led_words() == [] and backend.trigger_pulses() == []
    # the camera default gain (NaN) and the driver default exposure (0) are fine
    response = send(exposure_us=0, gain_db=float('nan'))
    assert response.success, response.message
    assert proc.poll() is None
