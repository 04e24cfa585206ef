"""Where a processor's configuration comes from: ROS parameters live, overrides offline.

Config dataclasses of the algorithm layer are filled field by field from a
:class:`ParameterSource`. The live node's source declares ROS parameters
(:class:`face_tracking_ros.nodes.processor_node.NodeParameters`); offline replay uses
:class:`OverrideParameters`, built from ``--param name=value`` options, with the same names
(``tracker.epsilon``), so a replay is configured exactly like the node.
"""

from __future__ import annotations

from collections.abc import Mapping
import dataclasses
from enum import Enum
import inspect
import re
from typing import Any, Protocol, TypeVar

from face_tracking_ros.errors import ConfigError, FieldError
from face_tracking_ros.wording import listed

ConfigT = TypeVar('ConfigT')
EnumT = TypeVar('EnumT', bound=Enum)

_TRUE = {'true', '1', 'yes', 'on'}
_FALSE = {'false', '0', 'no', 'off'}


class ParameterSource(Protocol):
    """Gives the value of each field of a config dataclass.

    Attributes:
        live: True for a live node's parameters (outputs are published as they are produced),
            False offline (a replay, which has an end of stream).
    """

    live: bool

    def config(self, config_type: type[ConfigT], prefix: str = '') -> ConfigT:
        """Build ``config_type`` with parameters named ``prefix + field`` (nested: dotted)."""
        ...


def build_config(config_type: type[ConfigT], values: Mapping[str, Any], prefix: str) -> ConfigT:
    """``config_type(**values)``, a field out of range named as the parameter ``prefix + field``.

    The message says what the check expects when it says more than the field's description
    (:attr:`~face_tracking_ros.errors.FieldError.expected`), else gives the description, the
    parameter's (:func:`attribute_descriptions`): a node that stops at start-up shows no
    parameter descriptions. Every field of a config has one (test/test_readme.py checks those
    of every node's configs, the ones given here).

    Raises:
        ConfigError: e.g. 'invalid parameter tracker.epsilon = 2.0: drift-monitoring weight
            epsilon of eq. 6, in [0, 1] (seed: 0.2).', or '... = inf (expected a finite
            number)'.
    """
    try:
        return config_type(**values)
    except FieldError as error:
        invalid = f'invalid parameter {prefix}{error.field} = {values.get(error.field)!r}'
        if error.expected:
            msg = f'{invalid} (expected {error.expected})'
        else:
            msg = f'{invalid}: {attribute_descriptions(config_type)[error.field]}'
        raise ConfigError(msg) from None


def field_default(field: dataclasses.Field) -> Any:
    """The default value of a dataclass field (calling its default factory if it has one)."""
    if field.default is dataclasses.MISSING and field.default_factory is not dataclasses.MISSING:
        return field.default_factory()
    return field.default


class OverrideParameters:
    """Config defaults, overridden by ``name=value`` strings (offline replay, tests)."""

    live = False

    def __init__(self, overrides: Mapping[str, str] | None = None) -> None:
        """Keep the overrides; :meth:`check_all_used` reports names no config field matched."""
        self._overrides = dict(overrides or {})
        self._used: set[str] = set()

    @property
    def overrides(self) -> dict[str, str]:
        """The overrides, name -> value text."""
        return dict(self._overrides)

    @classmethod
    def parse(cls, items: list[str] | None) -> OverrideParameters:
        """From ``['tracker.epsilon=0.1', ...]``.

        Raises:
            ConfigError: for an item without ``=``, or written ``name:=value`` (ros2 run's
                form, which read as a parameter ``name:`` that no node has).
        """
        overrides = {}
        for item in items or []:
            name, sep, value = item.partition('=')
            if not sep or not name:
                msg = f'parameter {item!r} must be written name=value'
                raise ConfigError(msg)
            if name.endswith(':'):
                msg = (
                    f'parameter {item!r} must be written name=value '
                    f"({name.removesuffix(':')}={value}; ':=' is ros2 run's -p form)"
                )
                raise ConfigError(msg)
            overrides[name.strip()] = value.strip()
        return cls(overrides)

    def config(self, config_type: type[ConfigT], prefix: str = '') -> ConfigT:
        """Build ``config_type`` from defaults and the matching overrides."""
        values: dict[str, Any] = {}
        for field in dataclasses.fields(config_type):  # type: ignore[arg-type]
            default = field_default(field)
            name = prefix + field.name
            if dataclasses.is_dataclass(default):
                values[field.name] = self.config(type(default), f'{name}.')
            elif name in self._overrides:
                self._used.add(name)
                values[field.name] = _coerce(name, self._overrides[name], default)
            else:
                values[field.name] = default
        return build_config(config_type, values, prefix)

    def check_all_used(self) -> None:
        """Raise ConfigError naming overrides that matched no parameter."""
        unused = sorted(set(self._overrides) - self._used)
        if unused:
            msg = f'unknown {listed("parameter", unused)}'
            raise ConfigError(msg)


def _coerce(name: str, text: str, default: Any) -> Any:
    """Convert ``text`` to the type of ``default``."""
    if isinstance(default, Enum):
        return enum_member(name, type(default), text)
    try:
        if isinstance(default, bool):
            lowered = text.lower()
            if lowered not in _TRUE | _FALSE:
                raise ValueError(text)
            return lowered in _TRUE
        return type(default)(text) if default is not None else text
    except ValueError:
        msg = f'parameter {name}={text!r} is not a valid {type(default).__name__}'
        raise ConfigError(msg) from None


def enum_member(name: str, enum_type: type[EnumT], value: Any) -> EnumT:
    """The member of enum parameter ``name`` given by its name (any case) or its number.

    Raises:
        ConfigError: naming the parameter and its members, for any other value.
    """
    text = str(value).strip()
    for member in enum_type:
        if text.upper() == member.name or text == str(member.value):
            return member
    names = ', '.join(member.name for member in enum_type)
    msg = f'parameter {name} = {value!r} is not one of {names}'
    raise ConfigError(msg)


def attribute_descriptions(cls: type) -> dict[str, str]:
    """Field descriptions from the ``Attributes:`` section of a Google-style class docstring."""
    descriptions: dict[str, str] = {}
    lines = inspect.cleandoc(cls.__doc__ or '').splitlines()
    inside, name = False, ''
    for line in lines:
        if line.strip() == 'Attributes:':
            inside = True
            continue
        if not inside:
            continue
        if line and not line.startswith(' '):
            break
        match = re.match(r'^ {4}(\w+)(?: \(.*?\))?: (.*)$', line)
        if match:
            name = match.group(1)
            descriptions[name] = match.group(2).strip()
        elif name and line.strip():
            descriptions[name] += ' ' + line.strip()
    return descriptions
