"""Strict configuration: frozen dataclasses built from dicts, YAML and ``--set key=value``.

Unknown keys are an error (unlike hloc's ``{**default, **conf}``), values are converted to the
field's type, and a config is never mutated after construction (``dataclasses.replace`` makes a
new one). ``config_hash`` names a stage's output by its settings.
"""
from __future__ import annotations

import dataclasses
import difflib
import hashlib
import json
import os
import types
import typing
from typing import Any, Mapping, Sequence, TypeVar

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
        nan = None
        for a in args:
            if a is type(None):
                continue
            try:
                return _convert(value, a, key)
            except InputError as e:
                nan = e if "NaN is no value" in e.problem else nan
                continue
        if nan is not None:
            raise nan
        raise InputError(f"setting {key!r}: cannot read {value!r} as {typ}")
    if typ in (set, frozenset) or origin in (set, frozenset):
        if isinstance(value, str):
            value = [v for v in value.replace(" ", "").split(",") if v]
        inner = args[0] if args else Any
        return frozenset(_convert(v, inner if inner is not Any else int, key) for v in value)
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
            out = typ(value)
        else:
            return value
    except (TypeError, ValueError):
        raise InputError(f"setting {key!r}: expected {typ.__name__}, got {value!r}") from None
    if typ is float and out != out:
        raise InputError(f"setting {key!r}: NaN is no value (give a number, or none where the "
                         "setting allows it)")
    return out


def _dataclass_type(typ: Any) -> type | None:
    return typ if isinstance(typ, type) and dataclasses.is_dataclass(typ) else None


def _field_default(f: dataclasses.Field) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return dataclasses.MISSING


def setting_keys(cls: type, prefix: str = "") -> list[str]:
    """Every leaf setting of a (nested) config dataclass as a dotted key, in field order."""
    hints = typing.get_type_hints(cls)
    out: list[str] = []
    for f in dataclasses.fields(cls):
        sub = _dataclass_type(hints[f.name])
        out += setting_keys(sub, f"{prefix}{f.name}.") if sub else [prefix + f.name]
    return out


def nearest_key(key: str, known: Sequence[str]) -> str | None:
    """The valid key a misspelt or un-nested ``key`` most likely means (None: no good guess)."""
    leaf = key.rsplit(".", 1)[-1]
    same_leaf = [k for k in known if k.rsplit(".", 1)[-1] == leaf]
    if len(same_leaf) == 1:
        return same_leaf[0]
    close = difflib.get_close_matches(key, known, n=1, cutoff=0.6)
    if close:
        return close[0]
    leaves = {k.rsplit(".", 1)[-1]: k for k in known}
    close = difflib.get_close_matches(leaf, list(leaves), n=1, cutoff=0.7)
    return leaves[close[0]] if close else None


def _unknown_error(cls: type, unknown: list[str], prefix: str, source: str | None) -> InputError:
    known = setting_keys(cls, prefix)
    guess = nearest_key(unknown[0], known)
    hint = f": did you mean {guess!r}?" if guess else ""
    listing = f"known: {known}" if len(known) <= 30 else f"{len(known)} settings"
    return InputError(f"unknown setting(s) {unknown} for {cls.__name__}{hint} ({listing})",
                      source)


