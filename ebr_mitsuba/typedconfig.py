"""The one typed-config engine: every option's default, meaning and range stated once, on the field.

A config is a frozen dataclass whose fields are declared with :func:`option` (alias ``field``);
the metadata of each field drives everything else:

* **validation** — :func:`from_dict` builds a config from a plain mapping (a TOML table, JSON,
  a checkpoint): unknown keys, wrong types, values out of range or not among the choices are a
  :class:`~ebr_mitsuba.errors.ConfigError` with one line in one format,
  ``"{where}: {key}: {problem}; {fix}"`` (``bad.toml: train.lr: expected float (a number), got
  'fast'``). Nested configs are tables or, where the field names ``presets``, a preset name.
  :func:`check`, called by the config's ``__post_init__``, applies the same field checks to a
  config built in code (lists become tuples, ints become floats where a float is declared);
  cross-field rules stay in the config's own ``__post_init__``.
* **named presets** instead of dict overlays: a preset is an instance of the config
  (``EXTRACT_PRESETS["training"] = ExtractConfig(iters=100, max_lobes=16)``); ``from_dict(...,
  base=preset)`` takes the keys a file does not set from it, and the docs table of that use
  shows the preset's values (:func:`table` ``base=``).
* **docs** — :func:`rows` / :func:`table` / :func:`markdown_table` render the option table
  (key, type, default, range, meaning); the :func:`config` decorator appends it to the class
  docstring, and ``python -m ebr_mitsuba.docgen`` writes every config's table to
  ``docs/config.md``.
* **command-line flags** — :func:`add_flags` adds one option per chosen field (flag name, default
  and help from the metadata; values read as text) and :func:`from_args` turns the parsed values
  back into the config, a bad value being one line naming the flag
  (:class:`~ebr_mitsuba.errors.InputError`, exit 2).

Declaring a config::

    from .typedconfig import config, option

    @config
    class RefineConfig:
        \"\"\"Options of :func:`refine`.\"\"\"

        steps: int = option(0, "Adam iterations (0: no refinement)", minimum=0, flag="--refine-steps")
        mode: str = option("sg", "environment term", choices=("sg", "quadrature"), flag="--render-mode")
        seconds: float | None = option(None, "time budget", above=0, flag="--refine-seconds",
                                       shown="none")

        def __post_init__(self):
            check(self)          # field checks (config() adds this when __post_init__ is absent)

Building a command's flags from it (how ``ebr extract-sg`` does it; ``ebr estimate`` does the
same for ``EstimateConfig``, ``RefineConfig`` and ``FiveLightConfig``)::

    REFINE_FLAGS = ("steps", "lobes", "lr", "seconds", "basis", "mode")

    def add_arguments(parser):
        add_flags(parser, RefineConfig, REFINE_FLAGS)      # --refine-steps N [0] ...

    def run(args):
        refine = from_args(RefineConfig, args, REFINE_FLAGS)   # InputError naming the flag

``add_flags(..., base=preset)`` makes a preset's values the defaults; ``rename={"env_mode":
"--mode"}`` (given to both calls) changes a flag's name for one command; :func:`flag_dest` is the
argparse attribute of a field's flag and :func:`flag_value` the checked value of one flag. A bool
field is a switch (``store_true``, or ``--x/--no-x`` when its default is true); ``X | None``
fields accept ``none``; a field without a default has no default on the command line either (its
flag is an argparse ``required`` one when the field is ``required``).

Field metadata (keywords of :func:`option`): ``minimum``/``maximum`` (inclusive), ``above``/
``below`` (exclusive) — for a sequence they apply to every item; ``choices`` (a str, or every
item of a list of str); ``nonempty``, ``length`` and ``ordered`` (non-decreasing) for sequences;
``required`` (a file must set it); ``presets`` (name → instance, for a nested config or a config
named by a string); ``flag``, ``metavar``, ``nargs`` (command line: ``"+"`` reads a
sequence as separate words, ``--lights A B C``); ``shown`` (the default as the docs and
``--help`` write it); ``fix`` (advice appended to a range error); ``extra`` (free metadata a
module interprets itself, e.g. the data config's ``path`` kind).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import re
import textwrap
import types
import typing
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import tomllib

from .errors import ConfigError, InputError

_KEY = "ebr_mitsuba.typedconfig"
_MISSING = dataclasses.MISSING


@dataclasses.dataclass(frozen=True)
class Meta:
    """What :func:`option` stores in ``dataclasses.field(metadata=...)``."""

    meaning: str
    minimum: float | None = None
    maximum: float | None = None
    above: float | None = None
    below: float | None = None
    choices: tuple | None = None
    nonempty: bool = False
    length: int | None = None
    ordered: bool = False
    required: bool = False
    presets: Mapping | None = None
    preset_kind: str = ""
    flag: str | None = None
    metavar: str | None = None
    nargs: str | None = None
    shown: str | None = None
    fix: str = ""
    extra: Mapping = dataclasses.field(default_factory=dict)


def option(default: Any = _MISSING, meaning: str = "", **kw) -> Any:
    """A dataclass field with its meaning and checks (keywords: the fields of :class:`Meta`).

    A list or dict default is copied per instance (``default_factory``)."""
    if "choices" in kw and kw["choices"] is not None:
        kw["choices"] = tuple(kw["choices"])
    meta = {_KEY: Meta(meaning, **kw)}
    if isinstance(default, (list, dict, set)):
        return dataclasses.field(default_factory=lambda d=default: type(d)(d), metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


field = option


def meta_of(f: dataclasses.Field) -> Meta:
    """The :class:`Meta` of a field (an empty one for a field declared without :func:`option`)."""
    return f.metadata.get(_KEY) or Meta("")


class _Settings(typing.NamedTuple):
    error: type
    cli: bool


def config(cls=None, *, error: type = ConfigError, cli: bool = False, frozen: bool = True):
    """Class decorator: a frozen dataclass whose fields are checked on construction
    (:func:`check`, unless the class defines ``__post_init__``, which then calls it) and whose
    docstring ends with its option table. ``error``: the exception of a bad value given in code
    (:class:`InputError` for the configs a command builds from flags); ``cli``: errors name a
    field's flag (``--refine-basis``) rather than its key."""

    def wrap(c):
        c.__typedconfig__ = _Settings(error, cli)
        if "__post_init__" not in c.__dict__:
            c.__post_init__ = lambda self: check(self)
        c = dataclasses.dataclass(frozen=frozen)(c)
        if c.__doc__ is not None and not c.__doc__.startswith(f"{c.__name__}("):
            c.__doc__ = c.__doc__.rstrip() + "\n\n" + textwrap.indent(table(c), "    ") + "\n"
        return c

    return wrap if cls is None else wrap(cls)


