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
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from . import sensors as sensor_mod
from . import track as track_mod
from . import wheel as wheel_mod
from ._modal import discrete_step_coefficients
from .contact.laws import CONTACT_MODELS, FLAT_MARGIN, ContactLaw, prepare
from .contact.newton import static_approach
from .params import Flat, Material, SimConfig, Track, Wheel
from .results import SimResult, summarise

__all__ = [
    "CONTACT_MODELS",
    "SimResult",
    "run_scan",
    "time_loop",
    "simulate",
    "impact_position_from_angle",
    "simulation_window",
    "batch_windows",
    "cast_precision",
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
    phi = track_mod.interpolate_nodal(model, node_major, x)
    return phi, track_mod.residual_compliance_at(model, x)


def time_loop(law: ContactLaw, struct: Structure, speed, dt, x_start, impact_position,
              n_steps: int, max_iter: int = 30, checkpoint: bool = False, sensors=None,
              detector=None, run_in_steps=0, sensor_history: bool = True,
              precision: str = "float64"):
    """The time loop under ``lax.scan`` for any contact law (pure).

    Args:
        law: the prepared contact law (:func:`wfjax.contact.laws.prepare`); its ``step``
            solves each step's contact equation, its ``force`` the static equilibrium.
        struct: modal wheel and track (:func:`structure`).
        speed: v [m/s]; dt: time step [s]; x_start: rail coordinate at t = 0 [m];
        impact_position: rail coordinate where s = 0 [m]; n_steps: steps incl. t = 0 (static).
        max_iter: Newton iteration cap of the per-step contact equation (static).
        checkpoint: rematerialise each step in reverse mode (``jax.checkpoint``): memory of
            the backward pass drops to the carry per step at the cost of recomputing steps.
        sensors: a :class:`wfjax.sensors.SensorSpec` (or None): readings at fixed rail
            positions from the modal state of every step.
        detector: a :class:`wfjax.sensors.DetectorSpec` (or None): the detector's per-bay
            load estimate, and its peak while the wheel is between each bay's bridges.
        run_in_steps: steps before the sensors' running max/min start (traced int).
        sensor_history: return the sensors' and detector's time histories (static; False
            keeps only running max/min and peaks in the carry: no [n_steps] arrays).
        precision: ``"float64"`` or ``"float32"`` (static, :attr:`SimConfig.precision`): the
            dtype of the loop (the sensors' and detector's specs are cast with it). The
            propagation coefficients exp(pole dt) and their hold integrals are computed in the
            inputs' precision (float64) and then cast: their series in pole dt cancels to
            ~1e-3 relative in float32.

    Returns:
        dict of [n_steps] arrays: t, x, s, force, approach, wheel_disp, rail_disp, residual;
        with ``sensors``: ``sensor_max``, ``sensor_min`` [n_quantities, n_s] after the run-in
        and (``sensor_history``) ``sensors`` [n_steps, n_quantities, n_s]; with
        ``detector``: ``detector_peak`` [n_bays] N and (``sensor_history``)
        ``detector_load`` [n_steps, n_bays] N (ungated estimate).
    """
    coefficients = (discrete_step_coefficients(struct.track.poles, dt),
                    discrete_step_coefficients(struct.wheel_poles, dt))
    (law, struct, coefficients, speed, dt, x_start, impact_position, sensors,
     detector) = cast_precision((law, struct, coefficients, speed, dt, x_start,
                                 impact_position, sensors, detector), precision)
    (e_r, ap_r, an_r), (e_w, ap_w, an_w) = coefficients
    model = struct.track
    w_r = model.weights
    preload = struct.preload
    c_wheel = jnp.real(jnp.sum(struct.wheel_residues * an_w))

    # static equilibrium at the start: F = P, rail in its static deflected shape
    s0 = x_start - impact_position
    node_major = _node_major_shapes(model)
    phi0, res0 = _rail_terms(model, node_major, x_start)
    q0 = -phi0 * preload / model.poles
    xi_r0 = jnp.real(jnp.sum(w_r * phi0 * q0)) + res0 * preload
    delta0 = static_approach(lambda d: law.force(d, s0), preload)
    xi_w_ref = xi_r0 + delta0
    p0 = jnp.zeros_like(struct.wheel_poles)

    def readings(q, f, x, n, acc):
        """Sensor and detector outputs at one instant; updates the running extremes ``acc``."""
        out = {}
        if sensors is not None:
            y = sensor_mod.evaluate(sensors, model, q, f, x)
            late = n >= run_in_steps
            acc = {**acc, "sensor_max": jnp.where(late, jnp.maximum(acc["sensor_max"], y),
                                                  acc["sensor_max"]),
                   "sensor_min": jnp.where(late, jnp.minimum(acc["sensor_min"], y),
                                           acc["sensor_min"])}
            out["sensors"] = y
        if detector is not None:
            est, gate = sensor_mod.detector_load(detector, model, q, f, x)
            acc = {**acc, "detector_peak": jnp.where(gate, jnp.maximum(acc["detector_peak"],
                                                                       est),
                                                     acc["detector_peak"])}
            out["detector_load"] = est
        return (out if sensor_history else {}), acc

    acc0 = {}
    real = jnp.asarray(preload).dtype  # the loop's precision
    if sensors is not None:
        shape = (len(sensors.quantities), sensors.positions.shape[0])
        acc0 |= {"sensor_max": jnp.full(shape, -jnp.inf, real),
                 "sensor_min": jnp.full(shape, jnp.inf, real)}
    if detector is not None:
        acc0["detector_peak"] = jnp.full(detector.left.shape, -jnp.inf, real)
    first_readings, acc0 = readings(q0, preload, x_start, 0, acc0)

    def step(carry, n):
        q, p, f_prev, phi_prev, state, acc = carry
        x = x_start + speed * dt * n
        s = x - impact_position
        phi, res = _rail_terms(model, node_major, x)
        q_hat = e_r * q + ap_r * phi_prev * f_prev
        xi_r_free = jnp.real(jnp.sum(w_r * phi * q_hat))
        c_rail = jnp.real(jnp.sum(w_r * an_r * phi * phi)) + res
        p_hat = e_w * p + ap_w * (f_prev - preload)
        xi_w_free = xi_w_ref - jnp.real(jnp.sum(struct.wheel_residues * p_hat)) + c_wheel * preload
        delta, f, r, state = law.step(xi_w_free - xi_r_free, c_wheel + c_rail, s, state,
                                      max_iter)
        q_new = q_hat + an_r * phi * f
        p_new = p_hat + an_w * (f - preload)
        extra, acc = readings(q_new, f, x, n, acc)
        out = (x, s, f, delta, xi_w_free - c_wheel * f, xi_r_free + c_rail * f, r, extra)
        return (q_new, p_new, f, phi, state, acc), out

    carry0 = (q0, p0, preload, phi0, law.init_state(), acc0)
    (*_, acc), outs = jax.lax.scan(jax.checkpoint(step) if checkpoint else step, carry0,
                                   jnp.arange(1, n_steps))
    first = (x_start, s0, preload, delta0, xi_w_ref, xi_r0, 0.0)
    keys = ("x", "s", "force", "approach", "wheel_disp", "rail_disp", "residual")
    result = {k: jnp.concatenate([jnp.asarray(a0, dtype=a.dtype)[None], a])
              for k, a0, a in zip(keys, first, outs[:-1], strict=True)}
    result |= {k: jnp.concatenate([first_readings[k][None], a]) for k, a in outs[-1].items()}
    result |= acc
    result["t"] = dt * jnp.arange(n_steps)
    return result


run_scan = jax.jit(time_loop, static_argnames=("n_steps", "max_iter", "checkpoint",
                                              "sensor_history", "precision"))
run_scan.__doc__ = """:func:`time_loop` compiled (one program per law class and grid shapes).

``vmap`` it over runs, and over laws prepared for a batch of flats; ``grad`` reaches every
traced leaf of the law (the flat's geometry) and of the structure."""


def simulate(flat: Flat, speed: float, contact: str = "3d", impact_position: float = 0.0,
             wheel: Wheel | None = None, track: Track | None = None,
             material: Material | None = None, config: SimConfig | None = None,
             angle0: float | None = None, cache_dir=None,
             n_steps: int | None = None, sensors=None, detector=None,
             sensor_quantities=sensor_mod.QUANTITIES) -> SimResult:
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
    if detector is not None:
        config = detector_config(detector, track, config)
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
    law = prepare(contact, flat, wheel, track, material, config, cache_dir)
    run_in_steps = int(0.5 * RUN_IN_TIME / dt)
    sensor_spec = (None if sensors is None
                   else sensor_mod.sensor_spec(sensors, track, struct.track, sensor_quantities))
    det_spec = (None if detector is None
                else sensor_mod.detector_spec(detector, track, struct.track))
    hist = run_scan(law, struct, v, dt, x_imp + s_start, x_imp, int(n_steps),
                    config.newton_iterations, sensors=sensor_spec, detector=det_spec,
                    run_in_steps=run_in_steps, precision=config.precision)
    if sensor_spec is None:
        return summarise(hist, v, x_imp, dt, run_in_steps, (), struct.preload)
    res = summarise(hist, v, x_imp, dt, run_in_steps, sensor_spec.quantities, struct.preload)
    return res._replace(sensor_positions=np.asarray(sensor_spec.positions))


def detector_config(detector, track: Track, config: SimConfig) -> SimConfig:
    """``config`` with ``run_in``/``run_out`` [m] long enough for the wheel to cross every bay
    of ``detector`` (for any impact position in [0, L_S) and any flat; 5 cm margin)."""
    a, b = detector.gauges(float(track.sleeper_spacing))
    run_in = float(track.sleeper_spacing) - float(a[0]) + 0.05
    run_out = float(b[-1]) + 0.05
    return dataclasses.replace(config, run_in=max(config.run_in, run_in),
                               run_out=max(config.run_out, run_out))
