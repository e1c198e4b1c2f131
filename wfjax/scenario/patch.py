"""The roughness a wheel feels through its contact patch: rail (or wheel) roughness averaged over
the patch (elliptic-pressure-weighted or plain mean), the filter's response against wavelength,
the static Hertz contact length that sizes it, and the filtered roughness as the time loop
reads it (:class:`LoopRoughness`)."""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .roughness import Roughness, roughness_at

CONTACT_FILTERS = ("ellipse", "mean")


def _filter_rule(kind: str, n_points: int) -> tuple[np.ndarray, np.ndarray]:
    """Nodes t in (-1, 1) and weights (sum 1) of the weighted average over the patch."""
    if kind not in CONTACT_FILTERS:
        raise ValueError(f"kind must be one of {CONTACT_FILTERS}, got {kind!r}")
    if not isinstance(n_points, (int, np.integer)) or n_points < 2:
        raise ValueError(f"n_points must be an integer >= 2, got {n_points!r}")
    if kind == "ellipse":  # Gauss-Chebyshev (2nd kind): weight sqrt(1 - t^2)
        th = np.arange(1, n_points + 1) * np.pi / (n_points + 1)
        return np.cos(th), np.sin(th) ** 2 * (2 / (n_points + 1))
    t, w = np.polynomial.legendre.leggauss(int(n_points))
    return t, w / 2


def contact_filter(rough: Roughness, x, contact_length, kind: str = "ellipse",
                   n_points: int = 32) -> jax.Array:
    """Equivalent point-contact roughness: the profile averaged over the contact length.

    ``r_eq(x) = int r(x + s) w(s) ds / int w(s) ds`` over ``|s| <= a = contact_length / 2``
    (along the rolling direction; the roughness is transversely uniform).

    ``kind="ellipse"`` (default) weights by the width of the elliptical (Hertz) contact
    patch at ``s``, ``w = sqrt(1 - (s/a)^2)``: the change of force of a bed of independent
    linear springs over the patch (the distributed point reacting spring idea of Remington &
    Webb 1996, J. Sound Vib. 193, 83-102) under a transversely uniform roughness is
    ``k int r(s) width(s) ds``, so a point-contact law sees this mean. Its wavenumber response
    is ``2 J1(k a) / (k a)``, the contact filter of a circular patch for fully correlated
    roughness (cf. Remington 1987, J. Acoust. Soc. Am. 81, 1805-1823). ``kind="mean"`` is
    the plain average over the patch, response ``sin(k a) / (k a)``. Neither holds the
    transverse averaging of uncorrelated roughness (not modelled: roughness is uniform
    across the width here). See :func:`contact_filter_response`.

    Quadrature: ``n_points`` Gauss nodes across the patch (Gauss-Chebyshev of the 2nd kind
    for ``"ellipse"``, Gauss-Legendre for ``"mean"``) on the linearly interpolated profile
    (:func:`roughness_at`); keep ``n_points`` above the number of samples in the patch.

    Args:
        rough: the profile.
        x: contact positions [m], any shape (rail: rail coordinate; wheel: circumferential).
        contact_length: contact patch length 2a [m] in the rolling direction, broadcastable
            with ``x`` (it may be traced: it changes with the load every step).
        kind: ``"ellipse"`` or ``"mean"`` (static).
        n_points: quadrature nodes (static, >= 2).

    Returns:
        float array ``[*x.shape]`` (``[R, *x.shape]`` for batched values) [m]. Pure
        ``jax.numpy``: jit / vmap / grad in ``x``, ``contact_length`` and the values.
    """
    t, w = _filter_rule(kind, n_points)
    x = jnp.asarray(x, dtype=jnp.result_type(x, float))
    half = 0.5 * jnp.asarray(contact_length, dtype=x.dtype)
    pts = x[..., None] + half[..., None] * jnp.asarray(t, dtype=x.dtype)
    return jnp.sum(roughness_at(rough, pts) * jnp.asarray(w, dtype=x.dtype), axis=-1)


