"""The serial link to the stage's firmware: framing, stop-and-wait, retries, reconnect.

`SerialLink` opens a port by path (`/dev/ttyACM0`, a `/dev/serial/by-id/...` link, a
simulator's pty link) or by USB serial number (`usb:SERIAL`, found again after a
re-plug under whatever /dev name it gets), sends one command at a time and waits for its
reply. A reply lost or corrupted is retried with the same sequence number (the firmware
answers a duplicate from its cache instead of executing it twice); a NAK raises
`NakError` with the firmware's reason. If the port goes away the command in flight
raises `DisconnectedError`; the next command reopens the port and re-identifies (unless
`auto_reopen` is off: then a closed link fails at once, and its owner reopens it with
`ensure_open`, as the driver node does from a thread of its own).
Events (sequence triggers, watchdog) that arrive are handed to `on_event`.
"""
from __future__ import annotations

import errno
import os
import stat
import termios
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import serial
from serial.tools import list_ports

from . import protocol as p
from .errors import (DisconnectedError, FirmwareMismatchError, LinkError, NakError, NoReplyError,
                     NotASerialPortError, PortNotFoundError, PortPermissionError, ProtocolError,
                     ReplyChecksumError)

USB_PREFIX = 'usb:'
DEFAULT_BAUD = 115200
PORT_FORMS = ('give the stage\'s serial port: a tty path such as /dev/ttyACM0 (better its '
              '/dev/serial/by-id/... link) or usb:SERIAL (its USB serial number); the driver node\'s '
              '`port` also takes `sim` for its built-in firmware simulator')


@dataclass
class LinkStats:
    commands: int = 0
    retries: int = 0
    timeouts: int = 0
    crc_errors: int = 0          # corrupted frames received by the host
    naks: int = 0
    firmware_crc_naks: int = 0   # our frames the firmware received corrupted
    disconnects: int = 0
    reconnects: int = 0
    stale_frames: int = 0        # replies to an earlier command (after a retry)
    events: int = 0

    def as_dict(self) -> dict[str, int]:
        return dict(self.__dict__)


@dataclass(frozen=True)
class Reply:
    frame: p.Frame
    host_send_s: float       # monotonic time the command's last attempt was written
    host_recv_s: float       # monotonic time the reply was decoded
    attempts: int = 1        # >1: the reply may answer an earlier attempt (no clock probe then)


def resolve_port(port: str) -> str:
    """Device path for `port` (a path, or `usb:SERIAL` looked up among USB serial ports)."""
    if port.startswith(USB_PREFIX):
        serial_number = port[len(USB_PREFIX):]
        found = [info.device for info in list_ports.comports() if info.serial_number == serial_number]
        if not found:
            present = sorted(f'{i.device} ({i.serial_number})' for i in list_ports.comports()
                             if i.serial_number)
            raise PortNotFoundError(
                f'no USB serial device with serial number {serial_number!r} is plugged in '
                f'(present: {", ".join(present) or "none"}); check the cable or the number')
        return found[0]
    return port


def not_a_serial_device(device: str) -> str:
    """What `device` is if it exists but is plainly no serial device ('' otherwise)."""
    try:
        mode = os.stat(device).st_mode
    except OSError:
        return ''        # missing or unreadable: opening it says which
    if stat.S_ISCHR(mode):
        return ''        # a character device: only opening it tells a tty from /dev/null
    if stat.S_ISREG(mode):
        return 'a regular file'
    if stat.S_ISDIR(mode):
        return 'a directory'
    return 'not a character device'


