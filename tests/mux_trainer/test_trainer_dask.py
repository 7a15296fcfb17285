"""The trainer node's Train action on a Dask cluster (`dask_scheduler` parameter): feedback
per column while the candidates are evaluated remotely, and a goal aborted with the reason,
naming the address, once the scheduler is gone (not a hang)."""
import pytest
import yaml

from helpers.ros import running_nodes
from helpers.suite import GraphClient, fresh_domain_id

distributed = pytest.importorskip('distributed')

pytestmark = [pytest.mark.ros, pytest.mark.process]
TRAIN = '/lightstage/train'


def test_train_goal_runs_on_the_cluster_then_aborts_when_it_is_gone(cluster, dask_scheduler,
                                                                    tmp_path, tiny_capture):
    from action_msgs.msg import GoalStatus
    from lightstage_interfaces.action import Train
    from rclpy.action import ActionClient
    address, workers = cluster
    _, scheduler = dask_scheduler
    params = tmp_path / 'params.yaml'
    params.write_text(yaml.safe_dump({'trainer': {'ros__parameters': {
        'n_jobs': 1, 'dask_scheduler': address, 'dask_timeout_s': 3.0}}}))
    domain_id = fresh_domain_id()
    with running_nodes({'trainer': 'mux_trainer.trainer_node'}, domain_id,
                       params_file=str(params)), GraphClient(domain_id) as c:
        client = ActionClient(c.node, Train, TRAIN)
        c.spin_until(client.server_is_ready, 30, 'the Train action server')
        feedback = []
        goal = Train.Goal(capture_dir=str(tiny_capture), output_path=str(tmp_path / 'a.npz'),
                          max_images=2, repeats=4, seed=3)
        with distributed.Client(address, set_as_default=False) as watcher:
            watcher.get_task_stream()  # starts the scheduler's record of the tasks
            handle = c.result(client.send_goal_async(
                goal, feedback_callback=lambda f: feedback.append(f.feedback)))
            assert handle.accepted
            result = c.result(handle.get_result_async(), 600, 'the Train result').result
            remote_tasks = [t for t in watcher.get_task_stream(count=100000)
                            if str(t['key']).startswith('score_chunk_with')]
        assert result.success, result.message
        assert remote_tasks  # the candidates were evaluated on the cluster
        columns = [f.column for f in feedback[1:]]
        assert columns[0] == 1 and columns == sorted(columns)
        # one report per column searched (the last may be one that did not improve)
        done = [f.candidates_done for f in feedback if f.candidates_done]
        assert done == [254] * len(done) and len(done) >= len(result.accuracy_by_images)

        # the whole cluster goes away: the next goal ends aborted, naming the address
        for proc in (scheduler, *workers.values()):
            proc.kill()
            proc.wait(timeout=30)
        handle = c.result(client.send_goal_async(
            Train.Goal(capture_dir=str(tiny_capture), output_path=str(tmp_path / 'b.npz'),
                       max_images=2, repeats=4, seed=3)))
        outcome = c.result(handle.get_result_async(), 120, 'the aborted Train result')
        assert outcome.status == GoalStatus.STATUS_ABORTED
        assert address in outcome.result.message and 'Dask scheduler' in outcome.result.message
        assert not (tmp_path / 'b.npz').exists()
        client.destroy()
