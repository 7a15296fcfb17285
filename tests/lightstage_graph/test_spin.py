"""How a node's main() stops (lightstage_graph.spin): a signal asks the spin loop to end,
the request in flight is answered, then the node is destroyed and rclpy shut down in that
order; a second signal does not wait. The node is tests/helpers/nodes/slow_service_node.py
(one service that takes delay_s to answer), started as a process, as `lightstage up` does."""
import contextlib
import signal
import subprocess
import sys

import pytest

from helpers.ros import child_environment
from helpers.suite import GraphClient, fresh_domain_id

pytestmark = [pytest.mark.ros, pytest.mark.process]


@contextlib.contextmanager
def slow_node(delay_s: float):
    """The node process (its service answers after `delay_s`) and a client in its domain;
    the process is killed at the end if a test left it running."""
    domain_id = fresh_domain_id()
    proc = subprocess.Popen([sys.executable, '-m', 'slow_service_node', '--ros-args', '-p', f'delay_s:={delay_s}'],
                            env=child_environment(domain_id), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    client = GraphClient(domain_id)
    try:
        yield proc, client
    finally:
        client.close()
        if proc.poll() is None:
            proc.kill()


def _call_and_wait_until_taken(client: GraphClient, proc: subprocess.Popen):
    from std_srvs.srv import Trigger
    cli = client.node.create_client(Trigger, '/slow')
    client.spin_until(cli.service_is_ready, 30.0, 'the /slow service')
    future = cli.call_async(Trigger.Request())
    assert proc.stdout.readline().strip() == 'request taken'
    return future


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM], ids=['SIGINT', 'SIGTERM'])
def test_a_stop_answers_the_request_in_flight_then_exits_0(sig):
    with slow_node(delay_s=1.5) as (proc, client):
        future = _call_and_wait_until_taken(client, proc)
        proc.send_signal(sig)
        # rclpy's own handler shut the context down here, under the callback: no answer
        answer = client.result(future, 20.0)
        assert answer.success and answer.message == 'answered'
        out, _ = proc.communicate(timeout=20)
    assert proc.returncode == 0, out
    assert 'Traceback' not in out, out


def test_a_second_signal_interrupts_a_long_callback_and_still_exits_0():
    with slow_node(delay_s=60.0) as (proc, client):
        _call_and_wait_until_taken(client, proc)
        proc.send_signal(signal.SIGINT)
        with pytest.raises(subprocess.TimeoutExpired):  # the first one waits for the answer
            proc.wait(timeout=1.0)
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=20)
    assert proc.returncode == 0, out
    assert 'Traceback' not in out, out
