"""A hand-written reverse mode (adjoint) of the time loop: :func:`adjoint_loop`.

Plain reverse-mode autodiff through :func:`wfjax.loop.run.time_loop` stores, at every step,
the residuals of every operation of the step (the mode shapes at the contact and the complex
modal states, [n_modes] each) and transposes every nonlinear operation, the contact law's
evaluations included. But the step is *linear* in the modal state (q, p, f_prev) except for
the contact solve, whose linearisation at the converged root only needs the law's slope
K_n = dF/d delta there. So the adjoint needs from the forward pass per-step scalars only:
the approach delta_n of every wheel and the rail's own compliance within the step
(positions, flat coordinates and the rest of the step's compliance C_n are recomputed from
the step index; K_n from delta_n). See ``docs/gradients.md``.

Forward (``custom_vjp`` fwd): the unchanged :func:`wfjax.loop.run.time_loop` (its results
are the ones of ``run_scan``, bit for bit) with its static extra output ``own_compliance``
and, for every instrument observer, its per-step readouts (small: [n_steps, n_quantities,
n_s] or [n_steps, n_bays]; recorded whether or not the observer keeps histories).

Backward: the laws' forces and slopes K_n at every step's approach (vectorised, in chunks of
steps), then a reverse loop over the transposed linear step (:func:`backward_scan`),
each step gathering the mode shapes of the step before and carrying them to it, so every
step reads the shapes once; per step a tiny transposed contact system
(I + C_n diag(K_n))^T mu_n = ... and the cotangent of the law's explicit force
F_expl(delta_n, s_n; law) at fixed delta_n. After the scan, the law's leaves get their
cotangent from ``vmap``-ed ``jax.vjp`` of F_expl over the steps (parallel). Steps after the
last nonzero output cotangent have an exactly zero adjoint and are skipped (the loop starts
at the last such step; the law's chunks by ``lax.cond``). The static start (delta_0, q_0,
xi_W,ref) is computed outside the ``custom_vjp`` and differentiated by JAX as usual.

Instruments (:class:`wfjax.loop.observers.Sensors`, ``DetectorReadings``): an observer's
readout at step n is linear in (q_n, F_n) at the fixed positions x_n; its outputs (histories
and running extremes) are a reduction of the readouts. The backward pass first replays each
reduction over the recorded readouts under ``jax.vjp`` (so a running max/min sends its
cotangent to the step where the extreme was attained, ties split evenly as plain autodiff's
``jnp.maximum``), then, in the reverse loop, adds ``jax.linear_transpose`` of the readout at
step n to the adjoints of q_hat_n and F_n (the force's path through q_n = q_hat_n +
an_r sum_i F_i phi_i included); step 0's goes to q_0.

Conventions: complex cotangents pair with their variable as Re(sum lambda z) (no conjugate;
JAX's convention for ``vjp`` of complex values), so the transpose of z -> a z is
lambda -> a lambda and of z -> Re(a z) is lambda_y -> a lambda_y.

Scope: every pointwise contact law (Hertz profile and trajectory, 2D bedding, 3D table, 3D
parametric family), one wheel or a vehicle's tuple of laws, rail/wheel roughness
(:class:`wfjax.scenario.patch.LoopRoughness`, not differentiated), float64 and float32,
``observers=`` instruments (``Sensors``, ``DetectorReadings``; history on or off). Outputs
with cotangents: ``force``, ``approach``, ``sensors``, ``sensor_max``, ``sensor_min``,
``detector_load`` and ``detector_peak``; the others (``x``, ``s``, ``t``, ``residual``)
do not depend on a differentiated input, and a cotangent on ``wheel_disp``, ``rail_disp`` or
``axle_acc`` raises ``NotImplementedError``. The contact law is differentiated, not the
structure, speed, time step, start or impact position, nor the roughness values:
differentiating any of them raises ``NotImplementedError`` (``jax.grad`` through
:func:`wfjax.loop.run.run_scan` covers them). Forward mode (``jvp``/``jacfwd``) is not
available through a ``custom_vjp``: use ``run_scan`` there. Not supported
(``NotImplementedError``): the direct 3D mode (a law with its own step: its step solves a
nonlinear gap system per element, not a pointwise F(delta) whose slope K_n linearises the
contact); hanging sleepers (their one-sided ballast is a second contact system in the solve
whose linearisation the backward step does not carry); observers without ``readout``/
``reduce`` (their outputs are not known to be linear read-outs of the state).
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp

from ..contact.newton import solve_small
from ..fields import pytree
from ..params import loop_precision
from .contacts import pointwise, roughness_inputs
from .observers import LoopContext, OwnCompliance, Reading
from .run import StepOutput, run_scan, time_loop
from .setup import LoopSetup, cast_precision, loop_setup, static_start
from .structure import modal_loads, rail_compliance_fn, shapes_fn

__all__ = ["adjoint_loop", "adjoint_runs", "run_adjoint", "run_adjoint_runs", "backward_scan",
           "LoopSetup", "loop_setup", "static_start", "contact_slopes", "forces_and_slopes",
           "SUPPORTED_OUTPUTS"]

# outputs whose cotangents the adjoint propagates (the last five: sensors and the detector)
SUPPORTED_OUTPUTS = ("force", "approach", "sensors", "sensor_max", "sensor_min",
                     "detector_load", "detector_peak")
_UNSUPPORTED = ("wheel_disp", "rail_disp", "axle_acc")
_READ = "_adjoint_readout{}"  # observer i's recorded readouts: a residual, not an output
_LOOP_KEYS = StepOutput._fields + ("t", "own_compliance")  # the rest are observers' outputs


@pytree(static=("key",))
class _Recorded:
    """An instrument observer (``readout``/``reduce``, :mod:`wfjax.loop.observers`) that also
    saves its per-step readout under ``key`` (for the backward pass); its own values and
    summaries are the observer's, computed the same way."""

    observer: Any
    key: str = ""

    def init(self, ctx):
        return self.observer.init(ctx)

    def update(self, state, r, ctx):
        value = self.observer.readout(r, ctx)
        state, saved = self.observer.reduce(state, value, r, ctx)
        return state, saved | {self.key: value}

    def finalize(self, state, ctx):
        return self.observer.finalize(state, ctx)


