"""Light stage driver: wire protocol, serial link, firmware simulator and the driver node.

The host side (no rclpy):
    protocol          wire protocol v1 (docs/PROTOCOL.md of this package): frames, CRC, payloads
    link              the serial link to the firmware: framing, stop-and-wait, retries, reconnect
    clock             the firmware's 32-bit microsecond clock mapped to the host's monotonic one
    patterns          LED patterns and exposures checked before anything is sent
    schedule          graded LED levels as on-times: the latch schedule of one exposure
    request_check     an ApplyPatterns request checked field by field, naming the field
    stage             `LightStage`: the typed host API of the stage (the node's, a notebook's)
    errors            every way talking to the stage can fail, each saying what to do
The firmware without a board (no rclpy):
    firmware_model    the microcontroller firmware as a pure state machine
    firmware_sim      that model behind a real pseudo-terminal (`lightstage-firmware-sim`)
    firmware_backend  what a firmware under test looks like to the tests and benchmarks
    sim_backend       `FirmwareBackend` for the Python simulator, run as its own process
    simavr_backend    `FirmwareBackend` for the AVR firmware (firmware/), compiled and run in simavr
ROS (rclpy):
    driver_node       the managed (lifecycle) driver node around `stage.LightStage`

Importing the package imports none of them: `from lightstage_driver.stage import LightStage`.
"""

__all__ = ['protocol', 'link', 'clock', 'patterns', 'schedule', 'request_check', 'stage',
           'errors', 'firmware_model', 'firmware_sim', 'firmware_backend', 'sim_backend',
           'simavr_backend', 'driver_node']
