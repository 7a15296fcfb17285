"""Files about to be written: refuse to replace one unless asked, replace only one of the
kind being written, check its folder takes files.

Shared by everything that writes an output a run must not lose at the end (a capture pose,
a noise file, a plot, a trained artifact, evaluation results): the check runs before the
work, so a long run does not end in an unwritable path. `overwrite` replaces only a file of
the kind being written (`FileKind`: a noise file by its `kind:` line, a plot by its image
format's signature): `lightstage calibrate CAPTURE/rig.yaml --overwrite` would otherwise
have replaced a capture's rig.yaml with a noise file, and the capture no longer loaded.
What cannot be written where it was meant to go at the end is kept in a rescue folder
(`save_in_rescue_dir`).
"""
from __future__ import annotations

import os
import re
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from .errors import DestinationError

__all__ = ["check_output_file", "writable_dir", "rescue_dirs", "save_in_rescue_dir", "RESCUE_DIR_ENV",
           "FileKind", "NOISE_FILE", "PLOT_FILE", "is_of_kind"]

RESCUE_DIR_ENV = "LIGHTSTAGE_RESCUE_DIR"
# how much of an existing file is read to tell its kind (its signature or header is at the start)
KIND_PROBE_BYTES = 64 * 1024


@dataclass(frozen=True)
class FileKind:
    """A kind of output file: `name` for messages, `recognizes(head)` whether an existing
    file's first KIND_PROBE_BYTES bytes are one of this kind."""
    name: str
    recognizes: Callable[[bytes], bool]


def _is_noise_file(head: bytes) -> bool:
    from .noise import NOISE_FILE_KIND  # save_noise_file writes it as a top-level key
    return re.search(rb"^kind:\s*['\"]?" + re.escape(NOISE_FILE_KIND.encode()) + rb"['\"]?\s*$",
                     head, re.MULTILINE) is not None


# the signatures of the formats plot_noise_characteristic writes (PLOT_SUFFIXES)
_IMAGE_SIGNATURES = (b"\x89PNG\r\n\x1a\n", b"%PDF-", b"\xff\xd8\xff", b"II*\x00", b"MM\x00*",
                     b"%!PS", b"\xc5\xd0\xd3\xc6")


def _is_plot(head: bytes) -> bool:
    if head.startswith(_IMAGE_SIGNATURES):
        return True
    text = head.lstrip()
    return text.startswith((b"<?xml", b"<svg", b"<!DOCTYPE svg")) and b"<svg" in head


NOISE_FILE = FileKind("noise file", _is_noise_file)
PLOT_FILE = FileKind("plot (PNG, PDF, SVG, JPEG, TIFF or PostScript image)", _is_plot)


def is_of_kind(path: Path, kind: FileKind) -> bool:
    """Whether the existing regular file `path` is of `kind`; an empty file counts as any
    kind (nothing in it to lose). Reads at most KIND_PROBE_BYTES bytes."""
    with open(path, "rb") as f:
        head = f.read(KIND_PROBE_BYTES)
    return not head or kind.recognizes(head)


def writable_dir(path: Path) -> None:
    """Raise DestinationError unless `path` (existing, or its first existing parent) can take
    new files; checked by creating and removing a file, not by permission bits alone."""
    probe_dir = path
    while not probe_dir.exists():
        if probe_dir.parent == probe_dir:
            break
        probe_dir = probe_dir.parent
    if not probe_dir.is_dir():
        raise DestinationError(f"{probe_dir} is not a folder; give a path in a folder")
    try:
        fd, name = tempfile.mkstemp(prefix=".lightstage-write-test-", dir=probe_dir)
        os.close(fd)
        os.unlink(name)
    except OSError as exc:
        raise DestinationError(f"cannot write into {probe_dir} ({exc.strerror or exc}); give a "
                               "writable folder") from None


def check_output_file(path, overwrite: bool = False, kind: FileKind | None = None) -> Path:
    """A file about to be written (a noise file, a plot): refuses to replace one unless
    `overwrite`, and with `overwrite` replaces only a file of `kind` (given: every writer
    that offers overwrite names what it writes); checks its folder (or the first existing
    parent) takes new files."""
    path = Path(path).expanduser()
    if path.is_dir():
        raise DestinationError(f"{path} is a folder; give a file name")
    if path.exists() and not overwrite:
        raise DestinationError(f"{path} already exists; choose another name or ask to "
                               "overwrite it (overwrite: true / --overwrite)")
    if path.exists() and kind is not None:
        if not path.is_file():
            raise DestinationError(f"{path} exists and is not a regular file; overwrite replaces "
                                   f"only a {kind.name}: choose another name")
        try:
            same_kind = is_of_kind(path, kind)
        except OSError as exc:
            raise DestinationError(f"{path} exists and cannot be read to check it is a "
                                   f"{kind.name} ({exc.strerror or exc}); overwrite replaces "
                                   f"only a {kind.name}: choose another name") from None
        if not same_kind:
            raise DestinationError(f"{path} exists and is not a {kind.name}; overwrite replaces "
                                   f"only a {kind.name}, nothing else: choose another name, or "
                                   "move that file away first")
    writable_dir(path.parent)
    return path


def rescue_dirs() -> list[Path]:
    """Where rescue files go, in order of preference: $LIGHTSTAGE_RESCUE_DIR, the user's
    cache folder, the temporary folder (another file system than a full capture disk, often)."""
    dirs = [Path(os.environ[RESCUE_DIR_ENV]).expanduser()] if os.environ.get(RESCUE_DIR_ENV) else []
    cache = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return dirs + [Path(cache) / "lightstage" / "rescued",
                   Path(tempfile.gettempdir()) / "lightstage-rescued"]


def save_in_rescue_dir(file_name: str, write: Callable[[Path], None]) -> Path:
    """`write(path)` a file named `file_name` into the first rescue folder that takes it;
    returns its path. Raises OSError naming each folder's error when none does."""
    errors = []
    for folder in rescue_dirs():
        path = folder / file_name
        try:
            folder.mkdir(parents=True, exist_ok=True)
            write(path)
            return path
        except OSError as exc:
            errors.append(f"{folder}: {exc.strerror or exc}")
            try:
                path.unlink()
            except OSError:
                pass
    raise OSError("; ".join(errors))
