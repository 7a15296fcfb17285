"""Stopping the trainer node (SIGINT, as `lightstage up` and Ctrl-C do) while a goal runs:
the goal ends at its next progress event, aborted with the reason, no artifact written, and
the node exits 0 without a traceback (lightstage_graph.spin's stop_work)."""
import signal
import subprocess
import sys

import pytest

from helpers.ros import child_environment
from helpers.suite import GraphClient, fresh_domain_id

pytestmark = [pytest.mark.ros, pytest.mark.process]
TRAIN = '/lightstage/train'


def test_a_stop_during_a_goal_aborts_it_with_the_reason_and_exits_0(tiny_capture, tmp_path):
    from action_msgs.msg import GoalStatus
    from lightstage_interfaces.action import Train
    from rclpy.action import ActionClient
    domain_id = fresh_domain_id()
    proc = subprocess.Popen([sys.executable, '-m', 'mux_trainer.trainer_node', '--ros-args',
                             '-p', 'n_jobs:=1'], env=child_environment(domain_id),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    client = GraphClient(domain_id)
    try:
        action = ActionClient(client.node, Train, TRAIN)
        client.spin_until(action.server_is_ready, 30, 'the Train action server')
        feedback = []
        artifact = tmp_path / 'never.npz'
        goal = Train.Goal(capture_dir=str(tiny_capture), output_path=str(artifact),
                          noise='sigma2', max_images=8, repeats=5, seed=7)
        handle = client.result(action.send_goal_async(
            goal, feedback_callback=lambda f: feedback.append(f.feedback)))
        assert handle.accepted
        client.spin_until(lambda: any(f.column >= 1 for f in feedback), 60, 'the first column')
        proc.send_signal(signal.SIGINT)
        outcome = client.result(handle.get_result_async(), 30, 'the stopped goal\'s result')
        out, _ = proc.communicate(timeout=30)
    finally:
        client.close()
        if proc.poll() is None:
            proc.kill()
    assert outcome.status == GoalStatus.STATUS_ABORTED, out
    assert outcome.result.message == 'aborted: the trainer node is stopping; no artifact written'
    assert not artifact.exists()
    assert proc.returncode == 0, out
    assert 'Traceback' not in out and 'exception was never retrieved' not in out, out
