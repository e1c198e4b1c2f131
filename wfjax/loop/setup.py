"""What the time loop computes before its scan: the discrete-step coefficients, the inputs in
the loop's precision (:class:`LoopSetup`) and the static equilibrium it starts from
(:class:`StaticStart`). :mod:`wfjax.loop.run` and :mod:`wfjax.loop.adjoint` read the same ones."""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..contact.newton import static_approach
from ..model import track as track_mod
from ..model.modal import discrete_step_coefficients
from .contacts import roughness_inputs, static_force, static_support_forces
from .structure import Structure, modal_loads, residual_matrix, shapes_fn

_NARROW = {np.dtype(np.float64): np.float32, np.dtype(np.complex128): np.complex64}


def cast_precision(tree, precision: str):
    """``tree`` with float64/complex128 array leaves cast to float32/complex64 when
    ``precision == "float32"`` (other leaves, and every leaf under ``"float64"``, unchanged).

    Python floats become float32 arrays too, so no float64 value promotes the loop back.
    """
    if precision == "float64":
        return tree

    def narrow(x):
        if isinstance(x, float):
            return jnp.asarray(x, jnp.float32)
        dtype = getattr(x, "dtype", None)
        if dtype is None or np.dtype(dtype) not in _NARROW:
            return x
        return jnp.asarray(x).astype(_NARROW[np.dtype(dtype)])

    return jax.tree.map(narrow, tree)


def widen(tree):
    """``tree`` with float32/complex64 array leaves cast to float64/complex128: the loop's
    outputs in the inputs' precision (a float32 loop's values keep float32's accuracy)."""
    wide = {np.dtype(v): k for k, v in _NARROW.items()}

    def up(x):
        dtype = getattr(x, "dtype", None)
        if dtype is None or np.dtype(dtype) not in wide:
            return x
        return x.astype(wide[np.dtype(dtype)])

    return jax.tree.map(up, tree)


class LoopSetup(NamedTuple):
    """What the time loop computes before its scan, in the loop's precision
    (:func:`loop_setup`; :func:`time_loop` and :mod:`wfjax.loop.adjoint` read the same one).

    Shapes: n = wheels, M = track modes, m = wheel modes. ``laws`` [n] (cast), ``struct``
    (cast), ``e_r, ap_r, an_r`` [M] (exp(pole dt) and first-order-hold weights of the
    track), ``e_w, ap_w, an_w`` [n, m] (the wheels'), ``preload`` [n] N, ``wheel_res``
    [n, m] m/(N s), ``c_wheel`` [n] m/N (each wheel's own compliance within the step),
    ``offsets``, ``delays`` [n] m (one wheel: [1] zeros), ``speed`` m/s, ``dt`` s,
    ``x_start``, ``impact_position`` m, ``roughness`` (cast, or None).
    """

    laws: tuple
    struct: Any
    e_r: Any
    ap_r: Any
    an_r: Any
    e_w: Any
    ap_w: Any
    an_w: Any
    preload: Any
    wheel_res: Any
    c_wheel: Any
    offsets: Any
    delays: Any
    speed: Any
    dt: Any
    x_start: Any
    impact_position: Any
    roughness: Any


def loop_setup(laws: tuple, struct: Structure, speed, dt, x_start, impact_position,
               precision: str, roughness=None) -> LoopSetup:
    """:class:`LoopSetup` of a run: the discrete-step coefficients of the track's and the
    wheels' poles (computed in the inputs' precision, then cast: see ``time_loop``'s
    ``precision``), the inputs cast to ``precision`` and the per-wheel arrays.

    Args: as :func:`time_loop` (``laws`` a tuple, one per wheel; ``precision`` static).
    """
    n_wheels = len(laws)
    wheel_poles = jnp.reshape(struct.wheel_poles, (n_wheels, -1))
    coefficients = (discrete_step_coefficients(struct.track.poles, dt),
                    discrete_step_coefficients(wheel_poles, dt))
    (laws, struct, coefficients, speed, dt, x_start, impact_position,
     roughness) = cast_precision((laws, struct, coefficients, speed, dt, x_start,
                                  impact_position, roughness), precision)
    (e_r, ap_r, an_r), (e_w, ap_w, an_w) = coefficients
    real = jnp.asarray(struct.preload).dtype  # the loop's precision
    wheel_res = jnp.reshape(struct.wheel_residues, (n_wheels, -1))
    offsets = jnp.zeros(1, real) if struct.offsets is None else struct.offsets
    delays = jnp.zeros(1, real) if struct.delays is None else struct.delays
    return LoopSetup(laws, struct, e_r, ap_r, an_r, e_w, ap_w, an_w,
                     jnp.reshape(struct.preload, (n_wheels,)), wheel_res,
                     jnp.real(jnp.sum(wheel_res * an_w, axis=-1)), offsets, delays, speed, dt,
                     x_start, impact_position, roughness)


