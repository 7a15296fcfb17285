"""Message definitions and type hashes for bag schemas, read from the installed interfaces.

A bag's schema for a topic type is the type's `.msg` text followed by the text of every type
it depends on, depth-first, once each, each after a line of 80 ``=`` and a line
``MSG: pkg/Type`` -- the ``ros2msg`` encoding rosbag2 writes (its
``LocalMessageDefinitionSource``): the same field-type pattern finds the dependencies, a type
without a package is resolved in the package of the text it appears in, and the
dependencies of one text are visited in sorted order.

Types that have no ``.msg`` file of their own are derived from the interface file that
generates them, so their messages stay decodable by readers that only have the bag:
``pkg/srv/Name_Request`` / ``_Response`` (the two halves of ``Name.srv``),
``pkg/srv/Name_Event`` (what service introspection publishes on
``<service>/_service_event``: ``service_msgs/ServiceEventInfo info``, at most one request,
at most one response), and the ``Goal`` / ``Result`` / ``Feedback`` / ``FeedbackMessage``
parts of an action. (rosbag2 of Jazzy leaves the schema of service event topics empty or
stores the raw ``.srv``; its player does not need it, other readers do.)

Type hashes (``RIHS01_...``) come from the ``.json`` files installed next to the
interface files. Pure Python: no rclpy import; the files are found under the prefixes on
``AMENT_PREFIX_PATH`` and this interpreter's prefix (the venv the ROS wheels live in).
"""
from __future__ import annotations

import json
import os
import re
import sys
from functools import lru_cache
from pathlib import Path

from lightstage_graph.names import SERVICE_EVENT_SUFFIX

SEPARATOR = '=' * 80
# rosbag2's MSG_FIELD_TYPE_REGEX: the type at the start of a field line
_FIELD_TYPE = re.compile(r'(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+')
PRIMITIVE_TYPES = frozenset({'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8',
                             'int16', 'uint16', 'int32', 'uint32', 'int64', 'uint64', 'string',
                             'wstring'})
_NAME = r'[a-zA-Z][a-zA-Z0-9_]*'
_TYPE = re.compile(rf'^({_NAME})/(?:({_NAME})/)?({_NAME})$')
_SRV_PARTS = ('_Request', '_Response', '_Event')
_ACTION_PARTS = ('_Goal', '_Result', '_Feedback', '_FeedbackMessage')


class DefinitionNotFoundError(LookupError):
    """No interface file defines this type on this machine."""


def split_type(type_name: str) -> tuple[str, str, str]:
    """``pkg/msg/Type`` or ``pkg/Type`` -> (pkg, namespace, Type); namespace defaults to msg."""
    match = _TYPE.match(type_name)
    if not match:
        raise ValueError(f'{type_name!r} is not a ROS type name like pkg/msg/Type')
    package, namespace, name = match.groups()
    return package, namespace or 'msg', name