class SerialLink:
    def __init__(self, port: str, baud: int = DEFAULT_BAUD, timeout_s: float = 0.1, retries: int = 3,
                 connect_timeout_s: float = 3.0,
                 on_event: Callable[[p.Frame, float], None] | None = None,
                 on_connect: Callable[[p.Identity], None] | None = None, auto_reopen: bool = True):
        if timeout_s <= 0 or retries < 0 or connect_timeout_s <= 0:
            raise ValueError('timeout_s and connect_timeout_s must be > 0 and retries >= 0')
        self.port = port
        self.baud = baud
        self.timeout_s = timeout_s
        self.retries = retries
        self.connect_timeout_s = connect_timeout_s
        self.on_event = on_event or (lambda frame, t: None)
        self.on_connect = on_connect or (lambda identity: None)
        self.auto_reopen = auto_reopen
        self.stats = LinkStats()
        self.identity: p.Identity | None = None
        self.device = ''
        self.lock = threading.RLock()      # one command at a time, across threads
        self._serial: serial.Serial | None = None
        self._decoder = self._new_decoder()
        self._seq = 0
        self._failures: list[str] = []   # why each attempt of the last command failed
        self.last_error = ''

    # ------------------------------------------------------------------ connection
    @staticmethod
    def _new_decoder() -> p.FrameDecoder:
        # The host reads when it is scheduled, not when bytes arrive: a gap between two reads
        # says nothing about the line, so a stalled frame is dropped at the reply timeout instead
        # of the 10 ms inter-byte timeout (see PROTOCOL.md, changelog). For the same reason it
        # skips a frame that fails its CRC whole where its length is believable, instead of
        # waiting behind a SOF found in its payload (`FrameDecoder.skip_bad_frames`).
        return p.FrameDecoder(inter_byte_timeout_s=float('inf'), skip_bad_frames=True)

    @property
    def is_open(self) -> bool:
        return self._serial is not None

    def open(self) -> p.Identity:
        """Open the port and identify the firmware (retrying up to connect_timeout_s)."""
        with self.lock:
            if self._serial is None:
                self._open_port()
            deadline = time.monotonic() + self.connect_timeout_s
            last: Exception | None = None
            while True:
                try:
                    reply = self._transact_once(p.Command.IDENTIFY, b'', min(self.timeout_s * 3, 0.5))
                    if reply is not None:
                        break
                except NakError as exc:
                    last = exc
                if time.monotonic() >= deadline:
                    self.close()
                    raise NoReplyError(
                        f'{self.port}: no IDENTIFY reply within {self.connect_timeout_s} s '
                        f'({last or "silence"}); is the stage firmware running, at {self.baud} baud?')
            try:
                identity = p.Identity.unpack(reply.frame.payload)
            except ProtocolError as exc:
                self.close()
                raise FirmwareMismatchError(f'{self.port}: the device answered IDENTIFY with an '
                                            f'unexpected payload ({exc}); is this a light stage?') from exc
            if identity.protocol_version != p.PROTOCOL_VERSION or identity.led_count != p.LED_COUNT:
                self.close()
                raise FirmwareMismatchError(
                    f'{self.port}: firmware {identity.name} speaks protocol v{identity.protocol_version} '
                    f'with {identity.led_count} LEDs; this driver needs v{p.PROTOCOL_VERSION} with '
                    f'{p.LED_COUNT} LEDs: update the firmware')
            self.identity = identity
            self.on_connect(identity)
            return identity

    def _open_port(self) -> None:
        device = resolve_port(self.port)
        kind = not_a_serial_device(device)
        if kind:
            raise NotASerialPortError(f'{device} is {kind}, not a serial device: {PORT_FORMS}')
        try:
            ser = serial.Serial(device, self.baud, timeout=0, write_timeout=1.0, exclusive=True)
        except serial.SerialException as exc:
            code = getattr(exc, 'errno', None)
            text = str(exc)
            if code == errno.ENOENT or 'No such file' in text or not os.path.exists(device):
                raise PortNotFoundError(
                    f'serial port {device} does not exist: is the stage plugged in (or the simulator '
                    f'running)? Try a /dev/serial/by-id/ path or usb:SERIAL') from exc
            if code == errno.EACCES or 'Permission denied' in text:
                raise PortPermissionError(
                    f'no permission to open {device}: add the user to the port\'s group '
                    f'(usually `sudo usermod -aG dialout $USER`, then log in again)') from exc
            if code in (errno.EBUSY, errno.EAGAIN) or 'lock' in text.lower():
                raise LinkError(f'serial port {device} is in use by another process: stop it first') from exc
            if code == errno.ENOTTY or 'Inappropriate ioctl' in text:
                # /dev/null and the like open fine but refuse the line settings
                raise NotASerialPortError(
                    f'{device} is not a serial device (a character device that takes no serial line '
                    f'settings: {exc}): {PORT_FORMS}') from exc
            raise LinkError(f'cannot open serial port {device}: {exc}') from exc
        self._serial = ser
        self.device = device
        self._decoder = self._new_decoder()

    def close(self) -> None:
        with self.lock:
            if self._serial is not None:
                try:
                    self._serial.close()
                except (OSError, serial.SerialException):
                    pass
            self._serial = None

    def _lost(self, exc: BaseException) -> DisconnectedError:
        self.stats.disconnects += 1
        self.close()
        self.last_error = f'{self.port} disconnected: {exc}'
        then = ' The next command reopens the port; check the cable.' if self.auto_reopen else ''
        return DisconnectedError(f'{self.port} went away ({exc}); the command may or may not have '
                                 f'run.{then}')

    def require_open(self) -> None:
        """Reopen a closed link (`auto_reopen`) or fail at once with why it is closed."""
        with self.lock:
            if self._serial is not None:
                return
            if not self.auto_reopen:
                raise DisconnectedError(f'{self.port} is not open ({self.last_error or "closed"})')
            self.ensure_open()

    def ensure_open(self) -> None:
        """Reopen (and re-identify) after a disconnect, waiting up to connect_timeout_s."""
        with self.lock:
            if self._serial is not None:
                return
            deadline = time.monotonic() + self.connect_timeout_s
            while True:
                try:
                    self.open()
                    self.stats.reconnects += 1
                    return
                except LinkError as exc:
                    if isinstance(exc, (PortPermissionError, NotASerialPortError)) \
                            or time.monotonic() >= deadline:
                        raise
                    time.sleep(0.05)

    # ------------------------------------------------------------------ commands
    def _next_seq(self) -> int:
        self._seq = self._seq % 255 + 1
        return self._seq

    def transact(self, cmd: int, payload: bytes = b'', extra_timeout_s: float = 0.0) -> Reply:
        """Send a command and return its reply; retries, NAKs and disconnects as described above."""
        with self.lock:
            self.require_open()
            self.stats.commands += 1
            reply = self._transact_once(cmd, payload, self.timeout_s + extra_timeout_s, self.retries)
            if reply is None:
                attempts = self.retries + 1
                name = p.Command(cmd).name if cmd in tuple(p.Command) else f'0x{cmd:02X}'
                self.last_error = f'no valid reply to {name}'
                if all(why != 'timeout' for why in self._failures):
                    raise ReplyChecksumError(
                        f'{self.port}: every one of {attempts} attempt(s) at {name} met a CRC mismatch '
                        f'({", ".join(self._failures)}): the line corrupts data; check the baud rate '
                        f'({self.baud}), the cable and its grounding')
                raise NoReplyError(
                    f'{self.port}: no valid reply to {name} after {attempts} attempt(s) of '
                    f'{(self.timeout_s + extra_timeout_s) * 1e3:.0f} ms; is the firmware alive? '
                    f'(timeouts {self.stats.timeouts}, corrupted replies {self.stats.crc_errors})')
            return reply

    def _transact_once(self, cmd: int, payload: bytes, timeout_s: float, retries: int = 0) -> Reply | None:
        seq = self._next_seq()
        frame = p.encode_frame(seq, cmd, payload)
        self._failures = []
        for attempt in range(retries + 1):
            if attempt:
                self.stats.retries += 1
            sent = self._write(frame)
            reply = self._await_reply(seq, cmd, sent + timeout_s)
            if isinstance(reply, Reply):
                return Reply(reply.frame, sent, reply.host_recv_s, attempt + 1)
            self._failures.append(reply)
        return None

    def _write(self, data: bytes) -> float:
        try:
            self._serial.write(data)
            self._serial.flush()
        except (OSError, serial.SerialException, termios.error) as exc:
            # termios.error: tcdrain on a pty whose other end just closed (EIO)
            raise self._lost(exc) from exc
        return time.monotonic()

    def _read(self, timeout_s: float) -> bytes:
        ser = self._serial
        try:
            ser.timeout = max(0.0, timeout_s)
            data = ser.read(1)
            if data and ser.in_waiting:
                data += ser.read(ser.in_waiting)
            return data
        except (OSError, serial.SerialException, termios.error, TypeError) as exc:
            # TypeError: pyserial on a port closed under it
            raise self._lost(exc) from exc

    def _await_reply(self, seq: int, cmd: int, deadline: float) -> Reply | str:
        """Read until the reply to (seq, cmd), or say why to retry: 'timeout', 'corrupt' (a frame
        arrived with a bad CRC, maybe our reply) or 'firmware-crc' (the firmware got ours corrupted)."""
        while True:
            now = time.monotonic()
            if now >= deadline:
                self.stats.timeouts += 1
                for item in self._decoder.expire():
                    self._dispatch_other(item, now)
                return 'timeout'
            data = self._read(min(deadline - now, 0.05))
            now = time.monotonic()
            result: Reply | str | None = None
            nak_error: NakError | None = None
            for item in self._decoder.feed(data, now):
                if result is not None or nak_error is not None:
                    self._dispatch_other(item, now)   # events after the reply still count
                    continue
                if isinstance(item, p.BadFrame):
                    self.stats.crc_errors += 1
                    result = 'corrupt'   # possibly our reply: ask again (the firmware caches it)
                    continue
                frame = item
                if frame.cmd == p.NAK_CMD:
                    try:
                        nak = p.Nak.unpack(frame.payload)
                    except ProtocolError:
                        self.stats.crc_errors += 1
                        result = 'corrupt'
                        continue
                    if nak.reason == p.NakReason.BAD_CRC:
                        self.stats.firmware_crc_naks += 1
                        result = 'firmware-crc'
                    elif frame.seq == seq:
                        self.stats.naks += 1
                        self.last_error = nak.describe()
                        nak_error = NakError(nak.describe(), nak.cmd, nak.reason, nak.value)
                    else:
                        self.stats.stale_frames += 1
                    continue
                if frame.seq == seq and frame.cmd == cmd | p.REPLY_BIT:
                    result = Reply(frame, 0.0, now)
                    continue
                self._dispatch_other(frame, now)
            if nak_error is not None:
                raise nak_error
            if result is not None:
                return result

    def _dispatch_other(self, item, now: float) -> None:
        if isinstance(item, p.Frame) and item.cmd in tuple(p.Event):
            self.stats.events += 1
            self.on_event(item, now)
        elif isinstance(item, p.BadFrame):
            self.stats.crc_errors += 1
        else:
            self.stats.stale_frames += 1

    def poll_events(self, timeout_s: float) -> None:
        """Read for up to timeout_s and dispatch whatever events arrive (no command sent)."""
        with self.lock:
            self.require_open()
            deadline = time.monotonic() + timeout_s
            while True:
                now = time.monotonic()
                if now >= deadline:
                    return
                data = self._read(deadline - now)
                now = time.monotonic()
                for item in self._decoder.feed(data, now):
                    self._dispatch_other(item, now)

    def wait_until(self, done: Callable[[], bool], timeout_s: float) -> bool:
        """Dispatch events until done() holds or timeout_s passes."""
        with self.lock:
            deadline = time.monotonic() + timeout_s
            while not done():
                now = time.monotonic()
                if now >= deadline:
                    return False
                data = self._read(min(deadline - now, 0.05))
                now = time.monotonic()
                for item in self._decoder.feed(data, now):
                    self._dispatch_other(item, now)
            return True
