"""Validated specs: plain mappings (TOML, JSON, CLI options) -> frozen dataclasses, clear errors.

Every spec dataclass validates itself in ``__post_init__`` and raises StarforgeError naming the
parameter and the allowed range.  :func:`from_mapping` adds the checks a mapping needs: unknown
keys are refused (with the known ones listed) and values are converted to the field types.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import types
import typing
from collections.abc import Mapping
from typing import Any, TypeVar

from starforge.errors import StarforgeError

T = TypeVar("T")


def require(cond: bool, message: str) -> None:
    """Raise StarforgeError(message) unless ``cond``."""
    if not cond:
        raise StarforgeError(message)


def positive(name: str, value: float) -> float:
    """``value`` as a finite float > 0, else StarforgeError naming ``name``."""
    v = _as_float(name, value)
    require(v > 0, f"{name} must be > 0, got {value}")
    return v


def non_negative(name: str, value: float) -> float:
    """``value`` as a finite float >= 0, else StarforgeError naming ``name``."""
    v = _as_float(name, value)
    require(v >= 0, f"{name} must be >= 0, got {value}")
    return v


def in_range(name: str, value: float, lo: float, hi: float) -> float:
    """``value`` as a finite float in [lo, hi], else StarforgeError naming ``name``."""
    v = _as_float(name, value)
    require(lo <= v <= hi, f"{name} must be in [{lo}, {hi}], got {value}")
    return v


def _as_float(name: str, value: Any) -> float:
    if isinstance(value, bool):
        raise StarforgeError(f"{name} must be a number, got {value!r}")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise StarforgeError(f"{name} must be a number, got {value!r}") from None
    require(math.isfinite(v), f"{name} must be finite, got {value}")
    return v


def _convert(name: str, tp: Any, value: Any) -> Any:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if tp is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        errors = []
        for a in args:
            if a is type(None):
                continue
            try:
                return _convert(name, a, value)
            except StarforgeError as exc:
                errors.append(str(exc))
        raise StarforgeError(errors[0] if errors else f"{name}: bad value {value!r}")
    if origin is typing.Literal:
        if value not in args:
            raise StarforgeError(f"{name} must be one of {', '.join(map(str, args))}, got {value!r}")
        return value
    if tp is float:
        return _as_float(name, value)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) \
                or int(value) != value:
            raise StarforgeError(f"{name} must be an integer, got {value!r}")
        return int(value)
    if tp is bool:
        if not isinstance(value, bool):
            raise StarforgeError(f"{name} must be true or false, got {value!r}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise StarforgeError(f"{name} must be text, got {value!r}")
        return value
    if origin is tuple:
        if not isinstance(value, list | tuple):
            raise StarforgeError(f"{name} must be a list, got {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(f"{name}[{i}]", args[0], v) for i, v in enumerate(value))
        if len(value) != len(args):
            raise StarforgeError(f"{name} must have {len(args)} values, got {len(value)}")
        return tuple(_convert(f"{name}[{i}]", a, v) for i, (a, v) in enumerate(zip(args, value, strict=True)))
    if dataclasses.is_dataclass(tp):
        if isinstance(value, tp):
            return value
        if not isinstance(value, Mapping):
            raise StarforgeError(f"{name} must be a table, got {value!r}")
        return from_mapping(tp, value, where=name)
    return value


@functools.cache
def _type_hints(cls: type) -> dict[str, Any]:
    """``cls``'s type hints, evaluated once per class (a spec class's annotations are strings)."""
    return typing.get_type_hints(cls)


def from_mapping(cls: type[T], data: Mapping[str, Any], where: str = "spec") -> T:
    """Build the frozen dataclass ``cls`` from ``data``; refuse unknown keys, convert types."""
    if not isinstance(data, Mapping):
        raise StarforgeError(f"{where} must be a table, got {type(data).__name__}")
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise StarforgeError(
            f"unknown key{'s' if len(unknown) > 1 else ''} {', '.join(map(repr, unknown))} in {where}; "
            f"known: {', '.join(fields)}"
        )
    hints = _type_hints(cls)
    kwargs = {k: _convert(k if where == "spec" else f"{where}.{k}", hints[k], v) for k, v in data.items()}
    missing = [
        n
        for n, f in fields.items()
        if n not in kwargs and f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
    ]
    if missing:
        raise StarforgeError(f"missing key{'s' if len(missing) > 1 else ''} {', '.join(missing)} in {where}")
    return cls(**kwargs)


def to_mapping(obj: Any) -> Any:
    """A spec dataclass (nested) as plain JSON-serialisable data (tuples become lists)."""
    if dataclasses.is_dataclass(obj):
        return {f.name: to_mapping(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, tuple | list):
        return [to_mapping(v) for v in obj]
    return obj
