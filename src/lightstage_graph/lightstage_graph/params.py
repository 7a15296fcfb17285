"""Node parameters: descriptors with types and ranges (what `ros2 param describe` shows), one
table per node, declared in one call and read back by name.

    PARAMETERS = {'timeout_s': (10.0, floating('time limit [s]', 0.1, 600.0)), ...}
    self.p = declare_parameters(self, PARAMETERS)
    self.p('timeout_s')
"""
from __future__ import annotations

from typing import Any

from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                ParameterType)

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


class Parameters:
    """A node's declared parameters; ``params(name)`` is the current value."""

    def __init__(self, node, table: ParameterTable):
        for name, (default, descriptor) in table.items():
            node.declare_parameter(name, default, descriptor)
        self._node = node

    def __call__(self, name: str):
        return self._node.get_parameter(name).value


def declare_parameters(node, table: ParameterTable) -> Parameters:
    """Declare every parameter of `table` ({name: (default, descriptor)}) on `node`."""
    return Parameters(node, table)
