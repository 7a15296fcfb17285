"""Wire protocol v1 of the light stage (docs/PROTOCOL.md): frames, CRC, payloads.

Pure Python, no I/O: the host link and the firmware simulator both build on it.
Everything that can go wrong while decoding raises a `ProtocolError` subclass.
"""
from __future__ import annotations

import enum
import struct
import time
from dataclasses import dataclass, field

from lightstage_graph.leds import N_LEDS

from .errors import ChecksumError, FramingError, PayloadError

PROTOCOL_VERSION = 1
SOF = 0xA5
MAX_PAYLOAD = 136
HEADER_LEN = 4          # SOF, LEN, SEQ, CMD
CRC_LEN = 2
OVERHEAD = HEADER_LEN + CRC_LEN
MAX_FRAME = MAX_PAYLOAD + OVERHEAD
INTER_BYTE_TIMEOUT_S = 0.010
REPLY_BIT = 0x80
NAK_CMD = 0xFF
LED_COUNT = N_LEDS  # the firmware's chain: one drive per LED of Pattern.msg
MAX_SEQUENCE = 16
MAX_GAP_US = 1_000_000
WATCHDOG_RANGE_MS = (50, 60000)
DEFAULT_WATCHDOG_MS = 1000
SHOW_NOW = 0x01
TABLE_LEVEL_BITS = 8        # SET_LEVEL_TABLE carries 8-bit levels (firmware with pwm_bits 8)
TABLE_ROWS_PER_FRAME = (MAX_PAYLOAD - 1) // LED_COUNT   # 4
NAME_MAX = 16


class Command(enum.IntEnum):
    IDENTIFY = 0x01
    HEARTBEAT = 0x02
    SET_PATTERN = 0x03
    SET_LEVELS = 0x04
    FIRE = 0x05
    RUN_SEQUENCE = 0x06
    ALL_OFF = 0x07
    SET_WATCHDOG = 0x08
    SET_LEVEL_TABLE = 0x09
    RUN_LEVEL_SEQUENCE = 0x0A


class Event(enum.IntEnum):
    READY = 0x40
    TRIGGER = 0x41
    SEQUENCE_DONE = 0x42
    WATCHDOG = 0x43


class NakReason(enum.IntEnum):
    BAD_CRC = 1
    BAD_LENGTH = 2
    UNKNOWN_COMMAND = 3
    EXPOSURE_RANGE = 4
    SEQUENCE_LENGTH = 5
    BUSY = 6
    UNSUPPORTED = 7
    LEVEL_RANGE = 8
    WATCHDOG_RANGE = 9
    BAD_FLAGS = 10
    GAP_RANGE = 11
    ROW_RANGE = 12


class SequenceStatus(enum.IntEnum):
    COMPLETE = 0
    ABORTED_BY_ALL_OFF = 1
    ABORTED_BY_WATCHDOG = 2


NAK_EXPLANATIONS = {
    NakReason.BAD_CRC: 'the firmware received a frame with a bad CRC (line noise?)',
    NakReason.BAD_LENGTH: 'the payload length does not fit the command',
    NakReason.UNKNOWN_COMMAND: 'the firmware does not know this command (firmware too old?)',
    NakReason.EXPOSURE_RANGE: 'exposure_us is outside the firmware range (see IDENTIFY)',
    NakReason.SEQUENCE_LENGTH: 'the sequence is empty or longer than max_sequence',
    NakReason.BUSY: 'a sequence is running; wait for it or send ALL_OFF',
    NakReason.UNSUPPORTED: 'the firmware cannot do this (e.g. PWM levels on an on/off rig)',
    NakReason.LEVEL_RANGE: 'an LED level is above the firmware PWM range',
    NakReason.WATCHDOG_RANGE: 'watchdog timeout outside 50..60000 ms',
    NakReason.BAD_FLAGS: 'reserved flag bits were set',
    NakReason.GAP_RANGE: 'sequence gap_us above 1000000',
    NakReason.ROW_RANGE: 'a level-table row outside 0..max_sequence - 1',
}

# CRC-16/CCITT-FALSE, table-driven (poly 0x1021, init 0xFFFF, no reflection, no xorout)
_CRC_TABLE = []
for _i in range(256):
    _c = _i << 8
    for _ in range(8):
        _c = ((_c << 1) ^ 0x1021) if _c & 0x8000 else (_c << 1)
    _CRC_TABLE.append(_c & 0xFFFF)
del _i, _c


