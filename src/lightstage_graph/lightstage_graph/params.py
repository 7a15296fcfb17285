"""Node parameters: descriptors with types and ranges (what `ros2 param describe` shows), one
table per node, declared in one call and read back by name.

    PARAMETERS = {'timeout_s': (10.0, floating('time limit [s]', 0.1, 600.0)), ...}
    self.p = declare_parameters(self, PARAMETERS)
    self.p('timeout_s')

Values given at start-up (a params file, `-p name:=value`, `parameter_overrides`) are checked
before they are declared, every problem named at once (`ParameterError`): a value out of
its range, of the wrong type, or a parameter the node does not have (with the closest
names). An integer where a float belongs is taken as that float (`exposure_us: 30000`).
`read_params_file` reads a params YAML and names the line of a syntax error; `lightstage
up` and `init_node` run it before anything starts. `markdown_table` writes a table as
docs/NODES.md shows it.
"""
from __future__ import annotations

import difflib
import math
from typing import Any

from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                ParameterType)

from .limits import number_text

ParameterTable = dict[str, tuple[Any, ParameterDescriptor]]


def integer(description: str, lo: int, hi: int, *, read_only: bool = False) -> ParameterDescriptor:
    return ParameterDescriptor(type=ParameterType.PARAMETER_INTEGER, description=description,
                               read_only=read_only,
                               integer_range=[IntegerRange(from_value=lo, to_value=hi, step=1)])


def floating(description: str, lo: float, hi: float, *, read_only: bool = False) -> ParameterDescriptor:
    return ParameterDescriptor(type=ParameterType.PARAMETER_DOUBLE, description=description,
                               read_only=read_only,
                               floating_point_range=[FloatingPointRange(from_value=lo, to_value=hi)])


def string(description: str, *, read_only: bool = False, constraints: str = '',
           dynamic: bool = False) -> ParameterDescriptor:
    """A string; `dynamic`: other types are accepted too (e.g. an index or a name)."""
    return ParameterDescriptor(type=ParameterType.PARAMETER_STRING, description=description,
                               read_only=read_only, additional_constraints=constraints,
                               dynamic_typing=dynamic)


def boolean(description: str, *, read_only: bool = False) -> ParameterDescriptor:
    return ParameterDescriptor(type=ParameterType.PARAMETER_BOOL, description=description,
                               read_only=read_only)


def string_array(description: str, *, read_only: bool = False) -> ParameterDescriptor:
    """A list of strings; declare it with the default ``Parameter.Type.STRING_ARRAY`` for
    one that may stay unset."""
    return ParameterDescriptor(type=ParameterType.PARAMETER_STRING_ARRAY, description=description,
                               read_only=read_only)


# parameters rclpy declares or reads on every node, never in a table
ROS_OWN_PARAMETERS = ('use_sim_time', 'start_type_description_service', 'qos_overrides.')

_TYPE_NAMES = {ParameterType.PARAMETER_BOOL: 'true or false',
               ParameterType.PARAMETER_INTEGER: 'a whole number',
               ParameterType.PARAMETER_DOUBLE: 'a number',
               ParameterType.PARAMETER_STRING: 'a string (quote it in YAML)',
               ParameterType.PARAMETER_STRING_ARRAY: 'a list of strings'}


class ParameterError(SystemExit):
    """Start-up parameters a node cannot run with. A SystemExit: the node's process ends
    with this message (every problem, each naming its parameter) and exit code 1, not a
    traceback; a test catches it like any exception."""

    def __init__(self, message: str):
        super().__init__(message)
        self.message = message

    def __str__(self) -> str:
        return self.message


def _number_range(descriptor: ParameterDescriptor):
    ranges = descriptor.floating_point_range or descriptor.integer_range
    return (ranges[0].from_value, ranges[0].to_value) if ranges else None


def check_value(name: str, value, descriptor: ParameterDescriptor):
    """`value` as the node takes it (an integer for a float parameter becomes the float, a
    whole float for an integer parameter the integer); ValueError naming the parameter, what
    it must be and its range otherwise."""
    kind = descriptor.type
    wanted = _TYPE_NAMES.get(kind, 'another type')
    limits = _number_range(descriptor)
    span = f' in {number_text(limits[0])} .. {number_text(limits[1])}' if limits else ''
    if descriptor.dynamic_typing or kind == ParameterType.PARAMETER_NOT_SET:
        return value
    if kind == ParameterType.PARAMETER_DOUBLE and isinstance(value, int) and not isinstance(value, bool):
        value = float(value)
    if kind == ParameterType.PARAMETER_INTEGER and isinstance(value, float) and value.is_integer():
        value = int(value)
    expected = {ParameterType.PARAMETER_BOOL: bool, ParameterType.PARAMETER_INTEGER: int,
                ParameterType.PARAMETER_DOUBLE: float, ParameterType.PARAMETER_STRING: str,
                ParameterType.PARAMETER_STRING_ARRAY: (list, tuple)}.get(kind)
    if expected is not None and (not isinstance(value, expected)
                                 or (expected is int and isinstance(value, bool))):
        raise ValueError(f'{name}: must be {wanted}{span}, got {value!r}')
    if kind == ParameterType.PARAMETER_STRING_ARRAY and not all(isinstance(v, str) for v in value):
        raise ValueError(f'{name}: must be {wanted}, got {value!r}')
    if limits and not (isinstance(value, (int, float)) and math.isfinite(value)
                       and limits[0] <= value <= limits[1]):
        raise ValueError(f'{name}: {value!r} is out of range: give {wanted}{span}'
                         f' ({descriptor.description})')
    return value