# -- types -------------------------------------------------------------------------------------------

_HINTS: dict[type, dict] = {}


def hints(cls) -> dict[str, Any]:
    """The resolved type hints of a dataclass (cached)."""
    if cls not in _HINTS:
        _HINTS[cls] = typing.get_type_hints(cls)
    return _HINTS[cls]


def _split_optional(hint):
    """(inner type, whether None is allowed)."""
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        if len(args) == 1 and len(typing.get_args(hint)) == 2:
            return args[0], True
    return hint, False


def type_name(hint) -> str:
    """How a type is written in tables and messages."""
    inner, optional = _split_optional(hint)
    if optional:
        return f"{type_name(inner)} | None"
    origin = typing.get_origin(inner)
    if origin in (list, tuple):
        args = typing.get_args(inner)
        if not args:
            return origin.__name__
        if len(args) == 2 and args[1] is Ellipsis:
            return f"{origin.__name__}[{type_name(args[0])}, ...]"
        return f"{origin.__name__}[{', '.join(type_name(a) for a in args)}]"
    return getattr(inner, "__name__", str(inner))


_EXPECTED = {bool: "bool (true or false)", int: "int (a whole number)", float: "float (a number)", str: "str"}


def _fail(error, where: str, key: str, problem: str) -> Exception:
    head = f"{where}: " if where else ""
    return error(f"{head}{key}: {problem}" if key else f"{head}{problem}")