def _context(ls: LoopSetup) -> LoopContext:
    """What the observers read of a run (as ``time_loop``'s; no hanging sleepers here)."""
    return LoopContext(ls.struct.track, len(ls.laws), ls.preload.dtype, None)


def _readout_transpose(ls: LoopSetup, observers):
    """(x [n] m, phi [n, M] or None, cts) -> (ct_q [M] complex, ct_f [n]): the transpose of
    every observer's readout at one step, ``cts`` a list of cotangents of its values.

    With ``phi`` (the step's mode shapes) the readout is taken as a function of the
    propagated state q_hat and the forces, q = q_hat + an_r sum_i f_i phi_i, so ct_f holds
    the force's path through q as well (``backward_scan``'s modal adjoint is q_hat's); without
    (the static start) of the state q itself."""
    ctx = _context(ls)

    def transpose(x, phi, cts):
        def read(q, f):
            q = q if phi is None else q + ls.an_r * modal_loads(f, phi)
            return [obs.readout(Reading(None, q, f, x, None, ()), ctx) for obs in observers]

        return jax.linear_transpose(read, ls.e_r, ls.preload)(cts)

    return transpose


def _readout_cotangents(ls: LoopSetup, observers, x, values, cts):
    """Cotangents [N, ...] of every observer's recorded readouts ``values`` [N, ...] (steps
    0..N-1, wheels at ``x`` [N, n] m) from its outputs' cotangents ``cts`` (by name): the
    ``vjp`` of its reduction replayed over the recorded values, so a running extreme's
    cotangent reaches the step(s) where it was attained exactly as in plain autodiff (ties
    split evenly, as ``jnp.maximum``'s gradient)."""
    ctx = _context(ls)
    q_zero = jnp.zeros_like(ls.e_r)  # a reduction reads a step's index and positions only

    def replay(obs, vals):
        def body(state, inp):
            n, value, xn = inp
            return obs.reduce(state, value, Reading(n, q_zero, jnp.zeros_like(xn), xn, None,
                                                    ()), ctx)

        state, saved = jax.lax.scan(body, obs.init(ctx), (jnp.arange(x.shape[0]), vals, x))
        return saved | obs.finalize(state, ctx)

    out = []
    for obs, vals in zip(observers, values, strict=True):
        primal, vjp = jax.vjp(functools.partial(replay, obs), vals)
        out.append(vjp({k: cts[k] for k in primal})[0])
    return out


