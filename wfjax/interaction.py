"""Time-domain wheel/rail interaction (Section 3, Eqs. 4-16): :func:`simulate`.

The model
---------
Displacements are positive downwards. The wheel (2-DOF, Table 1) carries the preload P and is
pushed up by the contact force F; the rail (Rayleigh-Timoshenko FE track, Table 2) is pushed
down by F at the moving contact point X(t) = X_0 + v t. Both are linear and enter through their
modal (complex-mode) impulse responses, which is Eqs. (4)-(5) written in state-space form:

* wheel:  xi_W(t) = xi_W,ref - int_0^t h_W(t - tau) (F(tau) - P) dtau,
* rail:   xi_R(t) = int F(tau) h_R(X(t), X(tau), t - tau) dtau  (the moving Green's function
  g^{v tau}(t - tau) of Eq. 5 is h_R between the two positions), evaluated mode by mode.

Both are propagated *exactly* in discrete time (exponential of each pole, first-order hold on
the input), so a step costs O(number of modes) and has no truncated memory. Modes of the track
above ``SimConfig.track_max_frequency`` enter through their static compliance at the contact.

The approach (compression of the contact relative to the undamaged surfaces) is
delta = xi_W - xi_R, and the contact law gives F = F_c(delta, s) with s the wheel position
relative to the impact (s = 0 when the flat centre is at the nominal contact point). Within a
step the structure responds to F_n through a scalar compliance c, so every step solves the
scalar equation r(delta) = delta - delta_free + c F_c(delta, s_n) = 0 (monotone in delta) by a
bracketed Newton iteration started at delta_free, where r >= 0. For a convex law
(Hertz-like) Newton from that end converges monotonically. Loss of contact is exact: if
F_c(delta_free) = 0, then delta = delta_free and F = 0. Gradients use the implicit function
theorem: one Newton step with the converged iterate held fixed.

Contact models (``contact=``): ``"hertz-profile"`` (Hertz spring, input = profile deviation),
``"hertz-trajectory"`` (Hertz spring, input = rigid wheel-centre trajectory, Wu & Thompson),
``"2d"`` (Winkler bedding) and ``"3d"`` (Kalker, through a precomputed table F(delta, s) or a
direct solve every step: ``SimConfig.contact_mode_3d``).

Impact position
---------------
``impact_position`` is the rail coordinate [m] (measured from a sleeper centre, within one bay
[0, L_S)) where the flat centre meets the nominal contact point. The paper instead varies the
initial angular position of the wheel, ``angle0`` [rad]: with the wheel starting at rail
coordinate X_0 with the flat centre at angle ``angle0`` ahead of the contact point (rolling
direction), the flat reaches the contact after rolling R * angle0, so
impact_position = (X_0 + R * angle0) mod L_S. :func:`impact_position_from_angle` does that.
"""

from __future__ import annotations

import csv
import io
import json
import math
from functools import partial
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from . import geometry
from . import track as track_mod
from . import wheel as wheel_mod
from ._modal import discrete_step_coefficients
from .contact import hertz, winkler
from .params import MAX_FLAT_DEPTH, Flat, Material, SimConfig, Track, Wheel, _is_concrete

__all__ = [
    "CONTACT_MODELS",
    "SimResult",
    "simulate",
    "impact_position_from_angle",
    "simulation_window",
]

CONTACT_MODELS = ("3d", "2d", "hertz-trajectory", "hertz-profile")
RUN_IN_TIME = 0.02  # s of travel before the flat's window, from static equilibrium
RUN_OUT_TIME = 0.03  # s after the flat's window: loss of contact and re-impacts
FLAT_MARGIN = 0.02  # m added to the flat's half extent on either side of the window