def _num(x) -> str:
    x = float(x)
    return str(int(x)) if x.is_integer() and abs(x) < 1e16 else f"{x:g}"


def _range_text(m: Meta) -> str:
    lo = (
        f"[{_num(m.minimum)}"
        if m.minimum is not None
        else (f"({_num(m.above)}" if m.above is not None else "")
    )
    hi = (
        f"{_num(m.maximum)}]"
        if m.maximum is not None
        else (f"{_num(m.below)})" if m.below is not None else "")
    )
    if lo and hi:
        return f"in {lo}, {hi}"
    if lo:
        return f">= {_num(m.minimum)}" if m.minimum is not None else f"> {_num(m.above)}"
    if hi:
        return f"<= {_num(m.maximum)}" if m.maximum is not None else f"< {_num(m.below)}"
    return ""


def range_text(m: Meta, hint=None) -> str:
    """The allowed values of a field in words (``in [0, 1]``, ``one of sg, quadrature``)."""
    parts = []
    seq = hint is not None and typing.get_origin(_split_optional(hint)[0]) in (list, tuple)
    r = _range_text(m)
    if r:
        parts.append(f"each {r}" if seq else r)
    if m.choices:
        parts.append(("each " if seq else "") + "one of " + ", ".join(map(str, m.choices)))
    if m.length is not None:
        parts.append(f"{m.length} values")
    if m.ordered:
        parts.append("low <= high")
    if m.nonempty:
        parts.append("not empty")
    if m.required:
        parts.append("required")
    return "; ".join(parts)


def _check_scalar(value, kind, m: Meta, error, where, key):
    if kind is bool:
        if not isinstance(value, bool):
            raise _fail(error, where, key, f"expected {_EXPECTED[bool]}, got {value!r}")
        return value
    if kind is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise _fail(error, where, key, f"expected {_EXPECTED[int]}, got {value!r}")
        value = int(value)
    elif kind is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise _fail(error, where, key, f"expected {_EXPECTED[float]}, got {value!r}")
        value = float(value)
        if not math.isfinite(value):
            raise _fail(error, where, key, f"must be finite, got {value}")
    elif kind is str:
        if not isinstance(value, str):
            raise _fail(error, where, key, f"expected {_EXPECTED[str]}, got {value!r}")
        if m.choices and value not in m.choices:
            raise _fail(error, where, key, f"got {value!r}; use one of {', '.join(map(str, m.choices))}")
        return value
    else:
        return value
    if (
        (m.minimum is not None and value < m.minimum)
        or (m.maximum is not None and value > m.maximum)
        or (m.above is not None and value <= m.above)
        or (m.below is not None and value >= m.below)
    ):
        fix = f"; {m.fix}" if m.fix else ""
        raise _fail(error, where, key, f"must be {_range_text(m)}, got {value!r}{fix}")
    return value


