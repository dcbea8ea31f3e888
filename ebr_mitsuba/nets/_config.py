"""Building the network config dataclasses from plain mappings (a TOML table, ``--json`` input).

Unknown keys are an error, lists become tuples, and a nested :class:`~.nafnet.NAFNetSize` may be
given by preset name (``"paper"``, ``"small"``) or as a table. Defaults live in the dataclasses only.
"""

from __future__ import annotations

import dataclasses
import typing
from collections.abc import Mapping
from typing import Any

from ..errors import ConfigError


def dataclass_from_dict(cls, data: Mapping[str, Any], where: str, nested=None):
    """``cls(**data)`` with unknown keys rejected and lists turned into tuples.

    ``where`` names the file/table in error messages; ``nested`` maps a field name to a function
    ``(value, where) -> object`` that converts that field's value.
    """
    if not isinstance(data, Mapping):
        raise ConfigError(f"{where}: expected a table of options, got {type(data).__name__}")
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise ConfigError(
            f"{where}: unknown key(s) {', '.join(unknown)}; allowed: {', '.join(sorted(names))}"
        )
    hints = typing.get_type_hints(cls)
    kwargs = {}
    for key, value in data.items():
        if nested and key in nested:
            value = nested[key](value, f"{where}.{key}")
        elif isinstance(value, list):
            value = tuple(value)
        expected = hints.get(key)
        if expected in (int, float, bool, str) and not _matches(value, expected):
            raise ConfigError(f"{where}.{key}: expected {expected.__name__}, got {value!r}")
        kwargs[key] = value
    return cls(**kwargs)


def _matches(value, expected) -> bool:
    if expected is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if expected is int:
        return isinstance(value, int) and not isinstance(value, bool)
    return isinstance(value, expected)
