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
``"2d"`` (Winkler bedding) and ``"3d"`` (Kalker: the exact table F(delta, s) of one flat, the
parametric family F(delta, s; depth, length) or a direct solve every step:
``SimConfig.contact_mode_3d``). Each is a law of :mod:`wfjax.contact.laws`, prepared once
outside the compiled program; this module owns only the time loop, which calls the law's
``step`` and knows no model by name.

Impact position
---------------
``impact_position`` is the rail coordinate [m] (measured from a sleeper centre, within one bay
[0, L_S)) where the flat centre meets the nominal contact point. The paper instead varies the
initial angular position of the wheel, ``angle0`` [rad]: with the wheel starting at rail
coordinate X_0 with the flat centre at angle ``angle0`` ahead of the contact point (rolling
direction), the flat reaches the contact after rolling R * angle0, so
impact_position = (X_0 + R * angle0) mod L_S. :func:`impact_position_from_angle` does that.
On a track whose supports vary (:func:`wfjax.supports.is_uniform` false) every bay differs and
``impact_position`` is an absolute rail coordinate (x = 0 above the middle sleeper;
``docs/real_track.md``).

Roughness
---------
``simulate(roughness=, wheel_roughness=)`` and ``time_loop(roughness=)`` (a
:class:`wfjax.roughness.LoopRoughness`): point-contact laws add the contact-filtered
roughness to the approach, the 2D bedding and the direct 3D solve take it off the gap element
by element (:meth:`wfjax.contact.laws.ContactLaw.rough_nodes`); see ``docs/real_track.md``.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from . import roughness as rough_mod
from . import sensors as sensor_mod
from . import supports as supports_mod
from . import track as track_mod
from . import vehicle as vehicle_mod
from . import wheel as wheel_mod
from ._modal import discrete_step_coefficients
from ._xla import LOOP_COMPILER_OPTIONS, to_device
from .contact.laws import CONTACT_MODELS, FLAT_MARGIN, ContactLaw, prepare
from .contact.newton import solve_contact_system, solve_small, static_approach
from .params import Flat, Material, SimConfig, Track, Wheel
from .results import SimResult, summarise, summarise_vehicle

__all__ = [
    "CONTACT_MODELS",
    "SimResult",
    "run_scan",
    "LOOP_COMPILER_OPTIONS",
    "time_loop",
    "simulate",
    "impact_position_from_angle",
    "simulation_window",
    "batch_windows",
    "run_windows",
    "cast_precision",
    "vehicle_structure",
    "vehicle_laws",
    "solve_contacts",
    "loop_roughness",
    "check_rail_span",
]

RUN_IN_TIME = 0.02  # s of travel before the flat's window, from static equilibrium
RUN_OUT_TIME = 0.03  # s after the flat's window: loss of contact and re-impacts


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


def _check_impact_position(position, spacing: float, track: Track | None = None) -> float:
    """``position`` [m] in one bay [0, L_S) (a uniform track) or, on a track whose supports
    vary, an absolute rail coordinate (:func:`wfjax.sweeps.check_impact_positions`)."""
    if track is not None:
        from .supports import is_uniform

        if not is_uniform(track):
            from .sweeps import check_impact_positions

            return float(check_impact_positions([position], track)[0])
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


def run_windows(flat: Flat, speeds, config: SimConfig):
    """Every speed's own window, as :func:`simulate` runs it (:func:`n_steps_for`).

    Returns:
        (n_steps [n_speeds] int, dt [n_speeds] s, s_start [n_speeds] m, run_in [n_speeds]
        steps before the max/min summaries start).
    """
    speeds = np.asarray(speeds, dtype=float)
    n_steps, dt = (np.array(a) for a in zip(*(n_steps_for(flat, float(v), config)
                                              for v in speeds), strict=True))
    s0 = np.array([simulation_window(flat, float(v), config)[0] for v in speeds])
    return n_steps.astype(int), dt, s0, np.floor(0.5 * RUN_IN_TIME / dt).astype(int)


def batch_windows(flat: Flat, speeds, config: SimConfig):
    """Windows of a batch of runs at ``speeds`` [m/s] that share one compiled step count.

    Every speed gets the step count of the one that needs the most and its own time step.

    Returns:
        (n_steps, dt [n_speeds] s, s_start [n_speeds] m, run_in [n_speeds] steps before the
        max/min summaries start).
    """
    speeds = np.asarray(speeds, dtype=float)
    n_steps = max(n_steps_for(flat, float(v), config)[0] for v in speeds)
    s0, s1 = np.array([simulation_window(flat, float(v), config) for v in speeds]).T
    dt = (s1 - s0) / speeds / (n_steps - 1)
    return n_steps, dt, s0, np.floor(0.5 * RUN_IN_TIME / dt).astype(int)


# -- the time loop -----------------------------------------------------------------------------
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


