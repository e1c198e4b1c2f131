"""The step's contact equation for every wheel (and hanging sleepers' one-sided ballast), and
the roughness each contact law sees."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..contact.newton import solve_contact_step, solve_contact_system, solve_small
from ..contact.protocol import ContactLaw
from ..scenario import patch


def pointwise(law: ContactLaw) -> bool:
    """Whether ``law`` solves its steps through :meth:`ContactLaw.step` (point/point_force)."""
    return type(law).step is ContactLaw.step


NEWTON_TOL = 1e-15  # m: the contact Newton's tolerance on |r| (wfjax.contact.newton's default)
FLOAT32_TOL_EPS = 8.0  # float32: |r| <= 8 eps32 max|delta_free| (its rounding floor, x a few)


def newton_tolerance(delta_free):
    """The step's contact Newton tolerance on |r| [m] for approaches ``delta_free`` [n] m.

    float64: :data:`NEWTON_TOL` (1e-15 m). float32: max(1e-15, 8 eps32 max|delta_free|).
    r = delta - delta_free + c F rounds at about eps32 |delta_free| in float32 (6e-11 m at a
    0.5 mm approach), so 1e-15 m is met only when an iterate happens to land on r = 0; the
    others ran to the iteration cap, and a batch (``vmap``) runs its Newton ``while_loop``
    until its last run converges: 30 iterations every step instead of 3, which made the
    float32 loop cost 0.68-0.95 of float64's (``benchmarks/README.md``, "Precision").
    """
    if jnp.dtype(delta_free.dtype) != jnp.dtype(jnp.float32):
        return NEWTON_TOL
    eps = float(jnp.finfo(jnp.float32).eps)
    return jnp.maximum(NEWTON_TOL, FLOAT32_TOL_EPS * eps * jnp.max(jnp.abs(delta_free)))


def _point_step(law, delta_free, compliance, s, max_iter: int, tol, roughness=None):
    """:meth:`ContactLaw.step` of a point law with the Newton tolerance ``tol`` [m]:
    (delta m, F N, |r| m)."""
    frozen = jax.lax.stop_gradient(law)
    point = law.point(s) if roughness is None else law.rough_point(s, roughness[0])
    point_ng = jax.lax.stop_gradient(point)
    return solve_contact_step(lambda d: law.point_force(point, d), delta_free, compliance,
                              max_iter, tol,
                              loop_force_fn=lambda d: frozen.point_force(point_ng, d))


def law_groups(laws: tuple) -> tuple:
    """Indices of the wheels that share one law object (e.g. every smooth wheel of a vehicle):
    each group's law is evaluated once, ``vmap``-ed over its wheels."""
    groups: dict[int, list[int]] = {}
    for i, law in enumerate(laws):
        groups.setdefault(id(law), []).append(i)
    return tuple(tuple(g) for g in groups.values())


def solve_contacts(laws: tuple, delta_free, compliance, s, states, max_iter: int,
                   groups: tuple | None = None, roughness=None, extra=None):
    """The step's n-contact equation delta = delta_free - C F(delta) for every contact law.

    One wheel: the law's own :meth:`ContactLaw.step` (a point law in float32: the same with
    :func:`newton_tolerance`). Several wheels with point laws (every
    model but the direct 3D mode): Newton over the n approaches
    (:func:`wfjax.contact.newton.solve_contact_system`, implicit-function gradients). Laws
    with their own step (the direct 3D mode, a forward reference) are coupled by
    Gauss-Seidel sweeps of their steps, each wheel seeing the others' current forces, until
    the forces change by less than 1e-9 relative.

    Args:
        laws: [n] prepared contact laws. delta_free: [n] approaches if F were 0 [m].
        compliance: C [n, n] [m/N]. s: [n] flat positions [m]. states: [n] law states.
        max_iter: Newton iteration cap (static).
        groups: :func:`law_groups` of ``laws`` (wheels that share a law; default: each
            wheel its own).
        roughness: None, or [n] per wheel: None (a point law: its roughness is already in
            ``delta_free``) or the pair (roughness at the law's :meth:`rough_nodes` [m], its
            contact-filtered value [m]).
        extra: None, or ``(force_fn, params)`` of n_e more contacts after the wheels (the
            hanging sleepers' ballast): ``force_fn(params, delta_e [n_e]) -> F [n_e]``; then
            ``delta_free`` and ``compliance`` cover n + n_e contacts, every law must be a
            point law, and the Newton directions are exact (the supports couple strongly).

    Returns:
        (delta [n] m, F [n] N, |r| [n] m, states); [n + n_e] with ``extra``.
    """
    rough = (None,) * len(laws) if roughness is None else roughness

    def kw(i):
        return {} if rough[i] is None else {"roughness": rough[i]}

    n = len(laws)
    tol = newton_tolerance(delta_free)
    if len(laws) == 1 and extra is None:
        (law,), (state,) = laws, states
        if pointwise(law) and tol is not NEWTON_TOL:  # float32
            delta, f, r = _point_step(law, delta_free[0], compliance[0, 0], s[0], max_iter,
                                      tol, **kw(0))
        else:
            delta, f, r, state = law.step(delta_free[0], compliance[0, 0], s[0], state,
                                          max_iter, **kw(0))
        return delta[None], f[None], r[None], (state,)
    if all(pointwise(law) for law in laws):
        groups = groups or tuple((i,) for i in range(len(laws)))
        order = np.argsort(np.concatenate([np.asarray(g) for g in groups]))
        reps = tuple(laws[g[0]] for g in groups)
        frozen = jax.lax.stop_gradient(reps)

        def group_points(law, g):
            if rough[g[0]] is None:
                return jax.vmap(law.point)(s[np.asarray(g)])
            values = jnp.stack([rough[i][0] for i in g])
            return jax.vmap(law.rough_point)(s[np.asarray(g)], values)

        points = [group_points(law, g) for law, g in zip(reps, groups, strict=True)]
        points_ng = jax.lax.stop_gradient(points)

        fn, params = extra if extra is not None else (None, None)
        params_ng = jax.lax.stop_gradient(params)

        def forces(ls, ps, delta, extra_params):
            parts = [jax.vmap(law.point_force)(p, delta[np.asarray(g)])
                     for law, p, g in zip(ls, ps, groups, strict=True)]
            wheels = jnp.concatenate(parts)[order]
            if fn is None:
                return wheels
            return jnp.concatenate([wheels, fn(extra_params, delta[n:])])

        delta, f, r = solve_contact_system(
            lambda d: forces(reps, points, d, params), delta_free, compliance, max_iter, tol,
            loop_force_fn=lambda d: forces(frozen, points_ng, d, params_ng),
            exact=extra is not None)
        return delta, f, r, states
    if extra is not None:
        raise ValueError("hanging sleepers (one-sided supports) need point contact laws, not "
                         "the direct 3D mode (a Kalker solve every step)")
    return _gauss_seidel(laws, delta_free, compliance, s, states, max_iter, kw)


