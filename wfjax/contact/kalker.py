"""3D non-Hertzian normal contact: Kalker's problem on an elastic half-space (Section 3.3.1).

The potential contact area is a rectangular grid of ``nx x ny`` elements of size ``dx x dy``
(x: rolling direction, y: transverse). Each element carries a uniform pressure p_e; the
combined normal surface displacement of wheel and rail (both of the same material) is
u = C p (Eq. 6), with the influence coefficients of Love (1929) for uniform pressure on a
rectangle and the combined modulus 1/E* = 2 (1 - nu^2) / E. With ``gap`` the undeformed
distance of the surfaces (Eq. 9 without the displacements) and ``delta`` the approach of the
bodies (> 0 compresses), the deformed distance is h = gap - delta + C p and the contact
conditions are h >= 0, p >= 0, h p = 0 (Eq. 8). The total force is F = A_e sum(p) (Eq. 7).

Numerics
--------
* ``C p`` is a discrete 2D convolution with a kernel of (2 nx - 1) x (2 ny - 1) coefficients.
  It is evaluated exactly (no periodic images) with a zero-padded 2D FFT of size
  mx x my >= (2 nx - 1) x (2 ny - 1) (circulant embedding; the next even 5-smooth lengths,
  2-3x faster than 2 nx x 2 ny when nx has a large prime factor). :func:`dense_matrix` gives
  the same operator as a matrix for small grids (test reference).
* The solver is an active-set method (Kalker's NORM; Vollebregt's active-set strategy): on the
  current active set A solve C_AA p_A = delta - gap_A with conjugate gradients (approach
  control) or the same system plus sum(p_A) = F / A_e with projected conjugate gradients
  (force control; delta becomes the Lagrange multiplier); then release elements with negative
  pressure and admit elements that penetrate, until the set does not change. A cold start is a
  warm start from p = 0 (the first pass admits the rigid overlap, a superset of the contact).
  Everything runs under ``lax.while_loop`` with a fixed-shape state, so ``solve`` works under
  ``jit``, ``vmap`` and inside ``lax.scan``.
* Internally pressures are scaled by E* (q = p / E*, dimensionless), so the iteration is
  independent of the material and the material enters through one differentiable factor.
* Gradients: the converged pressures are re-attached to the inputs through
  ``jax.custom_vjp`` rules that solve the adjoint system on the converged active set (the
  implicit function theorem; the loop is never unrolled). The active set is held fixed, which
  is exact wherever the solution is differentiable (no element exactly at the contact edge).
* Contact stiffness dF/d delta = A_e E* 1^T (C0_AA)^-1 1 [N/m] (one more CG solve), with C0
  the influence matrix for E* = 1. Its own gradient is not propagated (``stop_gradient``).

References: Love, Phil. Trans. R. Soc. A 228 (1929); Johnson, Contact Mechanics (1985) Sec. 3.2;
Kalker, Three-dimensional elastic bodies in rolling contact (1990); Vollebregt, J. Optim.
Theory Appl. 162 (2014).
"""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..params import Material
from .influence import check_element_size, combined_modulus, unit_operator, unit_preconditioner

__all__ = [
    "Diagnostics",
    "KalkerResult",
    "combined_modulus",
    "solve",
]

_DEFAULT_MATERIAL = Material()
LOOSE_TOL = 1e-4  # CG tolerance while the active set is still changing (1e-3: 6 % more CG
# iterations in the default sweep's table builds, later sets less settled; 1e-5: 3 % more)
MIN_ELEMENTS_ACROSS = 6  # elements across the contact required by the eager validation


# ----------------------------------------------------------------------------------------
# Influence coefficients
# ----------------------------------------------------------------------------------------


# ----------------------------------------------------------------------------------------
# Conjugate gradients on the active set
# ----------------------------------------------------------------------------------------


def _dot(a, b):
    return jnp.sum(a * b)


