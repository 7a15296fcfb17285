"""Every way talking to the stage can fail, each with a message that says what to do.

All of them derive from `LightStageError`. The frame decoder raises only `ProtocolError`
subclasses; the link adds the port and reply failures.
"""
from __future__ import annotations


class LightStageError(Exception):
    """Base of every error raised by lightstage_driver."""


class ProtocolError(LightStageError):
    """Bytes that are not a valid frame or payload of the wire protocol."""


class FramingError(ProtocolError):
    """A frame is cut short, too long, or does not start with SOF."""


class ChecksumError(ProtocolError):
    """A frame's CRC does not match its contents."""

    def __init__(self, message: str, received: int = 0, computed: int = 0):
        super().__init__(message)
        self.received = received
        self.computed = computed


class PayloadError(ProtocolError):
    """A frame is well formed but its payload does not fit its command."""


class PatternError(LightStageError, ValueError):
    """A pattern, exposure or setting the host refuses to send (nothing was sent)."""


class LinkError(LightStageError):
    """The serial link failed."""


class PortNotFoundError(LinkError):
    """The serial port (path or USB serial number) does not exist."""


class PortPermissionError(LinkError):
    """The serial port exists but this user may not open it."""


class NotASerialPortError(LinkError):
    """The port path exists but is no serial device (a regular file, a directory, /dev/null)."""


class NoReplyError(LinkError):
    """The firmware did not answer within the timeout, after every retry."""


class ReplyChecksumError(NoReplyError):
    """Replies kept arriving with a CRC mismatch (or the firmware kept receiving ours so)."""


class DisconnectedError(LinkError):
    """The port went away while in use (cable pulled, firmware process killed)."""


class FirmwareMismatchError(LinkError):
    """The device answered but is not a light stage firmware this driver supports."""


class NakError(LinkError):
    """The firmware refused a command; `reason` and `value` are the firmware's."""

    def __init__(self, message: str, command: int, reason: int, value: int):
        super().__init__(message)
        self.command = command
        self.reason = reason
        self.value = value