def _gauss_seidel(laws, delta_free, compliance, s, states, max_iter, kw, sweeps: int = 20):
    """Gauss-Seidel over the wheels of laws with their own step (no gradients)."""
    diag = jnp.diagonal(compliance)

    def one_sweep(carry):
        delta, f, r, states, _, it = carry
        f_old = f
        new_states = []
        for i, law in enumerate(laws):
            coupling = compliance[i] @ f - diag[i] * f[i]
            d_i, f_i, r_i, st = law.step(delta_free[i] - coupling, diag[i], s[i], states[i],
                                         max_iter, **kw(i))
            delta, f, r = delta.at[i].set(d_i), f.at[i].set(f_i), r.at[i].set(r_i)
            new_states.append(st)
        change = jnp.max(jnp.abs(f - f_old)) / jnp.maximum(jnp.max(jnp.abs(f)), 1.0)
        return delta, f, r, tuple(new_states), change, it + 1

    zeros = jnp.zeros_like(delta_free)
    carry = (delta_free, zeros, zeros, tuple(states), jnp.ones_like(delta_free[0]), 0)
    delta, f, r, states, *_ = jax.lax.while_loop(
        lambda c: (c[4] > 1e-9) & (c[5] < sweeps), one_sweep, carry)
    return delta, f, r, states


def roughness_inputs(laws, roughness, x, s):
    """(approach offsets [n] m, per-wheel element inputs) of the roughness at the wheels'
    rail positions ``x`` [n] and flat coordinates ``s`` [n]: a point law's offset is the
    contact-filtered roughness (its element input None); a law with ``rough_nodes`` gets
    offset 0 and the pair (roughness at its nodes, the filtered value)."""
    if roughness is None:
        return (0.0,) * len(laws), (None,) * len(laws)
    r_eq = patch.loop_equivalent(roughness, x, s)
    shift, rough = [], []
    for i, law in enumerate(laws):
        nodes = law.rough_nodes()
        if nodes is None:
            shift.append(r_eq[i])
            rough.append(None)
        else:
            shift.append(jnp.zeros_like(r_eq[i]))
            rough.append((patch.loop_at_nodes(roughness, x[i], s[i], nodes), r_eq[i]))
    return jnp.stack(shift), tuple(rough)


def static_force(law, s, shift, rough):
    """F(d) [N] of ``law`` at kinematic approach d (xi_W - xi_R) [m] with roughness: the
    static start (a law with its own step, the direct 3D mode, starts on its table)."""
    if rough is None:
        return lambda d: law.force(d + shift, s)
    if not pointwise(law):
        return lambda d: law.force(d + rough[1], s)
    point = law.rough_point(s, rough[0])
    return lambda d: law.point_force(point, d)


def support_force(params, closure):
    """Force [N] (upwards on the sleeper) of hanging sleepers' one-sided ballast, [n_s].

    F = max(0, k_B e+ + c_B (e+ - e_prev+) / dt) with e+ = max(closure, 0) [m]: no force while
    the gap is open, compression only, the damping on the step's change of e+ (continuous at
    closure, non-decreasing in ``closure``). ``params`` = (e_prev [n_s] m, k_B [n_s] N/m,
    c_B [n_s] N s/m, dt s)."""
    e_prev, stiffness, damping, dt = params
    e = jnp.maximum(closure, 0.0)
    return jnp.maximum(0.0, stiffness * e + damping * (e - jnp.maximum(e_prev, 0.0)) / dt)


def static_support_forces(closure_free, compliance, stiffness, iterations: int = 30):
    """Static one-sided ballast forces [N] [n_s]: e = e_free - C k e+ solved by Newton with
    exact directions (piecewise linear and monotone: the active set settles in a few
    iterations; a fixed count keeps reverse mode possible). ``closure_free`` [n_s] m: the
    sleepers' closure with no support force; ``compliance`` [n_s, n_s] m/N static."""
    eye = jnp.eye(closure_free.shape[0], dtype=closure_free.dtype)

    def body(_, e):
        active = (e > 0).astype(e.dtype)
        r = e - closure_free + compliance @ (stiffness * active * e)
        return e - solve_small(eye + compliance * (stiffness * active)[None, :], r)

    e = jax.lax.fori_loop(0, iterations, body, closure_free)
    return stiffness * jnp.maximum(e, 0.0)
