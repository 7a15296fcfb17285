"""One MCAP file walked record by record, so that a file whose writer was killed (no summary,
no footer) or that is damaged still yields every intact record; what was wrong is described.

A bag may come from anywhere, so what a file makes the reader hold in memory is bounded: a
chunk is inflated only if the size it declares is within ``max_chunk_bytes`` (`MAX_CHUNK_BYTES`,
256 MiB), and never beyond that declared size (`inflate_chunk`); a record the walk reads is
within the same limit. A file beyond it is refused (`BagError`, naming the file and the limit)
before anything is inflated.
"""
from __future__ import annotations

import io
import struct
import zlib
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Iterator

from mcap.writer import MCAP0_MAGIC as MCAP_MAGIC

from .exceptions import BagError

# the most one chunk (or one record) may take in memory once inflated: a full-resolution image
# is 1.3 MB, rosbag2 writes chunks of 768 KiB (one message may make one larger), this recorder
# 1 MiB; a file declaring more is refused, not inflated
MAX_CHUNK_BYTES = 256 << 20


def too_large_text(path: Path, what: str, size: int, limit: int) -> str:
    """The refusal of a record beyond the memory limit, naming the file and the limit."""
    return (f'{path}: {what} is {size} bytes ({size / 2**20:.1f} MiB) inflated, more than the '
            f'{limit} bytes ({limit / 2**20:.0f} MiB) this reader inflates per chunk; refused '
            'without inflating it (a damaged or hostile file, or a bag written with chunks or '
            'messages this large: read it with max_chunk_bytes raised, '
            '`BagReader(path, max_chunk_bytes=...)`)')


def inflate_chunk(chunk, limit: int, path: Path, offset: int) -> bytes:
    """The records of an MCAP chunk, inflated to at most the size it declares. `BagError` if it
    declares more than ``limit`` (nothing is inflated); ValueError if its data inflates to a
    different size than declared (damaged: described by the caller, its messages skipped) or
    does not match its CRC."""
    declared = int(chunk.uncompressed_size)
    if declared > limit:
        raise BagError(too_large_text(path, f'the chunk at byte {offset}', declared, limit))
    if chunk.compression == '':
        data = bytes(chunk.data)
    elif chunk.compression == 'lz4':
        import lz4.frame
        data = lz4.frame.LZ4FrameDecompressor().decompress(chunk.data, max_length=declared + 1)
    elif chunk.compression == 'zstd':
        import zstandard
        with zstandard.ZstdDecompressor().stream_reader(io.BytesIO(chunk.data)) as stream:
            data = stream.read(declared + 1)
    else:
        raise ValueError(f'unknown chunk compression {chunk.compression!r}')
    if len(data) != declared:
        more = 'more than' if len(data) > declared else f'{len(data)} bytes, not'
        raise ValueError(f'it inflates to {more} the {declared} bytes it declares')
    if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
        from mcap.exceptions import CRCValidationError
        raise CRCValidationError(expected=chunk.uncompressed_crc, actual=zlib.crc32(data),
                                 record=chunk)
    return data


def describe_non_mcap(head: bytes, path: Path) -> str:
    """What a file that does not start with the MCAP magic is, and what to do with it."""
    if head.startswith(b'SQLite format 3'):
        return (f'{path} is a rosbag2 sqlite3 file; this tool reads MCAP bags only: convert it '
                f'with `ros2 bag convert` (storage_id: mcap) or rosbags-convert')
    if head.startswith(b'\x28\xb5\x2f\xfd'):
        return (f'{path} is zstd-compressed (file compression mode); decompress it first '
                f'(`zstd -d {path.name}`)')
    if not head:
        return f'{path} is empty (0 bytes): the recorder wrote nothing; record again'
    return (f'{path} is not an MCAP file (it starts with {head[:8]!r}, an MCAP file with '
            f'{MCAP_MAGIC!r}); give a bag directory or .mcap file written by `lightstage record` '
            f'or `ros2 bag record -s mcap`')


@dataclass
class ChunkMessages:
    """Messages of one chunk (or one loose message) in file order, with its start time."""
    start_ns: int
    messages: list


