"""Injected faults (Python simulator): each leads to a retry or a clear error in time, LEDs end dark."""
import errno
import os
import signal
import termios
import time

import numpy as np
import pytest
import serial

from lightstage_driver import link as link_module
from lightstage_driver.errors import (DisconnectedError, LinkError, NoReplyError, NotASerialPortError,
                                      PortNotFoundError, PortPermissionError, ReplyChecksumError)
from lightstage_driver.stage import LightStage

from helpers.driver import wait_until

TIMEOUT_S = 0.1
RETRIES = 3


def one_hot(led):
    pattern = np.zeros(32)
    pattern[led] = 1.0
    return pattern


def observed_up_to_now(sim, stage) -> None:
    """A barrier on what the simulator reports: the firmware handles commands in order and
    reports a FIRE's pulse before it answers it, so once a word latched by a command sent now
    is observed, every pulse and latch before it is too."""
    word = stage.set_pattern(one_hot(31))
    assert wait_until(lambda: sim.current_word() == word, 5.0)


@pytest.fixture
def stage(sim):
    stage = LightStage(sim.port, timeout_s=TIMEOUT_S, retries=RETRIES, connect_timeout_s=2.0)
    stage.connect()
    sim.reset_observations()
    yield stage
    stage.close()


def test_dropped_bytes_are_retried(sim, stage):
    sim.set_faults(drop_rx_next=4)          # the next command loses its first 4 bytes
    word = stage.set_pattern(one_hot(3))
    # one attempt timed out, the retry was answered
    assert stage.link.stats.retries == 1 and stage.link.stats.timeouts == 1
    assert wait_until(lambda: sim.current_word() == word, 1.0)


def test_a_corrupted_reply_is_retried_and_fire_is_not_repeated(sim, stage):
    stage.set_pattern(one_hot(1), show_now=False)
    sim.set_faults(corrupt_tx_next=1)       # the FIRE reply arrives corrupted
    trigger = stage.fire(2000)
    # under load the retried reply can also come late and be retried once more; what must
    # hold is one bad CRC and a single trigger
    assert stage.link.stats.crc_errors == 1 and stage.link.stats.retries >= 1
    assert trigger.exposure_us == 2000
    observed_up_to_now(sim, stage)
    assert len(sim.trigger_pulses()) == 1   # the retry was answered from the firmware's cache


def test_a_missing_reply_is_retried(sim, stage):
    sim.set_faults(mute_next=2)
    stage.heartbeat()
    assert stage.link.stats.timeouts == 2 and stage.link.stats.retries == 2


def test_a_corrupted_command_gets_a_bad_crc_nak_and_is_resent(sim, stage):
    # line noise that looks like a frame start right before the command: the firmware reads
    # A5 05 + the command's first bytes as one frame, finds the CRC wrong and NAKs BAD_CRC.
    # The noise goes out in the command's own write: written separately, a loaded machine
    # can leave an inter-byte gap that makes the firmware drop it as a stale partial frame
    # (it did: no NAK, no retry)
    serial = stage.link._serial
    write = serial.write

    def write_after_noise(data):
        serial.write = write
        return write(bytes([0xA5, 0x05]) + bytes(data)) - 2

    serial.write = write_after_noise
    word = stage.set_pattern(one_hot(2), show_now=True)
    assert stage.link.stats.firmware_crc_naks == 1 and stage.link.stats.retries == 1
    assert wait_until(lambda: sim.current_word() == word, 1.0)
    assert stage.heartbeat().rx_errors == 1


def test_a_noisy_line_never_double_triggers(sim, stage):
    sim.set_faults(drop_rx_prob=0.01, corrupt_tx_prob=0.05, seed=7)
    fires = 40
    for k in range(fires):
        stage.set_pattern(one_hot(k % 32), show_now=False)
        stage.fire(100)
    stats = stage.link.stats
    assert stats.retries > 0 and stats.crc_errors > 0      # the faults really happened
    sim.set_faults(drop_rx_prob=0.0, corrupt_tx_prob=0.0)
    stage.heartbeat()
    assert wait_until(lambda: len(sim.trigger_pulses()) >= fires, 5.0)
    assert sim.current_word() == 0
    observed_up_to_now(sim, stage)
    assert len(sim.trigger_pulses()) == fires                 # exactly one trigger per FIRE


