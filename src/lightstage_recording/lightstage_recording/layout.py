"""The bag directory, as rosbag2 lays it out: ``NAME/`` holding ``NAME_0.mcap``,
``NAME_1.mcap``, ... (split by size or duration) and ``metadata.yaml`` (top key
``rosbag2_bagfile_information``, version 9) listing every file: names, the output directory
rule, and which files a bag path holds."""
from __future__ import annotations

import datetime as _dt
import os
import re
import stat
from pathlib import Path

import yaml

from .exceptions import BagError

ROS_DISTRO = 'jazzy'
METADATA_FILE = 'metadata.yaml'
METADATA_VERSION = 9
# A rosbag2 metadata.yaml is a few KiB (about 1 KiB per topic and per file); 1 MiB is far
# beyond any real one and bounds what a hostile file makes the reader load.
MAX_METADATA_BYTES = 1 << 20


def load_metadata(meta_path: Path, max_bytes: int = MAX_METADATA_BYTES):
    """The parsed metadata.yaml. A file larger than ``max_bytes`` or with YAML anchors or
    aliases (rosbag2 writes none; nested aliases expand exponentially, 'billion laughs') is
    refused with `BagError` naming the file and the rule, before it is expanded."""
    size = meta_path.stat().st_size
    if size > max_bytes:
        raise BagError(f'{meta_path} is {size} bytes, more than the {max_bytes} bytes a '
                       f'{METADATA_FILE} may hold; refused without reading it (a damaged or '
                       'hostile file)')
    text = meta_path.read_text()
    for event in yaml.parse(text, Loader=yaml.SafeLoader):
        if isinstance(event, yaml.AliasEvent) or getattr(event, 'anchor', None) is not None:
            raise BagError(f'{meta_path} uses YAML anchors or aliases (line '
                           f'{event.start_mark.line + 1}), which a rosbag2 {METADATA_FILE} never '
                           'holds; refused without expanding them (a hostile file)')
    return yaml.safe_load(text)


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
    if not path.is_dir():
        raise BagError(f'{path} is not a regular file nor a directory '
                       f'({_kind(path.stat().st_mode)}); give a bag directory or a .mcap file')
    meta_path = path / METADATA_FILE
    metadata = None
    if meta_path.is_file():
        try:
            loaded = load_metadata(meta_path)
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
        return listed_files(path, meta_path, metadata), metadata, problems
    files = sorted(path.glob('*.mcap'), key=lambda p: [int(t) if t.isdigit() else t
                                                      for t in re.split(r'(\d+)', p.name)])
    if not files:
        raise BagError(f'{path} holds no metadata.yaml and no .mcap file; give a bag directory '
                       'written by `lightstage record` or `ros2 bag record -s mcap`')
    for f in files:
        check_regular_file(f, path)
    if not meta_path.exists():
        problems.append(f'{path} has no {METADATA_FILE} (the recorder did not close the bag); '
                        'reading its .mcap files directly')
    return files, None, problems




def _kind(mode: int) -> str:
    for test, name in ((stat.S_ISFIFO, 'a FIFO'), (stat.S_ISSOCK, 'a socket'),
                       (stat.S_ISCHR, 'a character device'), (stat.S_ISBLK, 'a block device'),
                       (stat.S_ISDIR, 'a directory'), (stat.S_ISLNK, 'a symbolic link')):
        if test(mode):
            return name
    return 'not a regular file'


def check_regular_file(file: Path, bag: Path) -> None:
    """BagError unless ``file`` is a regular file in the bag directory ``bag`` itself (a
    symbolic link is followed and must end there too). Nothing is opened: a FIFO or device
    named as a bag file would block or never end."""
    try:
        mode = os.stat(file).st_mode
    except OSError as exc:
        raise BagError(f'cannot read {file}: {exc.strerror}; copy the whole bag directory') from None
    if not stat.S_ISREG(mode):
        raise BagError(f'{file} is {_kind(mode)}, not a regular file; a bag\'s files are regular '
                       'files; refused, nothing read')
    if file.resolve().parent != bag.resolve():
        raise BagError(f'{file} resolves to {file.resolve()}, outside the bag directory {bag}; a '
                       'bag\'s files are in its directory; refused, nothing read')


def listed_files(bag: Path, meta_path: Path, metadata: dict) -> list[Path]:
    """The files metadata.yaml lists, checked before any is opened: each a plain file name (no
    directory part, never ``..``) of a regular file in the bag directory, each once. BagError
    naming metadata.yaml and the entry otherwise: a metadata.yaml may come from anywhere, and
    one naming /etc/passwd, a FIFO or one file 20,000 times must not make a reader read it."""
    names = metadata.get('relative_file_paths') or [f.get('path') for f in metadata.get('files') or []
                                                    if isinstance(f, dict)]
    if not isinstance(names, list):
        raise BagError(f'{meta_path}: relative_file_paths is not a list; give a metadata.yaml '
                       'written by `lightstage record` or `ros2 bag record`')
    files, seen = [], set()
    for name in names:
        if not name:
            continue
        if not isinstance(name, str) or name in ('.', '..') or '/' in name or '\\' in name \
                or '\0' in name:
            raise BagError(f'{meta_path} lists {name!r}, which is not a file name in the bag '
                           f'directory {bag}; a bag lists only its own files; refused, nothing '
                           'read')
        if name in seen:
            raise BagError(f'{meta_path} lists {name} more than once '
                           f'({names.count(name)} times); a bag lists each of its files once; '
                           'refused, nothing read')
        seen.add(name)
        files.append(bag / name)
    missing = [f.name for f in files if not os.path.lexists(f)]
    if missing:
        raise BagError(f'{meta_path} lists {", ".join(missing)} but {bag} does not hold '
                       f'{"it" if len(missing) == 1 else "them"}; copy the whole bag directory')
    for f in files:
        check_regular_file(f, bag)
    return files