def check_values(table: ParameterTable, values: dict, where: str = 'node') -> dict:
    """`values` ({name: value}) checked against `table`: the values as the node takes them
    (`check_value`); ParameterError naming every unknown parameter (with the closest names)
    and every bad value."""
    problems, checked = [], {}
    for name, value in values.items():
        if name in table:
            try:
                checked[name] = check_value(name, value, table[name][1])
            except ValueError as exc:
                problems.append(str(exc))
        elif not str(name).startswith(ROS_OWN_PARAMETERS):
            close = difflib.get_close_matches(str(name), list(table), n=3)
            hint = f'did you mean {" or ".join(close)}?' if close else f'it has {", ".join(table)}'
            problems.append(f'{name}: {where} has no such parameter ({hint})')
        else:
            checked[name] = value
    if problems:
        raise ParameterError(f'{where}: cannot start with these parameters:\n  '
                             + '\n  '.join(problems))
    return checked


def read_params_file(path) -> dict:
    """A ROS params YAML as {section: {name: value}} (section: a node name, /name or /**);
    ValueError naming the file, and the line of a syntax error."""
    import yaml
    try:
        text = open(path, encoding='utf-8').read()
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f'params file {path}: cannot read it ({exc})') from None
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, 'problem_mark', None)
        where = f' at line {mark.line + 1}, column {mark.column + 1}' if mark else ''
        problem = getattr(exc, 'problem', None) or str(exc).splitlines()[0]
        raise ValueError(f'params file {path}: not valid YAML{where}: {problem}') from None
    if doc is None:
        return {}
    sections = {}
    if not isinstance(doc, dict):
        raise ValueError(f'params file {path}: expected NODE_NAME: {{ros__parameters: {{...}}}} '
                         f'sections, got {type(doc).__name__}')
    for section, body in doc.items():
        if not isinstance(body, dict):
            raise ValueError(f'params file {path}: section {section!r} must be a mapping '
                             f'(ros__parameters: {{name: value, ...}}), got {body!r}')
        if 'ros__parameters' not in body:
            continue  # a namespace holding node sections
        values = body['ros__parameters']
        if not isinstance(values, dict):
            raise ValueError(f'params file {path}: {section}.ros__parameters must map names to '
                             f'values, got {values!r}')
        sections[str(section)] = values
    return sections


def params_files_of(args) -> list[str]:
    """The --params-file paths of a node's command line (after --ros-args)."""
    args = list(args or [])
    return [args[i + 1] for i, a in enumerate(args[:-1]) if a == '--params-file']


def markdown_table(table: ParameterTable, defaults: dict | None = None) -> str:
    """The parameters of a node as a Markdown table: name, type, default, range (or the
    allowed values), read-only, description. `defaults` overrides how a default is written
    (e.g. one that depends on the machine)."""
    rows = ['| parameter | type | default | range | description |',
            '| --- | --- | --- | --- | --- |']
    for name, (default, d) in table.items():
        kind = _TYPE_NAMES.get(d.type, '?').split(' (')[0]
        if d.dynamic_typing:
            kind = 'a string or a number'
        limits = _number_range(d)
        if limits:
            span = f'{number_text(limits[0])} .. {number_text(limits[1])}'
        else:
            span = d.additional_constraints or ('true / false' if d.type == ParameterType.PARAMETER_BOOL
                                               else 'any')
        if defaults and name in defaults:
            shown = defaults[name]
        elif not isinstance(default, (bool, int, float, str)):
            shown = 'unset'
        elif isinstance(default, bool):
            shown = f'`{str(default).lower()}`'
        else:
            shown = f'`{default!r}`' if isinstance(default, str) else f'`{default}`'
        text = (d.description.replace('|', '\\|').replace('<', '\\<')
                + (' (read-only)' if d.read_only else ''))
        rows.append(f'| `{name}` | {kind} | {shown} | {span} | {text} |')
    return '\n'.join(rows)


class Parameters:
    """A node's declared parameters; ``params(name)`` is the current value."""

    def __init__(self, node, table: ParameterTable):
        overrides = getattr(node, '_parameter_overrides', None)
        if isinstance(overrides, dict) and overrides:
            given = {name: p.value for name, p in overrides.items()}
            checked = check_values(table, given, f'node {node.get_name()!r}')
            for name, value in checked.items():
                if type(value) is not type(given[name]):
                    old = overrides[name]  # rclpy's Parameter, without importing rclpy here
                    overrides[name] = type(old)(name, type(old).Type.from_parameter_value(value), value)
        for name, (default, descriptor) in table.items():
            node.declare_parameter(name, default, descriptor)
        self._node = node

    def __call__(self, name: str):
        return self._node.get_parameter(name).value


def declare_parameters(node, table: ParameterTable) -> Parameters:
    """Declare every parameter of `table` ({name: (default, descriptor)}) on `node`."""
    return Parameters(node, table)
