"""The fit itself: :func:`fit_flat` (optax L-BFGS with an Armijo line search, or Adam) and
its Gauss-Newton uncertainty."""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from .._xla import loop_compiler_options
from ..contact import registry
from ..params import Flat, Material, SimConfig, Track, Wheel, new_flat_length
from .data import DetectorData, MaxForceData, validate_data
from .models import MAX_FAMILY_ROUNDS, ForceModel, detector_model, history_model, max_force_model
from .parametrisations import parametrisation_for

__all__ = ["FitResult", "fit_flat"]


# -- the fit ---------------------------------------------------------------------------------
class FitResult(NamedTuple):
    """Result of :func:`fit_flat`.

    Attributes:
        flat: the fitted :class:`Flat` (concrete).
        params: fitted physical parameters {name: value} in SI units (m).
        std: Gauss-Newton standard deviations {name: value} [m].
        covariance: [p, p] Gauss-Newton covariance of the physical parameters [m^2].
        theta: [p] fitted unconstrained parameters.
        loss_history: [n_iter + 1] loss (mean squared relative residual + penalty).
        grad_norm_history: [n_iter + 1] max-norm of the loss gradient w.r.t. theta.
        n_iterations: optimiser iterations done.
        converged: whether a convergence criterion was met (see ``message``).
        message: why the optimiser stopped.
        prediction: [n] model forces at the data points [N]. measured: [n] data forces [N].
        x: [n] speeds [m/s] (max-force and detector data; per bay repeated for each bay)
            or times [s] (history data).
        residual_rms: root-mean-square force residual [N].
        kind: ``"max_force"``, ``"history"`` or ``"detector"``. contact: contact model.
        wall_time: fit duration [s].
    """

    flat: Flat
    params: dict
    std: dict
    covariance: Any
    theta: Any
    loss_history: Any
    grad_norm_history: Any
    n_iterations: int
    converged: bool
    message: str
    prediction: Any
    measured: Any
    x: Any
    residual_rms: float
    kind: str
    contact: str
    wall_time: float

    def summary(self) -> dict:
        """JSON-ready summary in practical units (mm, kN, km/h)."""
        out = {"flat": self.flat.kind, "contact": self.contact, "data": self.kind,
               "parameters_mm": {k: v * 1e3 for k, v in self.params.items()},
               "std_mm": {k: v * 1e3 for k, v in self.std.items()},
               "residual_rms_kN": self.residual_rms / 1e3,
               "final_loss": float(self.loss_history[-1]),
               "iterations": self.n_iterations, "converged": self.converged,
               "message": self.message, "wall_time_s": self.wall_time}
        if self.flat.kind != "profile":
            out["depth_mm"] = float(self.flat.depth) * 1e3
            out["length_mm"] = float(self.flat.length) * 1e3
        return out


def _gauss_newton(J, r, G):
    """Covariance of the physical parameters from residual Jacobian J [n, p] and G [q, p]."""
    n, p = J.shape
    s2 = float(np.sum(r**2)) / max(n - p, 1)
    cov_theta = s2 * np.linalg.pinv(J.T @ J)
    return G @ cov_theta @ G.T