def test_a_hung_firmware_gives_no_reply_error_in_time_and_its_watchdog_darkens(sim, stage):
    stage.set_watchdog(200)
    word = stage.set_pattern(one_hot(5))
    assert wait_until(lambda: sim.current_word() == word, 1.0)
    sim.set_faults(mute_all=True)
    start = time.monotonic()
    with pytest.raises(NoReplyError, match='no valid reply to HEARTBEAT after 4 attempt') as info:
        stage.heartbeat()
    assert time.monotonic() - start >= (RETRIES + 1) * TIMEOUT_S   # it waited out every attempt
    assert stage.link.stats.timeouts == RETRIES + 1
    assert 'firmware alive' in str(info.value)
    assert wait_until(lambda: sim.current_word() == 0, 1.0)   # host went silent: watchdog


def test_always_corrupted_replies_give_a_clear_error(sim, stage):
    sim.set_faults(corrupt_tx_prob=1.0)
    # a reply the loaded machine delays past the 100 ms reply timeout would count as a
    # timeout, not a CRC error: a generous timeout keeps this about corruption alone
    stage.link.timeout_s = 5.0
    with pytest.raises(ReplyChecksumError, match=r'4 attempt\(s\) at HEARTBEAT met a CRC mismatch.*baud rate'):
        stage.heartbeat()
    # corrupted replies are retried at once, not after the reply timeout
    assert stage.link.stats.crc_errors == RETRIES + 1 and stage.link.stats.timeouts == 0


def test_latency_within_the_timeout_is_fine_beyond_it_is_an_error(sim, stage):
    sim.set_faults(latency_ms=40)
    stage.heartbeat()
    assert stage.link.stats.retries == 0
    sim.set_faults(latency_ms=250)    # a late reply to an earlier attempt still counts (same seq)
    stage.heartbeat()
    sim.set_faults(latency_ms=600)    # later than all attempts together
    with pytest.raises(NoReplyError):
        stage.heartbeat()


def test_a_lost_sequence_event_is_an_error_and_leds_end_dark(sim, stage):
    patterns = np.array([one_hot(k) for k in range(3)])
    assert len(stage.apply(patterns, 1000)) == 3          # fine without faults
    sim.set_faults(corrupt_only_cmd=0x41, corrupt_tx_next=1)   # the next EVT_TRIGGER is corrupted
    with pytest.raises(LinkError, match=r'trigger event\(s\) \[0\] of the sequence were lost'):
        stage.apply(patterns, 1000)
    assert stage.link.stats.crc_errors == 1
    assert wait_until(lambda: len(sim.trigger_pulses()) == 6, 1.0)   # it did fire; only the stamp is lost
    assert wait_until(lambda: sim.current_word() == 0, 1.0)


def test_a_sequence_that_never_ends_on_a_dead_line_does_not_claim_the_leds_are_off(sim, stage):
    # the end-of-sequence event is lost and, once the first trigger is reported, the firmware
    # stops answering: the host's ALL_OFF goes unanswered, so nothing is known of the LEDs
    sim.set_faults(corrupt_only_cmd=0x42, corrupt_tx_next=1)
    patterns = np.ones((3, 32))
    with pytest.raises(LinkError, match='did not finish') as info:
        stage.apply(patterns, 1000, on_trigger=lambda trigger: sim.set_faults(mute_all=True))
    message = str(info.value)
    assert 'switching the LEDs off failed too' in message and 'their state is unknown' in message
    assert 'LEDs switched off' not in message


def test_a_sequence_that_never_ends_says_the_leds_were_switched_off_when_they_were(sim, stage):
    sim.set_faults(corrupt_only_cmd=0x42, corrupt_tx_next=1)   # only the end-of-sequence event lost
    with pytest.raises(LinkError, match='did not finish') as info:
        stage.apply(np.ones((3, 32)), 1000)
    assert str(info.value).endswith('LEDs switched off')
    assert wait_until(lambda: sim.current_word() == 0, 1.0)


def test_a_busy_host_does_not_fail_a_sequence_that_is_progressing(sim, stage):
    # the host stalls in its trigger callback (publishing, other processes) for longer than the
    # whole sequence's reply margin: the firmware went on, and the sequence completes
    margin_s = TIMEOUT_S * (RETRIES + 1)
    stalls = []

    def busy(trigger):
        if not stalls:
            stalls.append(trigger.index)
            time.sleep(margin_s + 0.3)
    triggers = stage.apply(np.ones((3, 32)), 1000, on_trigger=busy)
    assert len(triggers) == 3 and stalls == [triggers[0].index]
    assert wait_until(lambda: sim.current_word() == 0, 1.0)