def _dense(ct):
    """``ct``, or its zeros for a symbolic zero."""
    if isinstance(ct, jax.custom_derivatives.SymbolicZero):
        return jnp.zeros(ct.shape, ct.dtype)
    return ct


def _step_forces(laws, roughness, x, s, approach):
    """F [n] N of every wheel at one step (x, s, approach [n] m), and the point evaluated
    there: F_i = law_i.point_force(point_i, approach_i + shift_i), as the loop's solve."""
    shift, rough = roughness_inputs(laws, roughness, x, s)
    out = []
    for i, law in enumerate(laws):
        point = law.point(s[i]) if rough[i] is None else law.rough_point(s[i], rough[i][0])
        out.append((point, approach[i] + shift[i]))
    return out


def contact_slopes(laws, roughness, x, s, approach):
    """K [N, n] N/m: dF/d delta of every wheel's law at the loop's approach (delta held fixed
    at the loop's own value), from the loop's ``x``, ``s``, ``approach`` [N, n] m."""
    return forces_and_slopes(laws, roughness, x, s, approach)[1]


def forces_and_slopes(laws, roughness, x, s, approach):
    """(F_expl [N, n] N, K [N, n] N/m): every wheel's law force at the loop's (fixed) approach,
    a function of the laws' leaves (what the adjoint's law cotangent differentiates), and its
    slope dF/d delta there (the linearised contact solve), from the loop's ``x``, ``s``,
    ``approach`` [N, n] m (``laws`` and ``roughness`` in the loop's precision)."""

    def one(xn, sn, an):
        pairs = [jax.jvp(lambda dd, law=law, point=point: law.point_force(point, dd), (d,),
                         (jnp.ones_like(d),))
                 for law, (point, d) in zip(laws, _step_forces(laws, roughness, xn, sn, an),
                                            strict=True)]
        return jnp.stack([p[0] for p in pairs]), jnp.stack([p[1] for p in pairs])

    return jax.vmap(one)(x, s, approach)


def _compliance_fn(ls: LoopSetup):
    """(x_ref [m], c_own [n] m/N) -> the step's compliance C [n, n] m/N, as ``time_loop``."""
    rail_compliance = rail_compliance_fn(ls)
    return lambda x_ref, c_own: jnp.diag(ls.c_wheel) + rail_compliance(x_ref, c_own)


def _transposed_contact(C, K, rhs):
    """mu [n] with (I + C diag(K))^T mu = rhs (C [n, n] m/N, K [n] N/m, rhs [n] 1/m-like)."""
    if C.shape[0] == 1:
        return rhs / (1.0 + C[0, 0] * K)
    return solve_small(jnp.eye(C.shape[0], dtype=C.dtype) + K[:, None] * C.T, rhs)


