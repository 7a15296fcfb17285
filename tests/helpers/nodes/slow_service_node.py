"""A node whose one service (std_srvs/Trigger on /slow) takes `delay_s` (default 1.5 s) to
answer, run by lightstage_graph's spin_until_stopped: a stop that lands while a request is
in flight (tests/lightstage_graph/test_spin.py)."""
import sys
import time

from rclpy.node import Node
from std_srvs.srv import Trigger

from lightstage_graph.spin import init_node, spin_until_stopped


class SlowService(Node):
    def __init__(self):
        super().__init__('slow')
        self.declare_parameter('delay_s', 1.5)
        self.create_service(Trigger, '/slow', self._on_request)

    def _on_request(self, _request, response):
        print('request taken', flush=True)
        time.sleep(self.get_parameter('delay_s').value)
        response.success = True
        response.message = 'answered'
        return response


def main() -> int:
    init_node(sys.argv)
    return spin_until_stopped(SlowService())


if __name__ == '__main__':
    sys.exit(main())