def flat_coordinates(ls: LoopSetup, x_ref):
    """[n] every wheel's flat coordinate s [m] (0: its flat centre at the contact point) with
    the reference wheel at rail coordinate ``x_ref`` [m]: x_ref - impact_position - delays,
    taken to the nearest strike, s - C round(s / C), where the flats strike once per
    revolution of circumference C (``struct.revolutions``)."""
    s = x_ref - ls.impact_position - ls.delays
    c = ls.struct.revolutions
    return s if c is None else s - c * jnp.round(s / c)


class StaticStart(NamedTuple):
    """The loop's state at t = 0, the static equilibrium (F = P, the rail in its static
    deflected shape; :func:`static_start`).

    Shapes: n = wheels, M = track modes, n_s = hanging sleepers. ``s0`` [n] m (flat
    coordinates), ``x0`` [n] m (rail positions), ``phi0`` [n, M] complex (mode shapes there),
    ``q0`` [M] complex (the rail's static modal state), ``xi_r0`` [n] m (the rail under the
    wheels), ``delta0`` [n] m (the static approaches), ``xi_w_ref`` [n] m (the wheels'
    reference displacement, xi_r0 + delta0), ``supports``: () or, with hanging sleepers,
    (f_s0 [n_s] N: the one-sided ballast's static forces, upwards; e0 [n_s] m: the
    sleepers' closure).
    """

    s0: Any
    x0: Any
    phi0: Any
    q0: Any
    xi_r0: Any
    delta0: Any
    xi_w_ref: Any
    supports: tuple


def between_sleepers(sup, weight):
    """[n_s, n_s] m/N compliance between the hanging sleepers ``sup``: the kept modes
    weighted by ``weight`` [M] (w_r an_r within a step, w_r / -pole static) + the truncated
    ones."""
    psi = sup.shapes  # [n_s, M]
    return jnp.real(jnp.sum(weight * psi[:, None] * psi[None], axis=-1)) + sup.residual


def _hanging_start(ls: LoopSetup, q0, xi_r0, phi0):
    """The hanging sleepers' non-linear static start on top of the supported one (``q0``
    [M], ``xi_r0`` [n] m, ``phi0`` [n, M] without the ballast's forces): (q0, xi_r0, (f_s0
    [n_s] N, e0 [n_s] m)) with the one-sided ballast's static forces
    (:func:`static_support_forces`)."""
    model, sup = ls.struct.track, ls.struct.supports
    w_r, psi = model.weights, sup.shapes
    static_ss = between_sleepers(sup, w_r / -model.poles)
    r_ws0 = track_mod.read_residual_table(model, sup.residual_wheels, ls.x_start)  # [n, n_s]
    closure0 = (jnp.real(jnp.sum(psi * (w_r * q0), axis=-1)) + r_ws0.T @ ls.preload
                - sup.gap)
    f_s0 = static_support_forces(closure0, static_ss, sup.stiffness)
    q_s0 = (f_s0 @ psi) / model.poles
    xi_r0 = xi_r0 + jnp.real(jnp.sum(phi0 * (w_r * q_s0), axis=-1)) - r_ws0 @ f_s0
    return q0 + q_s0, xi_r0, (f_s0, closure0 - static_ss @ f_s0)


def static_start(ls: LoopSetup) -> StaticStart:
    """The loop's static start (:class:`StaticStart`) from its :class:`LoopSetup`:
    differentiable by plain autodiff (the contact's static approach by its implicit
    gradient; hanging sleepers by a fixed count of Newton iterations)."""
    model = ls.struct.track
    s0 = flat_coordinates(ls, ls.x_start)
    x0 = ls.x_start + ls.offsets
    phi0 = shapes_fn(model)(x0)
    q0 = -modal_loads(ls.preload, phi0) / model.poles
    xi_r0 = (jnp.real(jnp.sum(phi0 * (model.weights * q0), axis=-1))
             + residual_matrix(ls.struct, model, ls.x_start) @ ls.preload)
    supports = ()
    if ls.struct.supports is not None:  # hanging sleepers: a non-linear solve too
        q0, xi_r0, supports = _hanging_start(ls, q0, xi_r0, phi0)
    shift0, rough0 = roughness_inputs(ls.laws, ls.roughness, x0, s0)
    delta0 = jnp.stack([static_approach(static_force(lw, si, sh, ri), p)
                        for lw, si, p, sh, ri in zip(ls.laws, s0, ls.preload, shift0, rough0,
                                                     strict=True)])
    return StaticStart(s0, x0, phi0, q0, xi_r0, delta0, xi_r0 + delta0, supports)
