"""The scalar contact equation of one time step, solved for every contact law.

Within a step the structure (wheel and rail) responds to the contact force F through a scalar
compliance c [m/N], so the step's unknown approach delta [m] solves

    r(delta) = delta - delta_free + c F(delta) = 0,

with delta_free the approach if F were zero. r is increasing in delta for every law here
(F is non-decreasing in delta). :func:`bracketed_newton` solves it without gradients;
:func:`solve_contact_step` attaches exact first derivatives by the implicit function theorem
(one Newton step from the converged root with the root and the slope held fixed), so
reverse-mode autodiff never enters the ``while_loop``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = ["bracketed_newton", "solve_contact_step", "static_approach", "newton_system",
           "solve_contact_system", "solve_small"]


def bracketed_newton(evaluate, delta_free, compliance, aux0, max_iter: int = 30,
                     tol: float = 1e-15):
    """Root of r(delta) = delta - delta_free + c F(delta) (increasing), no gradients.

    Newton iteration started from delta_free (where r >= 0), bisection whenever a step leaves
    the bracket [delta_free - c F(delta_free), delta_free]. For a convex F the Newton iterates
    decrease monotonically to the root.

    Args:
        evaluate: (delta, aux) -> (F [N], dF/d delta [N/m], aux); ``aux`` carries solver state
            such as a warm start.
        delta_free: approach if F were zero [m]. compliance: c > 0 [m/N].
        aux0: initial ``aux``. max_iter: iteration cap (static). tol: tolerance on r [m].

    Returns:
        (delta [m], |r| [m], aux).
    """
    def residual(delta, aux):
        f, df, aux = evaluate(delta, aux)
        return delta - delta_free + compliance * f, 1.0 + compliance * df, aux

    def cond(state):
        return (jnp.abs(state[3]) > tol) & (state[4] < max_iter)

    def body(state):
        delta, lo, hi, _, it, aux = state
        r, dr, aux = residual(delta, aux)
        lo = jnp.where(r < 0, delta, lo)
        hi = jnp.where(r >= 0, delta, hi)
        step = delta - r / dr
        inside = (step >= lo) & (step <= hi)
        new = jnp.where(inside, step, 0.5 * (lo + hi))
        new = jnp.where(jnp.abs(r) <= tol, delta, new)  # converged: keep the evaluated iterate
        return new, lo, hi, r, it + 1, aux

    f_free, _, aux = evaluate(delta_free, aux0)
    r0 = compliance * f_free
    lo0 = delta_free - r0 - 1e-12
    state = (delta_free, lo0, delta_free, r0, 0, aux)
    delta, _, _, r, _, aux = jax.lax.while_loop(cond, body, state)
    return delta, jnp.abs(r), aux


def solve_contact_step(force_fn, delta_free, compliance, max_iter: int = 30, tol: float = 1e-15,
                       loop_force_fn=None):
    """Solve delta = delta_free - compliance * F(delta) for the approach delta [m].

    :func:`bracketed_newton` on r(delta), made differentiable by the implicit function
    theorem: one Newton step from the converged iterate with the iterate and the slope held
    fixed (exact first derivatives at the root).

    Args:
        force_fn: F(delta) [N], scalar -> scalar, jax-differentiable.
        delta_free: approach if F were zero [m]. compliance: c > 0 [m/N].
        max_iter: iteration cap (static). tol: absolute tolerance on r [m].
        loop_force_fn: ``force_fn`` with its parameters under ``stop_gradient``, used inside
            the ``while_loop`` so reverse-mode autodiff never has to enter the loop (default:
            ``force_fn``; pass it whenever ``force_fn`` closes over differentiated values).

    Returns:
        (delta [m], F [N], |r| [m]).
    """
    loop_force_fn = loop_force_fn or force_fn

    def evaluate(delta, aux):
        f, df = jax.value_and_grad(loop_force_fn)(delta)
        return f, df, aux

    d_free = jax.lax.stop_gradient(delta_free)
    c = jax.lax.stop_gradient(compliance)
    delta_star, r_abs, _ = bracketed_newton(evaluate, d_free, c, None, max_iter, tol)
    delta_star = jax.lax.stop_gradient(delta_star)
    f_star, df_star = jax.value_and_grad(force_fn)(delta_star)
    r_star = delta_star - delta_free + compliance * f_star
    delta = delta_star - r_star / jax.lax.stop_gradient(1.0 + c * df_star)
    return delta, force_fn(delta), jax.lax.stop_gradient(r_abs)


def newton_system(evaluate, delta_free, compliance, max_iter: int = 30, tol: float = 1e-15,
                  exact: bool = False):
    """Root of r(delta) = delta - delta_free + C F(delta) for n contacts, no gradients.

    F_i depends on delta_i only and is non-decreasing, C [n, n] is the structure's symmetric
    positive definite compliance, so J = I + C diag(F') is invertible and the root unique.
    Newton from delta_free (every F at its largest) with step halving whenever a step does not
    reduce max |r_i| (a contact opening or closing within the step makes F' jump); a halving
    below 1/32 is taken anyway, so the loop cannot stall. A contact with F_i = 0 at the root
    has lost contact: its row reads delta_i = delta_free_i - sum_j C_ij F_j.

    Args:
        evaluate: delta [n] -> (F [n] N, dF/d delta [n] N/m).
        delta_free: [n] approaches if every F were zero [m]. compliance: C [n, n] [m/N].
        max_iter: iteration cap (static). tol: tolerance on max |r_i| [m].
        exact: Newton directions by elimination (:func:`solve_small`) instead of Jacobi
            sweeps (static): for strongly coupled contacts such as a hanging sleeper's
            ballast under a wheel.

    Returns:
        (delta [n] m, |r| [n] m).
    """

    def residual(delta):
        f, df = evaluate(delta)
        return delta - delta_free + compliance @ f, df

    def size(r):
        return jnp.max(jnp.abs(r))

    def cond(state):
        return (size(state[1]) > tol) & (state[4] < max_iter)

    def body(state):
        delta, r, df, t, it = state
        if exact:
            eye = jnp.eye(r.shape[0], dtype=r.dtype)
            direction = solve_small(eye + compliance * df[None, :], r)
        else:
            direction = _jacobi_direction(compliance, df, r)
        trial = delta - t * direction
        r_trial, df_trial = residual(trial)
        take = (size(r_trial) < size(r)) | (t < 1.0 / 32)
        return (jnp.where(take, trial, delta), jnp.where(take, r_trial, r),
                jnp.where(take, df_trial, df), jnp.where(take, 1.0, 0.5 * t), it + 1)

    r0, df0 = residual(delta_free)
    one = jnp.ones((), delta_free.dtype)
    delta, r, *_ = jax.lax.while_loop(cond, body, (delta_free, r0, df0, one, 0))
    return delta, jnp.abs(r)


def solve_small(a, b):
    """x with a x = b for a small [n, n] ``a`` (n static) by Gaussian elimination without
    pivoting, unrolled: under ``vmap`` it is n^2 vector operations, where a LAPACK call per
    Newton iteration costs more than the whole step. For the step's Jacobians
    I + C diag(F'), which are strongly diagonally dominant (the wheels' coupling within one
    step is ~1e-3 of their own compliance), no pivoting is needed."""
    n = b.shape[0]
    rows = [a[i] for i in range(n)]
    rhs = [b[i] for i in range(n)]
    for k in range(n):
        for i in range(k + 1, n):
            m = rows[i][k] / rows[k][k]
            rows[i] = rows[i] - m * rows[k]
            rhs[i] = rhs[i] - m * rhs[k]
    x = [None] * n
    for i in reversed(range(n)):
        acc = rhs[i]
        for j in range(i + 1, n):
            acc = acc - rows[i][j] * x[j]
        x[i] = acc / rows[i][i]
    return jnp.stack(x)


def _jacobi_direction(compliance, df, r, sweeps: int = 2):
    """Newton direction (I + C diag(F'))^-1 r by Jacobi sweeps: the wheels' coupling within
    a step is ~1e-3 of their own compliance, so two sweeps leave ~1e-9 of the direction (an
    inexact Newton step converging to the same root) for a few vector operations, where an
    elimination costs n^2 of them."""
    own_coupling = jnp.diagonal(compliance) * df
    coupling = compliance * df[None, :]
    step = r / (1.0 + own_coupling)
    for _ in range(sweeps):
        others = jnp.sum(coupling * step[None, :], axis=-1) - own_coupling * step
        step = (r - others) / (1.0 + own_coupling)
    return step


def solve_contact_system(force_fn, delta_free, compliance, max_iter: int = 30,
                         tol: float = 1e-15, loop_force_fn=None, exact: bool = False):
    """Solve delta = delta_free - C F(delta) for n contacts (delta [n] m, C [n, n] m/N).

    :func:`newton_system` made differentiable by the implicit function theorem, as
    :func:`solve_contact_step`: one Newton step from the converged root with the root and
    the Jacobian I + C diag(F') held fixed.

    Args:
        force_fn: delta [n] -> F [n] [N], F_i a function of delta_i only, differentiable.
        loop_force_fn: ``force_fn`` with its parameters under ``stop_gradient`` (used inside
            the loop; default ``force_fn``).
        Others (``exact``) as :func:`newton_system`.

    Returns:
        (delta [n] m, F [n] N, |r| [n] m).
    """
    loop_force_fn = loop_force_fn or force_fn
    ones = jnp.ones_like(delta_free)

    def evaluate(delta):  # F and its diagonal Jacobian in one forward pass
        return jax.jvp(loop_force_fn, (delta,), (ones,))

    d_free = jax.lax.stop_gradient(delta_free)
    c = jax.lax.stop_gradient(compliance)
    delta_star, r_abs = newton_system(evaluate, d_free, c, max_iter, tol, exact)
    delta_star = jax.lax.stop_gradient(delta_star)
    f_star, df_star = jax.jvp(force_fn, (delta_star,), (ones,))
    r_star = delta_star - delta_free + compliance @ f_star
    jac = jax.lax.stop_gradient(jnp.eye(ones.shape[0], dtype=ones.dtype) + c * df_star[None, :])
    delta = delta_star - solve_small(jac, r_star)
    return delta, force_fn(delta), jax.lax.stop_gradient(r_abs)


STATIC_STEP_MAX = 1e-3  # m: the largest rise of one static Newton step (see static_approach)


def static_approach(force_fn, preload, max_iter: int = 30):
    """Approach [m] with force_fn(delta) = preload [N] (Newton from below; law convex).

    Starts below the root (10 um: F < P for any realistic contact): the first Newton step on
    the convex law overshoots above the root, from where the iterates decrease monotonically.
    A step rises by at most :data:`STATIC_STEP_MAX`: a wheel that starts on its flat has no
    contact at 10 um (F = 0, F' = 0) until the approach reaches the flat's depth (up to
    about 5 mm), and an unbounded step (P / 1 N/m, 125 km) sent the 3D table laws beyond
    their tables and the run to 1e11 N. A fixed iteration count keeps reverse-mode
    differentiation possible.
    """
    def body(_, d):
        f, df = jax.value_and_grad(force_fn)(d)
        rise = -(f - preload) / jnp.where(df > 0, df, 1.0)
        return d + jnp.minimum(rise, STATIC_STEP_MAX)

    return jax.lax.fori_loop(0, max_iter, body, jnp.asarray(1e-5))