class SimResult(NamedTuple):
    """Result of :func:`simulate` (a pytree: batched by :func:`wfjax.sweep`).

    Arrays are [n_steps] along time (batched results have leading batch axes).

    Attributes:
        t: time [s], 0 at the start (static equilibrium).
        x: rail coordinate of the nominal contact point [m] (0 at a sleeper centre).
        s: wheel position relative to the impact [m] (0: flat centre at the contact point).
        force: normal contact force F [N] (>= 0).
        approach: contact approach delta = xi_W - xi_R [m].
        wheel_disp: wheel displacement at the contact point, downwards [m].
        rail_disp: rail displacement at the contact point, downwards [m].
        residual: |r(delta)| of the per-step contact equation at the solution [m].
        max_force: maximum contact force after the run-in [N].
        min_force: minimum contact force after the run-in [N].
        loss_of_contact: whether F = 0 occurred.
        loss_of_contact_duration: total time with F = 0 [s].
        speed: train speed v [m/s].
        impact_position: rail coordinate of the impact within the bay [m].
        time_step: dt [s].
    """

    t: Any
    x: Any
    s: Any
    force: Any
    approach: Any
    wheel_disp: Any
    rail_disp: Any
    residual: Any
    max_force: Any
    min_force: Any
    loss_of_contact: Any
    loss_of_contact_duration: Any
    speed: Any
    impact_position: Any
    time_step: Any

    def summary(self) -> dict:
        """JSON-ready summary with practical units (kN, km/h, mm, ms)."""
        return {
            "speed_kmh": float(self.speed) * 3.6,
            "impact_position_mm": float(self.impact_position) * 1e3,
            "max_force_kN": float(self.max_force) / 1e3,
            "min_force_kN": float(self.min_force) / 1e3,
            "loss_of_contact": bool(self.loss_of_contact),
            "loss_of_contact_duration_ms": float(self.loss_of_contact_duration) * 1e3,
            "time_step_us": float(self.time_step) * 1e6,
            "n_steps": int(np.shape(self.t)[-1]),
            "max_contact_residual_m": float(np.max(self.residual)),
        }

    def to_csv(self) -> str:
        """The time histories as CSV text (SI units, one row per step)."""
        buf = io.StringIO()
        w = csv.writer(buf)
        w.writerow(["t_s", "x_m", "s_m", "force_N", "approach_m", "wheel_disp_m", "rail_disp_m"])
        cols = [np.asarray(getattr(self, k)) for k in
                ("t", "x", "s", "force", "approach", "wheel_disp", "rail_disp")]
        for row in zip(*cols, strict=True):
            w.writerow([f"{v:.9g}" for v in row])
        return buf.getvalue()

    def to_json(self) -> str:
        """:meth:`summary` as JSON text."""
        return json.dumps(self.summary(), indent=2)


# -- setup (concrete, outside jit) ----------------------------------------------------------
def impact_position_from_angle(angle0, start_position: float = 0.0, wheel_radius: float = 0.45,
                               sleeper_spacing: float = 0.65):
    """Impact position [m] within the bay from the paper's initial angular wheel position.

    Args:
        angle0: angle [rad] by which the flat centre is ahead of the contact point (in the
            rolling direction) when the wheel is at rail coordinate ``start_position`` [m].
        start_position: initial rail coordinate of the nominal contact point [m].
        wheel_radius: R_W [m]. sleeper_spacing: L_S [m].

    Returns:
        (start_position + R angle0) mod L_S [m].
    """
    return np.mod(start_position + wheel_radius * np.asarray(angle0), sleeper_spacing)


def simulation_window(flat: Flat, speed: float, config: SimConfig) -> tuple[float, float]:
    """(s_start, s_end) [m]: wheel positions relative to the impact where the run starts/ends.

    Run-in ``RUN_IN_TIME`` s of travel before the flat's window (half extent + 20 mm), and
    ``RUN_OUT_TIME`` s after it, or ``config.run_in``/``config.run_out`` m if longer.
    """
    half = flat.half_extent + FLAT_MARGIN
    run_in = max(config.run_in, RUN_IN_TIME * speed)
    run_out = max(config.run_out, RUN_OUT_TIME * speed)
    return -(half + run_in), half + run_out


def _check_speed(speed) -> float:
    v = float(speed)
    if not math.isfinite(v) or v <= 0 or v > 150:
        raise ValueError(f"speed must be in (0, 150] m/s (0-540 km/h), got {speed!r} m/s")
    return v


def _check_impact_position(position, spacing: float) -> float:
    p = float(position)
    if not math.isfinite(p) or p < 0 or p >= spacing:
        raise ValueError(
            f"impact_position must be in [0, {spacing:g}) m (within one sleeper bay), "
            f"got {position!r}"
        )
    return p


