"""Raw protocol-v1 access to a firmware's port, for tests that check bytes and pins.

The driver's `SerialLink` retries, resynchronises and hides NAKs; these tests need to see
exactly what the firmware answered, so they speak the protocol frame by frame with the
project's codec (`lightstage_driver.protocol`).
"""
from __future__ import annotations

import struct
import time

import serial

from lightstage_driver import protocol as p


class Wire:
    def __init__(self, port: str):
        self.serial = serial.Serial(port, 115200, timeout=0)
        # the host reads when it is scheduled: judging the firmware's 10 ms inter-byte
        # timeout by read times would drop frames whenever this process is descheduled
        self.decoder = p.FrameDecoder(inter_byte_timeout_s=1.0)
        self.frames: list[p.Frame | p.BadFrame] = []   # received, not yet taken
        self.seq = 0

    def close(self) -> None:
        self.serial.close()

    def next_seq(self) -> int:
        self.seq = self.seq % 255 + 1
        return self.seq

    def send_raw(self, data: bytes) -> None:
        self.serial.write(data)
        self.serial.flush()

    def send(self, cmd: int, payload: bytes = b'', seq: int | None = None) -> int:
        seq = self.next_seq() if seq is None else seq
        self.send_raw(p.encode_frame(seq, cmd, payload))
        return seq

    def _pump(self, timeout_s: float) -> None:
        self.serial.timeout = max(0.0, timeout_s)
        data = self.serial.read(1)
        if data and self.serial.in_waiting:
            data += self.serial.read(self.serial.in_waiting)
        self.frames += self.decoder.feed(data)

    def receive(self, match, timeout_s: float = 1.0):
        """The first received frame for which match(frame) holds (others stay queued)."""
        deadline = time.monotonic() + timeout_s
        while True:
            for i, frame in enumerate(self.frames):
                if match(frame):
                    return self.frames.pop(i)
            left = deadline - time.monotonic()
            if left <= 0:
                raise AssertionError(f'no matching frame within {timeout_s} s; got {self.frames}')
            self._pump(min(left, 0.05))

    def reply_to(self, seq: int, timeout_s: float = 1.0) -> p.Frame:
        """The reply or NAK carrying `seq` (events are left queued)."""
        return self.receive(lambda f: isinstance(f, p.Frame) and f.seq == seq and
                            (f.cmd & p.REPLY_BIT) and f.cmd not in (p.Event.READY,), timeout_s)

    def event(self, cmd: int, timeout_s: float = 1.0) -> p.Frame:
        return self.receive(lambda f: isinstance(f, p.Frame) and f.cmd == cmd, timeout_s)

    def call(self, cmd: int, payload: bytes = b'', timeout_s: float = 1.0, seq: int | None = None) -> p.Frame:
        return self.reply_to(self.send(cmd, payload, seq), timeout_s)

    def expect_ok(self, cmd: int, payload: bytes = b'', timeout_s: float = 1.0) -> bytes:
        reply = self.call(cmd, payload, timeout_s)
        assert reply.cmd == cmd | p.REPLY_BIT, (
            f'{p.Command(cmd).name} refused: {p.Nak.unpack(reply.payload).describe()}'
            if reply.cmd == p.NAK_CMD else f'unexpected reply {reply}')
        return reply.payload

    def expect_nak(self, cmd: int, payload: bytes = b'') -> p.Nak:
        reply = self.call(cmd, payload)
        assert reply.cmd == p.NAK_CMD, f'{p.Command(cmd).name} was accepted: {reply}'
        return p.Nak.unpack(reply.payload)

    def drain(self, quiet_s: float = 0.02) -> list:
        """Everything that arrives until the line has been quiet for quiet_s."""
        while True:
            before = len(self.frames)
            self._pump(quiet_s)
            if len(self.frames) == before and not self.serial.in_waiting:
                break
        frames, self.frames = self.frames, []
        return frames

    # -------------------------------------------------------------- typed shortcuts
    def set_pattern(self, word: int, show_now: bool = True) -> int:
        return p.unpack_u32(self.expect_ok(p.Command.SET_PATTERN, p.pack_set_pattern(word, show_now)),
                            'SET_PATTERN reply')

    def fire(self, exposure_us: int) -> tuple[int, int]:
        return p.unpack_u32_pair(self.expect_ok(p.Command.FIRE, p.pack_u32(exposure_us),
                                                timeout_s=1.0 + exposure_us / 1e6), 'FIRE reply')

    def heartbeat(self) -> p.Status:
        return p.Status.unpack(self.expect_ok(p.Command.HEARTBEAT))

    def set_watchdog(self, timeout_ms: int) -> int:
        return struct.unpack('<H', self.expect_ok(p.Command.SET_WATCHDOG, struct.pack('<H', timeout_ms)))[0]
