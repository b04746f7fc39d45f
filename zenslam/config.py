"""Typed, frozen configuration dataclasses built from YAML mappings with strict key checking."""

from __future__ import annotations

import dataclasses
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal, TypeVar, get_args, get_origin

import yaml

from zenslam.errors import ConfigError

# libyaml's parser where PyYAML was built with it (its wheels are): the same mappings as the
# pure-Python SafeLoader for a fraction of the CPU, and every stage process reads the run's config.
_SAFE_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)

C = TypeVar("C")


def from_mapping(cls: type[C], data: dict[str, Any] | None, where: str = "") -> C:
    """Build the frozen dataclass ``cls`` from a mapping.

    Unknown keys are an error; missing keys take the field defaults (a field without a default
    is required). Nested dataclasses are built recursively. All problems are reported at once.
    """
    if data is None:  # an empty section: every key takes its default
        data = {}
    if not isinstance(data, Mapping):
        raise ConfigError(
            f"'{where or cls.__name__}' must be a mapping of keys to values (`key: value` lines), "
            f"got a {type(data).__name__}: {data!r:.80}"
        )
    data = dict(data)
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    problems: list[str] = []
    unknown = sorted(set(data) - set(fields))
    if unknown:
        problems.append(f"unknown key(s) {unknown}; valid keys are {sorted(fields)}")
    kwargs: dict[str, Any] = {}
    for name, field in fields.items():
        path = f"{where}.{name}" if where else name
        if name not in data:
            if field.default is dataclasses.MISSING and field.default_factory is dataclasses.MISSING:
                problems.append(f"missing required key '{path}'")
            continue
        try:
            kwargs[name] = _coerce(hints[name], data[name], path)
        except ConfigError as exc:
            problems.append(str(exc))
    if problems:
        raise ConfigError(f"invalid configuration for {cls.__name__}: " + "; ".join(problems))
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"invalid configuration for {cls.__name__}: {exc}") from exc


def _coerce(hint: Any, value: Any, path: str) -> Any:
    origin = get_origin(hint)
    if dataclasses.is_dataclass(hint):
        if not isinstance(value, dict):
            raise ConfigError(f"'{path}' must be a mapping")
        return from_mapping(hint, value, path)
    if origin is Literal:
        if value not in get_args(hint):
            raise ConfigError(f"'{path}'={value!r} must be one of {list(get_args(hint))}")
        return value
    if origin in (typing.Union, types.UnionType):
        args = get_args(hint)
        if value is None and type(None) in args:
            return None
        errors = []
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _coerce(arg, value, path)
            except ConfigError as exc:
                errors.append(str(exc))
        raise ConfigError("; ".join(errors))
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"'{path}' must be a list")
        args = get_args(hint)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(args[0], v, f"{path}[{k}]") for k, v in enumerate(value))
        if len(args) != len(value):
            raise ConfigError(f"'{path}' must have {len(args)} entries, got {len(value)}")
        return tuple(_coerce(a, v, path) for a, v in zip(args, value))
    if hint is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"'{path}'={value!r} must be true or false")
        return value
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"'{path}'={value!r} must be an integer")
        return value
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"'{path}'={value!r} must be a number")
        return float(value)
    if hint is str:
        if not isinstance(value, str):
            raise ConfigError(f"'{path}'={value!r} must be a string")
        return value
    return value


def to_mapping(config: Any) -> dict[str, Any]:
    """The plain mapping of a config dataclass (tuples become lists), ready for YAML."""

    def plain(v: Any) -> Any:
        if isinstance(v, (tuple, list)):
            return [plain(x) for x in v]
        if isinstance(v, dict):
            return {k: plain(x) for k, x in v.items()}
        return v

    return plain(dataclasses.asdict(config))


def load_yaml(path: Path) -> dict[str, Any]:
    """Read a YAML mapping from ``path`` with errors that name the file."""
    if not path.is_file():
        raise ConfigError(f"configuration file {path} does not exist")
    try:
        data = yaml.load(path.read_text(), Loader=_SAFE_LOADER)
    except yaml.YAMLError as exc:
        raise ConfigError(f"configuration file {path} is not valid YAML: {exc}") from exc
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"configuration file {path} must hold a mapping with one section per stage")
    return data