def _cg(op, b, x0, mask, tol, max_iter, prec=None, u0=None):
    """Solve C_AA x_A = b_A (x = 0 off A) by preconditioned CG from x0.

    ``prec`` (default identity) approximates C^-1 on the whole grid; it is applied as
    mask * prec(mask * r), symmetric positive on the active set. The stopping test is on the
    unpreconditioned residual |r| <= tol |b_A| either way. The displacement u = op(x) on the
    whole grid is carried along (u += alpha op(d)), so the caller need not apply the operator
    again; ``u0`` = op(x0) when the caller has it (saves the starting application). The
    preconditioner is applied at the top of each iteration, so none is spent on the final
    residual. Returns (x, iterations, converged, u).
    """
    prec = _identity if prec is None else prec
    x = mask * x0
    u = op(x) if u0 is None else u0
    r = mask * (b - u)
    bb = _dot(mask * b, mask * b)
    thresh = tol**2 * bb

    def cond(s):
        return (s[5] > thresh) & (s[6] < max_iter)

    def body(s):
        x, u, r, d, rz, _, k = s
        z = mask * prec(r)
        rz_new = _dot(r, z)
        d = z + (rz_new / rz) * d  # d = 0 on entry: the first direction is z
        od = op(d)
        ad = mask * od
        alpha = rz_new / _dot(d, ad)
        x = x + alpha * d
        u = u + alpha * od
        r = r - alpha * ad
        return x, u, r, d, rz_new, _dot(r, r), k + 1

    one = jnp.ones((), r.dtype)
    x, u, _, _, _, rr, k = jax.lax.while_loop(
        cond, body, (x, u, r, jnp.zeros_like(r), one, _dot(r, r), jnp.int32(0)))
    return x, k, rr <= thresh, u


def _identity(v):
    return v


def _cg_fixed_sum(op, g, total, x0, mask, tol, max_iter, prec=None):
    """Solve C_AA x_A = mu 1 - g_A with sum(x) = total by projected (preconditioned) CG.

    The search stays in {sum(x) = total} through the projection P onto zero-sum vectors on
    the active set; the preconditioner is applied as P prec(P r) (``prec`` default identity).
    Returns (x, mu, iterations, converged); mu is the Lagrange multiplier (the approach in the
    forward problem).
    """
    prec = _identity if prec is None else prec
    n = jnp.maximum(jnp.sum(mask), 1.0)

    def proj(v):
        v = mask * v
        return mask * (v - jnp.sum(v) / n)

    x = mask * x0
    x = x + mask * (total - jnp.sum(x)) / n
    cx = op(x)
    r = proj(-g - cx)
    ref = _dot(mask * cx, mask * cx) + _dot(proj(g), proj(g))
    thresh = tol**2 * ref

    def cond(s):
        return (s[4] > thresh) & (s[5] < max_iter)

    def body(s):  # as in _cg: the preconditioner at the top, none on the final residual
        x, r, d, rz, _, k = s
        z = proj(prec(r))
        rz_new = _dot(r, z)
        d = z + (rz_new / rz) * d
        cd = op(d)
        alpha = rz_new / _dot(d, cd)
        x = x + alpha * d
        r = r - alpha * proj(cd)
        return x, r, d, rz_new, _dot(r, r), k + 1

    one = jnp.ones((), r.dtype)
    x, _, _, _, rr, k = jax.lax.while_loop(
        cond, body, (x, r, jnp.zeros_like(r), one, _dot(r, r), jnp.int32(0)))
    mu = jnp.sum(mask * (op(x) + g)) / n
    return x, mu, k, rr <= thresh


# ----------------------------------------------------------------------------------------
# Implicit differentiation: re-attach the converged solution to its inputs
# ----------------------------------------------------------------------------------------


class _Config(NamedTuple):
    nx: int
    ny: int
    dx: float
    dy: float
    method: str
    tol: float
    cg_max_iter: int
    precondition: bool = True

    def op(self):
        return unit_operator(self.nx, self.ny, self.dx, self.dy, self.method)

    def prec(self):
        """The CG preconditioner (None: plain CG)."""
        return (unit_preconditioner(self.nx, self.ny, self.dx, self.dy) if self.precondition
                else None)


@functools.partial(jax.custom_vjp, nondiff_argnums=(0,))
def _attach_approach(cfg: _Config, g, delta, q_star, maskf):
    """Identity on the converged q_star; VJP from C_AA q_A = delta - g_A (q = p / E*)."""
    del g, delta, maskf
    return q_star


def _attach_approach_fwd(cfg, g, delta, q_star, maskf):
    return q_star, (maskf, g, delta)