# Over 80 lines by its docstring (twenty documented arguments); the body is about 50.
def fit_flat(measured, initial: Flat, contact: str = "hertz-trajectory", *,
             parametrisation=None, impact_positions=3, temperature: float | None = 1e3,
             time_temperature: float | None = None, method: str = "lbfgs",
             max_iter: int = 40, learning_rate: float = 0.05, gtol: float = 1e-7,
             ftol: float = 1e-7, xtol: float = 2e-3, max_step: float = 0.5, mode: str = "auto",
             checkpoint: bool = False, extent_bound: float | None = None,
             wheel: Wheel | None = None, track: Track | None = None,
             material: Material | None = None, config: SimConfig | None = None,
             vehicle=None, roughness=None, wheel_roughness=None,
             callback=None, cache_dir=None) -> FitResult:
    """Fit the geometry of ``initial`` to measured forces by gradient descent (optax).

    Loss: mean over data points of ((model - measured) / mean |measured|)^2, plus the
    parametrisation's penalty (profiles only).

    Args:
        measured: :class:`MaxForceData` (speeds [m/s], max_force [N]), :class:`HistoryData`
            (t [s], force [N], speed [m/s], impact_position [m]), :class:`DetectorData`
            (speeds [m/s], peak [N] per bay or max over bays, detector, impact_position [m])
            or a dict with those keys.
        initial: starting flat (kind ``"new"``, ``"rounded"`` or ``"profile"``).
        contact: ``"hertz-trajectory"``, ``"hertz-profile"``, ``"2d"`` or ``"3d"``.
        parametrisation: :class:`NewFlatParam`, :class:`RoundedFlatParam` or
            :class:`ProfileParam`; default :func:`parametrisation_for` ``(initial)``.
        impact_positions: positions per speed for max-force data (count or [m] array).
        temperature, time_temperature: smooth-maximum temperatures [N] (module docstring).
        method: ``"lbfgs"`` (``optax.scale_by_lbfgs`` direction with a backtracking Armijo
            line search on the loss) or ``"adam"`` (``optax.adam(learning_rate)``).
        max_iter: iteration cap. gtol: stop when max |dL/dtheta| <= gtol.
        ftol: stop when the loss decreased by less than ftol x loss in two successive steps.
        xtol: stop when max |delta theta| <= xtol (about a relative change of the depth) in
            two successive steps.
        max_step: largest step in theta (a factor e^0.5 in depth) per iteration (L-BFGS).
        mode: ``"forward"`` (Jacobian by ``jacfwd``), ``"reverse"`` or ``"auto"`` (forward
            for <= 4 parameters except for ``"3d"`` with a measured profile). Reverse mode
            differentiates every kind of data through the time loop's adjoint
            (:mod:`wfjax.loop.adjoint`), except on a track with hanging sleepers (which the
            adjoint does not carry: plain autodiff there).
        checkpoint: see :func:`max_force_model` (reverse mode only).
        extent_bound: static bound of the flat's half extent [m] during the fit.
        wheel, track, material, config: model parameters (default track
            ``Track()``, Table 2 with R_R = 0.30 m, the default of every entry point; pass
            :meth:`Track.comparison` for the paper's R_R = 0.45 m); the track may have
            varying supports.
        vehicle: a :class:`wfjax.model.vehicle.Vehicle` whose reference wheel carries the fitted
            flat (the data are that wheel's). roughness, wheel_roughness: rail (or rail-top
            inputs such as :class:`wfjax.Joint`) and wheel roughness, one realisation
            (as :func:`wfjax.simulate`).
        callback: called as ``callback(iteration, loss, flat)`` after every iteration.

    Returns:
        :class:`FitResult`.
    """
    start = time.perf_counter()
    _check_arguments(contact, initial, method, mode, max_iter)
    par = parametrisation or parametrisation_for(initial, extent_bound)
    theta0 = np.asarray(par.from_flat(initial), dtype=float)
    data = validate_data(measured, theta0.size)
    mode = _differentiation_mode(mode, contact, initial, theta0.size)
    kw = dict(contact=contact, extent_bound=par.extent_bound, wheel=wheel, track=track,
              material=material, config=config, cache_dir=cache_dir, vehicle=vehicle,
              roughness=roughness, wheel_roughness=wheel_roughness)
    y, x, kind, build = _builder(data, kw, impact_positions, temperature, time_temperature,
                                 checkpoint, mode == "reverse" and not _hanging(track))
    scale = float(np.mean(np.abs(y)))
    optimise = _optimiser(par, callback, method, learning_rate, gtol, ftol, xtol, max_step)
    (theta, history, gnorms, message, converged, inside, family,
     jacobian) = _rounds(build, par, theta0, jnp.asarray(y), scale, mode, int(max_iter),
                         optimise)

    flat = _concrete_flat(jax.tree_util.tree_map(np.asarray, par.to_flat(theta)))
    warnings = _warnings(flat, par, inside, family)
    pred, cov, params, std = _uncertainty(jacobian, theta, par, scale, y)
    return FitResult(flat=flat, params=params, std=std, covariance=cov, theta=np.asarray(theta),
                     loss_history=np.asarray(history), grad_norm_history=np.asarray(gnorms),
                     n_iterations=len(history) - 1, converged=converged and not warnings,
                     message=message + warnings, prediction=pred, measured=np.asarray(y),
                     x=np.asarray(x), residual_rms=float(np.sqrt(np.mean((pred - y)**2))),
                     kind=kind, contact=contact, wall_time=time.perf_counter() - start)