def backward_scan(ls: LoopSetup, n_steps: int, K, c_own, ct_force, ct_approach, n_top=None,
                  unroll: int = 1, readout=None):
    """The reverse pass over the transposed linear step, from step ``n_top`` down to step 1.

    A ``fori_loop`` over the steps that carry an adjoint only (steps after ``n_top`` have an
    exactly zero one and cost nothing: a scan over every step with a ``lax.cond`` skip cost
    13 ms of 37 for 10 runs of 3073 steps, on the skipped steps and a compliance computed for
    every step). Per step: the step's compliance C_n from the forward pass's own part and the
    residual/cross tables, one gather of the previous step's mode shapes, one update of the
    modal adjoint with the current step's (carried) shapes and one reduction with the previous
    step's. (Measured on XLA CPU, 10 batched runs: complex arrays beat a real-pair layout,
    0.18 s against 0.30 s, and beat real-part arithmetic on complex arrays, 0.33 against
    0.39 s; the forward pass's own compliance saves a fifth.)

    Args:
        ls: :class:`LoopSetup`. n_steps: N (static). K: [N - 1, n] N/m slopes of steps 1..N-1.
        c_own: [N - 1, n] m/N the rail's own compliance within steps 1..N-1 (the forward
            pass's ``own_compliance``).
        ct_force, ct_approach: [N - 1, n] cotangents of the force [1/N-like] and approach
            [1/m-like] outputs of steps 1..N-1.
        n_top: None (every step), or the last step (int, may be traced) with a nonzero
            cotangent: the adjoint of every later step is exactly zero, so the loop starts
            there (under ``vmap`` with a batched ``n_top`` it runs to the largest, the other
            runs' extra steps selected away).
        unroll: the loop's unroll (static).
        readout: None, or (transpose, x [N - 1, n] m, cts): observers' readouts of steps
            1..N-1 with cotangents ``cts`` (a list of [N - 1, ...] arrays) and
            ``transpose`` of :func:`_readout_transpose`; each step adds them to the adjoints
            of its modal state and forces.

    Returns:
        (ct_F_expl [N - 1, n]: cotangents of the laws' explicit forces; ct_q0 [M] complex;
        ct_xi_w_ref [n]).
    """
    model = ls.struct.track
    w_r, e_r, e_w = model.weights, ls.e_r, ls.e_w
    g_r = ls.ap_r + ls.an_r * e_r  # f_n's weight in q_hat_{n+1}: through q_n and directly
    g_w = ls.ap_w + ls.an_w * e_w
    shapes_at = shapes_fn(model)
    real = ls.preload.dtype
    compliance = _compliance_fn(ls)

    def x_ref(n):  # the reference wheel's rail coordinate at step n [m], as time_loop
        return ls.x_start + ls.speed * ls.dt * jnp.asarray(n).astype(real)

    def step(i, carry):  # step n = n_top - i (its inputs at row n - 1)
        lq, lp, b, phi, l_expl, mu_all = carry  # adjoints of q_n, p_n; f_n's from later steps
        row = n_top - 1 - i
        k, gf, gd, c = (a[row] for a in (K, ct_force, ct_approach, c_own))
        if readout is not None:
            transpose, xs, cts = readout
            read_q, read_f = transpose(xs[row], phi, [a[row] for a in cts])
            lq, gf = lq + read_q, gf + read_f
        C = compliance(x_ref(row + 1), c)
        lf = b + gf
        mu = _transposed_contact(C, k, gd + k * lf)
        lq_hat = lq - w_r * modal_loads(mu, phi)
        lp_hat = lp - ls.wheel_res * mu[:, None]
        phi_prev = shapes_at(x_ref(row) + ls.offsets)
        b_prev = (jnp.real(jnp.sum(phi_prev * (g_r * lq_hat), axis=-1))
                  + jnp.real(jnp.sum(g_w * lp_hat, axis=-1)))
        return (e_r * lq_hat, e_w * lp_hat, b_prev, phi_prev, l_expl.at[row].set(lf - C.T @ mu),
                mu_all + mu)

    if n_top is None:
        n_top = n_steps - 1
    phi_top = shapes_at(x_ref(n_top) + ls.offsets)  # the shapes of the first step run
    carry0 = (jnp.zeros_like(e_r), jnp.zeros_like(e_w), jnp.zeros_like(ls.preload), phi_top,
              jnp.zeros_like(K), jnp.zeros_like(ls.preload))
    lq0, *_, l_expl, mu_sum = jax.lax.fori_loop(0, n_top, step, carry0, unroll=unroll)
    return l_expl, lq0, mu_sum


