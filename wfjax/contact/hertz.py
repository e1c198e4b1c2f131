"""Hertzian contact spring (Section 3.3.3 of Pieringer, Kropp & Nielsen 2014, Eqs. 14-15).

Wheel and rail head are taken with the same radius of curvature R (the paper's assumption), so
the contact is that of a sphere of radius R on a plane with combined modulus
E* = E / (2 (1 - nu^2)) (Johnson, *Contact Mechanics*, 1985, Section 4.2):

    F = C_H max(delta, 0)^(3/2),   C_H = (2/3) E / (1 - nu^2) sqrt(R)      (Eqs. 14-15)
    contact radius a = sqrt(R delta),  maximum pressure p0 = 3 F / (2 pi a^2).

All functions are pure ``jax.numpy``: they ``jit``, ``vmap`` and ``grad`` (also with respect to
the material and the radius). At zero and negative approach the force, its first and its second
derivative are zero (a double ``where`` keeps ``delta**1.5`` from producing NaN gradients).

Concrete (non-traced) arguments of the public functions are validated and bad values raise
``ValueError`` naming the parameter, its value and the allowed range; traced arguments (inside
``jit``/``vmap``/``grad``) are not checked.
"""

from __future__ import annotations

import math
from typing import Any

import jax.numpy as jnp
import numpy as np

from ..fields import is_concrete
from ..params import Material

__all__ = [
    "hertz_constant",
    "force",
    "force_and_stiffness",
    "approach_for_force",
    "contact_radius",
    "max_pressure",
]


# -- validation of concrete inputs (shared with winkler.py) ------------------------------------
def _check_range(
    name: str,
    value: Any,
    unit: str,
    low: float = -math.inf,
    high: float = math.inf,
    low_open: bool = False,
) -> None:
    """Raise ``ValueError`` unless every element of a concrete ``value`` is finite and in range.

    The allowed range is ``[low, high]`` (``(low, high]`` with ``low_open``); traced values are
    skipped. ``None`` is skipped too (an optional argument left at its default).
    """
    if value is None or not is_concrete(value):
        return
    arr = np.asarray(value, dtype=float)
    lo_bracket = "(" if low_open or math.isinf(low) else "["
    hi_bracket = ")" if math.isinf(high) else "]"
    allowed = f"{lo_bracket}{low:g}, {high:g}{hi_bracket} {unit}".rstrip()
    bad_low = arr <= low if low_open else arr < low
    if not np.all(np.isfinite(arr)) or np.any(bad_low) or np.any(arr > high):
        raise ValueError(f"{name} must be finite and in {allowed}, got {value!r}")


def _positive_part(value):
    """(max(value, 0), value > 0) with a safe (finite) stand-in where value <= 0."""
    positive = value > 0
    return jnp.where(positive, value, 1.0), positive


# -- public functions ----------------------------------------------------------------------
def hertz_constant(material: Material, radius):
    """C_H = (2/3) E / (1 - nu^2) sqrt(R) [N/m^1.5] (Eq. 15).

    Args:
        material: wheel and rail material (E [Pa], nu [-]).
        radius: R [m], wheel radius = rail head radius of curvature (scalar or array).

    Returns:
        C_H, shaped like ``radius`` (broadcast with the material's leaves).
    """
    _check_range("radius", radius, "m", low=0.0, low_open=True)
    return (2.0 / 3.0) * material.plane_strain_modulus * jnp.sqrt(radius)


def force(approach, material: Material, radius):
    """Hertzian contact force F = C_H max(delta, 0)^(3/2) [N] (Eq. 14).

    Args:
        approach: delta [m], the combined compression of wheel and rail (positive = contact),
            any shape.
        material: wheel and rail material.
        radius: R [m] (broadcasts with ``approach``).

    Returns:
        F [N], broadcast shape of ``approach`` and ``radius``. Zero, with zero first and second
        derivatives, for ``approach <= 0``.
    """
    _check_range("approach", approach, "m")
    safe, positive = _positive_part(jnp.asarray(approach))
    return jnp.where(positive, hertz_constant(material, radius) * safe**1.5, 0.0)


def force_and_stiffness(approach, material: Material, radius):
    """(F [N], dF/d delta [N/m]) of :func:`force`, e.g. for a Newton step on the approach.

    dF/d delta = (3/2) C_H sqrt(max(delta, 0)). Shapes as in :func:`force`.
    """
    _check_range("approach", approach, "m")
    safe, positive = _positive_part(jnp.asarray(approach))
    c_h = hertz_constant(material, radius)
    root = jnp.sqrt(safe)
    return (
        jnp.where(positive, c_h * safe * root, 0.0),
        jnp.where(positive, 1.5 * c_h * root, 0.0),
    )


def approach_for_force(force, material: Material, radius):
    """Inverse of :func:`force`: delta = (max(F, 0) / C_H)^(2/3) [m].

    Args:
        force: F [N] >= 0, any shape (traced negative values give zero approach).
        material: wheel and rail material.
        radius: R [m].

    Returns:
        delta [m], broadcast shape. Its derivative with respect to ``force`` (infinite at
        F = 0 in exact arithmetic) is returned as zero for F <= 0.
    """
    _check_range("force", force, "N", low=0.0)
    safe, positive = _positive_part(jnp.asarray(force))
    return jnp.where(positive, (safe / hertz_constant(material, radius)) ** (2.0 / 3.0), 0.0)


def contact_radius(approach, radius):
    """Radius a = sqrt(R max(delta, 0)) [m] of the circular Hertz contact (equal radii R).

    The derivative at ``approach <= 0`` is returned as zero.
    """
    _check_range("approach", approach, "m")
    _check_range("radius", radius, "m", low=0.0, low_open=True)
    safe, positive = _positive_part(jnp.asarray(approach))
    return jnp.where(positive, jnp.sqrt(radius * safe), 0.0)


def max_pressure(force, material: Material, radius):
    """Maximum Hertz pressure p0 = 3 F / (2 pi a^2) [Pa] at normal load ``force`` [N].

    With a^2 = R delta and delta from :func:`approach_for_force`:
    p0 = (3 / (2 pi)) F^(1/3) C_H^(2/3) / R. Zero for F <= 0.
    """
    _check_range("force", force, "N", low=0.0)
    _check_range("radius", radius, "m", low=0.0, low_open=True)
    safe, positive = _positive_part(jnp.asarray(force))
    c_h = hertz_constant(material, radius)
    return jnp.where(
        positive, 3.0 / (2.0 * jnp.pi) * jnp.cbrt(safe) * c_h ** (2.0 / 3.0) / radius, 0.0
    )
