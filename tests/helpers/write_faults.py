"""A disk that fills up under the bag writer: every byte the writer puts into a bag goes
through `lightstage_recording.fileio.write_all`, which `FailingDisk` replaces (no ROS needed)."""
from __future__ import annotations

import errno
import os

from lightstage_recording import fileio

CHUNK_OPCODE = 0x06


class FailingDisk:
    """Takes ``after_chunks`` chunk records (with their message indexes), then fails the next
    chunk record with OSError(``code``), after writing half of it (a torn write, as a full
    disk leaves one). ``stays_full``: every later write fails too; else the write after is
    fine again (space was freed). ``full = True`` makes the next write fail, whatever it is."""

    def __init__(self, monkeypatch, *, after_chunks: int | None = None, code: int = errno.ENOSPC,
                 stays_full: bool = True):
        self.after_chunks = after_chunks
        self.code = code
        self.stays_full = stays_full
        self.full = False
        self.chunks = 0
        self.failures = 0
        real = fileio.write_all

        def write_all(fd, data):
            data = bytes(data)
            if not data:
                return real(fd, data)
            if (self.after_chunks is not None and data[0] == CHUNK_OPCODE
                    and self.chunks >= self.after_chunks and not self.failures):
                self.full = True
            if self.full:
                self.failures += 1
                self.full = self.stays_full
                real(fd, data[:len(data) // 2])
                raise OSError(self.code, os.strerror(self.code))
            if data[0] == CHUNK_OPCODE:
                self.chunks += 1
            return real(fd, data)

        monkeypatch.setattr(fileio, 'write_all', write_all)
