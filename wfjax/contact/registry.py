"""The contact models by name: the one list every entry point, the case file and the CLI read.

A model is a name, a one-line description and a *prepare* function
``prepare(flat, wheel, track, material, config, cache_dir=None, **options) -> ContactLaw``
(:class:`wfjax.contact.protocol.ContactLaw`: the protocol the time loop calls). The built-in
models are named here and resolved lazily (``"module:function"``), so this module imports
nothing of the package and every module may import it. A user-defined law joins with
:func:`register`; it then runs in :func:`wfjax.simulate`, :func:`wfjax.sweep` and the fits
like the built-in ones.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import NamedTuple

__all__ = ["ContactModel", "register", "unregister", "names", "check", "get", "describe"]


class ContactModel(NamedTuple):
    """One registered contact model: ``name``, ``description`` (one line) and ``prepare``
    (a callable, or ``"module:function"`` resolved on first use)."""

    name: str
    description: str
    prepare: Callable | str


_MODELS: dict[str, ContactModel] = {}


def register(name: str, prepare: Callable | str, description: str,
             replace: bool = False) -> None:
    """Add contact model ``name`` (``prepare`` as in the module docstring).

    Raises ``ValueError`` if ``name`` is taken (unless ``replace``) or not a non-empty string
    without whitespace.
    """
    if not isinstance(name, str) or not name or any(c.isspace() for c in name):
        raise ValueError(f"contact model name must be a non-empty word, got {name!r}")
    if name in _MODELS and not replace:
        raise ValueError(f"contact model {name!r} is already registered")
    _MODELS[name] = ContactModel(name, description, prepare)


def unregister(name: str) -> None:
    """Remove user-registered model ``name`` (a test's clean-up, a plugin that unloads).

    Raises ``ValueError`` (one line) for a name not registered and for the built-in models,
    which every entry point relies on.
    """
    check(name)
    if name in _BUILT_IN:
        raise ValueError(f"contact model {name!r} is built in and cannot be unregistered")
    del _MODELS[name]


def names() -> tuple[str, ...]:
    """Registered model names, built-in first, in registration order."""
    return tuple(_MODELS)


def check(name, what: str = "contact") -> str:
    """``name`` if registered, else a one-line ``ValueError`` naming ``what`` and the choices."""
    if name not in _MODELS:
        raise ValueError(f"{what} must be one of {', '.join(_MODELS)}, got {name!r}")
    return name


def get(name: str) -> Callable:
    """The prepare function of model ``name`` (checked, resolved)."""
    model = _MODELS[check(name)]
    if isinstance(model.prepare, str):
        module, function = model.prepare.split(":")
        fn = getattr(importlib.import_module(module), function)
        _MODELS[name] = model._replace(prepare=fn)
        return fn
    return model.prepare


def describe() -> dict[str, str]:
    """``{name: description}`` of every registered model (docs, ``--help``)."""
    return {m.name: m.description for m in _MODELS.values()}


register("3d", "wfjax.contact.laws:prepare_3d",
         "3D non-Hertzian contact (Kalker, elastic half-space): table, family or direct solve")
register("2d", "wfjax.contact.laws:prepare_2d", "2D Winkler bedding (Eq. 3)")
register("hertz-trajectory", "wfjax.contact.laws:prepare_hertz_trajectory",
         "Hertz spring driven by the rigid wheel-centre trajectory (Wu & Thompson)")
register("hertz-profile", "wfjax.contact.laws:prepare_hertz_profile",
         "Hertz spring driven by the flat's profile deviation")

_BUILT_IN = frozenset(_MODELS)