# -- the custom_vjp core (over a batch of runs that share the laws and the structure) ---------
def _primal(statics, laws, struct, speed, dt, x_start, impact_position, roughness, observers,
            q0, xi_w_ref, delta0):
    """``time_loop`` of the tuple of laws for runs [B] (speed, dt, x_start, impact_position
    [B]; q0, xi_w_ref, delta0 [B, ...] are the runs' own start, computed again outside for
    their gradients: their values are unused here), with the instrument ``observers`` (each
    also recording its readouts under ``_READ``)."""
    n_steps, max_iter, precision, batched = statics
    observers = (OwnCompliance(),) + tuple(
        _Recorded(obs, _READ.format(i)) for i, obs in enumerate(observers))

    def one(v, d, xs, xi):
        return time_loop(laws, struct, v, d, xs, xi, n_steps, max_iter, precision=precision,
                         roughness=roughness, observers=observers)

    if not batched:  # adjoint_loop: time_loop itself (a batch of one can round apart)
        return {k: v[None] for k, v in one(speed[0], dt[0], x_start[0],
                                            impact_position[0]).items()}

    def compiled(v, d, xs, xi):  # as program.core.Autodiff: vmap of run_scan, the same rounding
        return run_scan(laws, struct, v, d, xs, xi, n_steps, max_iter, precision=precision,
                        roughness=roughness, observers=observers)

    return jax.vmap(compiled)(speed, dt, x_start, impact_position)


_core = jax.custom_vjp(_primal, nondiff_argnums=(0,))


def _perturbed(tree) -> bool:
    return any(leaf.perturbed for leaf in jax.tree.leaves(
        tree, is_leaf=lambda x: isinstance(x, jax.custom_derivatives.CustomVJPPrimal)))


def _fwd(statics, laws, struct, speed, dt, x_start, impact_position, roughness, observers, q0,
         xi_w_ref, delta0):
    names = ("struct", "speed", "dt", "x_start", "impact_position", "roughness", "observers")
    fixed = (struct, speed, dt, x_start, impact_position, roughness, observers)
    bad = [name for name, value in zip(names, fixed, strict=True) if _perturbed(value)]
    if bad:
        raise NotImplementedError(
            f"the adjoint time loop differentiates the contact law only, not {', '.join(bad)}: "
            "use jax.grad through wfjax.loop.run.run_scan for those")
    values = jax.custom_derivatives.custom_vjp_primal_tree_values
    laws, struct, speed, dt, x_start, impact_position, roughness, observers = values(
        (laws, struct, speed, dt, x_start, impact_position, roughness, observers))
    out = _primal(statics, laws, struct, speed, dt, x_start, impact_position, roughness,
                  observers, None, None, None)
    reads = [out[_READ.format(i)] for i in range(len(observers))]
    res = (laws, struct, speed, dt, x_start, impact_position, roughness, observers, out["x"],
           out["s"][:, 1:], out["approach"][:, 1:], out["own_compliance"][:, 1:], reads)
    return out, res


def _last_nonzero(*cts):
    """The last step (1..N-1) at which any of ``cts`` ([B, N - 1, n]) is nonzero (0: none)."""
    nonzero = functools.reduce(jnp.logical_or, [jnp.any(c != 0, axis=(0, 2)) for c in cts])
    return jnp.max(jnp.where(nonzero, jnp.arange(1, nonzero.shape[0] + 1), 0))