def _attach_approach_bwd(cfg, res, q_bar):
    maskf, g, delta = res
    lam, _, _, _ = _cg(cfg.op(), maskf * q_bar, jnp.zeros_like(q_bar), maskf, cfg.tol,
                    cfg.cg_max_iter, cfg.prec())
    return (-lam, jnp.sum(lam).astype(jnp.result_type(delta)), jnp.zeros_like(q_bar),
            jnp.zeros_like(maskf))


_attach_approach.defvjp(_attach_approach_fwd, _attach_approach_bwd)


@functools.partial(jax.custom_vjp, nondiff_argnums=(0,))
def _attach_force(cfg: _Config, g, total, q_star, delta_star, maskf):
    """Identity on (q_star, delta_star); VJP from C_AA q_A - delta = -g_A, sum(q) = total."""
    del g, total, maskf
    return q_star, delta_star


def _attach_force_fwd(cfg, g, total, q_star, delta_star, maskf):
    return (q_star, delta_star), (maskf, total)


def _attach_force_bwd(cfg, res, cot):
    # Adjoint of J = [[C, -1], [1^T, 0]]: solve J^T w = (q_bar, delta_bar), i.e.
    # C w1 + w2 = q_bar, -sum(w1) = delta_bar; then g_bar = -w1, total_bar = w2.
    maskf, total = res
    q_bar, delta_bar = cot
    w1, mu, _, _ = _cg_fixed_sum(cfg.op(), -maskf * q_bar, -delta_bar, jnp.zeros_like(q_bar),
                                 maskf, cfg.tol, cfg.cg_max_iter, cfg.prec())
    return (-w1, (-mu).astype(jnp.result_type(total)), jnp.zeros_like(q_bar),
            jnp.zeros_like(delta_bar), jnp.zeros_like(maskf))


_attach_force.defvjp(_attach_force_fwd, _attach_force_bwd)


# ----------------------------------------------------------------------------------------
# Active-set iteration
# ----------------------------------------------------------------------------------------


class Diagnostics(NamedTuple):
    """Solver diagnostics (arrays, so they survive ``jit``/``vmap``).

    Attributes:
        iterations: active-set (outer) iterations, int32.
        cg_iterations: conjugate-gradient iterations summed over the outer iterations, int32.
        residual: complementarity residual of Eq. (8), dimensionless:
            max_e |min(p_e / max(p), h_e / h_ref)| with h the deformed distance and
            h_ref = delta - min(gap) (the rigid overlap depth). 0 at an exact solution.
        converged: True when the active set settled and CG met its tolerance within the
            iteration limits.
    """

    iterations: Any
    cg_iterations: Any
    residual: Any
    converged: Any


class KalkerResult(NamedTuple):
    """Result of :func:`solve`.

    Attributes:
        pressure: [nx, ny] contact pressure [Pa].
        force: total normal force F = A_e sum(p) [N] (Eq. 7).
        approach: approach delta [m] (the input for approach control, the solution for force
            control).
        contact: [nx, ny] bool, elements in contact (active set).
        stiffness: contact stiffness dF/d delta [N/m] at the solution (no gradient).
        diagnostics: :class:`Diagnostics`.
    """

    pressure: Any
    force: Any
    approach: Any
    contact: Any
    stiffness: Any
    diagnostics: Diagnostics


