"""Machinery of the typed configuration: parameters with help, unit and allowed range.

Each section is a frozen dataclass whose fields are declared with :func:`param`;
validation happens on construction and names the full key (``match.ratio``) and
the allowed range. YAML is read with a ``yaml.SafeLoader`` (no object construction) that refuses
duplicate keys (:mod:`mercury_dem.config.yaml_loader`).
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from dataclasses import field, fields, is_dataclass
from typing import Any, get_type_hints

from mercury_dem.exceptions import ConfigError


def param(
    default: Any,
    help: str,
    *,
    unit: str = "",
    lo: float | None = None,
    hi: float | None = None,
    choices: typing.Sequence[Any] | None = None,
    internal: str | None = None,
) -> Any:
    """A configuration field with its documentation and allowed values.

    ``lo``/``hi`` are inclusive bounds for numbers; ``choices`` the allowed values.
    Mutable defaults (lists, dicts) are not allowed: use tuples. ``internal`` marks a field of a
    library's parameters that the run sets from another key (its text names that key): it is validated
    like the others but is no configuration key (refused in a file, left out of templates and of
    :func:`to_dict`, so of ``run.json``).
    """
    meta = {"help": help, "unit": unit, "lo": lo, "hi": hi, "choices": tuple(choices) if choices else None,
            "internal": internal}
    if is_dataclass(default):
        return field(default_factory=lambda: default, metadata=meta)
    return field(default=default, metadata=meta)


def section(default_factory: Any, help: str) -> Any:
    """A nested configuration section."""
    return field(default_factory=default_factory, metadata={"help": help, "section": True})


def _describe(f: dataclasses.Field[Any]) -> str:
    m = f.metadata
    parts = []
    if m.get("choices"):
        parts.append("one of " + ", ".join(repr(c) for c in m["choices"]))
    if m.get("lo") is not None or m.get("hi") is not None:
        lo = "-inf" if m.get("lo") is None else m["lo"]
        hi = "+inf" if m.get("hi") is None else m["hi"]
        parts.append(f"range [{lo}, {hi}]")
    return "; ".join(parts)


def _coerce(key: str, value: Any, typ: Any) -> Any:
    """Convert a YAML value to the declared type, or raise naming the key."""
    origin = typing.get_origin(typ)
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(typ)
        if value is None and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        return _coerce(key, value, inner[0])
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"config key '{key}': expected a list, got {value!r}")
        args = typing.get_args(typ)
        elem = args[0] if args else Any
        return tuple(_coerce(key, v, elem) for v in value)
    if typ is Any:
        return value
    if typ is bool:
        if isinstance(value, bool):
            return value
        raise ConfigError(f"config key '{key}': expected true/false, got {value!r}")
    if typ is int:
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                return int(value)
            raise ConfigError(f"config key '{key}': expected an integer, got {value!r}")
        return value
    if typ is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"config key '{key}': expected a number, got {value!r}")
        return float(value)
    if typ is str:
        if not isinstance(value, str):
            raise ConfigError(f"config key '{key}': expected a string, got {value!r}")
        return value
    return value


def validate_section(obj: Any, prefix: str = "") -> None:
    """Check every field of a section against its range/choices; raise ConfigError naming the key."""
    for f in fields(obj):
        key = f"{prefix}{f.name}"
        value = getattr(obj, f.name)
        m = f.metadata
        if m.get("section"):
            continue
        if value is None:
            continue
        if m.get("choices") and value not in m["choices"]:
            raise ConfigError(f"config key '{key}' = {value!r} is not allowed; {_describe(f)}")
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            if isinstance(value, float) and math.isnan(value):
                raise ConfigError(f"config key '{key}' is NaN; {_describe(f)}")
            lo, hi = m.get("lo"), m.get("hi")
            if (lo is not None and value < lo) or (hi is not None and value > hi):
                raise ConfigError(f"config key '{key}' = {value!r} is out of range; {_describe(f)}")


class ConfigSection:
    """Mixin for config dataclasses: validates itself on construction."""

    def __post_init__(self) -> None:
        validate_section(self)


def from_dict(cls: type, data: dict[str, Any] | None, prefix: str = "") -> Any:
    """Build a config dataclass from a nested dict, rejecting unknown keys by name."""
    data = dict(data or {})
    hints = get_type_hints(cls)
    kwargs: dict[str, Any] = {}
    known = {f.name: f for f in fields(cls)}
    for name in data:
        if name in known and known[name].metadata.get("internal"):
            raise ConfigError(f"config key '{prefix}{name}' is not a configuration key: {known[name].metadata['internal']}")
        if name not in known:
            raise ConfigError(
                f"unknown config key '{prefix}{name}'; known keys here: {', '.join(sorted(known))}"
            )
    for name, f in known.items():
        if name not in data:
            continue
        key = f"{prefix}{name}"
        typ = hints[name]
        if f.metadata.get("section"):
            if not isinstance(data[name], dict):
                raise ConfigError(f"config key '{key}' must be a mapping of its own keys")
            kwargs[name] = from_dict(typ, data[name], prefix=key + ".")
        else:
            kwargs[name] = _coerce(key, data[name], typ)
    try:
        obj = cls(**kwargs)
    except ConfigError as exc:
        # Re-raise with the full key path.
        msg = str(exc).replace("config key '", f"config key '{prefix}", 1)
        raise ConfigError(msg) from None
    return obj


def to_dict(obj: Any) -> dict[str, Any]:
    """Nested plain dict (YAML/JSON safe) of a config dataclass."""
    out: dict[str, Any] = {}
    for f in fields(obj):
        if f.metadata.get("internal"):
            continue
        v = getattr(obj, f.name)
        if is_dataclass(v):
            out[f.name] = to_dict(v)
        elif isinstance(v, tuple):
            out[f.name] = list(v)
        else:
            out[f.name] = v
    return out


def template(obj: Any, indent: int = 0) -> str:
    """Commented YAML of a config tree: every key with its help, unit and range."""
    import yaml

    lines: list[str] = []
    pad = "  " * indent
    for f in fields(obj):
        if f.metadata.get("internal"):
            continue
        v = getattr(obj, f.name)
        help_ = f.metadata.get("help", "")
        if is_dataclass(v):
            lines.append("")
            lines.append(f"{pad}# {help_}")
            lines.append(f"{pad}{f.name}:")
            lines.append(template(v, indent + 1))
            continue
        note = help_
        if f.metadata.get("unit"):
            note += f" [{f.metadata['unit']}]"
        d = _describe(f)
        if d:
            note += f" ({d})"
        lines.append(f"{pad}# {note}")
        val = list(v) if isinstance(v, tuple) else v
        dumped = yaml.safe_dump({f.name: val}, default_flow_style=True, width=1000).strip()
        if dumped.startswith("{") and dumped.endswith("}"):
            dumped = dumped[1:-1]
        lines.append(f"{pad}{dumped}")
    return "\n".join(lines)