def _optimiser(par, callback, method, learning_rate, gtol, ftol, xtol, max_step):
    """``optimise(value_and_grad, loss, theta, budget)``: :func:`_optimise` with the fit's
    settings, reporting every iteration's flat to ``callback`` (None: no report)."""
    def report(i, value, theta):
        return callback(i, value, par.to_flat(theta)) if callback is not None else None

    def optimise(value_and_grad, loss_j, theta, budget):
        return _optimise(value_and_grad, loss_j, theta, method, budget, learning_rate, gtol,
                         ftol, xtol, max_step, report)

    return optimise


def _differentiation_mode(mode: str, contact: str, initial: Flat, n_par: int) -> str:
    """``"forward"`` or ``"reverse"``: ``mode`` with ``"auto"`` resolved (forward for <= 4
    parameters, except a measured profile on the 3D law, whose traced Kalker table build has
    custom_vjp gradients only)."""
    exact_3d = contact == "3d" and initial.kind == "profile"
    if mode == "auto":
        return "forward" if n_par <= 4 and not exact_3d else "reverse"
    if mode == "forward" and exact_3d:
        raise ValueError("contact '3d' with a measured profile needs mode='reverse' "
                         "(its exact table's Kalker solves have custom_vjp gradients)")
    return mode


def _warnings(flat: Flat, par, inside: bool, family) -> str:
    """The fit's warnings ('' when none): a half length beyond the static extent bound, a
    3D family range that never held the fitted flat."""
    out = ""
    if flat.kind != "profile" and float(flat.length) / 2 > par.extent_bound + 1e-12:
        out += (f"; WARNING: fitted half length {float(flat.length) / 2 * 1e3:.1f} mm "
                f"exceeds extent_bound {par.extent_bound * 1e3:.1f} mm, refit with a "
                f"larger extent_bound")
    if not inside:
        lo, hi = family.spec.depth_range
        out += (f"; WARNING: after {MAX_FAMILY_ROUNDS} rounds the fitted flat lies outside "
                f"the 3D family's range (depth {lo * 1e3:.3g}-{hi * 1e3:.3g} mm), where the "
                "law is clamped: refit from a start closer to it")
    return out


def _rounds(build, par, theta0, y_j, scale: float, mode: str, max_iter: int, optimise):
    """The optimisation, in rounds: a 3D fit's family covers a box around its start; a fit
    that leaves the box is restarted from where it left, on a box around that point (nodes
    are cached, so only new ones build). Returns (theta, loss history, gradient norms,
    message, converged, inside the family, the family or None, the last jacobian)."""
    theta, history, gnorms = jnp.asarray(theta0), [], []
    for _ in range(MAX_FAMILY_ROUNDS):
        model = build(jax.tree_util.tree_map(np.asarray, par.to_flat(theta)))
        value_and_grad, loss_j, jacobian = _objective(model, par, y_j, scale, mode)
        theta, h, g, message, converged = optimise(value_and_grad, loss_j, theta,
                                                   max_iter - len(history))
        restart = 1 if history else 0  # a restart's first entry repeats the last one
        history, gnorms = history + list(h[restart:]), gnorms + list(g[restart:])
        family = model.law.family
        inside = family is None or _inside_family(family.spec, _concrete_flat(
            jax.tree_util.tree_map(np.asarray, par.to_flat(theta))))
        if inside or len(history) > max_iter:
            break
    return theta, history, gnorms, message, converged, inside, family, jacobian


