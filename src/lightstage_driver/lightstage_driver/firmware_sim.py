"""The firmware simulator process: `FirmwareModel` behind a real pseudo-terminal.

Run standalone (`lightstage-firmware-sim`, or `python -m lightstage_driver.firmware_sim`):
it prints `PTY <path>` and serves the protocol on that pty until killed. The driver opens
the path like a USB serial port. Faults can be injected for tests (`FaultConfig`): reply
latency, dropped received bytes, corrupted sent frames, commands ignored without reply,
and a disconnect (the pty closes; optionally a new one appears after a delay, as after a
USB re-plug, with `--link` pointing at it again).

With `--control`, JSON lines on stdin change the faults (`{"id": 1, "faults": {...}}`)
or disconnect (`{"id": 2, "disconnect": 0.5}`), each acknowledged with
`{"ev": "ack", "id": ...}` on stdout. With `--observe`, every latched LED word and
trigger pulse is written to stdout as a JSON line (`{"ev": "latch", "t": s, "word": w}`,
`{"ev": "pulse", "t": s, "width_us": w}`), times in seconds since the process started.
"""
from __future__ import annotations

import argparse
import errno
import json
import os
import random
import select
import signal
import sys
import time
import tty
from dataclasses import asdict, dataclass, fields

from . import protocol as p
from .firmware_model import FirmwareLimits, FirmwareModel


@dataclass
class FaultConfig:
    """Faults the simulator injects. Counters (`*_next`) are used up one by one."""
    latency_ms: float = 0.0          # delay before anything is sent
    emulate_baud: int = 0            # >0: also delay replies by the wire time at this baud
    drop_rx_next: int = 0            # drop the next N received bytes
    drop_rx_prob: float = 0.0        # drop each received byte with this probability
    corrupt_tx_next: int = 0         # corrupt the next N sent frames (one byte flipped)
    corrupt_tx_prob: float = 0.0
    corrupt_only_cmd: int = -1       # >=0: corrupt only frames with this CMD byte (e.g. 0x41 events)
    mute_next: int = 0               # ignore the next N valid frames: no execution, no reply
    mute_all: bool = False           # ignore every frame (a hung firmware)
    seed: int = 0

    def update(self, changes: dict) -> None:
        known = {f.name for f in fields(self)}
        unknown = set(changes) - known
        if unknown:
            raise ValueError(f'unknown fault setting(s) {sorted(unknown)}; known: {sorted(known)}')
        for key, value in changes.items():
            setattr(self, key, type(getattr(self, key))(value))


def open_pty() -> tuple[int, int, str]:
    """A raw pseudo-terminal pair: (master fd, slave fd, slave path)."""
    master, slave = os.openpty()
    tty.setraw(slave)     # no echo, no line discipline: bytes pass unchanged
    os.set_blocking(master, False)
    return master, slave, os.ttyname(slave)


def point_link(link: str, target: str) -> None:
    tmp = f'{link}.{os.getpid()}.tmp'
    if os.path.lexists(tmp):
        os.unlink(tmp)
    os.symlink(target, tmp)
    os.replace(tmp, link)


def remove_link(link: str, target: str) -> None:
    """Remove `link` if it still points at `target` (a pty that is going away).

    As udev removes /dev/serial/by-id/... on unplug: a link left pointing at a closed pty
    would lead whoever opens it to the next pty that reuses its number (another program's)."""
    try:
        if target and os.readlink(link) == target:
            os.unlink(link)
    except OSError:
        pass      # no link, or not ours any more


