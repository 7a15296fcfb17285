"""Stand-in for the trainer node in the cross-process interface tests.

Serves the Train action on `~/train`: one feedback message per pattern column
(1..max_images), then a result with a made-up but well-formed accuracy curve; no search
behind it. A goal with max_images == 0 is rejected, as the real trainer should.
"""
import sys
import time

import rclpy
from rclpy.action import ActionServer, GoalResponse
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node

from lightstage_interfaces.action import Train


class FakeTrainer(Node):
    def __init__(self):
        super().__init__('fake_trainer')
        self.server = ActionServer(self, Train, '~/train', self.execute,
                                   goal_callback=self.check_goal)

    def check_goal(self, goal):
        return GoalResponse.ACCEPT if goal.max_images > 0 else GoalResponse.REJECT

    def execute(self, goal_handle):
        goal = goal_handle.request
        t0 = time.monotonic()
        accuracy = []
        for column in range(1, goal.max_images + 1):
            accuracy.append(1.0 - 0.5 / column)
            feedback = Train.Feedback(column=column, candidates_done=column * 10,
                                      candidates_total=goal.max_images * 10,
                                      best_accuracy=accuracy[-1], stage=f'column {column}')
            goal_handle.publish_feedback(feedback)
            time.sleep(0.02)
        goal_handle.succeed()
        return Train.Result(success=True, message='', artifact_path=goal.output_path,
                            accuracy_by_images=accuracy, elapsed_s=time.monotonic() - t0)


def main() -> int:
    rclpy.init()
    node = FakeTrainer()
    print(f'fake trainer up as {node.get_fully_qualified_name()}', flush=True)
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    return 0


if __name__ == '__main__':
    sys.exit(main())