def n_steps_for(flat: Flat, speed: float, config: SimConfig) -> tuple[int, float]:
    """(number of steps, time step [s]) of a simulation at ``speed`` [m/s]."""
    s0, s1 = simulation_window(flat, speed, config)
    duration = (s1 - s0) / speed
    dt = config.time_step_for(speed)
    n = int(math.ceil(duration / dt)) + 1
    return n, duration / (n - 1)


class ContactSpec(NamedTuple):
    """What the per-step contact law needs: a static kind and a pytree of parameters."""

    kind: str  # static
    params: Any  # pytree


def _hertz_radius(wheel: Wheel, track: Track):
    # The paper's Hertz spring assumes equal wheel and rail-head radii (Eq. 15). For unequal
    # radii the geometric mean is the usual equivalent radius (exact for the contact area).
    return jnp.sqrt(wheel.radius * track.rail_head_radius)


def contact_spec(contact: str, flat: Flat, wheel: Wheel, track: Track, material: Material,
                 config: SimConfig, cache_dir=None) -> ContactSpec:
    """Prepare the contact law (concrete: builds node sets, trajectory grids or 3D tables).

    3D tables of concrete flats are cached on disk (see :func:`cached_table_3d`).
    """
    if contact not in CONTACT_MODELS:
        raise ValueError(f"contact must be one of {CONTACT_MODELS}, got {contact!r}")
    c_h = hertz.hertz_constant(material, _hertz_radius(wheel, track))
    if contact == "hertz-profile":
        return ContactSpec("hertz-profile", {"c_h": c_h, "flat": flat})
    if contact == "hertz-trajectory":
        half = flat.half_extent + FLAT_MARGIN
        grid = jnp.linspace(-half, half, int(2 * half / 2e-5) + 1)
        drop = -geometry.centre_trajectory(flat, grid)
        return ContactSpec("hertz-trajectory", {"c_h": c_h, "s_grid": grid, "drop": drop})
    if contact == "2d":
        deepest = (None if _is_concrete(flat.depth)
                   else MAX_FLAT_DEPTH + winkler.DEFAULT_APPROACH_MARGIN)
        half = winkler.default_half_window(flat, float(wheel.radius), deepest)
        nodes = jnp.asarray(winkler.bedding_nodes(half, config.contact_element))
        return ContactSpec("2d", {"flat": flat, "material": material,
                                  "radius": wheel.radius, "nodes": nodes})

    table = cached_table_3d(flat, float(wheel.radius), float(track.rail_head_radius), material,
                            config.contact_element, cache_dir)
    return ContactSpec("3d", {"table": table})


def cached_table_3d(flat: Flat, wheel_radius: float, rail_head_radius: float,
                    material: Material, element_size: float, cache_dir=None):
    """:func:`wfjax.contact.tables.build_table_3d` through the on-disk cache.

    The key holds every input of the table (flat kind and geometry, radii, material, element
    size, and the builder's defaults through the wfjax version). Flats with traced geometry
    (``grad``, ``vmap``) are built directly, so gradients flow through the solves.
    """
    from ._cache import load_or_build
    from .contact import tables

    def build():
        return tables.build_table_3d(flat, wheel_radius, rail_head_radius, material,
                                     element_size=element_size)

    leaves = jax.tree_util.tree_leaves((flat, material))
    if not all(_is_concrete(leaf) for leaf in leaves):
        return build()
    key = {"flat_kind": flat.kind, "flat": [np.asarray(v) for v in leaves],
           "wheel_radius": wheel_radius, "rail_head_radius": rail_head_radius,
           "element_size": element_size}
    arrays = load_or_build("table3d", key, lambda: build()._asdict(), cache_dir)
    return tables.ContactTable(**{k: jnp.asarray(v) for k, v in arrays.items()})


def contact_force(spec_kind: str, params, delta, s):
    """Contact force F [N] of the prepared law at approach ``delta`` [m], position ``s`` [m]."""
    if spec_kind == "hertz-profile":
        z = geometry.profile_deviation(params["flat"], s)
        return _hertz_law(params["c_h"], delta - z)
    if spec_kind == "hertz-trajectory":
        drop = jnp.interp(s, params["s_grid"], params["drop"], left=0.0, right=0.0)
        return _hertz_law(params["c_h"], delta - drop)
    if spec_kind == "2d":
        return winkler.force_at_nodes(params["flat"], delta, s, params["material"],
                                      params["radius"], params["nodes"])
    from .contact import tables

    return tables.table_force(params["table"], delta, s)


