"""2D Winkler bedding contact (Section 3.3.2 of Pieringer, Kropp & Nielsen 2014, Eqs. 11-13).

Independent springs between wheel and rail, of stiffness per unit length (Eq. 13)

    k = E / (2 sqrt(2) (1 - nu^2))   [N/m^2],

under the exact circular wheel profile z_W(x') = R - sqrt(R^2 - x'^2) plus the flat's profile
deviation, which moves with the wheel. With R equal to the rail head's transverse radius, k is
the value for which a smooth wheel reproduces the Hertz law of Eqs. 14-15 exactly (for the
parabolic approximation of the circle, F = (4/3) k sqrt(2R) delta^(3/2) = C_H delta^(3/2));
the model gets the radius, force and approach right and the contact length wrong (the paper's
choice, after Ford & Thompson 2006).

Conventions (used across wfjax):

* ``x'`` (``nodes``): rail coordinate relative to the nominal contact point, positive in the
  travel direction [m].
* ``s``: wheel position relative to the position where the flat centre is at the contact point
  [m]; ``s < 0`` before the flat arrives. The tread point above ``x'`` is at flat coordinate
  ``x' + s`` (the coordinate of :func:`wfjax.model.geometry.profile_deviation`).
* ``approach`` (delta): wheel-rail approach relative to the undamaged wheel [m], positive =
  compression, i.e. xi_W - xi_R in Eq. 11.

The spring compression is c(x') = delta - z_W(x') - z_flat(x' + s) and the force (Eq. 12)

    F = k int_{-a'}^{a'} max(c(x'), 0) dx'.

Discretisation: c is sampled at nodes (spacing ``element``, 1 mm by default as in the paper)
and the positive part of its piecewise-linear interpolant is integrated exactly per segment.
F is therefore continuous and continuously differentiable in delta (and in s and the flat's
parameters wherever the flat profile is smooth; across the kinks of a new flat it is
continuous and piecewise smooth), which the Newton iteration of the time loop relies on.
The discretisation under-estimates the force of a smooth wheel by about h^2 / (8 R delta)
relative (the linear interpolant of a concave profile), about 0.25 % for 1 mm elements at the
static load of 118 kN; see ``tests/test_winkler.py`` for the measured value.

Window: the flat only removes material (z_flat >= 0), so a spring can only be compressed where
z_W(x') < delta, i.e. |x'| < sqrt(2 R delta - delta^2) <= sqrt(2 R delta). The half window
a' = sqrt(2 R delta_max) (rounded up to whole elements, plus one) therefore holds every
potential contact point for approaches up to delta_max, whatever the flat and its position.
The default delta_max is the flat's depth plus 1 mm (a Hertz force of about 3.3 MN on top of
dropping into the full depth of the flat). Larger approaches under-estimate F (the compressed
region is cut off); :func:`window_max_approach` gives the limit of a node set.

For the time loop, build the nodes once with :func:`bedding_nodes` (static shape); per time
step compute the gap once with :func:`gap_at_nodes` (the flat position s is known) and run the
Newton iteration on delta with :func:`force_and_stiffness_from_gap` (pure, branch-free,
vectorised, no validation). :func:`force_at_nodes` does both in one call and :func:`force` is
the validated convenience wrapper.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from ..fields import is_concrete
from ..model.geometry import profile_deviation
from ..params import MAX_FLAT_DEPTH, Flat, Material
from .hertz import _check_range

__all__ = [
    "DEFAULT_APPROACH_MARGIN",
    "winkler_stiffness",
    "wheel_profile",
    "default_half_window",
    "bedding_nodes",
    "window_max_approach",
    "gap_at_nodes",
    "compression",
    "bedding_integral",
    "force_from_gap",
    "force_at_nodes",
    "force_and_stiffness_from_gap",
    "force_and_stiffness_at_nodes",
    "onset_at_nodes",
    "force",
    "onset",
]

DEFAULT_APPROACH_MARGIN = 1e-3  # m; default max approach = flat depth + this


def winkler_stiffness(material: Material):
    """Bedding stiffness per unit length k = E / (2 sqrt(2) (1 - nu^2)) [N/m^2] (Eq. 13)."""
    return material.plane_strain_modulus / (2.0 * math.sqrt(2.0))


def wheel_profile(nodes, wheel_radius):
    """Circular wheel profile z_W(x') = R - sqrt(R^2 - x'^2) [m] at ``nodes`` [m] (|x'| < R).

    Evaluated as x'^2 / (R + sqrt(R^2 - x'^2)), which keeps full relative precision at small x'.
    Same shape as ``nodes``.
    """
    nodes = jnp.asarray(nodes)
    return nodes**2 / (wheel_radius + jnp.sqrt(wheel_radius**2 - nodes**2))


# -- window and nodes (concrete, static shapes) ------------------------------------------------
def default_half_window(flat: Flat, wheel_radius=None, max_approach=None) -> float:
    """Half window a' = sqrt(2 R delta_max) [m] holding every potential contact point.

    Args:
        flat: the flat (only its concrete depth enters the default ``max_approach``).
        wheel_radius: R [m]; default ``flat.wheel_radius``.
        max_approach: largest approach delta_max [m] to be covered; default
            ``flat.depth + DEFAULT_APPROACH_MARGIN``.

    Returns:
        a' [m] as a Python float.
    """
    radius = flat.wheel_radius if wheel_radius is None else wheel_radius
    _check_range("wheel_radius", radius, "m", low=0.0, low_open=True)
    if max_approach is None:
        max_approach = float(np.max(np.asarray(flat.depth))) + DEFAULT_APPROACH_MARGIN
    _check_range("max_approach", max_approach, "m", low=0.0, low_open=True)
    radius = float(np.max(np.asarray(radius)))
    return math.sqrt(2.0 * radius * float(np.max(np.asarray(max_approach))))


def bedding_nodes(half_window: float, element: float = 1e-3) -> np.ndarray:
    """Bedding nodes x' = element * (-m, ..., m) [m], m = ceil(half_window / element) + 1.

    Args:
        half_window: a' [m] > 0 (e.g. from :func:`default_half_window`).
        element: node spacing h [m] > 0 (1 mm in the paper).

    Returns:
        [2 m + 1] NumPy array (concrete: its length is a static shape).
    """
    _check_range("element", element, "m", low=0.0, low_open=True)
    _check_range("half_window", half_window, "m", low=0.0, low_open=True)
    m = math.ceil(float(half_window) / float(element) - 1e-9) + 1
    return float(element) * np.arange(-m, m + 1, dtype=float)


def window_max_approach(nodes, wheel_radius):
    """Largest approach [m] for which ``nodes`` hold every compressed spring: min z_W(end nodes)."""
    nodes = jnp.asarray(nodes)
    ends = jnp.stack([nodes[0], nodes[-1]])
    return jnp.min(wheel_profile(ends, wheel_radius))


# -- the kernel (pure, branch-free) --------------------------------------------------------
def gap_at_nodes(flat: Flat, s, wheel_radius, nodes):
    """Undeformed gap g(x') = z_W(x') + z_flat(x' + s) [m] at the nodes (independent of delta).

    The time loop can compute it once per step (per flat position ``s``) and reuse it in every
    Newton iteration on the approach through :func:`force_from_gap`.

    Args:
        flat: the flat.
        s: flat position [m] (see module docstring), any shape B.
        wheel_radius: R [m].
        nodes: [n] bedding nodes x' [m].

    Returns:
        [*B, n] gap [m] (>= 0).
    """
    nodes = jnp.asarray(nodes)
    s = jnp.asarray(s)[..., None]
    return wheel_profile(nodes, wheel_radius) + profile_deviation(flat, nodes + s)


def compression(flat: Flat, approach, s, wheel_radius, nodes):
    """Spring compression c(x') = delta - z_W(x') - z_flat(x' + s) [m] at the nodes.

    Args:
        flat: the flat.
        approach: delta [m], any shape (batch shape B after broadcasting with ``s``).
        s: flat position [m] (see module docstring), broadcasts with ``approach``.
        wheel_radius: R [m].
        nodes: [n] bedding nodes x' [m].

    Returns:
        [*B, n] compression [m] (positive = compressed).
    """
    return jnp.asarray(approach)[..., None] - gap_at_nodes(flat, s, wheel_radius, nodes)


def bedding_integral(c, nodes):
    """Exact integral of the positive part of the piecewise-linear interpolant of ``c`` [m^2].

    Per segment [x_i, x_i+1] of length h_i with end values c0, c1 [m]:
    h (c0 + c1) / 2 if both >= 0, 0 if both <= 0, and h max(c0, c1)^2 / (2 |c1 - c0|) if they
    have opposite signs. The three branches join with matching value and first derivative, so
    the result is continuously differentiable in ``c``; the denominator is guarded (double
    ``where``) so gradients stay finite.

    Args:
        c: [..., n] values at the nodes [m].
        nodes: [n] strictly increasing node positions [m] (any spacing).

    Returns:
        [...] integral [m^2].
    """
    h = jnp.diff(jnp.asarray(nodes))
    c0 = c[..., :-1]
    c1 = c[..., 1:]
    both_positive = (c0 >= 0) & (c1 >= 0)
    mixed = (c0 > 0) != (c1 > 0)
    mixed = mixed & ~both_positive
    jump = jnp.where(mixed, jnp.abs(c1 - c0), 1.0)
    top = jnp.where(mixed, jnp.maximum(c0, c1), 0.0)
    segment = jnp.where(
        both_positive, 0.5 * (c0 + c1), jnp.where(mixed, 0.5 * top**2 / jump, 0.0)
    )
    return jnp.sum(h * segment, axis=-1)


@jax.jit
def force_from_gap(gap, approach, material: Material, nodes):
    """Bedding force F = k int max(delta - g, 0) dx' [N] from a precomputed gap (no validation).

    Args:
        gap: [*B, n] undeformed gap [m] from :func:`gap_at_nodes`.
        approach: delta [m], shape broadcasting with ``gap[..., 0]``.
        material: wheel and rail material.
        nodes: [n] nodes x' [m].

    Returns:
        [*B] force [N] (>= 0).
    """
    c = jnp.asarray(approach)[..., None] - gap
    return winkler_stiffness(material) * bedding_integral(c, nodes)


@jax.jit
def force_at_nodes(flat: Flat, approach, s, material: Material, wheel_radius, nodes):
    """Bedding contact force F [N] on fixed nodes: the time loop's kernel (no validation).

    Args:
        flat: the flat (depth, length, profile are differentiable leaves).
        approach: delta [m], any shape; broadcasts with ``s`` to batch shape B.
        s: flat position [m].
        material: wheel and rail material.
        wheel_radius: R [m].
        nodes: [n] nodes x' [m] from :func:`bedding_nodes` (a fixed, static-shape array).

    Returns:
        [*B] force [N] (>= 0).

    Wrapped in ``jax.jit`` (one compiled call per shape when used eagerly; inlined inside an
    outer ``jit``).
    """
    c = compression(flat, approach, s, wheel_radius, nodes)
    return winkler_stiffness(material) * bedding_integral(c, nodes)


def force_and_stiffness_from_gap(gap, approach, material: Material, nodes):
    """(F [N], dF/d delta [N/m]) of :func:`force_from_gap` in one forward-mode pass.

    For the Newton iteration on the approach at a fixed flat position. Shapes: both [*B].
    """
    approach = jnp.asarray(approach, dtype=jnp.result_type(float))

    def f(a):
        return force_from_gap(gap, a, material, nodes)

    return jax.jvp(f, (approach,), (jnp.ones_like(approach),))


def force_and_stiffness_at_nodes(flat: Flat, approach, s, material: Material, wheel_radius,
                                 nodes):
    """(F [N], dF/d delta [N/m]) of :func:`force_at_nodes` in one forward-mode pass.

    Shapes: both [*B] (``approach`` and ``s`` broadcast).
    """
    approach = jnp.asarray(approach, dtype=jnp.result_type(float))
    gap = gap_at_nodes(flat, s, wheel_radius, nodes)
    approach = jnp.broadcast_to(approach, gap.shape[:-1])
    return force_and_stiffness_from_gap(gap, approach, material, nodes)


@jax.jit
def onset_at_nodes(flat: Flat, s, wheel_radius, nodes):
    """Approach [m] at which contact begins: min over nodes of z_W(x') + z_flat(x' + s).

    F is zero for approaches at or below it and positive above (exactly, for the discretised
    bedding). Shape: ``s``'s shape.
    """
    return jnp.min(gap_at_nodes(flat, s, wheel_radius, nodes), axis=-1)


# -- validated wrappers ------------------------------------------------------------------------
def _nodes_for(flat, wheel_radius, element, half_window):
    _check_range("element", element, "m", low=0.0, low_open=True)
    _check_range("wheel_radius", wheel_radius, "m", low=0.0, low_open=True)
    _check_range("half_window", half_window, "m", low=0.0, low_open=True)
    if not is_concrete(element) or (half_window is not None and not is_concrete(half_window)):
        raise ValueError("element and half_window must be concrete numbers (they fix shapes)")
    if half_window is None:
        if not is_concrete(wheel_radius):
            raise ValueError(
                "wheel_radius is traced: pass a concrete half_window (see default_half_window)"
            )
        max_approach = None
        if not is_concrete(flat.depth):  # traced depth: cover the deepest valid flat
            max_approach = MAX_FLAT_DEPTH + DEFAULT_APPROACH_MARGIN
        half_window = default_half_window(flat, wheel_radius, max_approach)
    if is_concrete(wheel_radius):
        radius = float(np.min(np.asarray(wheel_radius)))
        if half_window >= 0.5 * radius:
            raise ValueError(
                f"half_window must be in (0, wheel_radius / 2 = {0.5 * radius:g}) m, "
                f"got {half_window!r}"
            )
    return bedding_nodes(half_window, element)


def force(flat: Flat, approach, s, material: Material, wheel_radius=None, element=1e-3,
          half_window=None):
    """Bedding contact force F [N] (Eqs. 11-13); validated wrapper of :func:`force_at_nodes`.

    Args:
        flat: the flat.
        approach: delta [m] relative to the undamaged wheel, any shape (broadcasts with ``s``).
        s: flat position [m] (``s < 0`` before the flat arrives).
        material: wheel and rail material.
        wheel_radius: R [m]; default ``flat.wheel_radius``. May be traced only if
            ``half_window`` is given.
        element: node spacing [m] (concrete), 1 mm by default.
        half_window: a' [m] (concrete); default :func:`default_half_window` (covers approaches
            up to the flat's depth + 1 mm).

    Returns:
        [*B] force [N]. Concrete inputs are validated (``ValueError`` naming the parameter,
        value and allowed range); traced ones are not.
    """
    if wheel_radius is None:
        wheel_radius = flat.wheel_radius
    _check_range("approach", approach, "m")
    _check_range("s", s, "m")
    nodes = _nodes_for(flat, wheel_radius, element, half_window)
    return force_at_nodes(flat, approach, s, material, wheel_radius, nodes)


def onset(flat: Flat, s, wheel_radius=None, element=1e-3, half_window=None):
    """Approach [m] at which contact begins at flat position ``s`` (validated wrapper of
    :func:`onset_at_nodes`, same nodes as :func:`force`)."""
    if wheel_radius is None:
        wheel_radius = flat.wheel_radius
    _check_range("s", s, "m")
    nodes = _nodes_for(flat, wheel_radius, element, half_window)
    return onset_at_nodes(flat, s, wheel_radius, nodes)
