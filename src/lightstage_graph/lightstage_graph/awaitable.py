"""Awaiting, in a node's executor, work that runs on a thread of its own.

A callback that blocks holds an executor thread; on rclpy 7.1's MultiThreadedExecutor every
thread that is free meanwhile re-dispatches a ready subscription until one takes its message
(10 to 50 empty handlers per image, docs/NODES.md "Observing mode"). So a node whose
callbacks must wait for long work (the stage) runs that work on a worker thread and its
callback, a coroutine, awaits `executor_future`: the node's one executor thread stays free
for the images and the replies the work waits for.
"""
from __future__ import annotations

from concurrent.futures import Future as ThreadFuture

from rclpy.task import Future

__all__ = ["executor_future"]


def executor_future(node, outcome: ThreadFuture) -> Future:
    """An rclpy Future done with `outcome` (the thread's future itself) when it is, waking
    the node's executor then (a result set from another thread does not wake it by itself:
    ros2/rclpy#1467)."""
    done = Future()

    def resolve(finished: ThreadFuture):
        done.set_result(finished)
        executor = node.executor
        if executor is not None:
            executor.wake()
    outcome.add_done_callback(resolve)
    return done