class Structure(NamedTuple):
    """Modal data of the wheels and the track used by the time loop (arrays; a pytree).

    One wheel (:func:`structure`): ``wheel_poles``, ``wheel_residues``, ``axle_residues``
    [n_w] and a scalar ``preload``; the vehicle fields are None. A vehicle
    (:func:`vehicle_structure`): the same with a leading wheel axis [n_wheels, ...] and
    ``offsets`` [n_wheels] (rail coordinate of every wheel relative to the reference wheel
    [m]), ``delays`` [n_wheels] (the flats' delays [m], :class:`wfjax.vehicle.Vehicle`) and
    ``residual_pairs`` [n_res, n_wheels, n_wheels] (static compliance of the truncated track
    modes between the wheels across one bay, or along the whole rail when the supports vary:
    :func:`wfjax.vehicle.residual_pairs`). ``supports``: the track's one-sided (hanging)
    sleepers, :func:`wfjax.supports.one_sided_spec`, or None.
    """

    track: Any  # track.ModalModel
    wheel_poles: Any  # complex [n_w] rad/s
    wheel_residues: Any  # complex [n_w] m/(N s): h_W(t) = Re sum residues exp(poles t)
    preload: Any  # N
    axle_residues: Any = None  # complex [n_w] m/(N s): the wheelset mass's (axle box's) h
    offsets: Any = None
    delays: Any = None
    residual_pairs: Any = None
    supports: Any = None  # supports.OneSidedSupports of hanging sleepers, or None


def structure(wheel: Wheel, track: Track, config: SimConfig, cache_dir=None) -> Structure:
    """Modal models of wheel and track (the track's is cached on disk)."""
    model = track_mod.modal_model(track, max_frequency=config.track_max_frequency,
                                  cache_dir=cache_dir)
    wheel_modes = wheel_mod.modal_model(wheel)
    return Structure(model, wheel_modes.poles, wheel_modes.residues,
                     to_device(wheel.preload, float), wheel_modes.axle_residues,
                     supports=_one_sided(track, model))


def vehicle_structure(vehicle, wheels: list[Wheel], track: Track, config: SimConfig,
                      cache_dir=None) -> Structure:
    """:class:`Structure` of a :class:`wfjax.vehicle.Vehicle` with wheel models ``wheels``
    ([n] :class:`Wheel`), placed on the track by :func:`wfjax.vehicle.placement`."""
    model = track_mod.modal_model(track, max_frequency=config.track_max_frequency,
                                  cache_dir=cache_dir)
    ws = vehicle_mod.wheel_set(wheels)
    offsets = vehicle.offsets()
    pairs = vehicle_mod.residual_pairs(
        track, model, offsets, vehicle_mod.placement(vehicle, float(track.sleeper_spacing)))
    return Structure(model, ws.poles, ws.residues, ws.preload, ws.axle_residues,
                     jnp.asarray(offsets), jnp.asarray(vehicle.delays()), jnp.asarray(pairs),
                     _one_sided(track, model, offsets))


def _one_sided(track: Track, model, offsets=(0.0,)):
    spec = supports_mod.one_sided_spec(track, model, offsets)
    return None if spec is None else jax.tree_util.tree_map(jnp.asarray, spec)


def _node_major_shapes(model):
    """Mode shapes as [n_nodes, 2, n_modes]: each step gathers two contiguous rows."""
    return jnp.transpose(model.shapes, (1, 2, 0))


def _rail_terms(model, node_major, x):
    """(phi_r(x) [n_modes], residual compliance [m/N]) at rail position ``x`` [m].

    Same interpolation as :func:`wfjax.track.mode_shapes_at` (tested equal), on node-major
    shapes so the per-step gather reads contiguous memory.
    """
    phi = track_mod.interpolate_nodal(model, node_major, x)
    return phi, track_mod.residual_compliance_at(model, x)


def _residual_matrix(struct: Structure, model, x_ref):
    """[n, n] static compliance of the truncated modes between the wheels [m/N] with the
    reference wheel at ``x_ref`` [m] (one wheel: the track's own residual there)."""
    if struct.residual_pairs is None:
        return track_mod.residual_compliance_at(model, x_ref)[None, None]
    return track_mod.read_residual_table(model, struct.residual_pairs, x_ref)


def _loads(f, phi):
    """sum_i f_i phi_i(x_i): modal loads [n_modes] of forces f [n] at shapes phi [n, n_modes]."""
    return sum(f[i] * phi[i] for i in range(f.shape[0]))


def _rail_reads(phi, w_r, an_r, q_hat):
    """(xi_free [n] m, c [n] m/N): the rail at every wheel from the propagated modal state
    ``q_hat`` [n_modes], Re sum_r w_r phi_ir q_r, and every wheel's own rail compliance
    within the step, Re sum_r w_r an_r phi_ir^2, for shapes ``phi`` [n, n_modes]."""
    xi = jnp.real(jnp.sum(phi * (w_r * q_hat), axis=-1))
    return xi, jnp.real(jnp.sum(w_r * an_r * phi * phi, axis=-1))


def shapes_fn(model):
    """x [n] m -> the mode shapes there, [n, n_modes] complex: the time loop's node-major
    interpolation (each wheel gathers two contiguous rows)."""
    node_major = _node_major_shapes(model)
    return lambda x: jax.vmap(lambda xi: track_mod.interpolate_nodal(model, node_major, xi))(x)


def cross_table_origin(model, impact_position):
    """x_bay [m] of :func:`_cross_table` for a run: the impact's bay on a uniform track (the
    table is read periodically), 0 when the supports vary (the table runs along the rail)."""
    return jnp.where(track_mod.residual_table_is_periodic(model),
                     impact_position - jnp.mod(impact_position, model.sleeper_spacing), 0.0)