def _hertz_law(c_h, compression):
    positive = compression > 0
    safe = jnp.where(positive, compression, 1.0)
    return jnp.where(positive, c_h * safe**1.5, 0.0)


# -- the scalar contact equation --------------------------------------------------------------
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

    :func:`bracketed_newton` on r(delta) = delta - delta_free + c F(delta), made
    differentiable by the implicit function theorem: one Newton step from the converged
    iterate with the iterate and the slope held fixed (exact first derivatives at the root).

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


# -- the time loop -----------------------------------------------------------------------------
class Structure(NamedTuple):
    """Modal data of wheel and track used by the time loop (arrays; a pytree)."""

    track: Any  # track.ModalModel
    wheel_poles: Any  # complex [n_w] rad/s
    wheel_residues: Any  # complex [n_w] m/(N s): h_W(t) = Re sum residues exp(poles t)
    preload: Any  # N


def structure(wheel: Wheel, track: Track, config: SimConfig, cache_dir=None) -> Structure:
    """Modal models of wheel and track (the track's is cached on disk)."""
    model = track_mod.modal_model(track, max_frequency=config.track_max_frequency,
                                  cache_dir=cache_dir)
    wheel_modes = wheel_mod.modal_model(wheel)
    return Structure(model, wheel_modes.poles, wheel_modes.residues,
                     jnp.asarray(wheel.preload, dtype=float))


def _node_major_shapes(model):
    """Mode shapes as [n_nodes, 2, n_modes]: each step gathers two contiguous rows."""
    return jnp.transpose(model.shapes, (1, 2, 0))


def _rail_terms(model, node_major, x):
    """(phi_r(x) [n_modes], residual compliance [m/N]) at rail position ``x`` [m].

    Same interpolation as :func:`wfjax.track.mode_shapes_at` (tested equal), on node-major
    shapes so the per-step gather reads contiguous memory.
    """
    node_x = model.node_x
    le = node_x[1] - node_x[0]
    xc = jnp.clip(x, node_x[0], node_x[-1])
    e = jnp.clip(jnp.floor((xc - node_x[0]) / le).astype(jnp.int32), 0, node_x.shape[0] - 2)
    n1, n2, n3, n4 = track_mod.shape_functions((xc - node_x[e]) / le, model.element_phi, le)
    a, b = node_major[e], node_major[e + 1]
    phi = n1 * a[0] + n2 * a[1] + n3 * b[0] + n4 * b[1]
    return phi, track_mod.residual_compliance_at(model, x)


