"""A participant of its own for the programs that talk to a running graph: the CLI verbs,
the demo, `lightstage up`'s graph watcher and the tests. One rclpy context (so it never disturbs another in the process),
one node without parameter services, one single-threaded executor it spins itself.

    with GraphClient(domain_id, 'lightstage_classify_cli') as graph:
        response = graph.call(Classify, CLASSIFY_SERVICE, request, timeout_s=15.0, wait_s=5.0)

Ctrl-C raises KeyboardInterrupt in the caller (rclpy's signal handler is not installed, so
the context stays usable, e.g. to cancel a running goal). Whatever does not happen in time
raises `GraphTimeout` saying what was awaited; a goal whose action server goes away raises
`ServerLost` (a GraphTimeout too) instead of waiting for a result that cannot come.
"""
from __future__ import annotations

import os
import time


class GraphTimeout(TimeoutError):
    """A service, action server, answer or condition did not come in time."""


class ServerLost(GraphTimeout):
    """The action server of a running goal went away (its node stopped or was killed), or
    came back without the goal: the goal's result will never come."""


class GraphClient:
    def __init__(self, domain_id: int | None = None, name: str | None = None, **node_options):
        """`node_options`: more keyword arguments of `rclpy.create_node`."""
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id, args=[],
                   signal_handler_options=SignalHandlerOptions.NO)
        self.domain_id = self.context.get_domain_id()
        self.node = rclpy.create_node(name or f'lightstage_client_{os.getpid()}',
                                      context=self.context, start_parameter_services=False,
                                      **node_options)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._clients = {}  # one client per service / action, discovered once

    def close(self) -> None:
        """Executor, node, then the context, in that order (idempotent). Shutting the context
        down first left the executor's guard conditions to a garbage collection after it:
        `Exception ignored in: <function Executor.__del__> ... InvalidHandle` on stderr."""
        if self.context.ok():
            self.executor.shutdown(timeout_sec=0)
            self.node.destroy_node()
        self.context.try_shutdown()

    def __enter__(self) -> GraphClient:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ spinning
    def spin_until(self, predicate, timeout_s: float = 10.0, what='condition') -> None:
        """Spin until predicate() holds; ``what`` (a string, or a callable giving one when the
        time is up, e.g. to show a log as it is then) names what was awaited."""
        deadline = time.monotonic() + timeout_s
        while not predicate():
            if time.monotonic() >= deadline:
                raise GraphTimeout(f'timed out after {timeout_s:g} s waiting for '
                                   f'{what() if callable(what) else what}')
            self.executor.spin_once(timeout_sec=0.05)

    def spin_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.05)

    def result(self, future, timeout_s: float = 10.0, what: str = 'a response'):
        self.spin_until(future.done, timeout_s, what)
        return future.result()

    # ------------------------------------------------------------------ services
    def service(self, srv_type, name: str):
        """The client of service `name` (made once), its reply reader 1000 deep
        (`qos.service_client`: many calls in flight may be answered at once)."""
        if name not in self._clients:
            from .qos import service_client
            self._clients[name] = service_client(self.node, srv_type, name)
        return self._clients[name]

    def _unavailable(self, what: str, wait_s: float, hint: str) -> GraphTimeout:
        return GraphTimeout(f'{what} is not available after {wait_s:g} s '
                            f'(ROS_DOMAIN_ID={self.domain_id})' + (f'; {hint}' if hint else ''))

    def call(self, srv_type, name: str, request, timeout_s: float = 30.0, wait_s: float = 10.0,
             attempts: int = 1, hint: str = ''):
        """Wait up to `wait_s` for service `name`, call it and return the response. With
        `attempts` > 1 an unanswered call is sent again (idempotent services only)."""
        client = self.service(srv_type, name)
        try:
            self.spin_until(client.service_is_ready, wait_s, f'service {name}')
        except GraphTimeout:
            raise self._unavailable(f'the service {name}', wait_s, hint) from None
        return self.call_until_answered(client, request, attempts, timeout_s)

    def call_until_answered(self, client, request, attempts: int = 4, per_try_s: float = 3.0):
        """Call until it answers: a request sent while the service's reply path (server ->
        this client) is still being matched, which `service_is_ready()` does not cover, can
        be lost. More than one attempt only for idempotent services."""
        for _ in range(attempts):
            future = client.call_async(request)
            deadline = time.monotonic() + per_try_s
            while not future.done() and time.monotonic() < deadline:
                self.executor.spin_once(timeout_sec=0.05)
            if future.done():
                return future.result()
            client.remove_pending_request(future)
        raise GraphTimeout(f'no answer from {client.srv_name} within {per_try_s:g} s'
                           + (f' ({attempts} attempts)' if attempts > 1 else ''))

    def set_parameters(self, node_name: str, **values) -> list:
        """SetParameters on a node; returns its list of SetParametersResult."""
        from rcl_interfaces.srv import SetParameters
        request = SetParameters.Request(parameters=parameter_msgs(values))
        return self.call(SetParameters, f'/{node_name}/set_parameters', request).results

    def set_parameters_atomically(self, node_name: str, values: dict, timeout_s: float = 30.0,
                                  wait_s: float = 10.0, hint: str = ''):
        """SetParametersAtomically on a node (it sees them as one change); returns the one
        SetParametersResult."""
        from rcl_interfaces.srv import SetParametersAtomically
        request = SetParametersAtomically.Request(parameters=parameter_msgs(values))
        return self.call(SetParametersAtomically, f'/{node_name}/set_parameters_atomically',
                         request, timeout_s=timeout_s, wait_s=wait_s, hint=hint).result

    # ------------------------------------------------------------------ actions
    def send_goal(self, action_type, name: str, goal, wait_s: float = 10.0, on_feedback=None,
                  timeout_s: float = 30.0, hint: str = ''):
        """Send `goal` to action `name` (waiting up to `wait_s` for its server); returns the
        goal handle (`.accepted` says whether the server took it). `on_feedback(feedback)`."""
        from rclpy.action import ActionClient
        key = ('action', name)
        if key not in self._clients:
            self._clients[key] = ActionClient(self.node, action_type, name)
        client = self._clients[key]
        if not client.wait_for_server(timeout_sec=wait_s):
            raise self._unavailable(f'the action {name}', wait_s, hint)
        send = client.send_goal_async(
            goal, feedback_callback=None if on_feedback is None else lambda m: on_feedback(m.feedback))
        return self.result(send, timeout_s, f'{name} to answer the goal')

    def goal_result(self, handle, result_future, name: str, grace_s: float = 1.0,
                    recheck_s: float = 10.0):
        """Spin until `result_future` (from `handle.get_result_async()`) is done and return
        its response (`.status`, `.result`); raise `ServerLost` once the server of action
        `name` has been gone for more than `grace_s` (`goal_watch.ServerWatch`).

        A killed server sends no result: the graph drops it when its participant's lease
        ends (the project's Fast DDS profile: 5 s), and this gives up `grace_s` after that.
        A server that came back (restarted within the lease, or after a gap shorter than
        the grace) has no record of the goal: the result is asked for again after every gap
        and every `recheck_s`, and the new server's STATUS_UNKNOWN answer ends the wait.
        """
        from action_msgs.msg import GoalStatus

        from .goal_watch import ServerWatch
        client = self._clients[('action', name)]
        watch = ServerWatch(grace_s)
        probes, gap, next_probe_at = [], False, time.monotonic() + recheck_s
        while not result_future.done():
            self.executor.spin_once(timeout_sec=0.1)
            if result_future.done():
                break
            ready = client.server_is_ready()
            if watch.observe(ready):
                raise ServerLost(f'the action server {name} went away while the goal ran (gone '
                                 f'for {watch.lost_for_s:.1f} s: its node stopped or was killed); '
                                 'the goal\'s outcome is unknown, check the node\'s log and output')
            gap = gap or not ready
            for probe in probes:
                if probe.done():
                    answer = probe.result()
                    if answer.status == GoalStatus.STATUS_UNKNOWN:
                        raise ServerLost(f'the action server {name} restarted while the goal ran '
                                         'and does not know the goal; its outcome is unknown, '
                                         'check the node\'s log and output')
                    return answer
            if ready and (gap or time.monotonic() >= next_probe_at):
                probes.append(handle.get_result_async())
                gap, next_probe_at = False, time.monotonic() + recheck_s
        return result_future.result()

    # ------------------------------------------------------------------ the graph
    def subscribed_by(self, topic: str, node_name: str) -> bool:
        return any(i.node_name == node_name for i in self.node.get_subscriptions_info_by_topic(topic))

    def wait_for_subscriptions(self, node_name: str, topics, timeout_s: float,
                               settle_s: float = 1.0) -> None:
        """Until `node_name` subscribes to every topic, then `settle_s` more: publishers match
        a new subscription a little after the graph shows it."""
        self.spin_until(lambda: all(self.subscribed_by(t, node_name) for t in topics), timeout_s,
                        lambda: f'{node_name} to subscribe to '
                                + ', '.join(t for t in topics if not self.subscribed_by(t, node_name)))
        self.spin_for(settle_s)


def parameter_msgs(values: dict) -> list:
    """{name: value} -> rcl_interfaces Parameter messages."""
    from rclpy.parameter import Parameter
    return [Parameter(k, value=v).to_parameter_msg() for k, v in values.items()]