class FileScan:
    """Walk one MCAP file record by record; damaged parts are skipped and described."""

    def __init__(self, path: Path, max_chunk_bytes: int = MAX_CHUNK_BYTES):
        self.path = path
        self.max_chunk_bytes = int(max_chunk_bytes)
        self.size = path.stat().st_size
        self.schemas: dict = {}
        self.channels: dict = {}
        self.metadata: dict[str, dict] = {}
        self.problems: list[str] = []
        self.complete = False
        self.library = ''
        self.summary = None
        self.chunks = self.chunks_without_crc = 0  # read back by the last walk
        with open(path, 'rb') as f:
            head = f.read(16)
        if head[:len(MCAP_MAGIC)] != MCAP_MAGIC:
            raise BagError(describe_non_mcap(head, path))
        self._read_summary()
        for index in (self.summary.chunk_indexes if self.summary is not None else ()):
            if index.uncompressed_size > self.max_chunk_bytes:
                raise BagError(too_large_text(path, f'the chunk at byte {index.chunk_start_offset}',
                                              index.uncompressed_size, self.max_chunk_bytes))

    def _read_summary(self) -> None:
        """Schemas, channels, statistics from the summary, if the file has an intact one."""
        from mcap.reader import SeekingReader
        try:
            with open(self.path, 'rb') as f:
                reader = SeekingReader(f)
                summary = reader.get_summary()
                self.library = reader.get_header().library
                if summary is not None:
                    for m in reader.iter_metadata():
                        self.metadata[m.name] = dict(m.metadata)
        except Exception:  # noqa: BLE001 - any failure means: no usable summary, walk instead
            return
        if summary is None or summary.statistics is None:
            return
        self.summary = summary
        self.schemas.update(summary.schemas)
        self.channels.update(summary.channels)
        self.complete = True

    def walk(self) -> Iterator[ChunkMessages]:
        """Every intact message, chunk by chunk, in file order. Problems go to .problems."""
        from mcap.opcode import Opcode
        from mcap.records import Channel, Chunk, Metadata, Message, Schema
        from mcap.stream_reader import StreamReader, breakup_chunk

        problems: list[str] = []
        found_footer = False
        self.chunks = self.chunks_without_crc = 0
        with open(self.path, 'rb') as f:
            f.seek(len(MCAP_MAGIC))
            offset = len(MCAP_MAGIC)
            while True:
                head = f.read(9)
                if len(head) < 9:
                    if not found_footer:
                        problems.append(
                            f'{self.path.name} ends at byte {offset} without the MCAP footer: the '
                            'writer did not close the file (killed, or out of disk)')
                    break
                opcode, length = struct.unpack('<BQ', head)
                if length > self.size - offset - 9:
                    problems.append(
                        f'{self.path.name} is cut off at byte {self.size}: the record at byte '
                        f'{offset} (opcode 0x{opcode:02x}) needs {length} bytes but only '
                        f'{self.size - offset - 9} are left (the writer was killed while writing, '
                        'or the copy is incomplete)')
                    break
                record_at = offset
                offset += 9 + length
                if opcode == Opcode.FOOTER:
                    found_footer = True
                    break
                if opcode not in (Opcode.CHUNK, Opcode.MESSAGE, Opcode.SCHEMA, Opcode.CHANNEL,
                                  Opcode.METADATA, Opcode.HEADER):
                    f.seek(length, io.SEEK_CUR)  # indexes, statistics, attachments, data end:
                    continue                     # the walk does not need them
                if length > self.max_chunk_bytes:
                    what = 'chunk' if opcode == Opcode.CHUNK else f'record (opcode 0x{opcode:02x})'
                    raise BagError(too_large_text(self.path, f'the {what} at byte {record_at}',
                                                  length, self.max_chunk_bytes))
                body = f.read(length)
                try:
                    reader = StreamReader(io.BytesIO(head + body), skip_magic=True, emit_chunks=True)
                    record = next(iter(reader.records))
                    if isinstance(record, Chunk):
                        self.chunks += 1
                        self.chunks_without_crc += record.uncompressed_crc == 0
                        data = inflate_chunk(record, self.max_chunk_bytes, self.path, record_at)
                        records = breakup_chunk(replace(record, compression='', data=data,
                                                        uncompressed_crc=0))
                    else:
                        records = [record]
                except BagError:
                    raise
                except Exception as exc:  # noqa: BLE001 - damaged data, described and skipped
                    what = 'chunk' if opcode == Opcode.CHUNK else f'record (opcode 0x{opcode:02x})'
                    problems.append(f'{self.path.name}: the {what} at byte {record_at} '
                                    f'({length} bytes) is damaged ({type(exc).__name__}: {exc}); '
                                    'its messages are skipped')
                    continue
                messages = []
                for r in records:
                    if isinstance(r, Schema):
                        self.schemas.setdefault(r.id, r)
                    elif isinstance(r, Channel):
                        self.channels.setdefault(r.id, r)
                    elif isinstance(r, Metadata):
                        self.metadata[r.name] = dict(r.metadata)
                    elif isinstance(r, Message):
                        messages.append(r)
                if not messages:
                    continue
                if isinstance(record, Chunk):
                    yield ChunkMessages(record.message_start_time, messages)
                else:
                    yield ChunkMessages(messages[0].log_time, messages)
        if not found_footer:
            self.complete = False
        for p in problems:
            if p not in self.problems:
                self.problems.append(p)
