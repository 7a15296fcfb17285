"""The bag directory, as rosbag2 lays it out: ``NAME/`` holding ``NAME_0.mcap``,
``NAME_1.mcap``, ... (split by size or duration) and ``metadata.yaml`` (top key
``rosbag2_bagfile_information``, version 9) listing every file: names, the output directory
rule, and which files a bag path holds."""
from __future__ import annotations

import datetime as _dt
import re
from pathlib import Path

import yaml

from .exceptions import BagError

ROS_DISTRO = 'jazzy'
METADATA_FILE = 'metadata.yaml'
METADATA_VERSION = 9


def file_name(bag: Path, index: int) -> Path:
    """The path of the bag's file number ``index`` (``NAME/NAME_<index>.mcap``)."""
    return bag / f'{bag.name}_{index}.mcap'


def default_bag_name(now: _dt.datetime | None = None) -> str:
    """``rosbag2_YYYY_MM_DD-HH_MM_SS`` (local time), the name ``ros2 bag record`` picks."""
    now = now or _dt.datetime.now()
    return now.strftime('rosbag2_%Y_%m_%d-%H_%M_%S')


def check_output_dir(path) -> None:
    """BagError unless ``path`` can become a new bag directory: it must not exist, or be an
    empty directory (``ros2 bag record`` refuses any existing directory; an empty one -- made
    by ``mkdir``, a fresh mount -- is accepted here). A bag is never overwritten."""
    path = Path(path)
    if not path.exists():
        return
    if not path.is_dir():
        raise BagError(f'{path} already exists and is not a directory; give a new bag directory '
                       '(it must not exist, or be an empty directory)')
    if any(path.iterdir()):
        raise BagError(f'{path} already exists and is not empty; choose another output directory '
                       'or delete it (a bag is never overwritten; an existing empty directory is '
                       'used)')


def resolve_files(path: Path) -> tuple[list[Path], dict | None, list[str]]:
    """The .mcap files of a bag path and its metadata.yaml contents (or None)."""
    problems: list[str] = []
    if not path.exists():
        raise BagError(f'{path} does not exist; give a bag directory (with metadata.yaml and '
                       '.mcap files) or a .mcap file')
    if path.is_file():
        if path.name == METADATA_FILE:
            return resolve_files(path.parent)
        return [path], None, problems
    meta_path = path / METADATA_FILE
    metadata = None
    if meta_path.is_file():
        try:
            loaded = yaml.safe_load(meta_path.read_text())
            metadata = loaded['rosbag2_bagfile_information']
            if not isinstance(metadata, dict):
                raise TypeError('rosbag2_bagfile_information is not a mapping')
        except (yaml.YAMLError, KeyError, TypeError) as exc:
            problems.append(f'{meta_path} is unreadable ({type(exc).__name__}: {exc}); reading the '
                            '.mcap files of the directory instead')
            metadata = None
    if metadata is not None:
        storage = metadata.get('storage_identifier', 'mcap')
        if storage != 'mcap':
            raise BagError(f'{path} is a rosbag2 bag with storage {storage!r}; this tool reads MCAP '
                           'bags only: convert it with `ros2 bag convert` (storage_id: mcap)')
        if metadata.get('compression_mode'):
            raise BagError(f'{path} uses rosbag2 {metadata.get("compression_mode")} compression '
                           f'({metadata.get("compression_format")}); decompress it first with '
                           '`ros2 bag convert`')
        names = metadata.get('relative_file_paths') or [f.get('path') for f in metadata.get('files', [])]
        files = [path / n for n in names if n]
        missing = [f.name for f in files if not f.is_file()]
        if missing:
            raise BagError(f'{meta_path} lists {", ".join(missing)} but {path} does not hold '
                           f'{"it" if len(missing) == 1 else "them"}; copy the whole bag directory')
        return files, metadata, problems
    files = sorted(path.glob('*.mcap'), key=lambda p: [int(t) if t.isdigit() else t
                                                      for t in re.split(r'(\d+)', p.name)])
    if not files:
        raise BagError(f'{path} holds no metadata.yaml and no .mcap file; give a bag directory '
                       'written by `lightstage record` or `ros2 bag record -s mcap`')
    if not meta_path.exists():
        problems.append(f'{path} has no {METADATA_FILE} (the recorder did not close the bag); '
                        'reading its .mcap files directly')
    return files, None, problems