def _cross_table(model, shapes_at, offsets, weight, x_bay):
    """[n_res, n, n] the rail's compliance within a step between different wheels,
    Re sum_r weight_r phi_r(x + o_i) phi_r(x + o_j) (zero diagonal), for the reference wheel
    at x = x_bay + model.residual_x: across one bay on a uniform track, along the whole rail
    (``x_bay`` = 0) when the supports vary (read by :func:`wfjax.track.read_residual_table`).

    These cross terms are about 1e-3 of a wheel's own step compliance (the rail's response
    within one step hardly reaches the next wheel), but summing them over the modes at every
    step would cost n (n - 1) / 2 passes over the modes: tabulated once per run across the
    bay, like the residual compliance, and interpolated, they cost what 33 steps cost (along
    the whole rail when the supports vary, 2241 points: a bogie's ``simulate`` there took
    1.26x the uniform track's, tables and all).
    """
    n = offsets.shape[0]
    upper = np.triu_indices(n, 1)

    def at(x):
        phi = shapes_at(x + offsets)
        values = jnp.real(jnp.sum(weight * phi[upper[0]] * phi[upper[1]], axis=-1))
        table = jnp.zeros((n, n), values.dtype).at[upper].set(values)
        return table + table.T

    return jax.lax.map(at, x_bay + model.residual_x)


def _pointwise(law: ContactLaw) -> bool:
    """Whether ``law`` solves its steps through :meth:`ContactLaw.step` (point/point_force)."""
    return type(law).step is ContactLaw.step


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

    One wheel: the law's own :meth:`ContactLaw.step`. Several wheels with point laws (every
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
    if len(laws) == 1 and extra is None:
        (law,), (state,) = laws, states
        delta, f, r, state = law.step(delta_free[0], compliance[0, 0], s[0], state, max_iter,
                                      **kw(0))
        return delta[None], f[None], r[None], (state,)
    if all(_pointwise(law) for law in laws):
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
            lambda d: forces(reps, points, d, params), delta_free, compliance, max_iter,
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


def _roughness_inputs(laws, roughness, x, s):
    """(approach offsets [n] m, per-wheel element inputs) of the roughness at the wheels'
    rail positions ``x`` [n] and flat coordinates ``s`` [n]: a point law's offset is the
    contact-filtered roughness (its element input None); a law with ``rough_nodes`` gets
    offset 0 and the pair (roughness at its nodes, the filtered value)."""
    if roughness is None:
        return (0.0,) * len(laws), (None,) * len(laws)
    r_eq = rough_mod.loop_equivalent(roughness, x, s)
    shift, rough = [], []
    for i, law in enumerate(laws):
        nodes = law.rough_nodes()
        if nodes is None:
            shift.append(r_eq[i])
            rough.append(None)
        else:
            shift.append(jnp.zeros_like(r_eq[i]))
            rough.append((rough_mod.loop_at_nodes(roughness, x[i], s[i], nodes), r_eq[i]))
    return jnp.stack(shift), tuple(rough)


def _static_force(law, s, shift, rough):
    """F(d) [N] of ``law`` at kinematic approach d (xi_W - xi_R) [m] with roughness: the
    static start (a law with its own step, the direct 3D mode, starts on its table)."""
    if rough is None:
        return lambda d: law.force(d + shift, s)
    if not _pointwise(law):
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


