"""The driver's own simulator killed under a running graph.

It was never restarted: every classify then waited 10-12 s for "driver did not answer".
Now the classify fails with the driver's reason and works again once the driver has
restarted its simulator.
"""
import os
import signal
import time

import pytest
from lightstage_bringup.supervisor import Supervisor

from helpers.driver import child_pids
from helpers.suite import GraphClient, fresh_domain_id, stage_graph_params, start_nodes, write_params

pytestmark = [pytest.mark.ros, pytest.mark.process]

LINK_DOWN = 'the link to the stage is down'


def test_classify_after_the_drivers_simulator_is_killed_fails_with_the_reason_then_works_again(
        stage_capture, stage_artifact_path, tmp_path):
    from lightstage_interfaces.srv import Classify
    domain_id = fresh_domain_id()
    params = write_params(tmp_path / 'params.yaml', stage_graph_params(
        stage_capture, 'banana-real/s0/p00', 3, stage_artifact_path,
        driver={'port': 'sim', 'reconnect_period_s': 5.0}))
    client = GraphClient(domain_id)

    def classify():
        return client.call(Classify, '/lightstage/classify', Classify.Request(max_images=4, timeout_s=10.0),
                           timeout_s=30.0)
    try:
        with Supervisor(sigint_timeout_s=5.0) as supervisor:
            start_nodes(supervisor, client, ['driver', 'camera', 'classifier'], domain_id, params)
            first = classify()
            assert first.success, first.message
            (simulator,) = child_pids(supervisor['driver'].pid, 'lightstage_driver.firmware_sim')
            os.kill(simulator, signal.SIGKILL)

            # the next classify: the driver's reason (its link down, or its port gone under the
            # request), not a wait for an answer that never comes
            response = classify()
            assert not response.success
            assert 'the driver did not apply the patterns' in response.message
            assert LINK_DOWN in response.message or 'went away' in response.message
            assert 'did not answer' not in response.message
            response = classify()
            assert not response.success and LINK_DOWN in response.message
            assert 'restarts its firmware simulator' in response.message

            # the driver restarts its simulator: classify works again (polled, generous bound)
            deadline = time.monotonic() + 90.0
            while not response.success and time.monotonic() < deadline:
                assert LINK_DOWN in response.message, response.message
                client.spin_for(0.5)
                response = classify()
            assert response.success, response.message
            assert not supervisor.exited()
    finally:
        client.close()
