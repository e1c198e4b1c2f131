"""How a parameter field is declared and checked: :func:`option` (a dataclass field with its unit,
range, documentation and CLI flag in the metadata, the one description of every option),
:func:`pytree` (numbers are leaves, structure is static) and the checks that construction from
concrete numbers runs."""

from __future__ import annotations

import dataclasses
import math
import types
from typing import Any

import jax
import numpy as np


def is_concrete(value: Any) -> bool:
    if isinstance(value, jax.core.Tracer):
        return False
    return isinstance(value, (int, float, np.number, np.ndarray)) or (
        hasattr(value, "shape") and hasattr(value, "dtype")
    )


def check_finite(cls_name: str, name: str, value: Any) -> None:
    arr = np.asarray(value, dtype=float)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{cls_name}.{name} must be finite, got {value!r}")


def check_positive(cls_name: str, name: str, value: Any, unit: str) -> None:
    check_finite(cls_name, name, value)
    arr = np.asarray(value, dtype=float)
    if np.any(arr <= 0):
        raise ValueError(
            f"{cls_name}.{name} must be > 0 {unit}, got {value!r} (allowed range: (0, inf) {unit})"
        )


def option(default: Any = dataclasses.MISSING, *, unit: str = "", doc: str = "",
           low: float | None = None, high: float | None = None,
           low_open: bool = False, high_open: bool = False, positive: bool = False,
           choices: tuple[str, ...] | None = None, flag: str | None = None,
           aliases: tuple[str, ...] = (), factor: float = 1.0, flag_unit: str | None = None,
           flag_commands: tuple[str, ...] | None = None) -> Any:
    """A dataclass field carrying the one description of a parameter in its metadata.

    Args:
        default: the field's default (SI units).
        unit: SI unit of the value ("" when dimensionless).
        doc: one-line meaning (case-file comments, ``--help``, ``docs/case_files.md``).
        low, high, low_open, high_open: the range a case file or flag may give (None:
            unbounded): wide enough for any real wheel and track, narrow enough that a value
            in the wrong unit (kN for N, mm for m) fails instead of running.
        positive: the constructor refuses values <= 0 (the physical limit; the Python API
            does not impose the plausible range above).
        choices: allowed strings.
        flag: the command-line flag (``--rail-head-radius-m``); ``aliases``: other spellings.
        factor, flag_unit: the flag's value x ``factor`` is SI; its unit (default ``unit``).
        flag_commands: subcommands that offer the flag (None: every one that reads the key).

    :mod:`wfjax.options` derives the case keys, flags, checks and docs from it.
    """
    meta = {"unit": unit, "doc": doc, "low": low, "high": high, "low_open": low_open,
            "high_open": high_open, "positive": positive, "choices": choices, "flag": flag,
            "aliases": aliases, "factor": factor, "flag_unit": flag_unit,
            "flag_commands": flag_commands}
    return dataclasses.field(default=default, metadata=types.MappingProxyType(meta))


def concrete_positive_numbers(obj, fields: tuple[str, ...]) -> dict[str, float]:
    """``{name: float}`` of ``obj``'s fields, each checked to be a concrete finite number > 0.

    For code that leaves JAX (NumPy/SciPy assembly of the wheel and track models). Raises
    ``ValueError`` naming the class, the field and the allowed range otherwise.
    """
    cls_name = type(obj).__name__
    out = {}
    for name in fields:
        raw = getattr(obj, name)
        try:
            value = float(np.asarray(raw))
        except (TypeError, jax.errors.ConcretizationTypeError) as exc:
            raise ValueError(f"{cls_name}.{name} must be a concrete scalar here, got "
                             f"{raw!r}") from exc
        if not math.isfinite(value) or value <= 0:
            raise ValueError(f"{cls_name}.{name} must be finite and > 0, got {value!r} "
                             "(allowed range: (0, inf))")
        out[name] = value
    return out


def pytree(cls=None, *, static: tuple[str, ...] = ()):
    """Register a frozen dataclass as a pytree; fields named in ``static`` are metadata."""

    def wrap(c):
        c = dataclasses.dataclass(frozen=True)(c)
        names = [f.name for f in dataclasses.fields(c)]
        data = tuple(n for n in names if n not in static)
        meta = tuple(n for n in names if n in static)

        def flatten(obj):
            children = tuple(getattr(obj, n) for n in data)
            return children, tuple(getattr(obj, n) for n in meta)

        def unflatten(aux, children):
            # Bypass __init__/__post_init__: JAX rebuilds objects with tracers, cotangents
            # (which may be negative or zero) and placeholders that must not be validated.
            obj = object.__new__(c)
            for n, v in zip(data, children, strict=True):
                object.__setattr__(obj, n, v)
            for n, v in zip(meta, aux, strict=True):
                object.__setattr__(obj, n, v)
            return obj

        jax.tree_util.register_pytree_node(c, flatten, unflatten)
        return c

    return wrap if cls is None else wrap(cls)


class Validated:
    """Mixin: check the leaves described ``positive`` on construction when concrete."""

    def __post_init__(self):
        for name, unit in positive_fields(self).items():
            value = getattr(self, name)
            if is_concrete(value):
                check_positive(type(self).__name__, name, value, unit)


def positive_fields(obj) -> dict[str, str]:
    """``{name: unit}`` of the fields of ``obj`` whose description says ``positive``."""
    return {f.name: f.metadata["unit"] for f in dataclasses.fields(obj)
            if f.metadata.get("positive")}
