"""Frozen dataclass config trees ↔ plain dicts / YAML, and ``a.b.c=value`` overrides.

The pipeline's settings are one tree of frozen dataclasses (:class:`rgbd_envmap.pipeline.PipelineConfig`).
This module turns any such tree into a plain mapping (for YAML / JSON), builds a tree back from a
(possibly partial) mapping, and applies dotted command-line overrides. Values are coerced to each
field's annotated type (``int``, ``float``, ``bool``, ``str``, tuples, ``X | None``); unknown keys
and unparsable values raise :class:`~rgbd_envmap.errors.InvalidInputError` naming the key.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from pathlib import Path
from typing import Any, TypeVar

import yaml

from rgbd_envmap.checks import check_instance, check_path
from rgbd_envmap.errors import DTypeError, InvalidInputError

__all__ = ["to_dict", "from_dict", "apply_overrides", "load_yaml", "dump_yaml"]

T = TypeVar("T")


def to_dict(cfg: Any) -> Any:
    """A plain nested dict / list / scalar view of a dataclass tree (tuples and arrays become lists);
    ``cfg`` is a dataclass instance (:class:`~rgbd_envmap.errors.DTypeError` otherwise)."""
    if not (dataclasses.is_dataclass(cfg) and not isinstance(cfg, type)):
        raise DTypeError(f"cfg: expected a config dataclass instance, got {type(cfg).__name__}")
    return _plain(cfg)


def _plain(cfg: Any) -> Any:
    if dataclasses.is_dataclass(cfg) and not isinstance(cfg, type):
        return {f.name: _plain(getattr(cfg, f.name)) for f in dataclasses.fields(cfg)}
    if isinstance(cfg, (tuple, list)):
        return [_plain(v) for v in cfg]
    if hasattr(cfg, "tolist") and callable(cfg.tolist):  # numpy scalars and arrays
        return cfg.tolist()
    return cfg


def _check_config_class(cls: object, name: str = "cls") -> None:
    if not (isinstance(cls, type) and dataclasses.is_dataclass(cls)):
        raise DTypeError(f"{name}: expected a config dataclass type (such as PipelineConfig), got {cls!r}")


def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def _coerce(value: Any, tp: Any, key: str) -> Any:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        if value is None or (isinstance(value, str) and value.strip().lower() in ("none", "null", "~")):
            if type(None) in args:
                return None
        errors = []
        for a in args:
            if a is type(None):
                continue
            try:
                return _coerce(value, a, key)
            except InvalidInputError as exc:
                errors.append(str(exc))
        raise InvalidInputError(f"{key}: cannot read {value!r} as {tp}: {'; '.join(errors)}")
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise InvalidInputError(f"{key}: expected a mapping of {tp.__name__} fields, got {value!r}")
        return from_dict(tp, value, prefix=key)
    if origin is tuple:
        if isinstance(value, str):
            value = yaml.safe_load(value if value.strip().startswith("[") else f"[{value}]")
        if not isinstance(value, (list, tuple)):
            raise InvalidInputError(f"{key}: expected a list, got {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(v, args[0], f"{key}[{i}]") for i, v in enumerate(value))
        if args and len(args) != len(value):
            raise InvalidInputError(f"{key}: expected {len(args)} values, got {len(value)}: {value!r}")
        return tuple(_coerce(v, a, f"{key}[{i}]") for i, (v, a) in enumerate(zip(value, args or [Any] * len(value))))
    if tp is Any:
        return value
    if tp is bool:
        if isinstance(value, bool):
            return value
        if isinstance(value, str) and value.strip().lower() in ("true", "yes", "on", "1", "false", "no", "off", "0"):
            return value.strip().lower() in ("true", "yes", "on", "1")
        raise InvalidInputError(f"{key}: expected true or false, got {value!r}")
    if tp is int:
        if isinstance(value, bool):
            raise InvalidInputError(f"{key}: expected an integer, got {value!r}")
        try:
            f = float(value)
        except (TypeError, ValueError):
            raise InvalidInputError(f"{key}: expected an integer, got {value!r}") from None
        if not f.is_integer():
            raise InvalidInputError(f"{key}: expected an integer, got {value!r}")
        return int(f)
    if tp is float:
        if isinstance(value, bool):
            raise InvalidInputError(f"{key}: expected a number, got {value!r}")
        try:
            return float(value)
        except (TypeError, ValueError):
            raise InvalidInputError(f"{key}: expected a number, got {value!r}") from None
    if tp is str:
        if not isinstance(value, str):
            raise InvalidInputError(f"{key}: expected a string, got {value!r}")
        return value
    raise InvalidInputError(f"{key}: unsupported field type {tp}")


def from_dict(cls: type[T], data: dict, *, base: T | None = None, prefix: str = "") -> T:
    """A ``cls`` tree from a (partial) mapping; missing keys keep ``base``'s values (or the defaults)."""
    _check_config_class(cls)
    if not isinstance(data, dict):
        raise InvalidInputError(f"{prefix or 'data'}: expected a mapping of {cls.__name__} fields, got {type(data).__name__}")
    check_instance(base, cls, "base", optional=True)
    hints = _hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - names)
    if unknown:
        where = f"{prefix}." if prefix else ""
        raise InvalidInputError(f"unknown config key(s) {', '.join(where + k for k in unknown)}; valid: {', '.join(sorted(names))}")
    base = base if base is not None else cls()
    changes = {}
    for name, value in data.items():
        key = f"{prefix}.{name}" if prefix else name
        tp = hints[name]
        current = getattr(base, name)
        if dataclasses.is_dataclass(current) and isinstance(value, dict):
            changes[name] = from_dict(type(current), value, base=current, prefix=key)
        else:
            changes[name] = _coerce(value, tp, key)
    return dataclasses.replace(base, **changes)