def convert(value, hint, m: Meta, *, where: str = "", key: str = "", error: type = ConfigError):
    """``value`` checked against a field's type and metadata, normalised (list → tuple for a tuple
    field, int → float for a float field, a preset name or table → the nested config)."""
    inner, optional = _split_optional(hint)
    if value is None:
        if optional:
            return None
        raise _fail(error, where, key, f"expected {type_name(inner)}, got None")
    if dataclasses.is_dataclass(inner) and isinstance(inner, type):
        return nested(inner, value, m.presets, where=where, key=key, what=m.preset_kind, error=error)
    origin = typing.get_origin(inner)
    if origin in (list, tuple) or inner in (list, tuple):
        if not isinstance(value, (list, tuple)):
            raise _fail(error, where, key, f"expected {type_name(inner)} (a list), got {value!r}")
        args = typing.get_args(inner)
        if origin is tuple and args and args[-1] is not Ellipsis and len(args) != len(value):
            raise _fail(error, where, key, f"expected {len(args)} values, got {list(value)!r}")
        if m.length is not None and len(value) != m.length:
            raise _fail(error, where, key, f"expected {m.length} values, got {list(value)!r}")
        if m.nonempty and not value:
            raise _fail(error, where, key, "must not be empty")
        items = []
        for i, item in enumerate(value):
            kind = (
                args[0]
                if (args and (len(args) == 1 or args[-1] is Ellipsis))
                else (args[i] if args else None)
            )
            items.append(_check_scalar(item, kind, m, error, where, f"{key}[{i}]"))
        if m.ordered and any(a > b for a, b in zip(items, items[1:])):
            raise _fail(error, where, key, f"got {items}; low must be <= high")
        return list(items) if (origin is list or inner is list) else tuple(items)
    return _check_scalar(value, inner, m, error, where, key)


def nested(cls, value, presets=None, *, where: str = "", key: str = "", what: str = "", error=ConfigError):
    """A nested config from an instance, a preset name (``presets``) or a table of its fields."""
    if isinstance(value, cls):
        return value
    if isinstance(value, str) and presets:
        if value not in presets:
            raise _fail(
                error,
                where,
                key,
                f"unknown {what or cls.__name__ + ' preset'} {value!r}; use one of "
                f"{', '.join(presets)} or a table of {cls.__name__} fields",
            )
        return presets[value]
    if isinstance(value, Mapping):
        return from_dict(cls, value, where, key=key)
    kinds = "a preset name or a table" if presets else "a table"
    raise _fail(error, where, key, f"expected {kinds} ({cls.__name__}), got {value!r}")


def _label(f: dataclasses.Field, settings: _Settings | None) -> str:
    m = meta_of(f)
    if settings is not None and settings.cli and m.flag:
        return m.flag
    return f.name


def check(obj) -> None:
    """The field checks of :func:`convert` on a config built in code (call from ``__post_init__``);
    normalised values are written back (frozen dataclasses included)."""
    cls = type(obj)
    settings = getattr(cls, "__typedconfig__", None)
    error = settings.error if settings else ConfigError
    hs = hints(cls)
    for f in dataclasses.fields(cls):
        value = getattr(obj, f.name)
        new = convert(value, hs[f.name], meta_of(f), where=cls.__name__, key=_label(f, settings), error=error)
        if new is not value:
            object.__setattr__(obj, f.name, new)


def unknown_keys(data: Mapping, allowed, *, where: str = "", key: str = "", noun: str = "key") -> None:
    """A :class:`ConfigError` naming the first key of ``data`` that is not in ``allowed``."""
    unknown = sorted(set(data) - set(allowed))
    if unknown:
        k = f"{key}.{unknown[0]}" if key else unknown[0]
        raise _fail(ConfigError, where, k, f"unknown {noun}; use one of {', '.join(allowed)}")


def convert_table(cls, data, where: str = "", *, key: str = "") -> dict:
    """The converted values of the keys ``data`` sets (unknown keys, types, ranges and choices
    checked; a ``required`` key missing is an error); nothing is constructed."""
    if not isinstance(data, Mapping):
        raise _fail(ConfigError, where, key, f"expected a table, got {data!r}")
    fs = {f.name: f for f in dataclasses.fields(cls)}
    unknown_keys(data, fs, where=where, key=key)
    hs = hints(cls)
    out = {}
    for name, f in fs.items():
        k = f"{key}.{name}" if key else name
        m = meta_of(f)
        if name in data:
            out[name] = convert(data[name], hs[name], m, where=where, key=k)
        elif m.required:
            fix = f" ({m.meaning})" if m.meaning else ""
            raise _fail(ConfigError, where, k, f"is required{fix}")
    return out


