"""Wheel-flat geometry (Section 2 of Pieringer, Kropp & Nielsen 2014), pure JAX.

Conventions (used across wfjax):

* ``x`` is the circumferential (arc-length) coordinate on the wheel tread, measured from the
  flat centre, in m. Rolling the wheel forward by a distance X turns it by X / R.
* The *profile deviation* z(x) >= 0 is the radial depth of material missing from the ideal
  circle of radius R (m). Outside the flat it is zero.
* The *wheel-centre trajectory* is the vertical position of the centre of a rigid wheel
  rolling on a rigid straight rail, relative to the undamaged wheel, in m (<= 0: the centre
  drops), as a function of the rolling distance measured from the position where the flat
  centre is at the bottom (Wu & Thompson 2002).

Every function is differentiable with respect to the flat's depth, length and profile values.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from ..fields import is_concrete
from ..params import Flat, new_flat_length
from . import surface

MIN_WHEEL_RADIUS = 0.3  # m; sizes the trajectory's search window when the radius is traced

__all__ = [
    "new_flat_length",
    "new_flat_half_angle",
    "profile_deviation",
    "profile_deviation_small_depth",
    "flat_surface",
    "centre_trajectory",
    "wheel_radius_at",
]


def new_flat_half_angle(depth, wheel_radius):
    """Half the angle [rad] subtended by the exact chord of a new flat: arccos(1 - d/R)."""
    return jnp.arccos(1.0 - depth / wheel_radius)


# The shape functions take the array module ``xp``: jnp (traceable, differentiable) or np,
# which the 3D table builds use for concrete flats (their gaps then compile nothing).


def _safe_positive(value, xp=jnp):
    """max(value, 0) with a zero (not NaN) gradient where value <= 0."""
    return xp.where(value > 0, value, 0.0)


def _new_flat_exact(depth, wheel_radius, x, xp=jnp):
    # Radial distance of the chord at angle theta = x/R is (R - d)/cos(theta); the deviation is
    # R minus that, clipped to zero beyond the chord's ends at theta = +-arccos(1 - d/R).
    theta = xp.clip(x / wheel_radius, -1.2, 1.2)
    return _safe_positive(wheel_radius - (wheel_radius - depth) / xp.cos(theta), xp)


def _rounded_flat(depth, length, x, xp=jnp):
    inside = xp.abs(x) <= length / 2
    safe_x = xp.where(inside, x, 0.0)
    return xp.where(inside, 0.5 * depth * (1.0 + xp.cos(2.0 * np.pi * safe_x / length)), 0.0)


def _profile_flat(profile_x, profile_z, x, xp=jnp):
    return xp.interp(x, profile_x, profile_z, left=0.0, right=0.0)


def profile_deviation(flat: Flat, x):
    """Profile deviation z(x) >= 0 [m] of ``flat`` at circumferential positions ``x`` [m].

    * ``"new"``: the exact chord of the circle, z = R - (R - d) / cos(x / R) for
      |x| <= R arccos(1 - d/R), else 0. Eq. (2) of the paper, z = d - x^2 / (2R), is its
      small-depth form (see :func:`profile_deviation_small_depth`); the two differ by less than
      d^2 / R + x^4 / (3 R^3) (about 4 um for d = 2 mm, R = 0.45 m).
    * ``"rounded"``: Eq. (3), z = d/2 (1 + cos(2 pi x / l)) for |x| <= l/2.
    * ``"profile"``: linear interpolation of the measured deviation, zero outside its support.
    * ``"sections"``: the measured surface on the nominal contact line y = 0
      (:func:`wfjax.model.surface.centre_line`): what the 2D bedding and the Hertz models see.
    * ``"none"``: zero.

    Args:
        flat: the flat.
        x: array of any shape, positions on the tread relative to the flat centre [m].

    Returns:
        Array shaped like ``x`` [m].
    """
    return _deviation(flat, jnp.asarray(x), jnp)


def _deviation(flat: Flat, x, xp):
    """:func:`profile_deviation` with array module ``xp`` (np: a concrete flat's leaves)."""
    if flat.kind == "new":
        return _new_flat_exact(flat.depth, flat.wheel_radius, x, xp)
    if flat.kind == "rounded":
        return _rounded_flat(flat.depth, flat.length, x, xp)
    if flat.kind == "profile":
        return _profile_flat(flat.profile_x, flat.profile_z, x, xp)
    if flat.kind == "sections":
        return surface.centre_line(flat.profile_x, flat.section_y, flat.section_z, x, xp)
    return xp.zeros_like(x, dtype=xp.result_type(x, float))  # float32 stays float32


def profile_deviation_small_depth(flat: Flat, x):
    """Eq. (2) of the paper for a new flat: z = d - x^2 / (2R) on |x| <= l0/2 [m].

    Kept to document (and test) its difference to the exact chord used by
    :func:`profile_deviation`. Only defined for ``flat.kind == "new"``.
    """
    if flat.kind != "new":
        raise ValueError(f"profile_deviation_small_depth needs a 'new' flat, got {flat.kind!r}")
    x = jnp.asarray(x)
    half = new_flat_length(flat.depth, flat.wheel_radius) / 2
    return jnp.where(jnp.abs(x) <= half, flat.depth - x**2 / (2 * flat.wheel_radius), 0.0)


def flat_surface(flat: Flat, x, y, transverse_radius):
    """3D profile deviation r(x, y) >= 0 [m] on a rectangular grid.

    The flat is the imprint of the rail head on which it formed (Section 2, Fig. 2): along the
    rolling direction its lines are those of :func:`profile_deviation`, across it they are
    circular arcs of the rail head radius, so
    r(x, y) = max(0, z(x) - (R_R - sqrt(R_R^2 - y^2))).
    A measured 3D flat (``"sections"``) is its interpolated surface instead
    (:func:`wfjax.model.surface.sections_surface`; R_R only continues its edge records
    beyond the measured band).

    Args:
        flat: the flat.
        x: [nx] circumferential positions relative to the flat centre [m].
        y: [ny] transverse positions relative to the running band centre [m].
        transverse_radius: R_R [m], the rail head radius that formed the flat.

    Returns:
        [nx, ny] deviation [m].
    """
    return _surface(flat, jnp.asarray(x), jnp.asarray(y), transverse_radius, jnp)


def _surface(flat: Flat, x, y, transverse_radius, xp):
    """:func:`flat_surface` with array module ``xp``; x may be [..., nx] (then [..., nx, ny])."""
    if flat.kind == "sections":
        return surface.sections_surface(flat.profile_x, flat.section_y, flat.section_z, x, y,
                                        transverse_radius, xp)
    z = _deviation(flat, x, xp)[..., None]
    arc = transverse_radius - xp.sqrt(transverse_radius**2 - y**2)
    return _safe_positive(z - arc, xp)


def wheel_radius_at(flat: Flat, theta):
    """Deviated wheel radius r(theta) = R - z(R theta) [m] at polar angles ``theta`` [rad]."""
    return flat.wheel_radius - profile_deviation(flat, flat.wheel_radius * theta)


def _kink_angles(flat: Flat):
    """Angles [rad] where r(theta) has a kink: candidates for the trajectory's maximiser."""
    R = flat.wheel_radius
    if flat.kind == "new":
        a = new_flat_half_angle(flat.depth, R)
        return jnp.stack([-a, a])
    if flat.kind == "rounded":
        return jnp.stack([-flat.length / (2 * R), flat.length / (2 * R)])
    if flat.kind in ("profile", "sections"):
        return jnp.asarray(flat.profile_x) / R
    return jnp.zeros((1,))


def _trajectory_window(flat: Flat) -> float:
    """Half-width [rad] of the angle range around phi searched for the contact (concrete).

    The contact point lies on the flat or at its edges while the flat passes, so it is within
    twice the flat's half angle of phi; a margin is added.
    """
    radius = flat.wheel_radius
    radius = float(np.min(np.asarray(radius))) if is_concrete(radius) else MIN_WHEEL_RADIUS
    return 2.5 * flat.half_extent / radius + 1e-3


def centre_trajectory(flat: Flat, x, n_coarse: int = 256, n_fine: int = 64):
    """Vertical wheel-centre trajectory [m] of a rigid wheel on a rigid rail (Wu & Thompson).

    With r(theta) the deviated radius, the centre height at rolling angle phi = X / R is
    H(phi) = max_theta r(theta) cos(theta - phi); the returned value is H - R (<= 0).

    The maximum is found on a coarse grid of ``n_coarse`` angles across the flat, refined on a
    grid of ``n_fine`` angles around the coarse maximiser, polished by Newton steps where the
    deviated surface is smooth, and compared with the kink angles of
    the profile (chord ends of a new flat, data points of a measured one), where the contact
    pivots. The gradient with respect to the flat's parameters follows from the envelope
    theorem (a smooth maximiser is held fixed; a kink maximiser moves with the parameters),
    which is exact where the maximiser is unique.

    Args:
        flat: the flat.
        x: [n] rolling distances [m] from the position where the flat centre is at the contact.
        n_coarse, n_fine: grid sizes (static).

    Returns:
        [n] centre height relative to the undamaged wheel [m].
    """
    x = jnp.asarray(x)
    x = x.astype(jnp.result_type(x, float))  # keeps a float32 loop in float32
    if flat.kind == "none":
        return jnp.zeros_like(x)
    return _centre_trajectory(flat, x, _trajectory_window(flat), n_coarse, n_fine)


@partial(jax.jit, static_argnames=("window", "n_coarse", "n_fine"))
def _centre_trajectory(flat: Flat, x, window: float, n_coarse: int, n_fine: int):
    R = flat.wheel_radius
    kinks = _kink_angles(flat)

    def height(theta, phi):
        return wheel_radius_at(flat, theta) * jnp.cos(theta - phi)

    def one(phi):
        coarse = phi + jnp.linspace(-window, window, n_coarse)
        step = 2 * window / (n_coarse - 1)
        h_coarse = height(coarse, phi)
        best = jax.lax.stop_gradient(coarse[jnp.argmax(h_coarse)])
        fine = best + jnp.linspace(-2 * step, 2 * step, n_fine)
        theta = fine[jnp.argmax(height(fine, phi))]
        # Two Newton steps polish a smooth maximiser (so the envelope gradient is accurate);
        # max() below discards them where the maximiser is a kink instead. A step must stay
        # within the fine grid: next to a kink, or on a chord (height nearly linear, d2 ~ 0),
        # Newton throws theta far away, where r(theta) cos(theta - phi) is no point of the
        # wheel near the rail (a round radius at theta ~ phi + 2 pi k) and could win the max.
        for _ in range(2):
            d1 = jax.grad(height)(theta, phi)
            d2 = jax.grad(jax.grad(height))(theta, phi)
            new = theta - d1 / jnp.where(d2 < 0, d2, -1.0)
            theta = jnp.where((d2 < 0) & (new >= fine[0]) & (new <= fine[-1]), new, theta)
        fine = jnp.concatenate([fine, theta[None]])
        # Grid maximisers are held fixed (envelope theorem); kink angles move with the flat's
        # parameters, and the pivot height depends on that motion, so they keep their gradient.
        candidates = jnp.concatenate([jax.lax.stop_gradient(fine), kinks, phi[None]])
        return jnp.max(height(candidates, phi))

    H = jax.vmap(one)(x / R)
    return H - R