def apply_overrides(cfg: T, overrides: list[str]) -> T:
    """Apply ``section.field=value`` strings (values parsed as YAML scalars / lists) in order."""
    if not (dataclasses.is_dataclass(cfg) and not isinstance(cfg, type)):
        raise DTypeError(f"cfg: expected a config dataclass instance, got {type(cfg).__name__}")
    if isinstance(overrides, str) or not isinstance(overrides, (list, tuple)):
        raise DTypeError(f"overrides: expected a list of KEY=VALUE strings, got {type(overrides).__name__}")
    for text in overrides:
        if not isinstance(text, str):
            raise DTypeError(f"overrides: expected KEY=VALUE strings, got {text!r}")
        if "=" not in text:
            raise InvalidInputError(f"overrides: expected KEY=VALUE such as capture.ccm_method=ridge, got {text!r}")
        key, raw = text.split("=", 1)
        parts = key.strip().split(".")
        value: Any = yaml.safe_load(raw) if raw.strip() else ""
        if isinstance(value, (int, float)) and not isinstance(value, bool) and raw.strip().lower() in ("yes", "no", "on", "off"):
            value = raw.strip()
        nested: Any = value
        for p in reversed(parts):
            nested = {p: nested}
        cfg = from_dict(type(cfg), nested, base=cfg)
    return cfg


def load_yaml(cls: type[T], path: str | Path, *, base: T | None = None) -> T:
    """A ``cls`` tree from a YAML file (partial files override ``base`` / the defaults)."""
    _check_config_class(cls)
    path = check_path(path)
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except FileNotFoundError:
        raise InvalidInputError(f"{path}: no such config file") from None
    except yaml.YAMLError as exc:
        raise InvalidInputError(f"{path}: not valid YAML: {exc}") from None
    try:
        return from_dict(cls, data, base=base)
    except InvalidInputError as exc:
        raise InvalidInputError(f"{path}: {exc}") from None


def dump_yaml(cfg: Any, path: str | Path) -> None:
    """Write the whole tree (every field, resolved) as YAML."""
    if not (dataclasses.is_dataclass(cfg) and not isinstance(cfg, type)):
        raise DTypeError(f"cfg: expected a config dataclass instance, got {type(cfg).__name__}")
    check_path(path).write_text(yaml.safe_dump(to_dict(cfg), sort_keys=False))