def from_dict(cls, data, where: str = "", *, key: str = "", base=None):
    """``cls`` from a mapping: the keys it sets over ``base`` (a preset instance) or the defaults.

    ``where`` names the file (or object) and ``key`` the table within it in error messages."""
    values = convert_table(cls, data, where, key=key)
    try:
        if base is not None:
            return dataclasses.replace(base, **values)
        return cls(**values)
    except ConfigError as exc:  # a cross-field rule of __post_init__: name the file and table
        text = str(exc).removeprefix(f"{cls.__name__}: ")
        if key:
            text = f"{key}.{text}" if text != str(exc) else f"{key}: {text}"
        raise ConfigError(f"{where}: {text}" if where else text) from None


def to_dict(obj) -> dict:
    """Plain data (tuples as lists, nested configs as tables), what :func:`from_dict` reads."""

    def plain(v):
        if dataclasses.is_dataclass(v) and not isinstance(v, type):
            return {f.name: plain(getattr(v, f.name)) for f in dataclasses.fields(v)}
        if isinstance(v, (list, tuple)):
            return [plain(x) for x in v]
        if isinstance(v, Mapping):
            return {k: plain(x) for k, x in v.items()}
        return v

    return plain(obj)


_VAR = re.compile(r"\$(\w+)|\$\{(\w+)\}")


def expand_path(text: str, base, *, where: str = "", key: str = "") -> Path:
    """A path value of a config file: ``$VAR``/``${VAR}`` and ``~`` expanded (an unset variable
    is an error naming it), then a relative path taken from ``base`` (the file's directory)."""
    for match in _VAR.finditer(text):
        name = match.group(1) or match.group(2)
        if name not in os.environ:
            raise _fail(
                ConfigError,
                where,
                key,
                f"${name} is not set; export {name} (e.g. EBR_DATA_DIR=/path/to/shared/data) or write "
                f"the path out",
            )
    path = Path(os.path.expanduser(os.path.expandvars(text)))
    return path if path.is_absolute() else Path(base) / path


# -- docs --------------------------------------------------------------------------------------------


def _default(f: dataclasses.Field, base=None):
    if base is not None:
        return getattr(base, f.name)
    if f.default is not _MISSING:
        return f.default
    if f.default_factory is not _MISSING:
        return f.default_factory()
    return _MISSING


def default_text(f: dataclasses.Field, base=None) -> str:
    """A field's default as tables and ``--help`` write it."""
    m = meta_of(f)
    value = _default(f, base)
    if m.shown is not None and (base is None or value == _default(f)):
        return m.shown
    if value is _MISSING:
        return "required"
    if value is None:
        return "none"
    if dataclasses.is_dataclass(value):
        for name, preset in (m.presets or {}).items():
            if preset == value:
                return json.dumps(name)
        return f"{type(value).__name__}(…)"
    if isinstance(value, float):
        return f"{value:g}"
    return json.dumps(to_dict(value))


def rows(cls, *, prefix: str = "", base=None) -> list[tuple[str, str, str, str, str]]:
    """(key, type, default, range, meaning) of every field."""
    hs = hints(cls)
    return [
        (
            f"{prefix}{f.name}",
            type_name(hs[f.name]),
            default_text(f, base),
            range_text(meta_of(f), hs[f.name]),
            meta_of(f).meaning,
        )
        for f in dataclasses.fields(cls)
    ]