def test_disconnect_mid_use_then_replug_recovers(sim, stage):
    stage.set_pattern(one_hot(9))
    assert wait_until(lambda: sim.current_word() == 1 << 9, 1.0)
    sim.disconnect(reconnect_after_s=0.3)
    assert sim.current_word() == 0
    with pytest.raises(DisconnectedError, match='went away'):
        stage.heartbeat()
    status = stage.heartbeat()                 # reopens (waits for the re-plug) and re-identifies
    assert not status.leds_lit                 # the device reset on re-plug: dark
    assert stage.link.stats.reconnects == 1
    stage.apply(one_hot(4), 500)


def test_a_port_failing_in_tcdrain_is_a_disconnect(sim, stage):
    # seen when the simulator died between a command's write and its flush: termios.error is
    # no OSError, and it took the driver node down
    def fail():
        raise termios.error(5, 'Input/output error')
    stage.link._serial.flush = fail
    with pytest.raises(DisconnectedError, match='went away'):
        stage.heartbeat()
    assert not stage.link.is_open


def test_port_gone_for_good_is_port_not_found(sim):
    stage = LightStage(sim.port, timeout_s=TIMEOUT_S, connect_timeout_s=0.3)
    stage.connect()
    sim.kill()
    with pytest.raises(DisconnectedError):
        stage.heartbeat()
    with pytest.raises(PortNotFoundError, match='does not exist'):   # given up, not hung
        stage.heartbeat()


def test_a_killed_simulator_leaves_no_link_to_its_pty(sim):
    # else a reconnecting driver would open whatever pty next gets the dead one's number
    assert os.path.realpath(sim.port) == sim.pty_path
    os.kill(sim.pid, signal.SIGKILL)
    assert wait_until(lambda: not os.path.lexists(sim.port), 5.0)
    sim.restart()
    assert os.path.realpath(sim.port) == sim.pty_path


def test_missing_port_and_unknown_usb_serial_are_named():
    with pytest.raises(PortNotFoundError, match='/nonexistent/ttyACM7 does not exist'):
        LightStage('/nonexistent/ttyACM7', connect_timeout_s=0.2).connect()
    with pytest.raises(PortNotFoundError, match="serial number 'NOSUCHSTAGE'"):
        LightStage('usb:NOSUCHSTAGE', connect_timeout_s=0.2).connect()


@pytest.mark.parametrize('kind', ['regular file', 'directory', '/dev/null'])
def test_a_path_that_is_no_serial_device_is_named_so(kind, tmp_path):
    # a regular file or /dev/null gave "Could not configure port: (25,
    # 'Inappropriate ioctl for device')"
    if kind == 'regular file':
        port, said = tmp_path / 'ttyACM0', 'is a regular file, not a serial device'
        port.write_bytes(b'')
    elif kind == 'directory':
        port, said = tmp_path, 'is a directory, not a serial device'
    else:
        port, said = '/dev/null', '/dev/null is not a serial device'
    with pytest.raises(NotASerialPortError) as info:
        LightStage(str(port), connect_timeout_s=0.2).connect()
    message = str(info.value)
    assert said in message
    assert '/dev/ttyACM0' in message and 'usb:SERIAL' in message and '`sim`' in message   # what to give


def test_usb_serial_number_resolves_to_its_device(monkeypatch):
    class Info:
        def __init__(self, device, serial_number):
            self.device, self.serial_number = device, serial_number
    monkeypatch.setattr(link_module.list_ports, 'comports',
                        lambda: [Info('/dev/ttyACM0', 'A1'), Info('/dev/ttyACM3', 'STAGE42')])
    assert link_module.resolve_port('usb:STAGE42') == '/dev/ttyACM3'
    assert link_module.resolve_port('/dev/ttyUSB0') == '/dev/ttyUSB0'


def test_permission_denied_says_what_to_do(monkeypatch, tmp_path):
    device = tmp_path / 'ttyACM0'
    device.touch()
    monkeypatch.setattr(link_module, 'not_a_serial_device', lambda path: '')  # the file stands in for a tty

    def refuse(*args, **kwargs):
        raise serial.SerialException(errno.EACCES, f"could not open port {device}: [Errno 13] Permission denied")
    monkeypatch.setattr(link_module.serial, 'Serial', refuse)
    with pytest.raises(PortPermissionError, match='dialout'):
        LightStage(str(device), connect_timeout_s=0.2).connect()


def test_a_silent_device_is_not_taken_for_a_stage(sim):
    sim.set_faults(mute_all=True)
    start = time.monotonic()
    with pytest.raises(NoReplyError, match='no IDENTIFY reply within 0.5 s'):
        LightStage(sim.port, timeout_s=TIMEOUT_S, connect_timeout_s=0.5).connect()
    assert time.monotonic() - start >= 0.5     # it gave the device its whole connect timeout
