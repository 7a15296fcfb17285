"""The page's classify client gets every reply of a burst: 30 classify calls in flight at once
from one process, answered at once by the service (lightstage_graph.qos.SERVICE_CLIENT_QOS).
Every client of a service receives every reply; with a reply reader of the default depth, 10,
4 and 15 of the 30 calls got no reply (two runs)."""
from __future__ import annotations

import asyncio
import threading

import pytest
from helpers.suite import fresh_domain_id

pytestmark = pytest.mark.ros

CALLS = 30


def test_thirty_page_classify_calls_at_once_each_get_their_answer():
    import rclpy
    from lightstage_bringup.web_node import WebBridge
    from lightstage_bringup.web_state import PageState
    from lightstage_graph.names import CLASSIFY_SERVICE
    from lightstage_graph.qos import QUEUED_SERVICE_QOS
    from lightstage_interfaces.srv import Classify
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    answered = []

    def classify(request, response):
        answered.append(request.max_images)
        response.success = True
        response.label = f'call {request.max_images}'
        return response

    context = Context()
    rclpy.init(context=context, domain_id=fresh_domain_id())
    executor = SingleThreadedExecutor(context=context)
    server_executor = SingleThreadedExecutor(context=context)  # answers while the page reads
    try:
        server = Node('classifier_stand_in', context=context)
        server.create_service(Classify, CLASSIFY_SERVICE, classify, qos_profile=QUEUED_SERVICE_QOS)
        page = WebBridge(PageState(history_size=10), context=context)
        server_executor.add_node(server)
        executor.add_node(page)
        threading.Thread(target=server_executor.spin, daemon=True).start()
        threading.Thread(target=executor.spin, daemon=True).start()

        async def burst():
            page.loop = asyncio.get_running_loop()
            # one call answered first: the reply path is matched (service_is_ready() does
            # not cover it, and a request sent before is lost)
            for _ in range(40):
                if page.classify_client.service_is_ready():
                    warm_up = page.classify_client.call_async(Classify.Request(max_images=0))
                    for _ in range(10):
                        if warm_up.done():
                            break
                        await asyncio.sleep(0.1)
                    if warm_up.done():
                        break
                    page.classify_client.remove_pending_request(warm_up)
                await asyncio.sleep(0.1)
            answered.clear()
            return await asyncio.gather(*(page.classify(max_images=i, timeout_s=1.0)
                                          for i in range(1, CALLS + 1)))

        replies = asyncio.run(burst())
        assert len(answered) == CALLS
        unanswered = [r['message'] for r in replies if not r['success']]
        assert not unanswered, f'{len(unanswered)} of {CALLS} calls got no reply: {unanswered[:2]}'
        assert [r['label'] for r in replies] == [f'call {i}' for i in range(1, CALLS + 1)]
    finally:
        executor.shutdown(timeout_sec=2.0)
        server_executor.shutdown(timeout_sec=2.0)
        rclpy.shutdown(context=context)
