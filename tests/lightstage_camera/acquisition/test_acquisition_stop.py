"""Stopping the acquisition node (SIGINT, as `lightstage up` and Ctrl-C do) while it captures
a model: the capture ends at its next cancellation check, the goal is aborted with the
reason, nothing is written, and the node exits 0 without a traceback (the goal's work runs
on a worker thread that the node's `stop_work` asks to end; lightstage_graph.spin)."""
import math
import signal
import subprocess
import sys

import pytest
from lightstage_bringup.supervisor import Supervisor

from helpers.acquisition import StageGraph
from helpers.ros import child_environment
from helpers.suite import fresh_domain_id, write_params

pytestmark = [pytest.mark.ros, pytest.mark.process]


def test_a_stop_during_a_capture_aborts_it_with_the_reason_and_exits_0(tmp_path):
    from action_msgs.msg import GoalStatus
    from lightstage_interfaces.action import CaptureModel
    from lightstage_physics import synth
    fruit = synth.generate(tmp_path / 'fruit', image_size=48, n_samples_per_class=1, n_poses=1,
                           object_types=('banana',), n_jobs=1)
    domain_id = fresh_domain_id()
    params = write_params(tmp_path / 'params.yaml', {
        'camera': {'capture_dir': str(fruit), 'sample': 'banana-real/s0/p00', 'dimmer': 1.0}})
    client = StageGraph(domain_id)
    proc = None
    try:
        with Supervisor(sigint_timeout_s=5.0) as supervisor:
            client.start(supervisor, ['driver', 'camera'], params)
            proc = subprocess.Popen([sys.executable, '-m', 'lightstage_camera.acquisition_node'],
                                    env=child_environment(domain_id), stdout=subprocess.PIPE,
                                    stderr=subprocess.STDOUT, text=True)
            out_dir = tmp_path / 'models'
            goal = CaptureModel.Goal(output_dir=str(out_dir), label='banana-real', sample='s0',
                                     pose='p00', exposure_us=5000, gain_db=math.nan,
                                     frames_averaged=16)
            stopped = []

            def stop_when(feedback) -> bool:   # SIGINT, not a cancel request
                if feedback.images_done >= 3 and not stopped:
                    stopped.append(True)
                    proc.send_signal(signal.SIGINT)
                return False

            status, result, feedback = client.action(CaptureModel, '/lightstage/capture_model',
                                                     goal, timeout_s=60, cancel_when=stop_when)
            out, _ = proc.communicate(timeout=30)
    finally:
        client.close()
        if proc is not None and proc.poll() is None:
            proc.kill()
    assert stopped and status == GoalStatus.STATUS_ABORTED, (result, out)
    assert result.message.endswith('failed: the acquisition node is stopping'), result.message
    assert max(f.images_done for f in feedback) < 32
    assert not out_dir.exists() or not any(out_dir.rglob('*.png')), list(out_dir.rglob('*'))
    assert proc.returncode == 0, out
    assert 'Traceback' not in out and 'exception was never retrieved' not in out, out