def _active_set_loop(cfg: _Config, g, target, q0, mask0, force_mode: bool, max_iter: int,
                     z0=None):
    """Outer active-set loop on q = p / E*. Returns (q, mask, delta, u, z, outer, cg, ok).

    Inexact-Newton flavour: while the active set still changes, CG stops at the loose
    tolerance ``LOOSE_TOL`` (the set update only needs the sign pattern); once the set has
    been stable once, the CG stays at ``cfg.tol`` and the set is checked again after every
    solve. Under approach control the displacement u = C q comes out of the CG; admitting
    elements (q = 0 there) leaves it unchanged, and only releasing elements costs an operator
    application, so an outer iteration costs its CG iterations and little more.

    With ``z0`` (approach control only) the stiffness solve C_AA z = 1_A on the final set runs
    as one more pass of the loop from ``z0``, through the same CG: one CG loop to compile, not
    two; ``ok`` then includes its convergence and ``outer`` leaves the pass out. ``z`` is None
    without it.
    """
    op, prec = cfg.op(), cfg.prec()
    loose = max(cfg.tol, LOOSE_TOL)
    gmin = jnp.min(g)
    fold = z0 is not None

    def inner(s, tol):
        q, u, mask, delta = s["q"], s["u"], s["mask"], s["delta"]
        if force_mode:
            q, delta, k, ok = _cg_fixed_sum(op, g, target, q, mask, tol, cfg.cg_max_iter,
                                            prec)
            return q, op(q), delta, k, ok
        rhs = delta - g
        if fold:  # the stiffness pass: 1_A from z (its displacement computed then only)
            zp = s["z_pass"]
            rhs, q = jnp.where(zp, mask, rhs), jnp.where(zp, s["z"], q)
            u = jax.lax.cond(zp, lambda: op(mask * s["z"]), lambda: u)
        q, k, ok, u = _cg(op, rhs, q, mask, tol, cfg.cg_max_iter, prec, u0=u)
        return q, u, delta, k, ok

    def cond(s):
        more = s["it"] < max_iter
        return (~s["done"]) & ((more | s["z_pass"]) if fold else more)

    def body(s):
        zp = s["z_pass"] if fold else jnp.bool_(False)
        tol = jnp.where(s["tight"] | zp, cfg.tol, loose)
        x, ux, delta, k, ok = inner(s, tol)
        q, u = jnp.where(zp, s["q"], x), jnp.where(zp, s["u"], ux)
        h = g - delta + u
        qmax = jnp.max(q)
        href = jnp.maximum(delta - gmin, 0.0)
        set_tol = 10.0 * tol
        active = s["mask"] > 0
        neg = active & (q < -set_tol * qmax) & ~zp
        pen = (~active) & (h < -set_tol * href) & ~zp
        new_active = (active & ~neg) | pen
        maskf = new_active.astype(q.dtype)
        changed = jnp.any(neg | pen)
        done = ~changed & ok & s["tight"]
        if not force_mode:  # u of the released pressures leaves with them
            u = jax.lax.cond(jnp.any(neg), lambda: u - op(q * neg), lambda: u)
        out = dict(q=q * maskf, mask=maskf, delta=delta, u=u,
                   it=s["it"] + jnp.where(zp, 0, 1).astype(s["it"].dtype), cg=s["cg"] + k,
                   done=done, tight=s["tight"] | ~changed)
        if fold:  # after the set has settled (or run out of passes), the stiffness pass
            out.update(done=zp, ok=jnp.where(zp, s["ok"] & ok, done), z=jnp.where(zp, x, s["z"]),
                       z_pass=~zp & (done | (out["it"] >= max_iter)))
        return out

    delta0 = jnp.zeros((), g.dtype) if force_mode else jnp.asarray(target, g.dtype)
    q0 = q0 * mask0
    state = dict(q=q0, mask=mask0, delta=delta0, u=jnp.zeros_like(g) if force_mode else op(q0),
                 it=jnp.int32(0), cg=jnp.int32(0), done=jnp.bool_(False),
                 tight=jnp.bool_(False))
    if fold:
        state.update(z=z0, z_pass=jnp.bool_(False), ok=jnp.bool_(False))
    s = jax.lax.while_loop(cond, body, state)
    return (s["q"], s["mask"], s["delta"], s["u"], s["z"] if fold else None, s["it"], s["cg"],
            s["ok"] if fold else s["done"])


def _residual(q, h, delta, gmin):
    qref = jnp.maximum(jnp.max(q), jnp.finfo(q.dtype).tiny)
    href = jnp.maximum(delta - gmin, jnp.finfo(q.dtype).tiny)
    return jnp.max(jnp.abs(jnp.minimum(q / qref, h / href)))


