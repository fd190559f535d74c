"""Strict configuration: frozen dataclasses built from dicts, YAML and ``--set key=value``.

Unknown keys are an error (unlike hloc's ``{**default, **conf}``), values are converted to the
field's type, and a config is never mutated after construction (``dataclasses.replace`` makes a
new one). ``config_hash`` names a stage's output by its settings.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import types
import typing
from typing import Any, Mapping, TypeVar

from staticdepth.errors import InputError

C = TypeVar("C")


def _convert(value: Any, typ: Any, key: str) -> Any:
    origin = typing.get_origin(typ)
    args = typing.get_args(typ)
    if typ is Any:
        return value
    if origin is typing.Union or origin is types.UnionType:
        if value is None or (isinstance(value, str) and value.lower() in ("none", "null")):
            if type(None) in args:
                return None
        for a in args:
            if a is type(None):
                continue
            try:
                return _convert(value, a, key)
            except InputError:
                continue
        raise InputError(f"setting {key!r}: cannot read {value!r} as {typ}")
    if origin in (tuple, list):
        if isinstance(value, str):
            value = [v for v in value.replace("x", ",").split(",") if v.strip()] \
                if args and args[0] in (int, float) else value.split(",")
        inner = args[0] if args else Any
        return origin(_convert(v, inner, key) for v in value)
    try:
        if typ is bool:
            if isinstance(value, str):
                if value.lower() in ("1", "true", "yes", "on"):
                    return True
                if value.lower() in ("0", "false", "no", "off"):
                    return False
                raise ValueError(value)
            return bool(value)
        if typ in (int, float, str):
            if typ is int and isinstance(value, float) and not value.is_integer():
                raise ValueError(value)
            return typ(value)
    except (TypeError, ValueError):
        raise InputError(f"setting {key!r}: expected {typ.__name__}, got {value!r}") from None
    return value


def from_dict(cls: type[C], values: Mapping[str, Any] | None = None, *,
              base: C | None = None, source: str | None = None) -> C:
    """Build ``cls`` (a dataclass) from ``base`` (or the defaults) with ``values`` applied."""
    fields = {f.name: f for f in dataclasses.fields(cls)}
    hints = typing.get_type_hints(cls)
    unknown = sorted(set(values or {}) - set(fields))
    if unknown:
        raise InputError(f"unknown setting(s) {unknown} for {cls.__name__} "
                         f"(known: {sorted(fields)})", source)
    kw = {k: _convert(v, hints[k], k) for k, v in (values or {}).items()}
    try:
        return dataclasses.replace(base, **kw) if base is not None else cls(**kw)
    except InputError as e:
        raise InputError(e.problem, source) from None
    except TypeError as e:
        raise InputError(f"{cls.__name__}: {e}", source) from None


def to_dict(conf: Any) -> dict[str, Any]:
    return dataclasses.asdict(conf)


def config_hash(conf: Any, n: int = 10) -> str:
    """Short stable hash of a config's values (names outputs by their settings)."""
    blob = json.dumps(to_dict(conf) if dataclasses.is_dataclass(conf) else conf, sort_keys=True,
                      default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:n]


def load_yaml(path: str | os.PathLike) -> dict[str, Any]:
    """Read a YAML mapping; errors name the file."""
    import yaml

    try:
        with open(path) as f:
            d = yaml.safe_load(f)
    except FileNotFoundError:
        raise InputError("file not found", path) from None
    except yaml.YAMLError as e:
        raise InputError(f"not valid YAML ({e})", path) from None
    except UnicodeDecodeError:
        raise InputError("not a text (UTF-8) YAML file", path) from None
    if not isinstance(d, dict):
        raise InputError("expected a YAML mapping at the top level", path)
    return d