class PtyFirmware:
    """Runs a `FirmwareModel` on a pty in real time, with fault injection."""

    def __init__(self, limits: FirmwareLimits | None = None, faults: FaultConfig | None = None,
                 link: str | None = None, observe=None, clock_offset_us: int = 0):
        self.limits = limits or FirmwareLimits()
        self.faults = faults or FaultConfig()
        self.link = link
        self.observe = observe            # callable(dict) or None
        self.clock_offset_us = clock_offset_us
        self.t0 = time.monotonic()
        self.rng = random.Random(self.faults.seed)
        self.master = self.slave = -1
        self.slave_path = ''
        self.outgoing: list[tuple[float, bytes]] = []
        self.reconnect_at: float | None = None
        self._tx_free_at = 0.0
        self._rx_free_at = 0.0
        self.incoming: list[tuple[float, bytes]] = []   # bytes still on the wire (emulate_baud)
        self.model: FirmwareModel | None = None

    # ------------------------------------------------------------------ lifecycle
    def power_up(self) -> None:
        self.master, self.slave, self.slave_path = open_pty()
        if self.link:
            point_link(self.link, self.slave_path)
        now = time.monotonic()
        boot_offset = now - self.t0
        self.model = FirmwareModel(
            self.limits, boot_time=now, clock_offset_us=self.clock_offset_us,
            on_latch=lambda t, w: self._emit({'ev': 'latch', 't': boot_offset + t, 'word': w}),
            on_pulse=lambda t, w: self._emit({'ev': 'pulse', 't': boot_offset + t, 'width_us': w}))
        self.model.accept_frame = self._accept_frame
        self.outgoing = [(now, frame) for frame in self.model.boot(now)]
        self._emit({'ev': 'ready', 'pty': self.slave_path})

    def disconnect(self, reconnect_after_s: float | None) -> None:
        """Close the pty like a pulled cable; come back (reset) after a delay if given."""
        if self.model is not None and self.model.lit_word:
            self.model._latch(time.monotonic(), 0)    # a USB-powered board loses power: dark
        if self.link:
            remove_link(self.link, self.slave_path)
        for fd in (self.master, self.slave):
            if fd >= 0:
                os.close(fd)
        self.master = self.slave = -1
        self.model = None
        self.outgoing = []
        self.incoming = []
        self._emit({'ev': 'disconnected'})
        self.reconnect_at = None if reconnect_after_s is None else time.monotonic() + reconnect_after_s

    def _emit(self, record: dict) -> None:
        if self.observe is not None:
            self.observe(record)

    # ------------------------------------------------------------------ faults
    def _accept_frame(self, frame) -> bool:
        if self.faults.mute_all:
            return False
        if self.faults.mute_next > 0:
            self.faults.mute_next -= 1
            return False
        return True

    def _filter_rx(self, data: bytes) -> bytes:
        f = self.faults
        if not (f.drop_rx_next or f.drop_rx_prob):
            return data
        kept = bytearray()
        for byte in data:
            if f.drop_rx_next > 0:
                f.drop_rx_next -= 1
                continue
            if f.drop_rx_prob and self.rng.random() < f.drop_rx_prob:
                continue
            kept.append(byte)
        return bytes(kept)

    def _corrupt(self, frame: bytes) -> bytes:
        f = self.faults
        hit = False
        if f.corrupt_only_cmd >= 0 and frame[3] != f.corrupt_only_cmd:
            return frame
        if f.corrupt_tx_next > 0:
            f.corrupt_tx_next -= 1
            hit = True
        elif f.corrupt_tx_prob and self.rng.random() < f.corrupt_tx_prob:
            hit = True
        if not hit:
            return frame
        data = bytearray(frame)
        index = self.rng.randrange(2, len(data))   # keep SOF and LEN: the CRC must catch it
        data[index] ^= 1 << self.rng.randrange(8)
        return bytes(data)

    def _queue(self, frames: list[bytes], now: float) -> None:
        for frame in frames:
            send_at = now + self.faults.latency_ms / 1000.0
            baud = self.faults.emulate_baud
            if baud:
                # frames leave one after another, each taking its wire time
                send_at = max(send_at, self._tx_free_at) + p.line_seconds(len(frame), baud)
                self._tx_free_at = send_at
            self.outgoing.append((send_at, self._corrupt(frame)))

    def _arrive(self, data: bytes, now: float) -> None:
        """Received bytes reach the firmware after their wire time (with emulate_baud)."""
        baud = self.faults.emulate_baud
        if not baud:
            self._queue(self.model.receive(data, now), now)
            return
        for i in range(len(data)):   # byte by byte, as a UART delivers them
            self._rx_free_at = max(now, self._rx_free_at) + p.line_seconds(1, baud)
            self.incoming.append((self._rx_free_at, data[i:i + 1]))

    # ------------------------------------------------------------------ loop
    def step(self, timeout: float, control_fd: int | None = None, on_control=None) -> None:
        now = time.monotonic()
        deadlines = [t for t, _ in self.outgoing[:1] + self.incoming[:1]]
        if self.model is not None and (d := self.model.next_deadline()) is not None:
            deadlines.append(d)
        if self.reconnect_at is not None:
            deadlines.append(self.reconnect_at)
        wait = max(0.0, min([timeout] + [d - now for d in deadlines]))
        fds = [fd for fd in (self.master, control_fd) if fd is not None and fd >= 0]
        readable, _, _ = select.select(fds, [], [], wait)
        now = time.monotonic()
        if control_fd is not None and control_fd in readable and on_control is not None:
            on_control()
        if self.model is not None and self.master in readable:
            try:
                data = os.read(self.master, 4096)
            except OSError as exc:
                if exc.errno not in (errno.EIO, errno.EAGAIN):
                    raise
                data = b''
            data = self._filter_rx(data)
            if data:
                self._arrive(data, now)
        if self.model is not None:
            while self.incoming and self.incoming[0][0] <= now:
                arrived, byte = self.incoming.pop(0)
                self._queue(self.model.receive(byte, arrived), now)
            self._queue(self.model.poll(now), now)
            self._flush(now)
        if self.reconnect_at is not None and now >= self.reconnect_at:
            self.reconnect_at = None
            self.power_up()

    def _flush(self, now: float) -> None:
        while self.outgoing and self.outgoing[0][0] <= now:
            _, frame = self.outgoing.pop(0)
            try:
                os.write(self.master, frame)
            except OSError:
                pass   # nobody listening: a real UART transmits into the void too
        self.outgoing.sort(key=lambda item: item[0])

    def close(self) -> None:
        if self.link:
            remove_link(self.link, self.slave_path)
        for fd in (self.master, self.slave):
            if fd >= 0:
                os.close(fd)
        self.master = self.slave = -1


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog='lightstage-firmware-sim', description=__doc__.split('\n')[0])
    parser.add_argument('--link', help='also make this path a symlink to the pty (stable across re-plugs)')
    parser.add_argument('--pwm-bits', type=int, default=0, choices=(0, 8, 12))
    parser.add_argument('--min-exposure-us', type=int, default=20)
    parser.add_argument('--max-exposure-us', type=int, default=2_000_000)
    parser.add_argument('--latency-ms', type=float, default=0.0, help='delay of every reply')
    parser.add_argument('--emulate-baud', type=int, default=0,
                        help='delay replies by the wire time at this baud (0: pty speed)')
    parser.add_argument('--clock-offset-us', type=int, default=0,
                        help='start the firmware clock here (e.g. near 2**32 to test wrap)')
    parser.add_argument('--control', action='store_true', help='read fault commands on stdin')
    parser.add_argument('--observe', action='store_true', help='print LED latches and pulses')
    return parser


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    limits = FirmwareLimits(pwm_bits=args.pwm_bits, min_exposure_us=args.min_exposure_us,
                            max_exposure_us=args.max_exposure_us)
    faults = FaultConfig(latency_ms=args.latency_ms, emulate_baud=args.emulate_baud)

    def write(record: dict) -> None:
        sys.stdout.write(json.dumps(record) + '\n')
        sys.stdout.flush()

    observe_all = args.observe
    sim = PtyFirmware(limits, faults, link=args.link, clock_offset_us=args.clock_offset_us,
                      observe=lambda r: write(r) if observe_all or r['ev'] != 'latch' and r['ev'] != 'pulse'
                      else None)
    stop = False

    def on_signal(signum, frame):
        raise SystemExit(0)    # leaves select() at once; the finally below darkens the LEDs

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    sim.power_up()
    print(f'PTY {sim.slave_path}', flush=True)
    control_fd = sys.stdin.fileno() if args.control else None
    control_buffer = bytearray()

    def on_control():
        nonlocal control_buffer, stop
        chunk = os.read(control_fd, 4096)
        if not chunk:
            stop = True   # the controlling process went away
            return
        control_buffer += chunk
        while b'\n' in control_buffer:
            line, _, rest = bytes(control_buffer).partition(b'\n')
            control_buffer = bytearray(rest)
            try:
                msg = json.loads(line)
                if 'faults' in msg:
                    sim.faults.update(msg['faults'])
                if 'disconnect' in msg:
                    sim.disconnect(msg['disconnect'])
                write({'ev': 'ack', 'id': msg.get('id'), 'faults': asdict(sim.faults)})
            except (ValueError, TypeError) as exc:
                write({'ev': 'error', 'message': str(exc)})

    try:
        while not stop:
            sim.step(0.2, control_fd, on_control)
    finally:
        if sim.model is not None and sim.model.lit_word:
            sim.model._latch(time.monotonic(), 0)   # power off: LEDs dark
        sim.close()
    return 0


if __name__ == '__main__':
    sys.exit(main())