def share_dirs() -> list[Path]:
    """``<prefix>/share`` of every prefix on AMENT_PREFIX_PATH, then of this interpreter's."""
    prefixes = [p for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
    prefixes.append(sys.prefix)
    seen, out = set(), []
    for prefix in prefixes:
        share = Path(prefix) / 'share'
        if share not in seen and share.is_dir():
            seen.add(share)
            out.append(share)
    return out


def _interface_file(package: str, namespace: str, filename: str) -> Path | None:
    for share in share_dirs():
        path = share / package / namespace / filename
        if path.is_file():
            return path
    return None


def dependencies(text: str, package: str) -> list[str]:
    """Types the fields of a .msg text refer to, as ``pkg/Type``, sorted (rosbag2's order)."""
    deps = set()
    for match in _FIELD_TYPE.finditer(text):
        name = match.group(1)
        if name in PRIMITIVE_TYPES:
            continue
        deps.add(name if '/' in name else f'{package}/{name}')
    return sorted(deps)


def _split_sections(text: str, count: int) -> list[str]:
    """The sections of a .srv / .action text, separated by lines of exactly ``---``."""
    sections, current = [], []
    for line in text.splitlines(keepends=True):
        if line.strip() == '---':
            sections.append(''.join(current))
            current = []
        else:
            current.append(line)
    sections.append(''.join(current))
    if len(sections) != count:
        raise ValueError(f'expected {count} sections separated by ---, found {len(sections)}')
    return [s.rstrip('\n') + '\n' if s.strip() else '' for s in sections]


@lru_cache(maxsize=None)
def definition_text(type_name: str) -> str:
    """The text of one type's own definition (no dependencies); DefinitionNotFoundError if none.

    ``type_name`` is ``pkg/Type`` or ``pkg/ns/Type``. ``pkg/Type`` is looked up as a message
    first, then as a part of a service or action, as a dependency line names it.
    """
    package, namespace, name = split_type(type_name)
    explicit = '/' in type_name.split('/', 1)[1]
    namespaces = [namespace] if explicit else ['msg', 'srv', 'action']
    for ns in namespaces:
        path = _interface_file(package, ns, f'{name}.msg')
        if path is not None:
            return path.read_text()
        if ns == 'srv':
            for suffix in _SRV_PARTS:
                if name.endswith(suffix):
                    base = name[:-len(suffix)]
                    path = _interface_file(package, 'srv', f'{base}.srv')
                    if path is None:
                        continue
                    request, response = _split_sections(path.read_text(), 2)
                    if suffix == '_Request':
                        return request
                    if suffix == '_Response':
                        return response
                    return (f'service_msgs/ServiceEventInfo info\n'
                            f'{package}/{base}_Request[<=1] request\n'
                            f'{package}/{base}_Response[<=1] response\n')
        if ns == 'action':
            for suffix in _ACTION_PARTS:
                if name.endswith(suffix):
                    base = name[:-len(suffix)]
                    path = _interface_file(package, 'action', f'{base}.action')
                    if path is None:
                        continue
                    goal, result, feedback = _split_sections(path.read_text(), 3)
                    if suffix == '_FeedbackMessage':
                        return (f'unique_identifier_msgs/UUID goal_id\n'
                                f'{package}/{base}_Feedback feedback\n')
                    return {'_Goal': goal, '_Result': result, '_Feedback': feedback}[suffix]
    where = ', '.join(str(s) for s in share_dirs()) or '(no share directories found)'
    raise DefinitionNotFoundError(
        f'no interface file defines {type_name} under {where}; install its package (or put its '
        f'prefix on AMENT_PREFIX_PATH) to record it with a schema')


def full_definition(type_name: str) -> str:
    """The ``ros2msg`` schema text of a topic type: its definition and all dependencies."""
    package = split_type(type_name)[0]
    seen: set[str] = set()

    def append(name: str, pkg: str, depth: int) -> str:
        if depth <= 0:
            raise ValueError(f'definition of {type_name} nests deeper than 50 levels')
        text = definition_text(name)
        out = text
        for dep in dependencies(text, pkg):
            if dep not in seen:
                seen.add(dep)
                out += f'\n{SEPARATOR}\nMSG: {dep}\n' + append(dep, split_type(dep)[0], depth - 1)
        return out

    return append(type_name, package, 50)


def type_hash(type_name: str) -> str:
    """The ``RIHS01_...`` hash of a type from the installed ``.json`` files, '' if unknown."""
    try:
        package, namespace, name = split_type(type_name)
    except ValueError:
        return ''
    full = f'{package}/{namespace}/{name}'
    candidates = [name]
    for suffix in _SRV_PARTS + _ACTION_PARTS:
        if name.endswith(suffix):
            candidates.append(name[:-len(suffix)])
    for base in candidates:
        path = _interface_file(package, namespace, f'{base}.json')
        if path is None:
            continue
        try:
            hashes = json.loads(path.read_text()).get('type_hashes', [])
        except (OSError, ValueError):
            continue
        for entry in hashes:
            if entry.get('type_name') == full:
                return str(entry.get('hash_string', ''))
    return ''


def is_service_event(topic: str, type_name: str) -> bool:
    """A service's introspection topic (``/srv/_service_event`` of a ``pkg/srv/Name_Event``)."""
    return topic.endswith(SERVICE_EVENT_SUFFIX) and is_service_event_type(type_name)


def is_service_event_type(type_name: str) -> bool:
    return '/srv/' in type_name and type_name.endswith('_Event')