def _check_arguments(contact: str, initial, method: str, mode: str, max_iter) -> None:
    registry.check(contact)
    if not isinstance(initial, Flat):
        raise ValueError(f"initial must be a Flat, got {type(initial).__name__}")
    if method not in ("lbfgs", "adam"):
        raise ValueError(f"method must be 'lbfgs' or 'adam', got {method!r}")
    if mode not in ("auto", "forward", "reverse"):
        raise ValueError(f"mode must be 'auto', 'forward' or 'reverse', got {mode!r}")
    if int(max_iter) < 1:
        raise ValueError(f"max_iter must be >= 1, got {max_iter!r}")


def _uncertainty(jacobian, theta, par, scale: float, y: np.ndarray):
    """(prediction [n] N, covariance of the physical parameters, their values and standard
    deviations by name) at ``theta``: Gauss-Newton on the force residuals in N."""
    J_rel, r_rel = jacobian(theta)
    pred = np.asarray(r_rel) * scale + y
    G = np.asarray(jax.jacfwd(par.physical)(theta))
    cov = _gauss_newton(np.asarray(J_rel) * scale, pred - y, G)
    phys = np.asarray(par.physical(theta))
    params = {n: float(v) for n, v in zip(par.names, phys, strict=True)}
    std = {n: float(math.sqrt(max(c, 0.0)))
           for n, c in zip(par.names, np.diag(cov), strict=True)}
    return pred, cov, params, std


def _objective(model: ForceModel, par, y_j, scale: float, mode: str):
    """(value_and_grad, loss, jacobian) of theta for ``model`` and data y_j, all jitted.

    ``jacobian(theta)`` is (J, r): the relative residuals and their Jacobian, for the
    Gauss-Newton uncertainty. In forward mode it is the iterations' own compiled evaluation.
    """
    def residuals(theta):
        return (model(par.to_flat(theta)) - y_j) / scale

    def loss(theta):
        r = residuals(theta)
        return jnp.mean(r**2) + par.penalty(theta)

    jit = functools.partial(jax.jit, compiler_options=loop_compiler_options())
    if mode == "forward":
        @jit
        def evaluate(theta):
            J, r = jax.jacfwd(lambda th: (residuals(th),) * 2, has_aux=True)(theta)
            pen, g_pen = jax.value_and_grad(par.penalty)(theta)
            return jnp.mean(r**2) + pen, 2 * J.T @ r / r.size + g_pen, J, r

        return (lambda theta: evaluate(theta)[:2]), jit(loss), (
            lambda theta: evaluate(theta)[2:])
    jacobian = jit(lambda theta: (jax.jacrev(residuals)(theta), residuals(theta)))
    return jit(jax.value_and_grad(loss)), jit(loss), jacobian


def _inside_family(spec, flat: Flat) -> bool:
    """Whether ``flat``'s depth (and length factor) lie inside a family's node range."""
    lo, hi = spec.depth_range
    depth = float(flat.depth)
    if not lo * (1 - 1e-9) <= depth <= hi * (1 + 1e-9):
        return False
    if flat.kind != "rounded":
        return True
    lam = float(flat.length) / float(new_flat_length(depth, float(flat.wheel_radius)))
    lam_lo, lam_hi = spec.length_factor_range
    return max(lam_lo, math.pi / 2) * (1 - 1e-9) <= lam <= lam_hi * (1 + 1e-9)


def _concrete_flat(flat: Flat) -> Flat:
    """Python floats for scalar leaves (keeps arrays for profiles)."""
    depth, length = float(flat.depth), float(flat.length)
    return dataclasses.replace(flat, depth=depth, length=length,
                               wheel_radius=float(flat.wheel_radius))