def _solve_impl(cfg: _Config, g, material, approach, force, p_init, max_iter, stiffness,
                force_mode, z_init=None):
    """The solver (traceable). Returns (KalkerResult, z) with z = C0_AA^-1 1 [1/m] (or zeros).

    ``z_init`` warm-starts the stiffness solve (used by the table builder's sweeps).
    """
    estar = combined_modulus(material)
    area = cfg.dx * cfg.dy
    g = jnp.asarray(g)
    dtype = jnp.result_type(g.dtype, float)
    g = g.astype(dtype)
    g_sg = jax.lax.stop_gradient(g)
    q0 = (jnp.zeros_like(g) if p_init is None
          else jax.lax.stop_gradient(jnp.maximum(jnp.asarray(p_init, dtype), 0.0) / estar))
    warm = q0 > 0
    if force_mode:
        total = jnp.asarray(force, dtype) / (area * estar)
        # Force control needs a non-empty start: the lowest point when there is no warm start.
        mask0 = jnp.where(jnp.any(warm), warm, g_sg <= jnp.min(g_sg)).astype(dtype)
        target = jax.lax.stop_gradient(total)
    else:
        delta_in = jnp.asarray(approach, dtype)
        mask0 = warm.astype(dtype)
        target = jax.lax.stop_gradient(delta_in)
    fold = stiffness and not force_mode  # the stiffness solve as the set loop's last pass
    z_start = None if not stiffness else jnp.zeros_like(g_sg) if z_init is None else (
        jax.lax.stop_gradient(jnp.asarray(z_init, dtype)))
    q, maskf, delta, u, z, it, cg_it, conv = _active_set_loop(
        cfg, g_sg, target, jax.lax.stop_gradient(q0), mask0, force_mode, max_iter,
        z_start if fold else None)  # z_start: None without the stiffness solve
    q = jnp.maximum(q, 0.0) * maskf
    h = g_sg - delta + u
    residual = _residual(q, h, delta, jnp.min(g_sg))
    if force_mode:
        q, delta = _attach_force(cfg, g, total, q, delta, maskf)
    else:
        q = _attach_approach(cfg, g, delta_in, q, maskf)
        delta = delta_in
    pressure = estar * q
    force_out = area * jnp.sum(pressure)
    if stiffness:
        if not fold:  # force control: the stiffness solve after the set loop
            z, k2, ok2, _ = _cg(cfg.op(), maskf, z_start, maskf, cfg.tol, cfg.cg_max_iter,
                                cfg.prec())
            cg_it, conv = cg_it + k2, conv & ok2
        stiff = jax.lax.stop_gradient(area * estar * jnp.sum(z))
    else:
        z = jnp.zeros_like(q)
        stiff = jnp.full((), jnp.nan, dtype)
    diag = Diagnostics(iterations=it, cg_iterations=cg_it, residual=residual, converged=conv)
    result = KalkerResult(pressure=pressure, force=force_out, approach=delta,
                          contact=maskf > 0, stiffness=stiff, diagnostics=diag)
    return result, jax.lax.stop_gradient(z)


# ----------------------------------------------------------------------------------------
# Validation helpers (concrete inputs only)
# ----------------------------------------------------------------------------------------


def _is_concrete(x) -> bool:
    return not isinstance(x, jax.core.Tracer)


def _is_concrete_tree(tree) -> bool:
    """No leaf of ``tree`` is a tracer (the inputs are numbers, not traced values)."""
    return all(_is_concrete(v) for v in jax.tree_util.tree_leaves(tree))


def _validate_inputs(gap, approach, force, p_init):
    if gap.ndim != 2 or min(gap.shape) < 2:
        raise ValueError(
            f"gap must be a 2-D array [nx, ny] with nx, ny >= 2, got shape {gap.shape}")
    if _is_concrete(gap) and not bool(np.all(np.isfinite(np.asarray(gap)))):
        raise ValueError("gap contains NaN or inf values (it must be finite, in m)")
    for name, v in (("approach", approach), ("force", force)):
        if v is not None and _is_concrete(v) and not np.all(np.isfinite(np.asarray(v))):
            raise ValueError(f"{name} must be finite, got {v!r}")
    if force is not None and _is_concrete(force) and np.any(np.asarray(force) <= 0):
        raise ValueError(f"force must be > 0 N for force control, got {force!r}")
    if p_init is not None and tuple(np.shape(p_init)) != tuple(gap.shape):
        raise ValueError(f"p_init must have the gap's shape {gap.shape}, got {np.shape(p_init)}")


