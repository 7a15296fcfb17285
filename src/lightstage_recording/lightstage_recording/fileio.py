"""Bag files written so that what was written survives: every byte goes through `write_all`
(the one place where it reaches the OS), the MCAP file through an unbuffered `Sink` that can
be cut back to a record boundary, metadata.yaml through `replace_atomically`; directories are
fsynced so that new names survive a power loss. `write_error_text` says what a write error
means for a bag."""
from __future__ import annotations

import errno
import os
from pathlib import Path


def write_all(fd: int, data) -> None:
    """Hand all of ``data`` to the OS (``os.write`` until done). Every byte the writer puts in
    a bag file or metadata.yaml goes through here."""
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view):]


def write_error_text(exc: OSError, path: Path, held: str, retry: str) -> str:
    """What a write error means for the bag at ``path``, what it holds, what to do."""
    if exc.errno in (errno.ENOSPC, errno.EDQUOT):
        return f'disk full writing {path}: {exc.strerror}; {held}; free space and {retry}'
    return f'cannot write {path}: {exc.strerror or exc}; {held}; check the disk and {retry}'


def fsync_dir(path: Path) -> None:
    """fsync a directory, so that the names created in it survive a power loss. Best effort:
    some file systems refuse to fsync directories."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def replace_atomically(path: Path, data: bytes) -> None:
    """Write ``path`` through a temporary file beside it (``NAME.tmp``), fsynced, then renamed
    over it: a reader finds the old file or the new one, never part of one. OSError: nothing
    is left behind."""
    tmp = path.with_name(path.name + '.tmp')
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o666)
        try:
            write_all(fd, data)
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, path)
    except OSError:
        try:
            tmp.unlink(missing_ok=True)
        except OSError:
            pass
        raise


class Sink:
    """A new file as the mcap writer's output stream, unbuffered: each write goes to the OS at
    once, so the file always ends where the writer's last completed call left it, and `cut`
    can take it back to such a point."""

    def __init__(self, path: Path):
        self.path = path
        self.fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, 'O_CLOEXEC', 0),
                          0o666)
        self.pos = 0

    def write(self, data) -> int:
        write_all(self.fd, data)
        self.pos += len(data)
        return len(data)

    def tell(self) -> int:
        return self.pos

    def flush(self) -> None:
        pass  # nothing is buffered here

    def cut(self, size: int) -> None:
        os.ftruncate(self.fd, size)
        os.lseek(self.fd, size, os.SEEK_SET)
        self.pos = size