def _optimise(value_and_grad, loss, theta, method, max_iter, learning_rate, gtol, ftol, xtol,
              max_step, callback):
    """Run the optax loop; returns (theta, losses, grad norms, message, converged)."""
    if method == "adam":
        opt = optax.adam(learning_rate)
    else:
        opt = optax.scale_by_lbfgs(memory_size=10)
    state = opt.init(theta)
    value, grad = value_and_grad(theta)
    losses, gnorms = [float(value)], [float(jnp.max(jnp.abs(grad)))]
    message, converged, small_f, small_x = f"reached max_iter = {max_iter}", False, 0, 0
    for i in range(max_iter):
        if not np.isfinite(losses[-1]) or not np.all(np.isfinite(np.asarray(grad))):
            return theta, losses, gnorms, "loss or gradient is not finite", False
        if gnorms[-1] <= gtol:
            message, converged = f"gradient norm {gnorms[-1]:.2e} <= gtol", True
            break
        previous = theta
        updates, state = opt.update(grad, state, theta)
        if method == "adam":
            theta = optax.apply_updates(theta, updates)
        else:
            theta, ok = _armijo(loss, theta, updates, value, grad, max_step)
            if not ok:
                message, converged = "line search found no decrease (at a minimum)", True
                break
        step = float(jnp.max(jnp.abs(theta - previous)))
        value, grad = value_and_grad(theta)
        losses.append(float(value))
        gnorms.append(float(jnp.max(jnp.abs(grad))))
        callback(i + 1, losses[-1], theta)
        drop = losses[-2] - losses[-1]
        small_f = small_f + 1 if abs(drop) <= ftol * max(losses[-1], 1e-30) else 0
        small_x = small_x + 1 if step <= xtol else 0
        if small_f >= 2:
            message, converged = "relative loss change <= ftol twice", True
            break
        if small_x >= 2:
            message, converged = "parameter step <= xtol twice", True
            break
    return theta, losses, gnorms, message, converged


def _armijo(loss, theta, precond_grad, value, grad, max_step, shrink=0.5, tries=12,
            c1=1e-4):
    """Backtracking Armijo step along -``precond_grad`` (``optax.scale_by_lbfgs`` output).

    Returns (new theta, whether a decrease was found).
    """
    d = -precond_grad
    slope = float(jnp.dot(grad, d))
    if slope >= 0:  # not a descent direction: fall back to steepest descent
        d, slope = -grad, -float(jnp.dot(grad, grad))
    alpha = min(1.0, max_step / max(float(jnp.max(jnp.abs(d))), 1e-300))
    for _ in range(tries):
        trial = theta + alpha * d
        if float(loss(trial)) <= float(value) + c1 * alpha * slope:
            return trial, True
        alpha *= shrink
    return theta, False


def _hanging(track) -> bool:
    from ..model.supports import hanging_sleepers

    return track is not None and hanging_sleepers(track).size > 0


def _builder(data, kw: dict, impact_positions, temperature, time_temperature, checkpoint,
             adjoint):
    """(measured values y, their abscissae x, data kind, reference flat -> ForceModel)."""
    if isinstance(data, DetectorData):
        per_bay = data.peak.ndim == 2
        y = data.peak.ravel()
        x = np.repeat(data.speeds, data.peak.shape[1]) if per_bay else data.speeds
        kind = "detector"

        def build(ref):
            return detector_model(data.speeds, ref, data.detector, per_bay,
                                  impact_positions=([data.impact_position] if per_bay
                                                    else impact_positions),
                                  temperature=temperature, adjoint=adjoint, **kw)
    elif isinstance(data, MaxForceData):
        y, x, kind = data.max_force, data.speeds, "max_force"

        def build(ref):
            return max_force_model(data.speeds, ref, impact_positions=impact_positions,
                                   temperature=temperature, time_temperature=time_temperature,
                                   checkpoint=checkpoint, adjoint=adjoint, **kw)
    else:
        y, x, kind = data.force, data.t, "history"

        def build(ref):
            return history_model(data.t, data.speed, ref, impact_position=data.impact_position,
                                 adjoint=adjoint, **kw)
    return y, x, kind, build