def _check_resolution(result: KalkerResult, dx: float, dy: float) -> None:
    """Eager post-check: the grid resolves the contact and contains it."""
    contact = np.asarray(result.contact)
    if not contact.any():
        return
    rows = np.flatnonzero(contact.any(axis=1))
    cols = np.flatnonzero(contact.any(axis=0))
    nx_c, ny_c = rows[-1] - rows[0] + 1, cols[-1] - cols[0] + 1
    if min(nx_c, ny_c) < MIN_ELEMENTS_ACROSS:
        raise ValueError(
            f"grid too coarse for the contact: it spans {nx_c} x {ny_c} elements "
            f"(dx = {dx * 1e3:.3g} mm, dy = {dy * 1e3:.3g} mm); at least {MIN_ELEMENTS_ACROSS} "
            "elements across are needed: reduce dx/dy (or pass validate=False)"
        )
    if contact[0].any() or contact[-1].any() or contact[:, 0].any() or contact[:, -1].any():
        raise ValueError(
            "gap grid too small: the contact reaches the edge of the potential contact area; "
            "enlarge the grid (see contact_grid) or pass validate=False"
        )


# ----------------------------------------------------------------------------------------
# Public solver
# ----------------------------------------------------------------------------------------


def solve(gap, dx: float, dy: float, material: Material = _DEFAULT_MATERIAL, approach=None,
          force=None, p_init=None, tol: float = 1e-10, max_iter: int = 50, cg_max_iter: int = 1000,
          method: str = "fft", stiffness: bool = True, validate: bool = True) -> KalkerResult:
    """Solve the 3D normal contact problem (Eqs. 6-9), approach- or force-controlled.

    Args:
        gap: [nx, ny] undeformed distance of the surfaces [m] on the element centres (e.g.
            :func:`gap_3d`). Differentiable.
        dx, dy: element size [m] along x and y (concrete Python numbers; static).
        material: wheel and rail material.
        approach: approach delta [m] (> 0 compresses); exactly one of approach/force.
            Differentiable.
        force: total normal force F [N] (> 0). Differentiable.
        p_init: [nx, ny] warm start [Pa] (e.g. the previous solution); its positive entries
            are the initial active set. ``None``: cold start.
        tol: relative tolerance of the CG solves (residual norm over right-hand side norm);
            the active-set thresholds are 10 * tol relative to max(p) and delta - min(gap).
        max_iter: maximum active-set iterations (static).
        cg_max_iter: maximum CG iterations per solve (static).
        method: ``"fft"`` (default) or ``"dense"`` influence operator (static).
        stiffness: compute dF/d delta (one more CG solve); NaN when False (static).
        validate: with concrete inputs, check the result resolves and fits in the grid (raise
            ``ValueError`` otherwise). Skipped under ``jit``/``vmap``.

    Returns:
        :class:`KalkerResult` (pressure [nx, ny] Pa, force N, approach m, contact mask,
        stiffness N/m, diagnostics). Non-convergence is reported in
        ``result.diagnostics.converged`` (the result is then the last iterate, finite).

    Raises:
        ValueError: non-positive or non-concrete element size, NaN gap, neither or both of
            approach/force, non-positive force, grid too coarse for (or too small to contain)
            the contact.
    """
    if (approach is None) == (force is None):
        raise ValueError("pass exactly one of approach= (m) or force= (N)")
    dx, dy = check_element_size(dx, dy)
    gap = jnp.asarray(gap) if not isinstance(gap, jax.core.Tracer) else gap
    _validate_inputs(gap, approach, force, p_init)
    if not (0 < tol < 1):
        raise ValueError(f"tol must be in (0, 1), got {tol!r}")
    if int(max_iter) < 1:
        raise ValueError(f"max_iter must be >= 1, got {max_iter!r}")
    nx, ny = gap.shape
    cfg = _Config(int(nx), int(ny), dx, dy, method, float(tol), int(cg_max_iter))
    result = _solve_jit(cfg, gap, material, approach, force, p_init, int(max_iter),
                        bool(stiffness), force is not None)
    if validate and _is_concrete_tree((gap, material, approach, force, p_init)):
        _check_resolution(result, dx, dy)
    return result


@functools.partial(jax.jit, static_argnums=(0, 6, 7, 8))
def _solve_jit(cfg, gap, material, approach, force, p_init, max_iter, stiffness, force_mode):
    return _solve_impl(cfg, gap, material, approach, force, p_init, max_iter, stiffness,
                       force_mode)[0]


# ----------------------------------------------------------------------------------------
# Geometry of the 3D contact (Eq. 9)
# ----------------------------------------------------------------------------------------


