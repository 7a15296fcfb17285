"""Files about to be written: refuse to replace one unless asked, check its folder takes files.

Shared by everything that writes an output a run must not lose at the end (a capture pose,
a noise file, a plot, a trained artifact, evaluation results): the check runs before the
work, so a long run does not end in an unwritable path. What cannot be written where it was
meant to go at the end is kept in a rescue folder (`save_in_rescue_dir`).
"""
from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Callable

from .errors import DestinationError

__all__ = ["check_output_file", "writable_dir", "rescue_dirs", "save_in_rescue_dir", "RESCUE_DIR_ENV"]

RESCUE_DIR_ENV = "LIGHTSTAGE_RESCUE_DIR"


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


def check_output_file(path, overwrite: bool = False) -> Path:
    """A file about to be written (a noise file, a plot): refuses to replace one unless
    `overwrite`, and checks its folder (or the first existing parent) takes new files."""
    path = Path(path).expanduser()
    if path.is_dir():
        raise DestinationError(f"{path} is a folder; give a file name")
    if path.exists() and not overwrite:
        raise DestinationError(f"{path} already exists; choose another name or ask to "
                               "overwrite it (overwrite: true / --overwrite)")
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
