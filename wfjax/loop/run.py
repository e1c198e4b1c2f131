"""The time loop (Section 3, Eqs. 4-16) under ``lax.scan``: :func:`time_loop`, compiled as
:data:`run_scan`.

Displacements are positive downwards. The wheels (2-DOF, Table 1) carry their preloads P and
are pushed up by the contact forces F; the rail (Rayleigh-Timoshenko FE track, Table 2) is
pushed down at the moving contact points. Both are linear and enter through their modal
impulse responses (Eqs. 4-5 in state-space form), propagated *exactly* in discrete time
(exponential of each pole, first-order hold on the input), so a step costs O(modes) and has
no truncated memory. Modes of the track above ``SimConfig.track_max_frequency`` enter through
their static compliance at the contacts.

The approach is delta = xi_W - xi_R and the contact law gives F = F_c(delta, s) with s the
wheel's position relative to its impact. Within a step the structure responds to the forces
through a compliance matrix C, so every step solves delta = delta_free - C F(delta)
(:func:`wfjax.loop.contacts.solve_contacts`; one wheel: a bracketed scalar Newton iteration
from delta_free; loss of contact exact; gradients by the implicit function theorem).

State and outputs are named: the scan's carry is a :class:`LoopState`, each step's contact
histories a :class:`StepOutput`; instruments and the other saved quantities are observers
(:mod:`wfjax.loop.observers`) chained in the same scan. The step knows no model's name and no
instrument.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.extend.core
import jax.numpy as jnp

from .._xla import loop_compiler_options
from ..model import track as track_mod
from ..params import loop_precision
from .contacts import law_groups, pointwise, roughness_inputs, solve_contacts, support_force
from .observers import HangingSleepers, LoopContext, Reading
from .setup import (
    LoopSetup,
    StaticStart,
    between_sleepers,
    cast_precision,
    flat_coordinates,
    loop_setup,
    static_start,
)
from .structure import modal_loads, rail_compliance_fn, rail_reads, shapes_fn

__all__ = ["LoopState", "StepOutput", "time_loop", "run_scan", "LOOP_BLOCK",
           "loop_compiler_options"]

LOOP_BLOCK = 128  # steps per block of a loop that stops early (``time_loop(n_run=...)``)


class LoopState(NamedTuple):
    """The scan's carry. Shapes: n = wheels, M = track modes, m = wheel modes.

    ``q`` [M] complex: the track's modal state; ``p`` [n, m] complex: the wheels'; ``force``
    [n] N: the last step's contact forces; ``phi`` [n, M] complex: the mode shapes at the
    last step's contacts; ``law_states``: [n] the contact laws' own states; ``observers``:
    the observers' states; ``supports``: () or the hanging sleepers' (force [n_s] N,
    closure [n_s] m).
    """

    q: Any
    p: Any
    force: Any
    phi: Any
    law_states: tuple
    observers: tuple
    supports: tuple


class StepOutput(NamedTuple):
    """One step's contact histories, each [n] (one per wheel): ``x`` rail position [m],
    ``s`` flat coordinate [m], ``force`` [N], ``approach`` delta [m], ``wheel_disp`` [m],
    ``rail_disp`` [m] (under the wheel), ``residual`` |r| of the contact equation [m],
    ``axle_acc`` the wheelset mass's acceleration, downwards [m/s^2]."""

    x: Any
    s: Any
    force: Any
    approach: Any
    wheel_disp: Any
    rail_disp: Any
    residual: Any
    axle_acc: Any


