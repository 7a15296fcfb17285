"""The page's classify client keeps every reply of a burst (lightstage_graph.qos.service_client).
Every client of a service receives every reply the service sends, to whichever client: the
page's client reads the replies to every CLI and script calling /lightstage/classify too, and
one the executor has not taken yet is evicted by later ones beyond the reader's depth. Here
30 calls in flight through the page's own client make the burst, answered at once by a
stand-in service; with the default depth, 10, 4 and 15 of the 30 got no reply (two runs)."""
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


def test_the_page_keeps_its_reply_while_another_client_of_the_service_gets_29():
    """The page's reply arrives while its executor is busy; then 29 replies to another client
    of /lightstage/classify arrive at the page's reply reader too. With the default depth, 10,
    they evicted the page's reply: it was never taken (4 runs of 4)."""
    import time

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
        return response

    def spin_until(executor, done, timeout_s=10.0):
        end = time.monotonic() + timeout_s
        while not done() and time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)
        return done()

    def answered_once(executor, client):
        """One call answered: the reply path is matched (service_is_ready() does not cover it)."""
        assert spin_until(executor, client.service_is_ready)
        for _ in range(10):
            future = client.call_async(Classify.Request())
            if spin_until(executor, future.done, 1.0):
                return
            client.remove_pending_request(future)
        raise AssertionError('the stand-in service never answered')

    context = Context()
    rclpy.init(context=context, domain_id=fresh_domain_id())
    server_executor = SingleThreadedExecutor(context=context)
    page_executor = SingleThreadedExecutor(context=context)
    other_executor = SingleThreadedExecutor(context=context)
    try:
        server = Node('classifier_stand_in', context=context)
        server.create_service(Classify, CLASSIFY_SERVICE, classify, qos_profile=QUEUED_SERVICE_QOS)
        server_executor.add_node(server)
        threading.Thread(target=server_executor.spin, daemon=True).start()
        page = WebBridge(PageState(history_size=10), context=context)
        page_executor.add_node(page)
        other = Node('another_caller', context=context)
        other_client = other.create_client(Classify, CLASSIFY_SERVICE, qos_profile=QUEUED_SERVICE_QOS)
        other_executor.add_node(other)
        answered_once(page_executor, page.classify_client)
        answered_once(other_executor, other_client)
        answered.clear()

        mine = page.classify_client.call_async(Classify.Request(max_images=100))
        end = time.monotonic() + 10.0
        while answered != [100] and time.monotonic() < end:  # answered, not yet taken
            time.sleep(0.05)
        assert answered == [100]
        theirs = [other_client.call_async(Classify.Request(max_images=i)) for i in range(1, 30)]
        assert spin_until(other_executor, lambda: all(f.done() for f in theirs))
        assert spin_until(page_executor, mine.done, 3.0), 'the page never got its reply'
        assert mine.result().success
    finally:
        for executor in (page_executor, other_executor, server_executor):
            executor.shutdown(timeout_sec=2.0)
        rclpy.shutdown(context=context)