def from_dict(cls: type[C], values: Mapping[str, Any] | None = None, *,
              base: C | None = None, source: str | None = None, _prefix: str = "") -> C:
    """Build ``cls`` (a dataclass) from ``base`` (or the defaults) with ``values`` applied.

    Keys of nested config dataclasses are dotted (``tracking.min_height_px``) or nested mappings
    (``{"tracking": {"min_height_px": 8}}``); an unknown key is an error naming the nearest valid
    key.
    """
    fields = {f.name: f for f in dataclasses.fields(cls)}
    hints = typing.get_type_hints(cls)
    groups: dict[str, Any] = {}
    unknown: list[str] = []
    for k, v in (values or {}).items():
        head, dot, rest = str(k).partition(".")
        if head not in fields:
            unknown.append(_prefix + str(k))
            continue
        sub = _dataclass_type(hints[head])
        if sub is None:
            if dot:
                unknown.append(_prefix + str(k))
            else:
                groups[head] = v
        elif dot:
            groups.setdefault(head, {})[rest] = v
        elif isinstance(v, Mapping):
            groups.setdefault(head, {}).update(v)
        elif isinstance(v, sub):
            groups[head] = v
        else:
            raise InputError(f"setting {_prefix + head!r} is a group of settings: set its keys "
                             f"({', '.join(setting_keys(sub, _prefix + head + '.')[:4])}, ...)",
                             source)
    if unknown:
        raise _unknown_error(cls, unknown, _prefix, source)
    kw: dict[str, Any] = {}
    for k, v in groups.items():
        sub = _dataclass_type(hints[k])
        if sub is not None and isinstance(v, dict):
            inner = getattr(base, k) if base is not None else _field_default(fields[k])
            kw[k] = from_dict(sub, v, base=None if inner is dataclasses.MISSING else inner,
                              source=source, _prefix=f"{_prefix}{k}.")
        elif sub is not None:
            kw[k] = v
        else:
            kw[k] = _convert(v, hints[k], _prefix + k)
    try:
        return dataclasses.replace(base, **kw) if base is not None else cls(**kw)
    except InputError as e:
        raise InputError(e.problem, source) from None
    except TypeError as e:
        raise InputError(f"{cls.__name__}: {e}", source) from None


def check_ranges(conf: Any, prefix: str, rules: Mapping[str, str], *, options: bool = False
                 ) -> None:
    """Check ``conf``'s numeric fields against ``rules`` (field -> ``">=0"``, ``">0"``, ``">=1"``,
    or a closed range ``"LO..HI"`` such as ``"0..1"``; every value finite unless the rule ends
    in ``"|inf"``; None passes): one :class:`InputError` naming the first setting out of its
    range (``prefix`` + its name; with ``options``, as the command-line option ``--max-steps``
    for ``max_steps``)."""
    import math

    for name, rule in rules.items():
        v = getattr(conf, name)
        if v is None:
            continue
        rule, _, inf = rule.partition("|")
        ok = isinstance(v, (int, float)) and not isinstance(v, bool) and v == v and (
            math.isfinite(v) or (inf == "inf" and v > 0))
        if ".." in rule:
            lo, hi = (float(x) for x in rule.split(".."))
            ok, want = ok and lo <= v <= hi, f"within {rule}"
        else:
            ok = ok and {">=0": lambda x: x >= 0, ">0": lambda x: x > 0,
                         ">=1": lambda x: x >= 1}[rule](v)
            want = {">=0": ">= 0", ">0": "> 0", ">=1": ">= 1"}[rule]
        if not ok:
            label = "--" + name.replace("_", "-") if options else prefix + name
            raise InputError(f"{label} must be {'a finite number ' if not inf else ''}"
                             f"{want}, got {v}")


SEED_LIMIT = 2 ** 32      # numpy's and torch's generators take seeds in [0, 2^32)


def check_seed(seed: Any, key: str = "--seed") -> int:
    """``seed`` as an int in [0, 2^32), else one :class:`InputError` naming ``key`` (numpy raised
    "expected non-negative integer" from deep inside a run for a negative one)."""
    import numbers

    if (isinstance(seed, bool) or not isinstance(seed, numbers.Integral)
            or not 0 <= seed < SEED_LIMIT):
        raise InputError(f"{key} must be a whole number in [0, 2^32), got {seed!r}")
    return int(seed)


