"""`lightstage bag export`: a copy of a bag that the Python readers ROS users reach for open --
rosbags' `Reader`, `AnyReader` and `rosbags-convert`, mcap_ros2's `iter_decoded_messages()` --
service events included.

Why a copy: a recorded bag names a service event topic's type as rosbag2 does,
``pkg/srv/Name_Event`` (the schema's name; `ros2 bag play` and `ros2 bag info` take the type
from it), and those readers cannot take that name: rosbags files every type under ``pkg/msg/``
(its ``normalize_msgtype``), so the type is registered as ``pkg/srv/msg/Name_Event`` and
`AnyReader` fails with ``KeyError('pkg/srv/Name_Event')`` when it checks the type hash -- for
the whole bag, whichever topics are wanted; mcap_ros2 refuses a type name with an underscore
(``'Classify_Event' is an invalid message name``). Bags written by rosbag2 itself fail in
them too (docs/RECORDING.md, *Compatibility*).

The export renames every such type -- a service or action part (``pkg/srv/Name_Event``,
``pkg/srv/Name_Request``, ``pkg/action/Name_FeedbackMessage``, ...) -- to a message type
without the underscore (``pkg/msg/NameEvent``, ``pkg/msg/NameRequest``, ...), in the topic's
type, its schema's name and every reference in the schema text, and stores no type hash for
the renamed types (ROS's hash is that of the original name). Everything else is copied as it
is: topics, the CDR bytes (names are not in them), times, sequence numbers, QoS, the other
types' schemas and hashes. metadata.yaml's ``custom_data`` names the source
(``exported_from``) and the renamed types (``renamed_types``). The copy is for reading; play
the original (`lightstage play`, `ros2 bag play`).
"""
from __future__ import annotations

import re

from . import msg_definitions
from .exceptions import BagError
from .recover import Recovery, copy_bag

_FIELD = re.compile(r'^(\s*)([a-zA-Z][a-zA-Z0-9_/]*)(?=(\[[^\]]*\])?\s)', re.MULTILINE)
_HEADER = re.compile(r'^MSG:\s*(\S+)\s*$', re.MULTILINE)


def exported_type(type_name: str) -> str:
    """The name a type gets in the export: ``pkg/msg/Name`` unchanged; a type of another
    namespace or with an underscore in its name -> ``pkg/msg/`` and the name without
    underscores (``pkg/srv/Classify_Event`` -> ``pkg/msg/ClassifyEvent``). Names without a
    namespace (``pkg/Name``, as schema texts refer to types) keep that form."""
    parts = type_name.split('/')
    if len(parts) == 3:
        package, namespace, name = parts
        if namespace == 'msg' and '_' not in name:
            return type_name
        return f'{package}/msg/{name.replace("_", "")}'
    if len(parts) == 2:
        return f'{parts[0]}/{parts[1].replace("_", "")}'
    return type_name.replace('_', '')


def needs_renaming(type_name: str) -> bool:
    return exported_type(type_name) != type_name


def exported_schema_text(text: str) -> str:
    """A ``ros2msg`` schema text with every type it refers to (``MSG:`` lines, field types)
    renamed as `exported_type` does."""
    def field(match):
        indent, name = match.group(1), match.group(2)
        if name in msg_definitions.PRIMITIVE_TYPES:
            return match.group(0)
        return indent + exported_type(name)
    text = _HEADER.sub(lambda m: f'MSG: {exported_type(m.group(1))}', text)
    return _FIELD.sub(field, text)


def _source_schema(topic) -> str:
    """The schema text to rename: the bag's own, if it is a message definition; for a bag
    whose service event schema is not one (rosbag2 stores the raw ``.srv`` after a ``SRV:``
    line, or nothing) the definition of the installed interfaces."""
    text = topic.schema_text
    if topic.schema_encoding == 'ros2msg' and text.strip() and not text.lstrip().startswith(
            ('=', 'SRV:', 'MSG:')):
        return text
    try:
        return msg_definitions.full_definition(topic.type)
    except (msg_definitions.DefinitionNotFoundError, ValueError) as exc:
        raise BagError(f'{topic.name}: the bag holds no message definition of {topic.type} '
                       f'(schema encoding {topic.schema_encoding or "none"!r}) and none is '
                       f'installed here ({exc}); install its package and export again') from None


def export_bag(src, dst, *, compression: str = 'lz4') -> tuple[Recovery, dict[str, str]]:
    """Write ``dst``, the export of bag ``src`` (see the module); returns what was copied (as
    `recover_bag` does: problems of ``src``, the new bag's info, an error if the copy stopped)
    and the renamed types (old -> new)."""
    renamed: dict[str, str] = {}

    def topic_as(t):
        if not needs_renaming(t.type) or t.schema_encoding not in ('ros2msg', '', 'unknown'):
            return t.type, (t.schema_encoding, t.schema_text), t.type_hash
        new = exported_type(t.type)
        renamed[t.type] = new
        return new, ('ros2msg', exported_schema_text(_source_schema(t))), ''

    from .reader import BagReader
    topics = BagReader(src).info().topics.values()
    for t in topics:  # a bag it cannot export is refused before anything is written
        if needs_renaming(t.type):
            topic_as(t)
    clashes = sorted(set(renamed.values()) & {t.type for t in topics})
    if clashes:
        raise BagError(f'{src} has topics of type {", ".join(clashes)}, the name the export '
                       'gives a service or action type; it cannot be exported')
    summary = ', '.join(f'{old} -> {new}' for old, new in sorted(renamed.items()))
    result = copy_bag(src, dst, compression=compression, verb='export',
                      source_key='exported_from', topic_as=topic_as,
                      custom_data={'renamed_types': summary} if summary else None)
    return result, renamed
