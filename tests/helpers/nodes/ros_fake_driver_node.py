"""Stand-in for the driver node in the cross-process interface tests.

Serves ApplyPatterns on `/lightstage/apply_patterns` and publishes one IlluminationState
on `/illumination` per pattern when the request asks for triggers, the names and
behaviour of lightstage_driver.driver_node; no hardware or firmware behind it.
"""
import sys

import numpy as np
import rclpy
from lightstage_graph.limits import requested_gain_db
from lightstage_graph.spin import spin_until_stopped
from rclpy.node import Node

from lightstage_interfaces.msg import IlluminationState
from lightstage_interfaces.srv import ApplyPatterns


class FakeDriver(Node):
    def __init__(self):
        super().__init__('fake_driver')
        self.publisher = self.create_publisher(IlluminationState, '/illumination', 50)
        self.create_service(ApplyPatterns, '/lightstage/apply_patterns', self.apply_patterns)
        self.frame_id = self.declare_parameter('frame_id', 'lightstage').value
        self.next_request_id = 1
        self.next_sequence = 0

    def apply_patterns(self, request, response):
        for i, p in enumerate(request.patterns):
            values = np.asarray(p.intensities)
            outside = np.flatnonzero((values < 0) | (values > 1))
            if outside.size:
                led = int(outside[0])
                response.success = False
                response.message = (f'pattern {i}, LED {led} (site {led // 4}, channel {led % 4}) is '
                                    f'{values[led]:g}, outside 0..1; scale the pattern')
                return response
        response.request_id = self.next_request_id
        self.next_request_id += 1
        response.success = True
        if not request.trigger:
            return response
        for i, p in enumerate(request.patterns):
            msg = IlluminationState()
            msg.header.stamp = self.get_clock().now().to_msg()
            msg.header.frame_id = self.frame_id
            msg.sequence = self.next_sequence
            msg.request_id = response.request_id
            msg.index_in_request = i
            msg.count_in_request = len(request.patterns)
            msg.intensities = p.intensities
            msg.exposure_us = p.exposure_us
            msg.gain_db = requested_gain_db(p.gain_db, p.gain_db_set)
            self.publisher.publish(msg)
            response.trigger_stamps.append(msg.header.stamp)
            response.sequences.append(msg.sequence)
            self.next_sequence += 1
        return response


def main() -> int:
    rclpy.init()
    node = FakeDriver()
    print(f'fake driver up as {node.get_fully_qualified_name()}', flush=True)
    return spin_until_stopped(node)


if __name__ == '__main__':
    sys.exit(main())