def parse_set(items: Sequence[str] | None, option: str = "--set") -> dict[str, str]:
    """The one ``--set KEY=VALUE`` grammar: dotted keys, values still strings (converted to the
    setting's type by :func:`from_dict`); ``option`` names the option in errors (``--var``)."""
    out: dict[str, str] = {}
    for item in items or ():
        k, sep, v = str(item).partition("=")
        k = k.strip()
        if not sep or not k or any(not part for part in k.split(".")):
            raise InputError(f"{option} expects key=value with a (dotted) key, got {item!r}")
        out[k] = v.strip()
    return out


def split_options(cls: type, values: Mapping[str, Any], options_field: str = "options", *,
                  strict: bool = True) -> tuple[dict[str, Any], dict[str, Any]]:
    """Route ``--set`` values of a config with a free-form ``options`` mapping (the stereo
    matcher's): a field of ``cls`` stays a setting, ``options.KEY`` goes to the options (values
    read as YAML scalars); any other key is a setting (``strict``: :func:`from_dict` then names
    it unknown) or, not ``strict``, an option. Returns (settings, options)."""
    import yaml

    names = {f.name for f in dataclasses.fields(cls)} - {options_field}
    settings: dict[str, Any] = {}
    options: dict[str, Any] = {}
    for k, v in values.items():
        if k in names or (strict and not k.startswith(options_field + ".")):
            settings[k] = v
            continue
        key = k[len(options_field) + 1:] if k.startswith(options_field + ".") else k
        options[key] = yaml.safe_load(v) if isinstance(v, str) else v
    return settings, options


def format_config(conf: Any, indent: int = 0) -> str:
    """A config tree as YAML-like text, one ``key: value`` per leaf (``--print-config``)."""
    lines = []
    for f in dataclasses.fields(conf):
        v = getattr(conf, f.name)
        pad = "  " * indent
        if dataclasses.is_dataclass(v):
            lines.append(f"{pad}{f.name}:")
            lines.append(format_config(v, indent + 1))
        else:
            if isinstance(v, (set, frozenset)):
                v = sorted(v)
            if isinstance(v, (tuple, list)):
                v = ", ".join(str(x) for x in v) if v else "[]"
            v = "null" if v is None else ('""' if v == "" else v)
            lines.append(f"{pad}{f.name}: {v}")
    return "\n".join(lines)


def to_dict(conf: Any) -> dict[str, Any]:
    return dataclasses.asdict(conf)


def _jsonable(o: Any) -> Any:
    if dataclasses.is_dataclass(o) and not isinstance(o, type):
        return dataclasses.asdict(o)
    if isinstance(o, (set, frozenset)):
        return sorted(o)
    return str(o)


def config_hash(conf: Any, n: int = 10) -> str:
    """Short stable hash of a config's values (names outputs by their settings)."""
    blob = json.dumps(to_dict(conf) if dataclasses.is_dataclass(conf) else conf, sort_keys=True,
                      default=_jsonable)
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
        from staticdepth.fileio import not_text

        raise InputError(not_text("a text (UTF-8) YAML file", path), path) from None
    if not isinstance(d, dict):
        raise InputError("expected a YAML mapping at the top level", path)
    return d


# Settings of the adaptation whose dotted key replaced a flat one (summaries written before the
# nested configuration have the flat key).
_LEGACY_KEYS = {"detector.name": "detector", "detector.model": "detector_model",
                "predict.eps": "eps", "align.erode_px": "erode_px",
                "scale.camera_height_m": "camera_height_m", "scale.metric_scale": "metric_scale"}


def setting_from(config: Mapping[str, Any] | None, key: str, default: Any = None) -> Any:
    """A setting by its dotted ``key`` from a stored config tree (e.g. an adapt summary's
    ``config``), falling back to the flat key older summaries used."""
    node: Any = config or {}
    for part in key.split("."):
        if not isinstance(node, Mapping) or part not in node:
            node = None
            break
        node = node[part]
    if node is not None:
        return node
    flat = (config or {}).get(_LEGACY_KEYS.get(key, key))
    return default if flat is None or isinstance(flat, Mapping) else flat