class LoopSetup(NamedTuple):
    """What the time loop computes before its scan, in the loop's precision
    (:func:`loop_setup`; :func:`time_loop` and :mod:`wfjax.adjoint` read the same one).

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


def _between_sleepers(sup, weight):
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
    static_ss = _between_sleepers(sup, w_r / -model.poles)
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
    s0 = ls.x_start - ls.impact_position - ls.delays
    x0 = ls.x_start + ls.offsets
    phi0 = shapes_fn(model)(x0)
    q0 = -_loads(ls.preload, phi0) / model.poles
    xi_r0 = (jnp.real(jnp.sum(phi0 * (model.weights * q0), axis=-1))
             + _residual_matrix(ls.struct, model, ls.x_start) @ ls.preload)
    supports = ()
    if ls.struct.supports is not None:  # hanging sleepers: a non-linear solve too
        q0, xi_r0, supports = _hanging_start(ls, q0, xi_r0, phi0)
    shift0, rough0 = _roughness_inputs(ls.laws, ls.roughness, x0, s0)
    delta0 = jnp.stack([static_approach(_static_force(lw, si, sh, ri), p)
                        for lw, si, p, sh, ri in zip(ls.laws, s0, ls.preload, shift0, rough0,
                                                     strict=True)])
    return StaticStart(s0, x0, phi0, q0, xi_r0, delta0, xi_r0 + delta0, supports)


def rail_compliance_fn(ls: LoopSetup):
    """(x_ref m, c_own [n] m/N) -> the rail's compliance within a step between the wheels,
    [n, n] m/N, with the reference wheel at ``x_ref``: the wheels' own kept-mode compliance
    ``c_own`` (:func:`_rail_reads`) on the diagonal, the truncated modes' static compliance
    and, for several wheels, the kept modes' cross terms (:func:`_cross_table`, built once
    here)."""
    struct, model = ls.struct, ls.struct.track
    cross = None
    if len(ls.laws) > 1:
        cross = _cross_table(model, shapes_fn(model), ls.offsets, model.weights * ls.an_r,
                             cross_table_origin(model, ls.impact_position))

    def rail_compliance(x_ref, c_own):
        c_rail = jnp.diag(c_own) + _residual_matrix(struct, model, x_ref)
        if cross is not None:
            c_rail = c_rail + track_mod.read_residual_table(model, cross, x_ref)
        return c_rail

    return rail_compliance


LOOP_BLOCK = 128  # steps per block of a loop that stops early (``time_loop(n_run=...)``)


def _scan_until(step, carry0, n_steps: int, n_run, block: int = LOOP_BLOCK):
    """``lax.scan(step, carry0, arange(1, n_steps))`` that computes only the steps before
    ``n_run`` (traced int; rounded up to whole blocks of ``block`` steps): a ``fori_loop`` over
    blocks, each a scan of ``block`` steps written into the stacked outputs. The outputs of the
    steps not computed are zeros; the carry is the one after the last step computed."""
    n_blocks = -(-(n_steps - 1) // block)
    shapes = jax.eval_shape(lambda c: step(c, jnp.arange(1, 2)[0])[1], carry0)
    outs0 = jax.tree.map(lambda a: jnp.zeros((n_blocks * block,) + a.shape, a.dtype), shapes)

    def run_block(b, state):
        carry, outs = state
        first = 1 + b * block
        carry, out = jax.lax.scan(step, carry, first + jnp.arange(block))
        return carry, jax.tree.map(
            lambda a, o: jax.lax.dynamic_update_slice_in_dim(a, o, first - 1, 0), outs, out)

    todo = jnp.clip((jnp.asarray(n_run) - 1 + block - 1) // block, 0, n_blocks)
    carry, outs = jax.lax.fori_loop(0, todo, run_block, (carry0, outs0))
    return carry, jax.tree.map(lambda a: a[:n_steps - 1], outs)


def time_loop(law, struct: Structure, speed, dt, x_start, impact_position,
              n_steps: int, max_iter: int = 30, checkpoint: bool = False, sensors=None,
              detector=None, run_in_steps=0, sensor_history: bool = True,
              precision: str = "float64", roughness=None, own_compliance: bool = False,
              end_steps=None, n_run=None):
    """The time loop under ``lax.scan`` for any contact law and any number of wheels (pure).

    Args:
        law: the prepared contact law (:func:`wfjax.contact.laws.prepare`); its ``step``
            solves each step's contact equation, its ``force`` the static equilibrium. A
            tuple of laws, one per wheel of a vehicle (``struct`` from
            :func:`vehicle_structure`), runs every wheel on the shared track.
        struct: modal wheel(s) and track (:func:`structure`, :func:`vehicle_structure`).
        speed: v [m/s]; dt: time step [s]; x_start: rail coordinate of the (reference) wheel
            at t = 0 [m]; impact_position: its rail coordinate where s = 0 [m] (a wheel i of
            a vehicle is at x + offsets[i] with s_i = s - delays[i]);
            n_steps: steps incl. t = 0 (static).
        max_iter: Newton iteration cap of the per-step contact equation (static).
        checkpoint: rematerialise each step in reverse mode (``jax.checkpoint``): memory of
            the backward pass drops to the carry per step at the cost of recomputing steps.
        sensors: a :class:`wfjax.sensors.SensorSpec` (or None): readings at fixed rail
            positions from the modal state of every step (every wheel's load included).
        detector: a :class:`wfjax.sensors.DetectorSpec` (or None): the detector's per-bay
            load estimate, and its peak while a wheel is between each bay's bridges.
        run_in_steps: steps before the sensors' running max/min start (traced int).
        end_steps: steps of the run's own window (traced int; default ``n_steps``): the
            sensors' and detector's running extremes count the steps
            ``run_in_steps <= n < end_steps`` only (a sweep runs a batch's shorter windows
            for its longest one's step count).
        n_run: steps to compute (traced int, at most ``n_steps``; default all): the loop
            stops after the block of :data:`LOOP_BLOCK` steps that holds step ``n_run - 1``
            and the later steps' outputs are zeros (a sweep's chunk of runs stops at its
            longest run's own window; ``end_steps`` keeps the zeros out of the summaries).
            A loop of traced length: forward evaluation and ``jvp`` only, no reverse mode.
        sensor_history: return the sensors' and detector's time histories (static; False
            keeps only running max/min and peaks in the carry: no [n_steps] arrays).
        precision: ``"float64"`` or ``"float32"`` (static, :attr:`SimConfig.precision`): the
            dtype of the loop (the sensors' and detector's specs are cast with it). The
            propagation coefficients exp(pole dt) and their hold integrals are computed in the
            inputs' precision (float64) and then cast: their series in pole dt cancels to
            ~1e-3 relative in float32.
        roughness: a :class:`wfjax.roughness.LoopRoughness` (rail and wheel profiles and the
            contact filter's length; traced: ``vmap`` over realisations of its values), or
            None (the smooth program, unchanged). Point-contact laws (Hertz, the 3D table and
            family) see the contact-filtered roughness added to the approach; laws with
            :meth:`~wfjax.contact.laws.ContactLaw.rough_nodes` (the 2D bedding, the direct 3D
            solve) see it element by element in the gap. ``approach`` stays xi_W - xi_R.
        own_compliance: also return ``own_compliance`` [n_steps, n_wheels] (one law too):
            each wheel's rail compliance within the step from the kept modes,
            Re sum_r w_r an_r phi_r^2 [m/N] (static; for :mod:`wfjax.adjoint`).

    Returns:
        dict of [n_steps] arrays (one law) or [n_steps, n_wheels] (a tuple of laws): x, s,
        force, approach, wheel_disp, rail_disp, residual, axle_acc (acceleration of the
        wheelset mass, the axle box, downwards [m/s^2]); t [n_steps]; with ``sensors``:
        ``sensor_max``, ``sensor_min`` [n_quantities, n_s] after the run-in and
        (``sensor_history``) ``sensors`` [n_steps, n_quantities, n_s]; with ``detector``:
        ``detector_peak`` [n_bays] N ([n_wheels, n_bays] for a vehicle: each wheel's peak)
        and (``sensor_history``) ``detector_load`` [n_steps, n_bays] N (ungated estimate).
        With hanging sleepers (``struct.supports``): ``support_force`` [n_steps, n_s] N (the
        one-sided ballast's force, upwards on each sleeper) and ``sleeper_disp`` [n_steps,
        n_s] m (downwards).
    """
    single = not isinstance(law, tuple)
    laws = (law,) if single else law
    groups = law_groups(laws)  # before the precision cast, which copies every law
    ls = loop_setup(laws, struct, speed, dt, x_start, impact_position, precision, roughness)
    (laws, struct, e_r, ap_r, an_r, e_w, ap_w, an_w, preload, wheel_res, c_wheel, offsets,
     delays, speed, dt, x_start, impact_position, roughness) = ls
    sensors, detector = cast_precision((sensors, detector), precision)
    n_wheels = len(laws)
    wheel_poles = jnp.reshape(struct.wheel_poles, (n_wheels, -1))  # in the loop's precision
    model = struct.track
    w_r = model.weights
    real = preload.dtype  # the loop's precision
    axle_res = (jnp.zeros_like(wheel_res) if struct.axle_residues is None
                else jnp.reshape(struct.axle_residues, (n_wheels, -1)))
    axle_acc_res = -axle_res * wheel_poles**2
    shapes_at = shapes_fn(model)
    rail_compliance = rail_compliance_fn(ls)
    sup = struct.supports
    if sup is not None and (sensors is not None or detector is not None):
        raise ValueError("hanging sleepers (Track.ballast_gap > 0) are not supported with "
                         "sensors or a detector: their readings lack the support forces")

    # static equilibrium at the start: F = P, rail in its static deflected shape
    s0, x0, phi0, q0, xi_r0, delta0, xi_w_ref, support0 = static_start(ls)
    if sup is not None:  # hanging sleepers: their shapes and compliance within a step
        psi = sup.shapes  # [n_s, n_modes]
        within_ss = _between_sleepers(sup, w_r * an_r)
    p0 = jnp.zeros_like(wheel_poles)

    def counted(n):
        return True if end_steps is None else n < end_steps

    def readings(q, f, x, n, acc):
        """Sensor and detector outputs at one instant; updates the running extremes ``acc``."""
        out = {}
        if sensors is not None:
            y = sensor_mod.evaluate(sensors, model, q, f, x)
            late = (n >= run_in_steps) & counted(n)
            acc = {**acc, "sensor_max": jnp.where(late, jnp.maximum(acc["sensor_max"], y),
                                                  acc["sensor_max"]),
                   "sensor_min": jnp.where(late, jnp.minimum(acc["sensor_min"], y),
                                           acc["sensor_min"])}
            out["sensors"] = y
        if detector is not None:
            est, gate = sensor_mod.detector_load(detector, model, q, f, x)
            acc = {**acc, "detector_peak": jnp.where(gate & counted(n),
                                                     jnp.maximum(acc["detector_peak"], est),
                                                     acc["detector_peak"])}
            out["detector_load"] = est
        return (out if sensor_history else {}), acc

    acc0 = {}
    if sensors is not None:
        shape = (len(sensors.quantities), sensors.positions.shape[0])
        acc0 |= {"sensor_max": jnp.full(shape, -jnp.inf, real),
                 "sensor_min": jnp.full(shape, jnp.inf, real)}
    if detector is not None:
        acc0["detector_peak"] = jnp.full((n_wheels,) + detector.left.shape, -jnp.inf, real)
    first_readings, acc0 = readings(q0, preload, x0, 0, acc0)
    if own_compliance:
        first_readings["own_compliance"] = _rail_reads(phi0, w_r, an_r, q0)[1]

    def support_loads(support_state):
        """Modal loads [n_modes] of the hanging sleepers' ballast forces (upwards), or 0."""
        return 0.0 if sup is None else support_state[0] @ psi

    def step(carry, n):
        q, p, f_prev, phi_prev, states, acc, support_state = carry
        x_ref = x_start + speed * dt * n
        x = x_ref + offsets
        s = x_ref - impact_position - delays
        phi = shapes_at(x)
        q_hat = e_r * q + ap_r * (_loads(f_prev, phi_prev) - support_loads(support_state))
        xi_r_free, c_own = _rail_reads(phi, w_r, an_r, q_hat)
        c_rail = rail_compliance(x_ref, c_own)
        p_hat = e_w * p + ap_w * (f_prev - preload)[:, None]
        xi_w_free = (xi_w_ref - jnp.real(jnp.sum(wheel_res * p_hat, axis=-1))
                     + c_wheel * preload)
        shift, rough = (0.0, None) if roughness is None else _roughness_inputs(
            laws, roughness, x, s)
        delta_free, compliance = xi_w_free - xi_r_free + shift, jnp.diag(c_wheel) + c_rail
        if sup is None:
            delta, f, r, states = solve_contacts(laws, delta_free, compliance, s, states,
                                                 max_iter, groups, rough)
        else:  # the wheels and the hanging sleepers' ballast in one system
            g_ws = (jnp.real(jnp.sum(w_r * an_r * phi[:, None] * psi[None], axis=-1))
                    + track_mod.read_residual_table(model, sup.residual_wheels, x_ref))
            closure_free = jnp.real(jnp.sum(psi * (w_r * q_hat), axis=-1)) - sup.gap
            system = jnp.block([[compliance, -g_ws], [-g_ws.T, within_ss]])
            params = (support_state[1], sup.stiffness, sup.damping, dt)
            d_all, f_all, r_all, states = solve_contacts(
                laws, jnp.concatenate([delta_free, closure_free]), system, s, states,
                max_iter, groups, rough, extra=(support_force, params))
            delta, f, r = d_all[:n_wheels], f_all[:n_wheels], r_all[:n_wheels]
            support_state = (f_all[n_wheels:], d_all[n_wheels:])
            xi_r_free = xi_r_free - g_ws @ support_state[0]
        delta = delta - shift
        q_new = q_hat + an_r * (_loads(f, phi) - support_loads(support_state))
        p_new = p_hat + an_w * (f - preload)[:, None]
        axle_acc = jnp.real(jnp.sum(axle_acc_res * p_new, axis=-1))
        extra, acc = readings(q_new, f, x, n, acc)
        if sup is not None:
            extra = {**extra, "support_force": support_state[0],
                     "sleeper_disp": support_state[1] + sup.gap}
        if own_compliance:
            extra = {**extra, "own_compliance": c_own}
        out = (x, s, f, delta, xi_w_free - c_wheel * f, xi_r_free + c_rail @ f, r, axle_acc,
               extra)
        return (q_new, p_new, f, phi, states, acc, support_state), out

    carry0 = (q0, p0, preload, phi0, tuple(law.init_state() for law in laws), acc0, support0)
    step_fn = jax.checkpoint(step) if checkpoint else step
    if n_run is None:
        (*_, acc, _), outs = jax.lax.scan(step_fn, carry0, jnp.arange(1, n_steps))
    else:
        (*_, acc, _), outs = _scan_until(step_fn, carry0, n_steps, n_run)
    first = (x0, s0, preload, delta0, xi_w_ref, xi_r0, jnp.zeros_like(preload),
             jnp.zeros_like(preload))
    keys = ("x", "s", "force", "approach", "wheel_disp", "rail_disp", "residual", "axle_acc")
    result = {k: jnp.concatenate([jnp.asarray(a0, dtype=a.dtype)[None], a])
              for k, a0, a in zip(keys, first, outs[:-1], strict=True)}
    if single:
        result = {k: a[:, 0] for k, a in result.items()}
        acc = {k: (a[0] if k == "detector_peak" else a) for k, a in acc.items()}
    if sup is not None:
        first_readings = {**first_readings, "support_force": support0[0],
                          "sleeper_disp": support0[1] + sup.gap}
    result |= {k: jnp.concatenate([first_readings[k][None], a]) for k, a in outs[-1].items()}
    result |= acc
    result["t"] = dt * jnp.arange(n_steps)
    return result


_LOOP_STATIC = ("n_steps", "max_iter", "checkpoint", "sensor_history", "precision",
                "own_compliance")
run_scan = jax.jit(time_loop, static_argnames=_LOOP_STATIC)
run_scan.__doc__ = """:func:`time_loop` compiled (one program per law class and grid shapes).

``vmap`` it over runs, and over laws prepared for a batch of flats; ``grad`` reaches every
traced leaf of the law (the flat's geometry) and of the structure. Under your own top-level
``jax.jit`` on a CPU, ``compiler_options=LOOP_COMPILER_OPTIONS`` (this module's) compiles it
in about half the CPU time (:mod:`wfjax._xla`)."""
# simulate's own program: a top-level jit may carry compiler options, a nested one may not
_simulation = jax.jit(time_loop, static_argnames=_LOOP_STATIC,
                      compiler_options=LOOP_COMPILER_OPTIONS)


def simulate(flat: Flat, speed: float, contact: str = "3d", impact_position: float = 0.0,
             wheel: Wheel | None = None, track: Track | None = None,
             material: Material | None = None, config: SimConfig | None = None,
             angle0: float | None = None, cache_dir=None,
             n_steps: int | None = None, sensors=None, detector=None,
             sensor_quantities=sensor_mod.QUANTITIES, vehicle=None, roughness=None,
             wheel_roughness=None) -> SimResult:
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
        sensors: [n_s] fixed rail positions [m] (x = 0 at the middle sleeper; within
            :func:`wfjax.sensors.allowed_range`): every quantity of
            :data:`wfjax.sensors.QUANTITIES` at each, as time histories.
        sensor_quantities: the subset of :data:`wfjax.sensors.QUANTITIES` to compute (each
            costs one modal dot product per sensor and step).
        detector: a :class:`wfjax.sensors.Detector`: its per-bay load estimate and peaks.
            The run's window is lengthened (``run_in``/``run_out``) so that the wheel
            crosses every instrumented bay.
        vehicle: a :class:`wfjax.vehicle.Vehicle` (default: the paper's single wheel): its
            wheels roll together on the track, ``flat`` on ``vehicle.flat_wheel`` (whose
            impact ``impact_position`` places), the others with the vehicle's flats or
            smooth; ``wheel`` is every wheel's model unless the vehicle gives its own.
        roughness: rail roughness, a :class:`wfjax.roughness.Roughness` (``values [n]``,
            rail coordinate x [m]; see :func:`loop_roughness` for how each model reads it).
        wheel_roughness: wheel roughness (periodic :class:`wfjax.roughness.Roughness`),
            read at the circumferential coordinate s [m] of each wheel.

    Returns:
        :class:`SimResult` with time histories [n_steps] and summary values (a vehicle's:
        the flat wheel's, plus every wheel's in the ``wheel_*`` fields).
    """
    wheel = wheel or Wheel()
    track = track or Track()
    material = material or Material()
    config = config or SimConfig()
    v = _check_speed(speed)
    wheels = [wheel] if vehicle is None else vehicle.wheel_list(wheel)
    flats = [flat] if vehicle is None else vehicle.flat_list(
        flat, lambda i: float(wheels[i].radius))
    if vehicle is not None:
        vehicle.check_spacing(wheels)
    for i, (f, w) in enumerate(zip(flats, wheels, strict=True)):
        if abs(float(f.wheel_radius) - float(w.radius)) > 1e-12:
            where = "" if vehicle is None else f" of wheel {i}"
            raise ValueError(
                f"flat.wheel_radius{where} ({float(f.wheel_radius)} m) must equal wheel.radius "
                f"({float(w.radius)} m)"
            )
    spacing = float(track.sleeper_spacing)
    if detector is not None:
        config = detector_config(detector, track, config, _wheel_positions(vehicle, spacing))
    window_flat = flat
    if vehicle is not None:
        window_flat = vehicle_window_flat(vehicle, flats)
    s_start, s_end = simulation_window(window_flat, v, config)
    if angle0 is not None:
        impact_position = float(impact_position_from_angle(
            angle0, s_start, float(wheels[0 if vehicle is None else vehicle.flat_wheel].radius),
            spacing))
    x_imp = _check_impact_position(impact_position, spacing, track)
    n_auto, dt = n_steps_for(window_flat, v, config)
    if n_steps is None:
        n_steps = n_auto
    elif int(n_steps) < 2:
        raise ValueError(f"n_steps must be >= 2, got {n_steps!r}")
    else:
        dt = (s_end - s_start) / v / (int(n_steps) - 1)
    if contact not in CONTACT_MODELS:
        raise ValueError(f"contact must be one of {CONTACT_MODELS}, got {contact!r}")
    run_in_steps = int(0.5 * RUN_IN_TIME / dt)
    if vehicle is None:
        struct = structure(wheel, track, config, cache_dir)
        law = prepare(contact, flat, wheel, track, material, config, cache_dir)
        x_abs = x_imp
    else:
        x_abs = x_imp + vehicle_mod.placement(vehicle, spacing)
        vehicle_mod.check_on_track(vehicle, track, x_abs + s_start, x_abs + s_end)
        struct = vehicle_structure(vehicle, wheels, track, config, cache_dir)
        law = vehicle_laws(contact, flats, wheels, track, material, config, cache_dir)
    sensor_spec = (None if sensors is None
                   else sensor_mod.sensor_spec(sensors, track, struct.track, sensor_quantities))
    det_spec = (None if detector is None
                else sensor_mod.detector_spec(detector, track, struct.track))
    rough = loop_roughness(roughness, wheel_roughness, wheels, track, material)
    offsets = np.zeros(1) if vehicle is None else vehicle.offsets()
    check_rail_span(roughness, x_abs + s_start + offsets.min(), x_abs + s_end + offsets.max())
    hist = _simulation(law, struct, v, dt, x_abs + s_start, x_abs, int(n_steps),
                    config.newton_iterations, sensors=sensor_spec, detector=det_spec,
                    run_in_steps=run_in_steps, precision=config.precision, roughness=rough)
    quantities = () if sensor_spec is None else sensor_spec.quantities
    if vehicle is None:
        res = summarise(hist, v, x_imp, dt, run_in_steps, quantities, struct.preload)
    else:
        res = summarise_vehicle(hist, vehicle.flat_wheel, v, x_imp, dt, run_in_steps,
                                quantities, struct.preload)
    if struct.supports is not None:
        res = res._replace(support_force=hist["support_force"],
                           sleeper_disp=hist["sleeper_disp"],
                           hanging_sleepers=supports_mod.hanging_sleepers(track))
    if sensor_spec is None:
        return res
    return res._replace(sensor_positions=np.asarray(sensor_spec.positions))


def loop_roughness(rail=None, wheel=None, wheels=None, track: Track | None = None,
                   material: Material | None = None):
    """The time loop's :class:`wfjax.roughness.LoopRoughness` (None when both are None).

    The contact filter's length (point-contact laws) is each wheel's static Hertz contact
    length (:func:`wfjax.roughness.static_contact_length` at its preload, on the Hertz radius
    sqrt(R_W R_R)), 13.1 mm for the default wheel and track: the patch the wheel rolls on between
    impacts, where roughness excites it.

    Args:
        rail: rail :class:`wfjax.roughness.Roughness` (``values [n]`` or, for
            :func:`wfjax.sweep`'s Monte Carlo, ``[R, n]``) or None.
        wheel: wheel roughness (periodic) or None. wheels: [n_wheels] :class:`Wheel`
            (default: one default wheel). track, material: as :func:`simulate`.
    """
    if rail is None and wheel is None:
        return None
    from .contact.laws import hertz_radius

    if rail is not None and rail.periodic:
        raise ValueError("roughness (rail) must not be periodic; a wheel profile goes to "
                         "wheel_roughness")
    if wheel is not None and not wheel.periodic:
        raise ValueError("wheel_roughness must be periodic (roughness.read_csv(..., "
                         "wheel_radius=R) or roughness.generate_wheel)")
    wheels = wheels or [Wheel()]
    track, material = track or Track(), material or Material()
    length = np.array([float(rough_mod.static_contact_length(
        float(w.preload), material, float(hertz_radius(w, track)))) for w in wheels])
    return rough_mod.LoopRoughness(rail, wheel, jnp.asarray(length))


def check_rail_span(rail, x_lo: float, x_hi: float) -> None:
    """One-line ``ValueError`` unless the rail roughness ``rail`` (or None) covers every
    contact position of the run, ``[x_lo, x_hi]`` [m] (a profile holds its end values
    beyond its span: the run would see a constant there)."""
    if rail is None:
        return
    x0 = float(np.asarray(rail.x_start))
    x1 = x0 + float(np.asarray(rail.spacing)) * (np.shape(rail.values)[-1] - 1)
    if x_lo < x0 - 1e-9 or x_hi > x1 + 1e-9:
        raise ValueError(f"roughness covers x in [{x0:.4g}, {x1:.4g}] m but the run's contacts "
                         f"reach [{x_lo:.4g}, {x_hi:.4g}] m: give a profile over at least that "
                         f"span (x_start, length)")


def _wheel_positions(vehicle, sleeper_spacing: float) -> tuple:
    """Every wheel's rail coordinate at the reference impact, less the impact position [m]."""
    if vehicle is None:
        return (0.0,)
    shift = vehicle_mod.placement(vehicle, sleeper_spacing)
    return tuple(float(shift + o) for o in vehicle.offsets())


def vehicle_window_flat(vehicle, flats: list[Flat]) -> Flat:
    """The flat whose simulation window covers every flat of the vehicle.

    Every wheel's flat must pass its contact within the window: a flat delayed by d [m]
    needs the reference window widened by |d| on that side, which a flat of half extent
    max_i(half_i + |d_i|) gives (an ``extent_bound`` on the reference flat; its geometry is
    unchanged).
    """
    delays = vehicle.delays()
    reach = max(float(f.half_extent) + abs(d) for f, d in zip(flats, delays, strict=True)
                if f.kind != "none" or f is flats[vehicle.flat_wheel])
    ref = flats[vehicle.flat_wheel]
    if reach <= float(ref.half_extent):
        return ref
    return dataclasses.replace(ref, extent_bound=reach)


def vehicle_laws(contact: str, flats: list[Flat], wheels: list[Wheel], track: Track,
                 material: Material, config: SimConfig, cache_dir=None) -> tuple:
    """[n] contact laws of the vehicle's wheels (one per distinct flat and wheel radius)."""
    laws, done = [], {}
    for f, w in zip(flats, wheels, strict=True):
        key = (id(f), float(w.radius)) if f.kind != "none" else ("none", float(w.radius))
        if key not in done:
            done[key] = prepare(contact, f, w, track, material, config, cache_dir)
        laws.append(done[key])
    return tuple(laws)


def detector_config(detector, track: Track, config: SimConfig,
                    wheel_positions=(0.0,)) -> SimConfig:
    """``config`` with ``run_in``/``run_out`` [m] long enough for every wheel to cross every
    bay of ``detector`` (for any impact position in [0, L_S) and any flat; 5 cm margin).

    ``wheel_positions``: [n] every wheel's rail coordinate at the reference impact, less the
    impact position [m] (a vehicle: its placement plus the wheels' offsets; one wheel: 0).
    """
    a, b = detector.gauges(float(track.sleeper_spacing))
    run_in = max(wheel_positions) + float(track.sleeper_spacing) - float(a[0]) + 0.05
    run_out = float(b[-1]) - min(wheel_positions) + 0.05
    return dataclasses.replace(config, run_in=max(config.run_in, run_in),
                               run_out=max(config.run_out, run_out))