def time_loop(contact_step, static_law, aux0, struct: Structure, speed, dt, x_start,
              impact_position, n_steps: int, checkpoint: bool = False):
    """The time loop under ``lax.scan`` with a pluggable per-step contact solve (pure).

    Args:
        contact_step: (delta_free [m], compliance [m/N], s [m], aux) -> (delta [m], F [N],
            |r| [m], aux): solves the step's scalar contact equation.
        static_law: (delta, s) -> F, used for the static equilibrium at the start.
        aux0: initial contact-solver state (e.g. a pressure warm start; ``None``).
        struct: modal wheel and track (:func:`structure`).
        speed: v [m/s]; dt: time step [s]; x_start: rail coordinate at t = 0 [m];
        impact_position: rail coordinate where s = 0 [m]; n_steps: steps incl. t = 0 (static).
        checkpoint: rematerialise each step in reverse mode (``jax.checkpoint``): memory of
            the backward pass drops to the carry per step at the cost of recomputing steps.

    Returns:
        dict of [n_steps] arrays: t, x, s, force, approach, wheel_disp, rail_disp, residual.
    """
    model = struct.track
    w_r = model.weights
    preload = struct.preload
    e_r, ap_r, an_r = discrete_step_coefficients(model.poles, dt)
    e_w, ap_w, an_w = discrete_step_coefficients(struct.wheel_poles, dt)
    c_wheel = jnp.real(jnp.sum(struct.wheel_residues * an_w))

    # static equilibrium at the start: F = P, rail in its static deflected shape
    s0 = x_start - impact_position
    node_major = _node_major_shapes(model)
    phi0, res0 = _rail_terms(model, node_major, x_start)
    q0 = -phi0 * preload / model.poles
    xi_r0 = jnp.real(jnp.sum(w_r * phi0 * q0)) + res0 * preload
    delta0 = _static_approach(static_law, s0, preload)
    xi_w_ref = xi_r0 + delta0
    p0 = jnp.zeros_like(struct.wheel_poles)

    def step(carry, n):
        q, p, f_prev, phi_prev, aux = carry
        x = x_start + speed * dt * n
        s = x - impact_position
        phi, res = _rail_terms(model, node_major, x)
        q_hat = e_r * q + ap_r * phi_prev * f_prev
        xi_r_free = jnp.real(jnp.sum(w_r * phi * q_hat))
        c_rail = jnp.real(jnp.sum(w_r * an_r * phi * phi)) + res
        p_hat = e_w * p + ap_w * (f_prev - preload)
        xi_w_free = xi_w_ref - jnp.real(jnp.sum(struct.wheel_residues * p_hat)) + c_wheel * preload
        delta, f, r, aux = contact_step(xi_w_free - xi_r_free, c_wheel + c_rail, s, aux)
        q_new = q_hat + an_r * phi * f
        p_new = p_hat + an_w * (f - preload)
        out = (x, s, f, delta, xi_w_free - c_wheel * f, xi_r_free + c_rail * f, r)
        return (q_new, p_new, f, phi, aux), out

    carry0 = (q0, p0, preload, phi0, aux0)
    _, outs = jax.lax.scan(jax.checkpoint(step) if checkpoint else step, carry0,
                           jnp.arange(1, n_steps))
    first = (x_start, s0, preload, delta0, xi_w_ref, xi_r0, 0.0)
    keys = ("x", "s", "force", "approach", "wheel_disp", "rail_disp", "residual")
    result = {k: jnp.concatenate([jnp.asarray(a0, dtype=a.dtype)[None], a])
              for k, a0, a in zip(keys, first, outs, strict=True)}
    result["t"] = dt * jnp.arange(n_steps)
    return result


@partial(jax.jit, static_argnames=("spec_kind", "n_steps", "max_iter", "checkpoint"))
def run_scan(spec_kind: str, params, struct: Structure, speed, dt, x_start, impact_position,
             n_steps: int, max_iter: int = 30, checkpoint: bool = False):
    """:func:`time_loop` with a tabulated/closed-form contact law (vmap- and grad-able).

    Args:
        spec_kind, params: the prepared contact law (see :func:`contact_spec`).
        other arguments: as :func:`time_loop`; ``max_iter`` caps the per-step Newton loop;
        ``checkpoint`` rematerialises steps in reverse mode (memory).

    Returns:
        dict of [n_steps] arrays (see :func:`time_loop`).
    """
    params_ng = jax.lax.stop_gradient(params)

    def law(delta, s, params=params):
        return contact_force(spec_kind, params, delta, s)

    def contact_step(delta_free, compliance, s, aux):
        delta, f, r = solve_contact_step(
            lambda d: law(d, s), delta_free, compliance, max_iter,
            loop_force_fn=lambda d: law(d, s, params_ng))
        return delta, f, r, aux

    return time_loop(contact_step, law, None, struct, speed, dt, x_start, impact_position,
                     n_steps, checkpoint)


def _static_approach(law, s0, preload, max_iter: int = 30):
    """Approach [m] with law(delta, s0) = preload (Newton from the right; law convex)."""
    def body(_, d):
        f, df = jax.value_and_grad(lambda a: law(a, s0))(d)
        return d - (f - preload) / jnp.where(df > 0, df, 1.0)

    # Start below the root (10 um: F < P for any realistic contact): the first Newton step on
    # the convex law overshoots above the root, from where the iterates decrease monotonically.
    # A fixed iteration count keeps reverse-mode differentiation possible.
    return jax.lax.fori_loop(0, max_iter, body, jnp.asarray(1e-5))