def contact_filter_response(wavelengths, contact_length, kind: str = "ellipse") -> np.ndarray:
    """Amplitude response of :func:`contact_filter` to a sinusoid of wavelength ``lambda``.

    ``2 J1(k a) / (k a)`` (``"ellipse"``) or ``sin(k a) / (k a)`` (``"mean"``) with
    ``k = 2 pi / lambda`` and ``a = contact_length / 2``; signed (negative lobes invert the
    sinusoid). NumPy; for documentation and tests.

    Args:
        wavelengths: [...] wavelengths [m]. contact_length: 2a [m].

    Returns:
        float [...] (dimensionless).
    """
    import scipy.special

    if kind not in CONTACT_FILTERS:
        raise ValueError(f"kind must be one of {CONTACT_FILTERS}, got {kind!r}")
    ka = 2 * np.pi / np.asarray(wavelengths, dtype=float) * (0.5 * float(contact_length))
    ka = np.where(ka == 0, 1e-300, ka)
    if kind == "ellipse":
        return 2 * scipy.special.j1(ka) / ka
    return np.sin(ka) / ka


# --------------------------------------------------------------------------------------------
# the time loop's roughness input
# --------------------------------------------------------------------------------------------
class LoopRoughness(NamedTuple):
    """Rail and wheel roughness as the time loop reads it (a pytree: ``time_loop(roughness=)``).

    Attributes:
        rail: :class:`Roughness` of the rail (``values [n]``), read at the rail coordinate
            ``x`` [m] of each wheel's nominal contact point, or None.
        wheel: :class:`Roughness` of the wheels (periodic, ``values [n]``), read at the
            circumferential coordinate ``s_w = s`` [m] (the wheel's flat coordinate: the
            distance rolled relative to the impact, so the tread point at ``s_w = 0`` meets
            the rail where the flat centre does), or None. A vehicle's wheels share it.
        contact_length: 2a [m], scalar or [n_wheels]: the length of the contact filter of the
            point-contact laws (:func:`static_contact_length`: the Hertz contact under the
            wheel's static load).
    """

    rail: Any = None
    wheel: Any = None
    contact_length: Any = 0.0


def static_contact_length(preload, material, radius) -> float:
    """Hertz contact length 2a [m] under the static wheel load (the contact filter's length).

    ``a = sqrt(R delta)`` with ``delta = (P / C_H)^(2/3)`` (equal radii ``R``; the time loop's
    Hertz radius ``sqrt(R_W R_R)``): 13.1 mm for 118 kN with R_W = 0.45 m, R_R = 0.30 m.
    The filter keeps this length through the run (see ``docs/real_track.md``: a
    load-dependent length would make the input depend on the step's unknown force; ``a``
    changes with ``F^(1/3)``).

    Args:
        preload: P [N] (scalar or [n_wheels]). material: :class:`wfjax.Material`.
        radius: equivalent radius [m].
    """
    from ..contact import hertz

    approach = hertz.approach_for_force(np.asarray(preload, dtype=float), material, radius)
    return np.asarray(2 * hertz.contact_radius(approach, radius))


def _parts(lr: LoopRoughness):
    return [(p, is_wheel) for p, is_wheel in ((lr.rail, False), (lr.wheel, True))
            if p is not None]


def loop_equivalent(lr: LoopRoughness, x, s) -> jax.Array:
    """Contact-filtered rail + wheel roughness [m] at the wheels' rail positions ``x`` [n] and
    flat coordinates ``s`` [n] (the approach offset of a point-contact law), shape [n]."""
    length = jnp.broadcast_to(jnp.asarray(lr.contact_length, dtype=x.dtype), x.shape)
    out = jnp.zeros_like(x)
    for part, is_wheel in _parts(lr):
        out = out + contact_filter(part, s if is_wheel else x, length)
    return out


def loop_at_nodes(lr: LoopRoughness, x, s, nodes) -> jax.Array:
    """Rail + wheel roughness [m] at offsets ``nodes`` [m] (relative to the nominal contact
    point, along the travel direction) of one wheel at rail position ``x`` and flat coordinate
    ``s`` (scalars): the element-by-element input of the 2D bedding and the direct 3D law,
    shape [n_nodes]."""
    nodes = jnp.asarray(nodes, dtype=jnp.result_type(x, float))
    out = jnp.zeros_like(nodes)
    for part, is_wheel in _parts(lr):
        out = out + roughness_at(part, (s if is_wheel else x) + nodes)
    return out