def crc16_ccitt(data: bytes | bytearray | memoryview, crc: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE of `data` ("123456789" -> 0x29B1)."""
    table = _CRC_TABLE
    for byte in data:
        crc = ((crc << 8) & 0xFFFF) ^ table[((crc >> 8) ^ byte) & 0xFF]
    return crc


@dataclass(frozen=True)
class Frame:
    seq: int
    cmd: int
    payload: bytes = b''

    def encode(self) -> bytes:
        return encode_frame(self.seq, self.cmd, self.payload)


@dataclass(frozen=True)
class BadFrame:
    """A frame that arrived with a CRC mismatch (its header fields may be garbage)."""
    seq: int
    cmd: int
    received_crc: int
    computed_crc: int


def encode_frame(seq: int, cmd: int, payload: bytes = b'') -> bytes:
    if not 0 <= seq <= 255:
        raise PayloadError(f'sequence number {seq} is outside 0..255')
    if not 0 <= cmd <= 255:
        raise PayloadError(f'command code {cmd} is outside 0..255')
    if len(payload) > MAX_PAYLOAD:
        raise PayloadError(f'payload of {len(payload)} bytes exceeds MAX_PAYLOAD {MAX_PAYLOAD}')
    body = bytes((len(payload), seq, cmd)) + bytes(payload)
    return bytes((SOF,)) + body + struct.pack('<H', crc16_ccitt(body))


def decode_frame(data: bytes) -> Frame:
    """Decode exactly one complete frame; raise FramingError / ChecksumError otherwise."""
    data = bytes(data)
    if len(data) < OVERHEAD:
        raise FramingError(f'frame of {len(data)} bytes is shorter than the minimum {OVERHEAD}')
    if data[0] != SOF:
        raise FramingError(f'frame starts with 0x{data[0]:02X}, expected SOF 0x{SOF:02X}')
    length = data[1]
    if length > MAX_PAYLOAD:
        raise FramingError(f'LEN {length} exceeds MAX_PAYLOAD {MAX_PAYLOAD}')
    if len(data) != length + OVERHEAD:
        raise FramingError(f'frame has {len(data)} bytes but LEN {length} needs {length + OVERHEAD}')
    received = data[-2] | (data[-1] << 8)
    computed = crc16_ccitt(data[1:-2])
    if received != computed:
        raise ChecksumError(f'CRC mismatch: frame says 0x{received:04X}, contents give 0x{computed:04X}',
                            received, computed)
    return Frame(data[2], data[3], data[HEADER_LEN:-2])


@dataclass
class FrameDecoder:
    """Streaming decoder: feed it bytes as they arrive, get frames back.

    Resynchronisation follows the protocol: hunt for SOF; drop a frame whose LEN is too
    big, whose CRC fails (reported as `BadFrame`) or that stalls longer than the
    inter-byte timeout, then rescan from the byte after the dropped frame's SOF.
    `skip_bad_frames` (the host's rule): a frame whose CRC fails is skipped whole when a SOF
    or the end of the bytes so far follows it, as its LEN says. Rescanning inside it could
    take a byte of its payload for a SOF and wait, behind that phantom frame, for bytes that
    never come: the host, which has no inter-byte timeout, would then miss the next reply
    until its reply timeout. Never raises on any input.
    """
    inter_byte_timeout_s: float = INTER_BYTE_TIMEOUT_S
    skip_bad_frames: bool = False
    buffer: bytearray = field(default_factory=bytearray)
    crc_errors: int = 0
    length_errors: int = 0
    timeouts: int = 0
    discarded_bytes: int = 0
    _last_byte_time: float = 0.0

    def feed(self, data: bytes, now: float | None = None) -> list[Frame | BadFrame]:
        now = time.monotonic() if now is None else now
        out: list[Frame | BadFrame] = []
        if self.buffer and now - self._last_byte_time > self.inter_byte_timeout_s:
            out.extend(self.expire())
        if data:
            self.buffer += data
            self._last_byte_time = now
        out.extend(self._scan())
        return out

    def expire(self) -> list[Frame | BadFrame]:
        """The line went quiet mid-frame: drop the pending frame's SOF and rescan the rest."""
        out: list[Frame | BadFrame] = []
        while self.buffer:
            self.timeouts += 1
            self._discard(1)
            out.extend(self._scan())
        return out

    def _discard(self, n: int) -> None:
        self.discarded_bytes += n
        del self.buffer[:n]

    def _scan(self) -> list[Frame | BadFrame]:
        out: list[Frame | BadFrame] = []
        buf = self.buffer
        while buf:
            start = buf.find(SOF)
            if start < 0:
                self._discard(len(buf))
                break
            if start:
                self._discard(start)
            if len(buf) < 2:
                break
            length = buf[1]
            if length > MAX_PAYLOAD:
                self.length_errors += 1
                self._discard(1)
                continue
            total = length + OVERHEAD
            if len(buf) < total:
                break
            received = buf[total - 2] | (buf[total - 1] << 8)
            computed = crc16_ccitt(memoryview(buf)[1:total - 2])
            if received != computed:
                self.crc_errors += 1
                out.append(BadFrame(buf[2], buf[3], received, computed))
                whole = self.skip_bad_frames and (len(buf) == total or buf[total] == SOF)
                self._discard(total if whole else 1)
                continue
            out.append(Frame(buf[2], buf[3], bytes(buf[HEADER_LEN:total - 2])))
            del buf[:total]
        return out


# ---------------------------------------------------------------------------- payloads

def _expect(payload: bytes, size: int, what: str) -> None:
    if len(payload) != size:
        raise PayloadError(f'{what} payload must be {size} bytes, got {len(payload)}')


@dataclass(frozen=True)
class Identity:
    protocol_version: int
    fw_version: tuple[int, int, int]
    led_count: int
    sites: int
    channels: int
    pwm_bits: int
    min_exposure_us: int
    max_exposure_us: int
    watchdog_ms: int
    max_sequence: int
    max_payload: int
    name: str

    _FIXED = struct.Struct('<BBBBBBBBIIHBB')

    def pack(self) -> bytes:
        name = self.name.encode('ascii')[:NAME_MAX]
        return self._FIXED.pack(self.protocol_version, *self.fw_version, self.led_count, self.sites,
                                self.channels, self.pwm_bits, self.min_exposure_us,
                                self.max_exposure_us, self.watchdog_ms, self.max_sequence,
                                self.max_payload) + name

    @classmethod
    def unpack(cls, payload: bytes) -> 'Identity':
        size = cls._FIXED.size
        if not size <= len(payload) <= size + NAME_MAX:
            raise PayloadError(f'identity payload must be {size}..{size + NAME_MAX} bytes, '
                               f'got {len(payload)}')
        f = cls._FIXED.unpack_from(payload)
        try:
            name = bytes(payload[size:]).decode('ascii')
        except UnicodeDecodeError as exc:
            raise PayloadError(f'identity name is not ASCII: {bytes(payload[size:])!r}') from exc
        return cls(f[0], (f[1], f[2], f[3]), f[4], f[5], f[6], f[7], f[8], f[9], f[10], f[11],
                   f[12], name)

    @property
    def version_string(self) -> str:
        return '.'.join(map(str, self.fw_version))


@dataclass(frozen=True)
class Status:
    """HEARTBEAT reply."""
    t_us: int
    leds_lit: bool
    sequence_running: bool
    watchdog_tripped: bool
    rx_errors: int

    _S = struct.Struct('<IBH')

    def pack(self) -> bytes:
        flags = int(self.leds_lit) | int(self.sequence_running) << 1 | int(self.watchdog_tripped) << 2
        return self._S.pack(self.t_us, flags, self.rx_errors)

    @classmethod
    def unpack(cls, payload: bytes) -> 'Status':
        _expect(payload, cls._S.size, 'HEARTBEAT reply')
        t, flags, errors = cls._S.unpack(payload)
        return cls(t, bool(flags & 1), bool(flags & 2), bool(flags & 4), errors)


@dataclass(frozen=True)
class Nak:
    cmd: int
    reason: int
    value: int

    _S = struct.Struct('<BBI')

    def pack(self) -> bytes:
        return self._S.pack(self.cmd, self.reason, self.value)

    @classmethod
    def unpack(cls, payload: bytes) -> 'Nak':
        _expect(payload, cls._S.size, 'NAK')
        return cls(*cls._S.unpack(payload))

    def describe(self) -> str:
        try:
            reason = NakReason(self.reason)
            text = f'{reason.name}: {NAK_EXPLANATIONS[reason]}'
        except ValueError:
            text = f'unknown reason {self.reason}'
        try:
            cmd = Command(self.cmd).name
        except ValueError:
            cmd = f'0x{self.cmd:02X}'
        return f'firmware refused {cmd}: {text} (value {self.value})'


@dataclass(frozen=True)
class TriggerEvent:
    index: int
    t_trigger_us: int
    t_end_us: int

    _S = struct.Struct('<BII')

    def pack(self) -> bytes:
        return self._S.pack(self.index, self.t_trigger_us, self.t_end_us)

    @classmethod
    def unpack(cls, payload: bytes) -> 'TriggerEvent':
        _expect(payload, cls._S.size, 'EVT_TRIGGER')
        return cls(*cls._S.unpack(payload))


@dataclass(frozen=True)
class SequenceDone:
    count_done: int
    status: int

    def pack(self) -> bytes:
        return bytes((self.count_done, self.status))

    @classmethod
    def unpack(cls, payload: bytes) -> 'SequenceDone':
        _expect(payload, 2, 'EVT_SEQUENCE_DONE')
        return cls(payload[0], payload[1])


@dataclass(frozen=True)
class SequenceEntry:
    word: int
    exposure_us: int


def pack_u32(value: int) -> bytes:
    return struct.pack('<I', value)


def unpack_u32(payload: bytes, what: str) -> int:
    _expect(payload, 4, what)
    return struct.unpack('<I', payload)[0]


def unpack_u32_pair(payload: bytes, what: str) -> tuple[int, int]:
    _expect(payload, 8, what)
    return struct.unpack('<II', payload)


def pack_set_pattern(word: int, show_now: bool) -> bytes:
    return struct.pack('<BI', SHOW_NOW if show_now else 0, word)


def unpack_set_pattern(payload: bytes) -> tuple[int, int]:
    _expect(payload, 5, 'SET_PATTERN')
    return struct.unpack('<BI', payload)


def pack_set_levels(levels: list[int], show_now: bool) -> bytes:
    if len(levels) != LED_COUNT:
        raise PayloadError(f'SET_LEVELS needs {LED_COUNT} levels, got {len(levels)}')
    return struct.pack(f'<B{LED_COUNT}H', SHOW_NOW if show_now else 0, *levels)


def unpack_set_levels(payload: bytes) -> tuple[int, tuple[int, ...]]:
    _expect(payload, 1 + 2 * LED_COUNT, 'SET_LEVELS')
    values = struct.unpack(f'<B{LED_COUNT}H', payload)
    return values[0], values[1:]


def pack_sequence(gap_us: int, entries: list[SequenceEntry]) -> bytes:
    out = struct.pack('<IB', gap_us, len(entries))
    return out + b''.join(struct.pack('<II', e.word, e.exposure_us) for e in entries)


def unpack_sequence_header(payload: bytes) -> tuple[int, int]:
    if len(payload) < 5:
        raise PayloadError(f'RUN_SEQUENCE payload must be at least 5 bytes, got {len(payload)}')
    return struct.unpack_from('<IB', payload)


def unpack_sequence_entries(payload: bytes, count: int) -> list[SequenceEntry]:
    _expect(payload, 5 + 8 * count, 'RUN_SEQUENCE')
    return [SequenceEntry(*struct.unpack_from('<II', payload, 5 + 8 * i)) for i in range(count)]


@dataclass(frozen=True)
class LevelSequenceEntry:
    row: int             # row of the level table (SET_LEVEL_TABLE)
    exposure_us: int


def pack_level_table(first: int, rows) -> bytes:
    """SET_LEVEL_TABLE: `first` row, then 1..4 rows of 32 levels 0..255."""
    rows = [bytes(row) for row in rows]
    if not 1 <= len(rows) <= TABLE_ROWS_PER_FRAME or any(len(r) != LED_COUNT for r in rows):
        raise PayloadError(f'SET_LEVEL_TABLE takes 1..{TABLE_ROWS_PER_FRAME} rows of {LED_COUNT} levels')
    return bytes((first,)) + b''.join(rows)


def unpack_level_table(payload: bytes) -> tuple[int, list[tuple[int, ...]]]:
    n = len(payload) - 1
    if n < LED_COUNT or n % LED_COUNT:
        raise PayloadError(f'SET_LEVEL_TABLE payload must be 1 + 32 x rows bytes, got {len(payload)}')
    return payload[0], [tuple(payload[1 + k:1 + k + LED_COUNT]) for k in range(0, n, LED_COUNT)]


def pack_level_sequence(gap_us: int, entries: list[LevelSequenceEntry]) -> bytes:
    out = struct.pack('<IB', gap_us, len(entries))
    return out + b''.join(struct.pack('<BI', e.row, e.exposure_us) for e in entries)


def unpack_level_sequence_entries(payload: bytes, count: int) -> list[LevelSequenceEntry]:
    _expect(payload, 5 + 5 * count, 'RUN_LEVEL_SEQUENCE')
    return [LevelSequenceEntry(*struct.unpack_from('<BI', payload, 5 + 5 * i)) for i in range(count)]


def frame_bytes(payload_len: int) -> int:
    """Bytes on the wire of a frame with a payload of `payload_len` bytes."""
    return payload_len + OVERHEAD


def line_seconds(n_bytes: int, baud: int) -> float:
    """Time the serial line needs for `n_bytes` at `baud` 8N1 (10 bits per byte)."""
    return n_bytes * 10.0 / baud