def _scan_until(step, carry0, n_steps: int, n_run, block: int = LOOP_BLOCK):
    """``lax.scan(step, carry0, arange(1, n_steps))`` that computes only the steps before
    ``n_run`` (traced int; rounded up to whole blocks of ``block`` steps): a ``fori_loop`` over
    blocks, each a scan of ``block`` steps written into the stacked outputs. The outputs of the
    steps not computed are zeros; the carry is the one after the last step computed."""
    n_blocks = -(-(n_steps - 1) // block)
    steps = jnp.arange(1, block + 1)
    # the step traced once: its jaxpr gives the outputs' shapes and is the scan's body (an
    # eval_shape and the scan traced it twice: 0.1-0.25 s of the cold main job's trace)
    closed, shapes = jax.make_jaxpr(step, return_shape=True)(carry0, steps[0])
    body, tree = jax.extend.core.jaxpr_as_fun(closed), jax.tree.structure(shapes)
    outs0 = jax.tree.map(lambda a: jnp.zeros((n_blocks * block,) + a.shape, a.dtype), shapes[1])

    def traced_step(carry, n):
        return jax.tree.unflatten(tree, body(*jax.tree.leaves((carry, n))))

    def run_block(b, state):
        carry, outs = state
        first = 1 + b * block
        carry, out = jax.lax.scan(traced_step, carry, first.astype(steps.dtype) + steps - 1)
        return carry, jax.tree.map(
            lambda a, o: jax.lax.dynamic_update_slice_in_dim(a, o, first - 1, 0), outs, out)

    todo = jnp.clip((jnp.asarray(n_run) - 1 + block - 1) // block, 0, n_blocks)
    carry, outs = jax.lax.fori_loop(0, todo, run_block, (carry0, outs0))
    return carry, jax.tree.map(lambda a: a[:n_steps - 1], outs)


def _observe(observers, states, reading: Reading, ctx: LoopContext):
    """Every observer's update at ``reading``: (new states, merged per-step dict)."""
    new, saved = [], {}
    for obs, state in zip(observers, states, strict=True):
        state, out = obs.update(state, reading, ctx)
        new.append(state)
        saved |= out
    return tuple(new), saved


def _supported_solve(ls: LoopSetup, within_ss, phi, q_hat, x_ref, state: LoopState, args):
    """The wheels' and the hanging sleepers' contact system in one solve:
    (delta [n], F [n], |r| [n], law states, supports (force, closure), the sleepers' pull on
    the rail under the wheels [n] m)."""
    delta_free, compliance, s, groups, rough, max_iter = args
    model, sup, n = ls.struct.track, ls.struct.supports, len(ls.laws)
    w_an = model.weights * ls.an_r
    g_ws = (jnp.real(jnp.sum(w_an * phi[:, None] * sup.shapes[None], axis=-1))
            + track_mod.read_residual_table(model, sup.residual_wheels, x_ref))
    closure_free = jnp.real(jnp.sum(sup.shapes * (model.weights * q_hat), axis=-1)) - sup.gap
    system = jnp.block([[compliance, -g_ws], [-g_ws.T, within_ss]])
    params = (state.supports[1], sup.stiffness, sup.damping, ls.dt)
    d_all, f_all, r_all, law_states = solve_contacts(
        ls.laws, jnp.concatenate([delta_free, closure_free]), system, s, state.law_states,
        max_iter, groups, rough, extra=(support_force, params))
    supports = (f_all[n:], d_all[n:])
    return d_all[:n], f_all[:n], r_all[:n], law_states, supports, g_ws @ supports[0]


def _step_fn(ls: LoopSetup, start: StaticStart, observers, ctx: LoopContext, groups,
             max_iter: int):
    """The scan's step ``(LoopState, n) -> (LoopState, (StepOutput, per-step dict))``."""
    model, sup = ls.struct.track, ls.struct.supports
    w_r, n_wheels = model.weights, len(ls.laws)
    wheel_poles = jnp.reshape(ls.struct.wheel_poles, (n_wheels, -1))
    axle_res = (jnp.zeros_like(ls.wheel_res) if ls.struct.axle_residues is None
                else jnp.reshape(ls.struct.axle_residues, (n_wheels, -1)))
    axle_acc_res = -axle_res * wheel_poles**2
    shapes_at, rail_compliance = shapes_fn(model), rail_compliance_fn(ls)
    within_ss = None if sup is None else between_sleepers(sup, w_r * ls.an_r)

    def support_loads(supports):
        return 0.0 if sup is None else supports[0] @ sup.shapes

    def step(state: LoopState, n):
        x_ref = ls.x_start + ls.speed * ls.dt * n
        x, s = x_ref + ls.offsets, flat_coordinates(ls, x_ref)
        phi = shapes_at(x)
        q_hat = ls.e_r * state.q + ls.ap_r * (modal_loads(state.force, state.phi)
                                             - support_loads(state.supports))
        xi_r_free, c_own = rail_reads(phi, w_r, ls.an_r, q_hat)
        c_rail = rail_compliance(x_ref, c_own)
        p_hat = ls.e_w * state.p + ls.ap_w * (state.force - ls.preload)[:, None]
        xi_w_free = (start.xi_w_ref - jnp.real(jnp.sum(ls.wheel_res * p_hat, axis=-1))
                     + ls.c_wheel * ls.preload)
        shift, rough = (0.0, None) if ls.roughness is None else roughness_inputs(
            ls.laws, ls.roughness, x, s)
        delta_free = xi_w_free - xi_r_free + shift
        compliance = jnp.diag(ls.c_wheel) + c_rail
        supports = state.supports
        if sup is None:
            delta, f, r, law_states = solve_contacts(ls.laws, delta_free, compliance, s,
                                                     state.law_states, max_iter, groups, rough)
        else:
            args = (delta_free, compliance, s, groups, rough, max_iter)
            delta, f, r, law_states, supports, pull = _supported_solve(ls, within_ss, phi, q_hat,
                                                                      x_ref, state, args)
            xi_r_free = xi_r_free - pull
        q_new = q_hat + ls.an_r * (modal_loads(f, phi) - support_loads(supports))
        p_new = p_hat + ls.an_w * (f - ls.preload)[:, None]
        obs, saved = _observe(observers, state.observers,
                              Reading(n, q_new, f, x, c_own, supports), ctx)
        out = StepOutput(x, s, f, delta - shift, xi_w_free - ls.c_wheel * f,
                         xi_r_free + c_rail @ f, r,
                         jnp.real(jnp.sum(axle_acc_res * p_new, axis=-1)))
        return LoopState(q_new, p_new, f, phi, law_states, obs, supports), (out, saved)

    return step


def time_loop(law, struct, speed, dt, x_start, impact_position, n_steps: int,
              max_iter: int = 30, checkpoint: bool = False, observers: tuple = (),
              precision: str = "float64", roughness=None, n_run=None):
    """The time loop under ``lax.scan`` for any contact law and any number of wheels (pure).

    Args:
        law: the prepared contact law (:func:`wfjax.contact.laws.prepare`), or a tuple of
            laws, one per wheel of a vehicle (``struct`` from
            :func:`wfjax.loop.structure.structure`) on the shared track.
        struct: modal wheel(s) and track (:class:`wfjax.loop.structure.Structure`).
        speed: v [m/s]; dt: time step [s]; x_start: rail coordinate of the (reference) wheel
            at t = 0 [m]; impact_position: its rail coordinate where s = 0 [m] (wheel i of a
            vehicle is at x + offsets[i] with s_i = s - delays[i]);
            n_steps: steps incl. t = 0 (static).
        max_iter: Newton iteration cap of the per-step contact equation (static).
        checkpoint: rematerialise each step in reverse mode (``jax.checkpoint``).
        observers: observers (:mod:`wfjax.loop.observers`: sensors, a detector, ...) chained
            in the scan; their per-step values and summaries join the result by name. With
            hanging sleepers (``struct.supports``) the loop adds
            :class:`~wfjax.loop.observers.HangingSleepers`.
        precision: ``"float64"``, ``"float32"`` or ``"auto"`` (static,
            :attr:`SimConfig.precision`; :func:`wfjax.params.loop_precision` with the laws:
            float64 if a law solves its own steps, else float32): the loop's dtype
            (observers are cast with it). The propagation coefficients are computed in the
            inputs' precision (float64) and then cast: their series in
            pole dt cancels to ~1e-3 relative in float32. The outputs are in the loop's
            precision (``t`` from the uncast step); :func:`wfjax.program.core.run_one`
            widens a program's results to float64 (:func:`wfjax.loop.setup.widen`).
        roughness: a :class:`wfjax.scenario.patch.LoopRoughness` (traced: ``vmap`` over its
            realisations), or None. Point-contact laws see the contact-filtered roughness
            added to the approach; laws with ``rough_nodes`` (2D bedding, direct 3D) see it
            element by element in the gap. ``approach`` stays xi_W - xi_R.
        n_run: steps to compute (traced int, at most ``n_steps``; default all): the loop stops
            after the block of :data:`LOOP_BLOCK` steps that holds step ``n_run - 1``; later
            steps' outputs are zeros (forward and ``jvp`` only, no reverse mode).

    Returns:
        dict: the :class:`StepOutput` fields, [n_steps] for one law or [n_steps, n_wheels]
        for a tuple of laws; ``t`` [n_steps] s; every observer's per-step values
        (``[n_steps, ...]``) and summaries, by name.
    """
    single = not isinstance(law, tuple)
    laws = (law,) if single else law
    precision = loop_precision(precision, direct=not all(pointwise(lw) for lw in laws))
    groups = law_groups(laws)  # before the precision cast, which copies every law
    ls = loop_setup(laws, struct, speed, dt, x_start, impact_position, precision, roughness)
    observers = tuple(cast_precision(tuple(observers), precision))
    if ls.struct.supports is not None:
        observers += (HangingSleepers(),)
    ctx = LoopContext(ls.struct.track, len(laws), ls.preload.dtype, ls.struct.supports)
    start = static_start(ls)
    states0 = tuple(o.init(ctx) for o in observers)
    own0 = rail_reads(start.phi0, ctx.model.weights, ls.an_r, start.q0)[1]
    states0, first_saved = _observe(observers, states0, Reading(
        0, start.q0, ls.preload, start.x0, own0, start.supports), ctx)
    carry0 = LoopState(start.q0, jnp.zeros_like(ls.e_w), ls.preload, start.phi0,
                       tuple(lw.init_state() for lw in ls.laws), states0, start.supports)
    step = _step_fn(ls, start, observers, ctx, groups, max_iter)
    step = jax.checkpoint(step) if checkpoint else step
    if n_run is None:
        last, (outs, saved) = jax.lax.scan(step, carry0, jnp.arange(1, n_steps))
    else:
        last, (outs, saved) = _scan_until(step, carry0, n_steps, n_run)
    first = StepOutput(start.x0, start.s0, ls.preload, start.delta0, start.xi_w_ref,
                       start.xi_r0, jnp.zeros_like(ls.preload), jnp.zeros_like(ls.preload))
    result = {k: jnp.concatenate([jnp.asarray(a0, dtype=a.dtype)[None], a])
              for k, a0, a in zip(StepOutput._fields, first, outs, strict=True)}
    summaries = {}
    for obs, state in zip(observers, last.observers, strict=True):
        summaries |= obs.finalize(state, ctx)
    if single:
        result = {k: a[:, 0] for k, a in result.items()}
        summaries = {k: (a[0] if k == "detector_peak" else a) for k, a in summaries.items()}
    result |= {k: jnp.concatenate([first_saved[k][None], a]) for k, a in saved.items()}
    return result | summaries | {"t": dt * jnp.arange(n_steps)}  # t from the uncast step


_LOOP_STATIC = ("n_steps", "max_iter", "checkpoint", "precision")
run_scan = jax.jit(time_loop, static_argnames=_LOOP_STATIC)
run_scan.__doc__ = """:func:`time_loop` compiled (one program per law class, observers' static
fields and grid shapes).

``vmap`` it over runs, and over laws prepared for a batch of flats; ``grad`` reaches every
traced leaf of the law (the flat's geometry) and of the structure. Under your own top-level
``jax.jit``, ``compiler_options=loop_compiler_options()`` compiles it in about half the CPU time
on a CPU (and is None elsewhere; :mod:`wfjax._xla`)."""