def table(cls, *, prefix: str = "", base=None, width: int = 96) -> str:
    """The option table of ``cls`` as a reStructuredText simple table (key, type, default,
    meaning with the range), for docstrings; long cells wrap onto continuation lines."""
    body = [
        (f"``{k}``", t, d, f"{m}; {r}" if r else m) for k, t, d, r, m in rows(cls, prefix=prefix, base=base)
    ]
    head = ("key", "type", "default", "meaning")
    widths = [max(len(head[i]), *(len(r[i]) for r in body)) for i in range(2)]
    widths.append(min(24, max(len(head[2]), *(len(r[2]) for r in body))))
    widths.append(max(30, width - sum(widths) - 6))
    rule = "  ".join("=" * w for w in widths)

    def line(cells):
        return "  ".join(c.ljust(w) for c, w in zip(cells, widths)).rstrip()

    out = [rule, line(head), rule]
    for r in body:
        cols = [
            [r[0]],
            [r[1]],
            textwrap.wrap(r[2], widths[2]) or [""],
            textwrap.wrap(r[3], widths[3]) or [""],
        ]
        for i in range(max(map(len, cols))):
            out.append(line([c[i] if i < len(c) else "" for c in cols]))
    out.append(rule)
    return "\n".join(out)


def markdown_table(cls, *, prefix: str = "", base=None) -> str:
    """The option table of ``cls`` in Markdown (for ``docs/config.md``)."""

    def esc(s: str) -> str:
        return s.replace("|", "\\|")

    out = ["| key | type | default | range | meaning |", "|---|---|---|---|---|"]
    out += [
        f"| `{k}` | `{esc(t)}` | `{esc(d)}` | {esc(r)} | {esc(m)} |"
        for k, t, d, r, m in rows(cls, prefix=prefix, base=base)
    ]
    return "\n".join(out)


def document(doc: str | None, **configs) -> str | None:
    """``doc`` with each line ``.. options:: NAME`` replaced by the option table of
    ``configs[NAME]`` (a config class, or ``(class, preset)`` to show a preset's values), indented
    like the marker: how a module docstring carries generated tables."""
    if doc is None:
        return None
    out = []
    for line in doc.splitlines():
        stripped = line.strip()
        if stripped.startswith(".. options::"):
            spec = configs[stripped.split("::", 1)[1].strip()]
            cls, base = spec if isinstance(spec, tuple) else (spec, None)
            indent = line[: len(line) - len(line.lstrip())]
            out.append(textwrap.indent(table(cls, base=base), indent))
        else:
            out.append(line)
    return "\n".join(out) + ("\n" if doc.endswith("\n") else "")


# -- command line ------------------------------------------------------------------------------------


def _fields(cls) -> dict[str, dataclasses.Field]:
    return {f.name: f for f in dataclasses.fields(cls)}


def flag_name(cls, name: str, rename: Mapping | None = None) -> str:
    """The flag of a field: ``rename[name]``, its ``flag`` metadata, or ``--field-name``."""
    if rename and name in rename:
        return rename[name]
    return meta_of(_fields(cls)[name]).flag or "--" + name.replace("_", "-")


def flag_dest(cls, name: str, rename: Mapping | None = None) -> str:
    """The argparse attribute that holds a field's flag value."""
    return flag_name(cls, name, rename).lstrip("-").replace("-", "_")


_METAVARS = {int: "N", float: "X", str: "S"}