class _StepChunks:
    """Steps 1..N-1 of [B, N - 1, ...] arrays in chunks of ``size`` steps ([n_chunks, B,
    size, ...], the last padded with the last step, or zeros for cotangents), so work on the
    steps after the last nonzero cotangent can be skipped chunk by chunk (``lax.cond``)."""

    def __init__(self, n: int, size: int = 256):
        self.n, self.size = n, size
        self.count = -(-n // size)
        self.first = 1 + size * jnp.arange(self.count)  # each chunk's first step

    def split(self, a, zero_pad: bool = False):
        pad = self.count * self.size - self.n
        tail = jnp.repeat(a[:, -1:], pad, axis=1)
        a = jnp.concatenate([a, jnp.zeros_like(tail) if zero_pad else tail], axis=1)
        a = a.reshape((a.shape[0], self.count, self.size) + a.shape[2:])
        return jnp.moveaxis(a, 1, 0)

    def join(self, a):
        a = jnp.moveaxis(a, 0, 1)
        return a.reshape((a.shape[0], -1) + a.shape[3:])[:, :self.n]


class _LawSteps:
    """The laws at every step of a batch's forward pass ([B, N - 1, n] ``x``, ``s``,
    ``approach``), in chunks (:class:`_StepChunks`) up to the last step the cotangents reach:
    their slopes K and the cotangent of their leaves from the explicit forces' cotangents."""

    def __init__(self, laws, roughness, precision, x, s, approach):
        self.leaves, self.treedef = jax.tree.flatten(laws)
        self.diff = [i for i, leaf in enumerate(self.leaves)
                     if jnp.issubdtype(jnp.result_type(leaf), jnp.inexact)]
        self.roughness, self.precision = roughness, precision
        self.chunks = _StepChunks(x.shape[1])
        self.steps = tuple(self.chunks.split(a) for a in (x, s, approach))

    def evaluate(self, diff_leaves, xc, sc, ac):  # forces and slopes [B, chunk, n] of a chunk
        full = list(self.leaves)
        for i, leaf in zip(self.diff, diff_leaves, strict=True):
            full[i] = leaf
        cast_laws, cast_rough = cast_precision(
            (jax.tree.unflatten(self.treedef, full), self.roughness), self.precision)
        return jax.vmap(lambda *a: forces_and_slopes(cast_laws, cast_rough, *a))(xc, sc, ac)

    def diff_leaves(self):
        return [self.leaves[i] for i in self.diff]

    def slopes(self, n_top):
        """K [B, N - 1, n] N/m (zeros after the chunk of step ``n_top``)."""
        return self.chunks.join(jax.lax.map(lambda c: jax.lax.cond(
            c[0] <= n_top, lambda: self.evaluate(self.diff_leaves(), *c[1:])[1],
            lambda: jnp.zeros_like(c[1])), (self.chunks.first,) + self.steps))

    def cotangent(self, l_expl, n_top):
        """The laws' cotangent (a pytree like them) from the explicit forces' [B, N - 1, n]."""
        def law_cotangent(acc, c):  # sum over the chunks of the vjp of their explicit forces
            def run():
                _, vjp = jax.vjp(lambda d: self.evaluate(d, *c[1:4])[0], self.diff_leaves())
                return [a + b for a, b in zip(acc, vjp(c[4])[0], strict=True)]

            return jax.lax.cond(c[0] <= n_top, run, lambda: acc), None

        acc0 = [jnp.zeros_like(leaf) for leaf in self.diff_leaves()]
        ct_diff, _ = jax.lax.scan(law_cotangent, acc0, (self.chunks.first,) + self.steps + (
            self.chunks.split(l_expl, zero_pad=True),))
        ct_leaves = [None] * len(self.leaves)
        for i, ct in zip(self.diff, ct_diff, strict=True):
            ct_leaves[i] = ct
        return jax.tree.unflatten(self.treedef, ct_leaves)


def _check_cotangents(cts):
    for key, ct in cts.items():
        if key in _UNSUPPORTED and not isinstance(ct, jax.custom_derivatives.SymbolicZero):
            raise NotImplementedError(
                f"the adjoint time loop propagates cotangents of {SUPPORTED_OUTPUTS} only, "
                f"not of {key!r}: use jax.grad through wfjax.loop.run.run_scan for it")


def _run_backward(setup, n_steps, n_top, observers, run, k, c, cf, ca, x_run, ct_run):
    """One run's :func:`backward_scan` with its observers' readout cotangents ``ct_run``
    ([N, ...] each, steps 0..N-1; wheels at ``x_run`` [N, n] m); ``setup(*run)`` is its
    :class:`LoopSetup`."""
    ls = setup(*run)
    if not observers:
        return backward_scan(ls, n_steps, k, c, cf, ca, n_top)
    transpose = _readout_transpose(ls, observers)
    l_expl, ct_q0, ct_xi = backward_scan(ls, n_steps, k, c, cf, ca, n_top, readout=(
        transpose, x_run[1:], [a[1:] for a in ct_run]))
    return l_expl, ct_q0 + transpose(x_run[0], None, [a[0] for a in ct_run])[0], ct_xi


def _bwd(statics, res, cts):
    n_steps, _, precision, _ = statics
    (laws, struct, speed, dt, x_start, impact_position, roughness, observers, x_all, s,
     approach, c_own, reads) = res
    _check_cotangents(cts)
    runs = (speed, dt, x_start, impact_position)

    def setup(v, d, xs, xi):
        return loop_setup(laws, struct, v, d, xs, xi, precision, roughness)

    observers = cast_precision(observers, precision)
    ct_obs = {k: _dense(v) for k, v in cts.items() if k not in _LOOP_KEYS}
    ct_reads = jax.vmap(lambda run, *a: _readout_cotangents(setup(*run), observers, *a))(
        runs, x_all, reads, ct_obs)
    ct_force, ct_approach = (_dense(cts[k])[:, 1:] for k in ("force", "approach"))
    n_top = _last_nonzero(ct_force, ct_approach, *(
        jnp.reshape(c[:, 1:], (c.shape[0], c.shape[1] - 1, -1)) for c in ct_reads))
    law_steps = _LawSteps(laws, roughness, precision, x_all[:, 1:], s, approach)
    K = law_steps.slopes(n_top)
    l_expl, ct_q0, ct_xi_w_ref = jax.vmap(functools.partial(
        _run_backward, setup, n_steps, n_top, observers))(runs, K, c_own, ct_force,
                                                           ct_approach, x_all, ct_reads)
    ct_laws = law_steps.cotangent(l_expl.astype(K.dtype), n_top)
    approach_ct = cts["approach"]
    ct_delta0 = (None if isinstance(approach_ct, jax.custom_derivatives.SymbolicZero)
                 else approach_ct[:, 0])
    return (ct_laws, None, None, None, None, None, None, None, ct_q0, ct_xi_w_ref, ct_delta0)


_core.defvjp(_fwd, _bwd, symbolic_zeros=True)


def adjoint_runs(law, struct, speed, dt, x_start, impact_position, n_steps: int,
                 max_iter: int = 30, precision: str = "float64", roughness=None,
                 observers: tuple = (), _batched: bool = True) -> dict:
    """:func:`adjoint_loop` of a batch of runs [B] that share the law(s) and the structure.

    ``speed``, ``dt``, ``x_start``, ``impact_position``: [B] arrays (m/s, s, m, m). Returns
    the dict of :func:`adjoint_loop` with a leading run axis [B, ...] (as ``jax.vmap`` of it),
    the same values as ``jax.vmap`` of :func:`wfjax.loop.run.run_scan` (bit for bit,
    also for one run, as ``program.core.Autodiff`` computes without the adjoint). Under one
    ``custom_vjp`` for the batch, the backward pass skips the steps after the last one that
    any run's cotangent reaches (a max-force misfit: after the peak), which a ``vmap`` of
    :func:`adjoint_loop` cannot (its steps are selected, not skipped, per run).
    ``observers`` are shared by the batch.
    """
    single = not isinstance(law, tuple)
    laws = (law,) if single else law
    precision = loop_precision(precision, gradients=True)
    observers = tuple(observers)
    _check_supported(laws, struct, observers)
    args = tuple(jnp.asarray(a) for a in (speed, dt, x_start, impact_position))

    def start(v, d, xs, xi):
        st = static_start(loop_setup(laws, struct, v, d, xs, xi, precision, roughness))
        return st.q0, st.xi_w_ref, st.delta0

    q0, xi_w_ref, delta0 = jax.vmap(start)(*args)
    if not _batched and args[0].shape != (1,):
        raise ValueError("_batched=False is adjoint_loop's: one run")
    out = _core((int(n_steps), int(max_iter), precision, bool(_batched)), laws, struct, *args,
                roughness, observers, q0, xi_w_ref, delta0)
    # the backward pass's inputs, not time_loop's outputs
    out = {k: v for k, v in out.items() if k != "own_compliance" and not k.startswith("_")}
    if single:  # as time_loop of one law: its histories and detector peaks lose the wheel axis
        out |= {k: out[k][..., 0] for k in StepOutput._fields}
        if "detector_peak" in out:
            out["detector_peak"] = out["detector_peak"][:, 0]
    return out


def _check_supported(laws, struct, observers):
    """NotImplementedError for what the adjoint does not carry (see the module docstring)."""
    for lw in laws:
        if not pointwise(lw):
            raise NotImplementedError(
                f"the adjoint supports pointwise contact laws only; {type(lw).__name__} "
                "solves its own step (the direct 3D mode): use run_scan")
    if struct.supports is not None:
        raise NotImplementedError(
            "the adjoint does not carry hanging sleepers' one-sided ballast (Track.ballast_gap"
            " > 0): use run_scan (plain autodiff)")
    for obs in observers:
        if not (hasattr(obs, "readout") and hasattr(obs, "reduce")):
            raise NotImplementedError(
                f"the adjoint carries instrument observers (readout/reduce: Sensors, "
                f"DetectorReadings) only, not {type(obs).__name__}: use run_scan")


def adjoint_loop(law, struct, speed, dt, x_start, impact_position, n_steps: int,
                 max_iter: int = 30, precision: str = "float64", roughness=None,
                 observers: tuple = ()) -> dict:
    """:func:`wfjax.loop.run.time_loop` with a hand-written reverse mode (pure).

    The same results as ``time_loop`` (bit for bit: it runs it); ``jax.grad``/``vjp``/
    ``jacrev`` of the ``force`` and ``approach`` histories with respect to the contact law's
    leaves (the flat's geometry, a 3D table or family) run the adjoint described in the module
    docstring, without plain reverse mode's stored [n_steps, n_modes] residuals (3D family,
    10 speeds, :func:`adjoint_runs`: value_and_grad 1.3-1.4 forward evaluations against 3.3-4,
    ``benchmarks/README.md``). Works under ``jit`` and ``vmap``.

    Args:
        law: a pointwise contact law (:func:`wfjax.contact.laws.prepare`; not the direct 3D
            mode), or a tuple of them, one per wheel of a vehicle (``struct`` from
            :func:`wfjax.loop.structure.structure`).
        struct: :class:`wfjax.loop.structure.Structure` (not differentiated).
        speed: v [m/s]; dt: time step [s]; x_start: rail coordinate of the reference wheel at
            t = 0 [m]; impact_position: where s = 0 [m] (none of them differentiated).
        n_steps: steps incl. t = 0 (static). max_iter: Newton iteration cap (static).
        precision: ``"float64"`` or ``"float32"`` (static; ``"auto"``: float64, as for every
            gradient, :func:`wfjax.params.loop_precision`).
        roughness: a :class:`wfjax.scenario.patch.LoopRoughness` or None (not differentiated).
        observers: instruments (:class:`wfjax.loop.observers.Sensors`,
            :class:`~wfjax.loop.observers.DetectorReadings`, history on or off; not
            differentiated themselves): their outputs join the result as in ``time_loop``
            and carry cotangents.

    Returns:
        dict as ``time_loop``: x, s, force, approach, wheel_disp, rail_disp, residual,
        axle_acc ([n_steps] for one law, [n_steps, n] for a tuple), t [n_steps] and the
        observers' outputs (``sensors`` [n_steps, n_quantities, n_s], ``sensor_max``,
        ``sensor_min`` [n_quantities, n_s], ``detector_load`` [n_steps, n_bays],
        ``detector_peak`` [n_bays] or [n, n_bays]).

    Raises:
        NotImplementedError: a law with its own step (the direct 3D mode); a track with
        hanging sleepers (``struct.supports``); an observer other than an instrument
        (``readout``/``reduce``); in reverse mode, a cotangent on
        ``wheel_disp``, ``rail_disp`` or ``axle_acc``, or a differentiated input other than
        the law.
    """
    out = adjoint_runs(law, struct, *(jnp.asarray(a)[None] for a in (
        speed, dt, x_start, impact_position)), n_steps, max_iter, precision, roughness,
        observers, _batched=False)
    return {k: v[0] for k, v in out.items()}


run_adjoint = jax.jit(adjoint_loop, static_argnames=("n_steps", "max_iter", "precision"))
run_adjoint.__doc__ = """:func:`adjoint_loop` compiled (as :func:`wfjax.loop.run.run_scan`)."""
run_adjoint_runs = jax.jit(adjoint_runs, static_argnames=("n_steps", "max_iter", "precision"))
run_adjoint_runs.__doc__ = """:func:`adjoint_runs` compiled."""