def summarise(hist: dict, speed, impact_position, dt, run_in_steps) -> SimResult:
    """Reduce histories to a :class:`SimResult` (pure jnp; works batched under vmap)."""
    f = hist["force"]
    n = f.shape[-1]
    after = jnp.arange(n) >= run_in_steps
    f_after = jnp.where(after, f, jnp.nan)
    lost = after & (f <= 0)
    return SimResult(
        t=hist["t"], x=hist["x"], s=hist["s"], force=f, approach=hist["approach"],
        wheel_disp=hist["wheel_disp"], rail_disp=hist["rail_disp"], residual=hist["residual"],
        max_force=jnp.nanmax(f_after, axis=-1), min_force=jnp.nanmin(f_after, axis=-1),
        loss_of_contact=jnp.any(lost, axis=-1),
        loss_of_contact_duration=jnp.sum(lost, axis=-1) * dt,
        speed=jnp.asarray(speed, dtype=float), impact_position=jnp.asarray(impact_position,
                                                                             dtype=float),
        time_step=jnp.asarray(dt, dtype=float),
    )


def simulate(flat: Flat, speed: float, contact: str = "3d", impact_position: float = 0.0,
             wheel: Wheel | None = None, track: Track | None = None,
             material: Material | None = None, config: SimConfig | None = None,
             angle0: float | None = None, cache_dir=None,
             n_steps: int | None = None) -> SimResult:
    """Simulate a wheel with ``flat`` rolling at ``speed`` over the discretely supported track.

    Args:
        flat: the wheel flat (:class:`wfjax.Flat`); ``Flat.none()`` for a smooth wheel.
        speed: train speed v [m/s] in (0, 150].
        contact: ``"3d"``, ``"2d"``, ``"hertz-trajectory"`` or ``"hertz-profile"``.
        impact_position: rail coordinate [m] in [0, L_S) measured from a sleeper centre where
            the flat centre meets the nominal contact point.
        wheel, track, material, config: model parameters (defaults: Tables 1 and 2, E = 210 GPa,
            nu = 0.3, :class:`SimConfig` defaults).
        angle0: alternatively the paper's initial angular position of the flat [rad] ahead of
            the contact at the start of the run; overrides ``impact_position`` (see module doc).
        cache_dir: where the track's modal model is cached (default: ``WFJAX_CACHE_DIR`` or
            ``~/.cache/wfjax``).
        n_steps: number of time steps (default: from ``config``); the time step becomes the
            window's duration / (n_steps - 1), as in :func:`wfjax.sweep`.

    Returns:
        :class:`SimResult` with time histories [n_steps] and summary values.
    """
    wheel = wheel or Wheel()
    track = track or Track()
    material = material or Material()
    config = config or SimConfig()
    v = _check_speed(speed)
    if abs(float(flat.wheel_radius) - float(wheel.radius)) > 1e-12:
        raise ValueError(
            f"flat.wheel_radius ({float(flat.wheel_radius)} m) must equal wheel.radius "
            f"({float(wheel.radius)} m)"
        )
    spacing = float(track.sleeper_spacing)
    s_start, _ = simulation_window(flat, v, config)
    if angle0 is not None:
        impact_position = float(impact_position_from_angle(
            angle0, s_start, float(wheel.radius), spacing))
    x_imp = _check_impact_position(impact_position, spacing)
    n_auto, dt = n_steps_for(flat, v, config)
    if n_steps is None:
        n_steps = n_auto
    elif int(n_steps) < 2:
        raise ValueError(f"n_steps must be >= 2, got {n_steps!r}")
    else:
        s0, s1 = simulation_window(flat, v, config)
        dt = (s1 - s0) / v / (int(n_steps) - 1)
    if contact not in CONTACT_MODELS:
        raise ValueError(f"contact must be one of {CONTACT_MODELS}, got {contact!r}")
    struct = structure(wheel, track, config, cache_dir)
    if contact == "3d" and config.contact_mode_3d == "direct":
        from .direct3d import run_direct_3d

        hist = run_direct_3d(flat, struct, v, dt, x_imp + s_start, x_imp, int(n_steps),
                             wheel, track, material, config)
    else:
        spec = contact_spec(contact, flat, wheel, track, material, config, cache_dir)
        hist = run_scan(spec.kind, spec.params, struct, v, dt, x_imp + s_start, x_imp,
                        int(n_steps), config.newton_iterations)
    run_in_steps = int(0.5 * RUN_IN_TIME / dt)
    return summarise(hist, v, x_imp, dt, run_in_steps)