def add_flags(parser, cls, names: Sequence[str], *, base=None, rename: Mapping | None = None) -> None:
    """One option per field in ``names``: flag, default (``base``'s or the field's) and help
    (meaning, range and default) from the metadata. Values are read as text and checked by
    :func:`from_args`, so a bad one is one line naming the flag. A field without a default gets
    none (None when not given; argparse-required when the field is ``required``)."""
    fs, hs = _fields(cls), hints(cls)
    for name in names:
        f, m = fs[name], meta_of(fs[name])
        inner, _ = _split_optional(hs[name])
        default = _default(f, base)
        flag = flag_name(cls, name, rename)
        rng = range_text(dataclasses.replace(m, required=False), hs[name])
        text = m.meaning + (f" ({rng})" if rng and inner is not bool else "")
        if default is _MISSING:
            text = (f"{text} [{m.shown}]" if m.shown is not None else text).replace("%", "%%")
            extra = {"nargs": m.nargs} if m.nargs else {}
            parser.add_argument(
                flag, default=None, required=m.required, metavar=m.metavar or "V", help=text, **extra
            )
            continue
        shown = default_text(f, base)
        shown = shown[1:-1] if isinstance(default, str) and shown == json.dumps(default) else shown
        if isinstance(default, (list, tuple)) and m.shown is None and shown == default_text(f):
            shown = ",".join(f"{v:g}" if isinstance(v, float) else str(v) for v in default)
        text = f"{text} [{shown}]".replace("%", "%%")
        if inner is bool:
            if default:
                import argparse

                parser.add_argument(flag, action=argparse.BooleanOptionalAction, default=True, help=text)
            else:
                parser.add_argument(flag, action="store_true", default=False, help=text)
            continue
        origin = typing.get_origin(inner)
        metavar = m.metavar or ("A,B" if origin in (list, tuple) else _METAVARS.get(inner, "V"))
        extra = {"nargs": m.nargs} if m.nargs else {}
        parser.add_argument(flag, default=default, metavar=metavar, help=text, **extra)


def _parse_text(text: str, hint, flag: str):
    inner, optional = _split_optional(hint)
    t = text.strip()
    if optional and t.lower() in ("none", ""):
        return None
    origin = typing.get_origin(inner)
    if origin in (list, tuple):
        args = typing.get_args(inner)
        kind = args[0] if args else float
        parts = [p.strip() for p in t.split(",") if p.strip()]
        try:
            return [kind(p) for p in parts]
        except ValueError:
            n = "two" if origin is tuple and len(args) == 2 and args[1] is not Ellipsis else "comma-separated"
            raise InputError(f"{flag} {text!r}: give {n} numbers, e.g. 0.1,0.9") from None
    if inner in (int, float):
        try:
            return inner(t)
        except ValueError:
            raise InputError(
                f"{flag} {text!r}: give {'an integer' if inner is int else 'a number'}"
            ) from None
    return text


def flag_value(cls, args, name: str, *, rename: Mapping | None = None):
    """The value of one field's flag in the parsed ``args``: text parsed, then checked like the
    field (an :class:`InputError` naming the flag)."""
    hint = hints(cls)[name]
    flag = flag_name(cls, name, rename)
    value = getattr(args, flag_dest(cls, name, rename))
    if isinstance(value, str) and hint is not str:
        value = _parse_text(value, hint, flag)
    return convert(value, hint, meta_of(_fields(cls)[name]), key=flag, error=InputError)


def from_args(cls, args, names: Sequence[str], *, base=None, rename: Mapping | None = None, **fixed):
    """The config of the flags :func:`add_flags` added (text parsed, then every field checked,
    an error naming the flag), over ``base`` or the defaults; ``fixed`` sets other fields."""
    values = {name: flag_value(cls, args, name, rename=rename) for name in names}
    values.update(fixed)
    return dataclasses.replace(base, **values) if base is not None else cls(**values)


__all__ = [
    "Meta",
    "add_flags",
    "check",
    "config",
    "convert",
    "convert_table",
    "default_text",
    "document",
    "expand_path",
    "field",
    "flag_dest",
    "flag_name",
    "flag_value",
    "from_args",
    "from_dict",
    "hints",
    "markdown_table",
    "meta_of",
    "nested",
    "option",
    "range_text",
    "rows",
    "table",
    "to_dict",
    "type_name",
    "unknown_keys",
]


def parse_toml(text: str, source) -> dict:
    """The TOML document ``text`` (from ``source``, named in the error) as a dict; a syntax error is
    one :class:`ConfigError` line."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{source}: not valid TOML ({exc})") from None


def read_toml(path: Path) -> dict:
    """The TOML file at ``path`` (which exists) as a dict; not UTF-8 or not TOML is one
    :class:`ConfigError` line naming the file."""
    try:
        text = Path(path).read_text()
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: not a UTF-8 text file; give a TOML config") from None
    return parse_toml(text, path)
