"""The driver's parameters that it takes at a lifecycle transition (port, baud, timeout_ms, ...
at configure; heartbeat_period_s at activate) change only while that transition is ahead:
`ros2 param set` at another time answers unsuccessful with the reason and what to do, instead
of "successful" and no effect until the next cleanup / configure. Those read only at start-up
are read-only; the ones read at each use stay settable."""
import pytest
from lightstage_bringup.supervisor import Supervisor

from helpers.suite import GraphClient, fresh_domain_id, start_nodes, write_params

from lightstage_driver.driver_node import ON_ACTIVATE, ON_CONFIGURE, PARAMETERS, refused_change

pytestmark = [pytest.mark.ros, pytest.mark.process]


def test_the_parameters_taken_at_a_transition_are_the_ones_read_there():
    """The table's notes against what on_configure / on_activate read (driver_node.py)."""
    at_configure = {n for n, (_, d) in PARAMETERS.items() if d.description.endswith(ON_CONFIGURE)}
    at_activate = {n for n, (_, d) in PARAMETERS.items() if d.description.endswith(ON_ACTIVATE)}
    assert at_configure == {'port', 'baud', 'timeout_ms', 'retries', 'connect_timeout_s',
                            'watchdog_ms', 'sites', 'channels'}
    assert at_activate == {'heartbeat_period_s'}
    assert refused_change('baud', 'unconfigured') == ''
    assert refused_change('default_exposure_us', 'active') == ''
    assert 'cleanup' in refused_change('baud', 'inactive')


def change_state(client: GraphClient, transition: int) -> None:
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState
    answer = client.call(ChangeState, '/driver/change_state',
                         ChangeState.Request(transition=Transition(id=transition)))
    assert answer.success, transition


def test_a_parameter_taken_at_configure_changes_only_while_the_driver_is_unconfigured(tmp_path):
    from lifecycle_msgs.msg import Transition
    domain_id = fresh_domain_id()
    params = write_params(tmp_path / 'params.yaml', {'driver': {'port': 'sim'}})
    client = GraphClient(domain_id)
    try:
        with Supervisor(sigint_timeout_s=5.0) as supervisor:
            start_nodes(supervisor, client, ['driver'], domain_id, params)   # autostart: active
            (baud,) = client.set_parameters('driver', baud=9600)
            assert not baud.successful
            assert 'baud is taken when the driver is configured and it is active' in baud.reason
            assert 'deactivate, cleanup' in baud.reason
            (port, timeout) = client.set_parameters('driver', port='/dev/ttyACM7', timeout_ms=50)
            assert not port.successful and not timeout.successful and 'timeout_ms' in timeout.reason
            (heartbeat,) = client.set_parameters('driver', heartbeat_period_s=0.1)
            assert not heartbeat.successful and 'deactivate' in heartbeat.reason
            (exposure,) = client.set_parameters('driver', default_exposure_us=20_000)
            assert exposure.successful, exposure.reason     # read at each request
            (diagnostics,) = client.set_parameters('driver', diagnostics_period_s=0.5)
            assert not diagnostics.successful               # read once, at start-up

            change_state(client, Transition.TRANSITION_DEACTIVATE)
            (heartbeat,) = client.set_parameters('driver', heartbeat_period_s=0.1)
            assert heartbeat.successful, heartbeat.reason
            (baud,) = client.set_parameters('driver', baud=9600)
            assert not baud.successful and 'it is inactive' in baud.reason

            change_state(client, Transition.TRANSITION_CLEANUP)
            (baud, timeout) = client.set_parameters('driver', baud=9600, timeout_ms=50)
            assert baud.successful and timeout.successful, (baud.reason, timeout.reason)
            change_state(client, Transition.TRANSITION_CONFIGURE)   # the simulator: any baud
            change_state(client, Transition.TRANSITION_ACTIVATE)
    finally:
        client.close()
