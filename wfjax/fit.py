"""Gradient-based fitting of a wheel flat's geometry to measured impact forces (optax).

A wheel impact load detector measures forces, not geometry. This module differentiates the
simulator (:func:`wfjax.loop.run.run_scan`) with respect to the flat's depth, length and
shape parameters and fits them to

(a) the **maximum impact force against speed** (:class:`MaxForceData`): for every speed the
    model force is the maximum over time of each simulation, then a *smooth* maximum over a
    few impact positions in the sleeper bay (a detector reports the worst passage; the smooth
    maximum keeps the loss differentiable where the worst position changes);
(b) a **force time history** at one speed (:class:`HistoryData`), with t = 0 when the flat
    centre is over the nominal contact point;
(c) **detector readings against speed** (:class:`DetectorData`): the peaks of a strain-gauge
    detector's load estimate (:class:`wfjax.sensors.Detector`, the rail's shear difference
    across each instrumented crib), per bay at a known impact position or the maximum over
    the bays (then a smooth maximum over impact positions as in (a)). The measurement
    operator (shear at the bridges from the track's modal state, gating, peak) runs inside
    the simulation's scan, so it is differentiated with the rest of the model.

Smooth maximum
--------------
``smooth_max(x, T) = T log sum_i exp(x_i / T)`` with temperature T in N. It lies between
max(x) and max(x) + T log(n) and its gradient is the softmax weighting of the candidates;
T -> 0 is the hard maximum (``T = 0`` or ``None`` selects ``jnp.max``). Defaults: T = 1 kN
over impact positions (bias <= 1.1 kN for 3 positions, ~0.5 % of a typical 200 kN impact),
hard maximum over time (one sharp peak per simulation, so its gradient is well defined).

Parametrisations (constraints kept by reparametrisation; unconstrained vector ``theta``)
-----------------------------------------------------------------------------------------
* :class:`NewFlatParam`: depth = 1 mm * exp(theta_0) > 0.
* :class:`RoundedFlatParam`: depth as above and
  length = l0(depth) (pi/2 + softplus(theta_1)) >= pi/2 l0, l0 = sqrt(8 R d) (Eq. 1).
* :class:`ProfileParam`: a measured-like flat: the deviation is a sum of K raised-cosine bumps
  with amplitudes a_k = 1 mm * softplus(theta_k) >= 0 evenly spread over a fixed support
  [-L/2, L/2]; smooth, non-negative, zero outside the support, produced as
  ``Flat("profile", ...)`` on a fixed grid (linear interpolation, differentiable in the
  values). Regularised against noise by a second-difference penalty on the amplitudes.

Gradients
---------
Forward mode (``jax.jacfwd`` of the residual vector, one tangent per parameter) when there are
few parameters: it costs about (1 + n_params) forward runs, needs no stored time history, and
returns the Jacobian used by Gauss-Newton. Reverse mode (``jax.grad``; for max-force and
history data through the hand-written adjoint of the time loop, :mod:`wfjax.adjoint`, about
1.3-1.4 forward evaluations per gradient, ``max_force_model(adjoint=True)``) otherwise, and always
for ``"3d"`` with a measured profile (its exact table is rebuilt at every evaluation and the
Kalker solver's implicit gradients are ``custom_vjp``); with
``checkpoint=True`` the simulations are run one after the other under ``jax.checkpoint``, so the
backward pass holds one time history at a time.

3D contact
----------
``contact="3d"`` evaluates the paper's own contact model through the parametric family
F(delta, s; depth, length) of :mod:`wfjax.contact.family`, built over a box around the start
(:func:`fit_range`: depth within a factor ``FIT_DEPTH_FACTOR`` and, for rounded flats, l / l0
within ``FIT_LENGTH_FACTOR``; node tables cached on disk). A fit that leaves the box is
restarted from there on a box around that point, up to ``MAX_FAMILY_ROUNDS`` times. Every
evaluation is an interpolation with the geometry traced: forward-mode Jacobians as for the
Hertz models, and no contact table is rebuilt. A fit that still ends outside its family's
range is flagged (not converged). Measured profiles (:class:`ProfileParam`) use their exact
table, rebuilt at every evaluation with implicit-function gradients (slow).

Uncertainty
-----------
Gauss-Newton covariance at the optimum: Cov(theta) = s^2 (J^T J)^-1 with J the Jacobian of the
force residuals [N] and s^2 = sum r^2 / (n - p) the residual variance, mapped to the physical
parameters with the Jacobian G of theta -> (depth, length, ...): Cov = G Cov(theta) G^T. It is
the linearised, data-noise-only uncertainty (no model error, no prior/penalty).
"""

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

from ._xla import LOOP_COMPILER_OPTIONS, to_device
from .contact import registry
from .contact.laws import prepare, prepare_family_range
from .contact.protocol import ContactLaw
from .contact.table_law import TableLaw
from .loop.observers import DetectorReadings
from .loop.run import run_scan
from .loop.structure import structure
from .params import Flat, Material, SimConfig, Track, Wheel, new_flat_length
from .scenario.windows import (
    batch_windows,
    check_speed,
    check_speeds,
    detector_config,
    impact_positions_grid,
)

__all__ = [
    "D_REF",
    "MaxForceData",
    "HistoryData",
    "DetectorData",
    "detector_model",
    "NewFlatParam",
    "RoundedFlatParam",
    "ProfileParam",
    "parametrisation_for",
    "smooth_max",
    "ForceModel",
    "max_force_model",
    "history_model",
    "FitResult",
    "fit_flat",
]

D_REF = 1e-3  # m: depth scale of the parametrisations
MIN_POINTS_MAX_FORCE = 3
MIN_POINTS_HISTORY = 10


# -- measured data ------------------------------------------------------------------------
class MaxForceData(NamedTuple):
    """Maximum impact force against speed (a wheel impact load detector).

    Attributes:
        speeds: [n] train speeds [m/s], > 0.
        max_force: [n] measured maximum contact force [N] at each speed.
    """

    speeds: Any
    max_force: Any


class HistoryData(NamedTuple):
    """A contact-force time history at one speed.

    Attributes:
        t: [n] strictly increasing times [s], t = 0 when the flat centre is over the nominal
            contact point.
        force: [n] measured contact force [N].
        speed: train speed [m/s].
        impact_position: rail coordinate [m] of the impact within the sleeper bay [0, L_S).
    """

    t: Any
    force: Any
    speed: float
    impact_position: float = 0.0


class DetectorData(NamedTuple):
    """Wheel impact load detector readings against speed.

    Attributes:
        speeds: [n] train speeds [m/s], > 0.
        peak: [n] the maximum over the detector's bays of each passage's reading [N], or
            [n, n_bays] the reading of every bay [N] (then ``impact_position`` is needed).
        detector: the :class:`wfjax.sensors.Detector` (default ``Detector()``: 3 bays).
        impact_position: rail coordinate [m] of the impact in [0, L_S) for per-bay data
            (None for max-over-bays data: the model takes a smooth max over positions).
    """

    speeds: Any
    peak: Any
    detector: Any = None
    impact_position: float | None = None


def _finite_1d(name: str, value) -> np.ndarray:
    a = np.asarray(value, dtype=float)
    if a.ndim != 1:
        raise ValueError(f"{name} must be a 1-D array, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} contains NaN or infinite values: {a!r}")
    return a


def _check_data_speeds(v: np.ndarray, n_params: int, what: str) -> None:
    """Enough speeds [m/s], checked by :func:`check_speeds`, for ``n_params`` parameters of
    ``what`` data."""
    need = max(MIN_POINTS_MAX_FORCE, n_params + 1)
    if v.size < need:
        raise ValueError(f"{what} data needs at least {need} speeds to fit {n_params} "
                         f"parameter(s), got {v.size}")
    check_speeds(v)


def _validate_data(measured, n_params: int):
    """Check ``measured`` and return it as :class:`MaxForceData` or :class:`HistoryData`."""
    if isinstance(measured, dict):
        if "peak" in measured:
            measured = DetectorData(**measured)
        elif "t" in measured:
            measured = HistoryData(**measured)
        else:
            measured = MaxForceData(**measured)
    if isinstance(measured, MaxForceData):
        v = _finite_1d("speeds", measured.speeds)
        f = _finite_1d("max_force", measured.max_force)
        if f.shape != v.shape:
            raise ValueError(f"speeds and max_force must have equal length, got {v.size} and "
                             f"{f.size}")
        _check_data_speeds(v, n_params, "max-force")
        if np.any(f <= 0):
            raise ValueError(f"max_force must be > 0 N, got min {f.min():.6g} N")
        return MaxForceData(v, f)
    if isinstance(measured, DetectorData):
        from .sensors import Detector

        v = _finite_1d("speeds", measured.speeds)
        peak = np.asarray(measured.peak, dtype=float)
        det = measured.detector or Detector()
        if not isinstance(det, Detector):
            raise ValueError(f"detector must be a wfjax.sensors.Detector, got {det!r}")
        if peak.ndim == 2 and peak.shape != (v.size, det.n_bays):
            raise ValueError(f"per-bay peak must be [n_speeds, n_bays] = [{v.size}, "
                             f"{det.n_bays}], got {peak.shape}")
        if peak.ndim not in (1, 2) or peak.shape[0] != v.size:
            raise ValueError(f"peak must be [n_speeds] or [n_speeds, n_bays] with n_speeds = "
                             f"{v.size}, got shape {peak.shape}")
        if not np.all(np.isfinite(peak)) or np.any(peak <= 0):
            raise ValueError("peak readings must be finite and > 0 N")
        _check_data_speeds(v, n_params, "detector")
        if peak.ndim == 2 and measured.impact_position is None:
            raise ValueError("per-bay detector data needs impact_position [m]")
        return DetectorData(v, peak, det, measured.impact_position)
    if isinstance(measured, HistoryData):
        t = _finite_1d("t", measured.t)
        f = _finite_1d("force", measured.force)
        if f.shape != t.shape:
            raise ValueError(f"t and force must have equal length, got {t.size} and {f.size}")
        if t.size < max(MIN_POINTS_HISTORY, n_params + 1):
            raise ValueError(f"a force history needs at least {MIN_POINTS_HISTORY} samples, "
                             f"got {t.size}")
        if np.any(np.diff(t) <= 0):
            raise ValueError("t must be strictly increasing")
        if np.any(f < 0):
            raise ValueError(f"force must be >= 0 N, got min {f.min():.6g} N")
        speed = check_speed(measured.speed)
        pos = float(measured.impact_position)
        if not math.isfinite(pos):
            raise ValueError(f"impact_position must be finite, got {measured.impact_position!r}")
        return HistoryData(t, f, speed, pos)
    raise ValueError(f"measured must be MaxForceData, HistoryData, DetectorData or a dict, got "
                     f"{type(measured).__name__}")


# -- parametrisations -----------------------------------------------------------------------
def _softplus_inv(y):
    y = np.asarray(y, dtype=float)
    return y + np.log(-np.expm1(-y))


@dataclasses.dataclass(frozen=True)
class NewFlatParam:
    """New flat: theta = [log(depth / 1 mm)]; physical parameters (depth [m],).

    Attributes:
        wheel_radius: R_W [m]. extent_bound: static bound of the flat's half extent [m].
    """

    wheel_radius: float = 0.45
    extent_bound: float = 0.06
    names: tuple = ("depth",)

    def to_flat(self, theta) -> Flat:
        depth = D_REF * jnp.exp(theta[0])
        return Flat("new", depth, new_flat_length(depth, self.wheel_radius),
                    wheel_radius=self.wheel_radius, extent_bound=self.extent_bound)

    def physical(self, theta):
        """[1] depth [m]."""
        return D_REF * jnp.exp(theta[:1])

    def from_flat(self, flat: Flat) -> np.ndarray:
        return np.array([math.log(float(flat.depth) / D_REF)])

    def penalty(self, theta):
        return jnp.zeros(())


@dataclasses.dataclass(frozen=True)
class RoundedFlatParam:
    """Rounded flat: theta = [log(d / 1 mm), softplus^-1(l / l0(d) - pi/2)].

    Physical parameters (depth [m], length [m]); length >= pi/2 l0(depth) for every theta.
    """

    wheel_radius: float = 0.45
    extent_bound: float = 0.1
    names: tuple = ("depth", "length")

    def physical(self, theta):
        """[2] (depth [m], length [m])."""
        depth = D_REF * jnp.exp(theta[0])
        l0 = new_flat_length(depth, self.wheel_radius)
        return jnp.stack([depth, l0 * (jnp.pi / 2 + jax.nn.softplus(theta[1]))])

    def to_flat(self, theta) -> Flat:
        depth, length = self.physical(theta)
        return Flat("rounded", depth, length, wheel_radius=self.wheel_radius,
                    extent_bound=self.extent_bound)

    def from_flat(self, flat: Flat) -> np.ndarray:
        depth, length = float(flat.depth), float(flat.length)
        ratio = length / float(new_flat_length(depth, self.wheel_radius)) - math.pi / 2
        return np.array([math.log(depth / D_REF), float(_softplus_inv(max(ratio, 1e-6)))])

    def penalty(self, theta):
        return jnp.zeros(())


@dataclasses.dataclass(frozen=True)
class ProfileParam:
    """Measured-like flat: K non-negative raised-cosine bumps on a fixed support.

    z(x) = sum_k a_k b_k(x), a_k = 1 mm * softplus(theta_k) >= 0, with
    b_k(x) = (1 + cos(pi (x - x_k) / h)) / 2 for |x - x_k| < h, h = 2 dx, centres x_k evenly
    spaced (dx) from -L/2 + h to L/2 - h, so z is C1, >= 0 and zero outside [-L/2, L/2].
    Physical parameters: the amplitudes a_k [m]. Penalty (added to the loss):
    ``smoothing * sum_k (a_{k-1} - 2 a_k + a_{k+1})^2 / (1 mm)^2`` against noise.

    Attributes:
        half_length: L/2 [m] (static support). n_basis: K. n_grid: samples of the profile.
        smoothing: weight of the penalty (the data term is the mean squared relative residual).
        wheel_radius: R_W [m].
    """

    half_length: float = 0.06
    n_basis: int = 8
    n_grid: int = 121
    smoothing: float = 1e-3
    wheel_radius: float = 0.45

    @property
    def names(self) -> tuple:
        return tuple(f"amplitude_{k}" for k in range(self.n_basis))

    @property
    def extent_bound(self) -> float:
        return float(self.half_length)

    def _basis(self) -> np.ndarray:
        """[n_grid, K] basis values on the profile grid."""
        dx = 2 * self.half_length / (self.n_basis + 3)
        h = 2 * dx
        centres = -self.half_length + h + dx * np.arange(self.n_basis)
        x = self.grid()[:, None]
        u = np.clip((x - centres) / h, -1.0, 1.0)
        return 0.5 * (1 + np.cos(np.pi * u))

    def grid(self) -> np.ndarray:
        """[n_grid] circumferential positions of the profile samples [m]."""
        return np.linspace(-self.half_length, self.half_length, self.n_grid)

    def physical(self, theta):
        """[K] bump amplitudes [m]."""
        return D_REF * jax.nn.softplus(theta)

    def to_flat(self, theta) -> Flat:
        z = jnp.asarray(self._basis()) @ self.physical(theta)
        return Flat("profile", jnp.max(z), 2 * self.half_length, wheel_radius=self.wheel_radius,
                    profile_x=jnp.asarray(self.grid()), profile_z=z,
                    extent_bound=self.extent_bound)

    def from_flat(self, flat: Flat) -> np.ndarray:
        from .geometry import profile_deviation

        z = np.asarray(profile_deviation(flat, self.grid()))
        amp, *_ = np.linalg.lstsq(self._basis(), z, rcond=None)
        return _softplus_inv(np.maximum(amp / D_REF, 1e-3))

    def penalty(self, theta):
        a = jax.nn.softplus(theta)
        return self.smoothing * jnp.sum((a[:-2] - 2 * a[1:-1] + a[2:]) ** 2)


def parametrisation_for(flat: Flat, extent_bound: float | None = None, **options):
    """Default parametrisation for the kind of ``flat`` (new, rounded or profile).

    ``extent_bound`` [m] bounds the half extent the flat may reach during the fit (sizes the
    numerical windows); default 1.5 x the initial half extent (the profile support for
    ``"profile"``, whose support is fixed).
    """
    radius = float(flat.wheel_radius)
    if flat.kind == "profile":
        half = float(max(abs(np.asarray(flat.profile_x)[[0, -1]])))
        return ProfileParam(half_length=half, wheel_radius=radius, **options)
    half = float(flat.length) / 2
    bound = 1.5 * half if extent_bound is None else float(extent_bound)
    if flat.kind == "new":
        return NewFlatParam(wheel_radius=radius, extent_bound=bound)
    if flat.kind == "rounded":
        return RoundedFlatParam(wheel_radius=radius, extent_bound=bound)
    raise ValueError(f"cannot fit a flat of kind {flat.kind!r}; use new, rounded or profile")


# -- smooth maximum -------------------------------------------------------------------------
def smooth_max(x, temperature=None, axis=-1):
    """T log sum exp(x / T) along ``axis`` (same units as x, e.g. N); hard max if T is 0/None.

    Lies in [max x, max x + T log n] for n candidates; differentiable everywhere.
    """
    if not temperature:
        return jnp.max(x, axis=axis)
    return temperature * jax.nn.logsumexp(jnp.asarray(x) / temperature, axis=axis)


# -- differentiable force models ------------------------------------------------------------
FIT_DEPTH_FACTOR = 1.4  # the 3D family of a fit covers depths in [d0 / 1.4, 1.4 d0]
FIT_LENGTH_FACTOR = 1.2  # ... and l / l0 within a factor 1.2 of the start (rounded flats)
MAX_FAMILY_ROUNDS = 5  # restarts of a 3D fit on a family around where it left the last one


@dataclasses.dataclass(frozen=True)
class _Setup:
    """Concrete model data shared by every evaluation (built once, outside ``jit``)."""

    contact: str
    wheel: Wheel
    track: Track
    material: Material
    config: SimConfig
    struct: Any
    table_spec: Any  # TableSpec for "3d" with a measured profile, else None
    family: Any  # FlatFamily for "3d" with a new or rounded flat, else None


def fit_range(reference: Flat, wheel_radius: float, depth_factor: float = FIT_DEPTH_FACTOR,
              length_factor: float = FIT_LENGTH_FACTOR):
    """(depths [m], length factors l / l0 or None) spanning the range a 3D fit may visit.

    Depths from d0 / ``depth_factor`` to d0 x ``depth_factor`` (within the model's 0-5 mm);
    rounded flats from l / l0 = lambda0 / ``length_factor`` (at least pi/2, the shortest
    rounded flat) to lambda0 x ``length_factor``. The parametric family of the fit covers this
    range; :func:`fit_flat` warns when the fitted flat ends on its edge.
    """
    from .params import MAX_FLAT_DEPTH

    d0 = float(reference.depth)
    depths = [d0 / depth_factor, min(d0 * depth_factor, MAX_FLAT_DEPTH)]
    if reference.kind == "new":
        return depths, None
    factor = float(reference.length) / float(new_flat_length(d0, wheel_radius))
    return depths, [max(factor / length_factor, math.pi / 2), factor * length_factor]


def _setup(contact: str, reference: Flat, wheel, track, material, config, cache_dir=None):
    registry.check(contact)
    wheel = wheel or Wheel()
    track = track or Track()
    material = material or Material()
    config = config or SimConfig()
    spec3d = family = None
    if contact == "3d" and reference.kind == "profile":
        from .contact import tables

        spec3d = tables.table_spec(reference, float(wheel.radius), float(track.rail_head_radius),
                                   material, element_size=config.contact_element)
    elif contact == "3d":
        depths, factors = fit_range(reference, float(wheel.radius))
        family = prepare_family_range(reference.kind, depths, factors, wheel, track, material,
                                      config, cache_dir)
    return _Setup(contact, wheel, track, material, config,
                  structure(wheel, track, config, cache_dir), spec3d, family)


def _contact(setup: _Setup, flat: Flat) -> ContactLaw:
    """The contact law of ``flat`` (depth, length, profile may be traced)."""
    if setup.table_spec is not None:  # a measured profile: its exact table, built traced
        from .contact import tables

        return TableLaw(tables.build_table_3d(
            flat, float(setup.wheel.radius), float(setup.track.rail_head_radius),
            setup.material, element_size=setup.config.contact_element, spec=setup.table_spec))
    return prepare(setup.contact, flat, setup.wheel, setup.track, setup.material,
                   setup.config, family=setup.family)


class ForceModel(NamedTuple):
    """A differentiable map flat -> forces [N], with the concrete setup behind it.

    ``model(flat)`` returns [n_out] forces; depth, length and profile values of ``flat`` may be
    traced (``jax.grad``/``jacfwd``), its kind and ``extent_bound`` are fixed.
    """

    fn: Any
    setup: Any
    info: dict

    def __call__(self, flat: Flat):
        return self.fn(flat)


def _reference_flat(flat: Flat, extent_bound: float | None) -> Flat:
    """A concrete flat like ``flat`` whose windows are sized by ``extent_bound``."""
    bound = flat.half_extent if extent_bound is None else float(extent_bound)
    return dataclasses.replace(flat, extent_bound=bound)


def _batch_runs(setup: _Setup, law, n_steps, speeds, dt, x_start, impact, checkpoint: bool,
                adjoint: bool = False, observers: tuple = (), output: str = "force"):
    """The ``output`` [batch, ...] (default the force histories [batch, n_steps] N) of runs
    batched over (speed, dt, x_start, impact), with ``observers`` shared by the runs.

    ``adjoint``: run :func:`wfjax.adjoint.run_adjoint` (same outputs; a hand-written reverse
    mode, no forward mode) instead of :func:`wfjax.loop.run.run_scan`."""
    max_iter = setup.config.newton_iterations
    runner = run_scan
    args = tuple(jnp.asarray(a, dtype=float) for a in (speeds, dt, x_start, impact))
    if adjoint:
        from . import adjoint as adjoint_mod

        if not checkpoint:  # one custom_vjp for the batch (its backward skips late steps)
            return adjoint_mod.run_adjoint_runs(law, setup.struct, *args, n_steps, max_iter,
                                                precision=setup.config.precision,
                                                observers=observers)[output]
        runner = adjoint_mod.run_adjoint

    def one(args):
        v, d, xs, xi = args
        return runner(law, setup.struct, v, d, xs, xi, n_steps, max_iter,
                      precision=setup.config.precision, observers=observers)[output]

    if checkpoint:
        return jax.lax.map(jax.checkpoint(one), args)
    return jax.vmap(one)(args)


def max_force_model(speeds, reference: Flat, contact: str = "hertz-trajectory",
                    impact_positions=3, temperature: float | None = 1e3,
                    time_temperature: float | None = None, extent_bound: float | None = None,
                    wheel: Wheel | None = None, track: Track | None = None,
                    material: Material | None = None, config: SimConfig | None = None,
                    checkpoint: bool = False, cache_dir=None,
                    adjoint: bool = False) -> ForceModel:
    """Differentiable maximum impact force [N] at each of ``speeds`` (impact load detector).

    For every speed and impact position one simulation is run (all with the step count of the
    slowest, each with its own time step: one rectangular batch,
    :func:`wfjax.scenario.windows.batch_windows`, finer than :func:`wfjax.simulate`'s time step at
    most speeds); its maximum force after the run-in (``smooth_max`` with
    ``time_temperature``, hard by default) is then reduced over the positions with
    ``smooth_max(temperature)`` [N].

    Args:
        speeds: [n] train speeds [m/s].
        reference: a concrete flat of the kind to be evaluated (sizes windows and 3D tables).
        contact: one of :func:`wfjax.contact.registry.names`.
        impact_positions: number of positions evenly covering a bay, or [m] positions [m].
        temperature, time_temperature: smooth-maximum temperatures [N] (None: hard max).
        extent_bound: static bound [m] of the flat's half extent (default: the reference's).
        wheel, track, material, config: model parameters (default track:
            ``Track()``, as :func:`wfjax.simulate` and :func:`wfjax.sweep`).
        checkpoint: run the simulations sequentially under ``jax.checkpoint`` (reverse-mode
            memory: one time history at a time instead of n x positions).
        adjoint: reverse mode through the hand-written adjoint of the time loop
            (:mod:`wfjax.adjoint`: the same forces; measured for 10 speeds of the 3D family,
            value_and_grad at 1.3-1.4 forward evaluations instead of 3.3-4); the model then
            supports reverse mode only (``grad``/``jacrev``, not ``jacfwd``). Default False:
            plain autodiff.

    Returns:
        :class:`ForceModel`: ``model(flat) -> [n]`` forces [N].
    """
    ref = _reference_flat(reference, extent_bound)
    setup = _setup(contact, ref, wheel, track, material, config, cache_dir)
    v = np.atleast_1d(np.asarray(speeds, dtype=float))
    spacing = float(setup.track.sleeper_spacing)
    pos = (impact_positions_grid(impact_positions, spacing) if np.ndim(impact_positions) == 0
           else np.asarray(impact_positions, dtype=float))
    n_steps, dt, s0, run_in = batch_windows(ref, v, setup.config)
    vv, pp = (a.ravel() for a in np.meshgrid(v, pos, indexing="ij"))
    dd, ss, rr = (np.repeat(a, pos.size) for a in (dt, s0, run_in))
    after = to_device(np.arange(n_steps)[None, :] >= rr[:, None])

    def fn(flat: Flat):
        law = _contact(setup, flat)
        force = _batch_runs(setup, law, n_steps, vv, dd, pp + ss, pp, checkpoint, adjoint)
        peak = smooth_max(jnp.where(after, force, 0.0), time_temperature, axis=-1)
        return smooth_max(peak.reshape(v.size, pos.size), temperature, axis=-1)

    info = {"kind": "max_force", "speeds": v, "impact_positions": pos, "n_steps": n_steps,
            "time_steps": dt, "temperature": temperature, "time_temperature": time_temperature,
            "adjoint": adjoint}
    return ForceModel(fn, setup, info)


def detector_model(speeds, reference: Flat, detector=None, per_bay: bool = False,
                   contact: str = "hertz-trajectory", impact_positions=3,
                   temperature: float | None = 1e3, extent_bound: float | None = None,
                   wheel: Wheel | None = None, track: Track | None = None,
                   material: Material | None = None, config: SimConfig | None = None,
                   cache_dir=None, adjoint: bool = False) -> ForceModel:
    """Differentiable detector readings [N] at each of ``speeds`` [m/s].

    Every run carries the detector (:class:`wfjax.sensors.Detector`, default 3 bays) in its
    scan; windows are lengthened so the wheel crosses every bay. ``per_bay``: the readings
    of every bay at the one position ``impact_positions`` (a single [m] value), flattened
    [n * n_bays]; otherwise the maximum over bays, then ``smooth_max(temperature)`` [N] over
    the impact positions (count or [m] array), [n]. ``adjoint``: reverse mode through
    :mod:`wfjax.adjoint` (as :func:`max_force_model`: the same readings, reverse mode only).
    """
    from . import sensors as sensor_mod

    detector = detector or sensor_mod.Detector()
    ref = _reference_flat(reference, extent_bound)
    track = track or Track()
    config = detector_config(detector, track, config or SimConfig())
    setup = _setup(contact, ref, wheel, track, material, config, cache_dir)
    spec = sensor_mod.detector_spec(detector, setup.track, setup.struct.track)
    v = np.atleast_1d(np.asarray(speeds, dtype=float))
    spacing = float(setup.track.sleeper_spacing)
    pos = (impact_positions_grid(impact_positions, spacing) if np.ndim(impact_positions) == 0
           else np.atleast_1d(np.asarray(impact_positions, dtype=float)))
    if per_bay and pos.size != 1:
        raise ValueError(f"per-bay detector data needs one impact position, got {pos!r}")
    n_steps, dt, s0, _ = batch_windows(ref, v, setup.config)
    vv, pp = (a.ravel() for a in np.meshgrid(v, pos, indexing="ij"))
    dd, ss = (np.repeat(a, pos.size) for a in (dt, s0))
    observers = (DetectorReadings(spec, history=False),)

    def fn(flat: Flat):
        peaks = _batch_runs(setup, _contact(setup, flat), n_steps, vv, dd, pp + ss, pp, False,
                            adjoint, observers, "detector_peak")  # [n * n_pos, n_bays]
        if per_bay:
            return peaks.reshape(-1)
        return smooth_max(jnp.max(peaks, axis=-1).reshape(v.size, pos.size), temperature,
                          axis=-1)

    info = {"kind": "detector", "speeds": v, "impact_positions": pos, "n_steps": n_steps,
            "time_steps": dt, "temperature": temperature, "detector": detector,
            "per_bay": per_bay, "adjoint": adjoint}
    return ForceModel(fn, setup, info)


def history_model(t, speed: float, reference: Flat, contact: str = "hertz-trajectory",
                  impact_position: float = 0.0, extent_bound: float | None = None,
                  wheel: Wheel | None = None, track: Track | None = None,
                  material: Material | None = None, config: SimConfig | None = None,
                  cache_dir=None, adjoint: bool = False) -> ForceModel:
    """Differentiable contact force [N] at times ``t`` [s] (t = 0: flat centre at the contact).

    The simulation of :func:`wfjax.simulate` at ``speed`` [m/s] and ``impact_position`` [m],
    linearly interpolated at ``t``, which must lie inside the simulated window.
    ``adjoint``: reverse mode through :mod:`wfjax.adjoint` (as :func:`max_force_model`).
    """
    ref = _reference_flat(reference, extent_bound)
    setup = _setup(contact, ref, wheel, track, material, config, cache_dir)
    spacing = float(setup.track.sleeper_spacing)
    pos = float(impact_position)
    if not 0 <= pos < spacing:
        raise ValueError(f"impact_position must be in [0, {spacing:g}) m, got {pos!r}")
    n_steps, dt, s0, _ = batch_windows(ref, [speed], setup.config)
    t = np.asarray(t, dtype=float)
    t_first, t_last = s0[0] / speed, s0[0] / speed + dt[0] * (n_steps - 1)
    if t.min() < t_first or t.max() > t_last:
        raise ValueError(f"t must lie in the simulated window [{t_first * 1e3:.1f}, "
                         f"{t_last * 1e3:.1f}] ms (t = 0: flat centre at the contact), got "
                         f"[{t.min() * 1e3:.1f}, {t.max() * 1e3:.1f}] ms")
    t_sim = jnp.asarray(t_first + dt[0] * np.arange(n_steps))

    def fn(flat: Flat):
        law = _contact(setup, flat)
        force = _batch_runs(setup, law, n_steps, [speed], dt, [pos + s0[0]], [pos], False,
                            adjoint)[0]
        return jnp.interp(jnp.asarray(t), t_sim, force)

    info = {"kind": "history", "speed": float(speed), "impact_position": pos,
            "n_steps": n_steps, "time_step": float(dt[0]), "t_sim": np.asarray(t_sim),
            "adjoint": adjoint}
    return ForceModel(fn, setup, info)


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


def fit_flat(measured, initial: Flat, contact: str = "hertz-trajectory", *,
             parametrisation=None, impact_positions=3, temperature: float | None = 1e3,
             time_temperature: float | None = None, method: str = "lbfgs",
             max_iter: int = 40, learning_rate: float = 0.05, gtol: float = 1e-7,
             ftol: float = 1e-7, xtol: float = 2e-3, max_step: float = 0.5, mode: str = "auto",
             checkpoint: bool = False, extent_bound: float | None = None,
             wheel: Wheel | None = None, track: Track | None = None,
             material: Material | None = None, config: SimConfig | None = None,
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
            differentiates max-force and history data through the time loop's adjoint
            (:mod:`wfjax.adjoint`), detector data by plain autodiff.
        checkpoint: see :func:`max_force_model` (reverse mode only).
        extent_bound: static bound of the flat's half extent [m] during the fit.
        wheel, track, material, config: model parameters (default track
            ``Track()``, Table 2 with R_R = 0.30 m, the default of every entry point; pass
            :meth:`Track.comparison` for the paper's R_R = 0.45 m).
        callback: called as ``callback(iteration, loss, flat)`` after every iteration.

    Returns:
        :class:`FitResult`.
    """
    start = time.perf_counter()
    registry.check(contact)
    if not isinstance(initial, Flat):
        raise ValueError(f"initial must be a Flat, got {type(initial).__name__}")
    if method not in ("lbfgs", "adam"):
        raise ValueError(f"method must be 'lbfgs' or 'adam', got {method!r}")
    if mode not in ("auto", "forward", "reverse"):
        raise ValueError(f"mode must be 'auto', 'forward' or 'reverse', got {mode!r}")
    if int(max_iter) < 1:
        raise ValueError(f"max_iter must be >= 1, got {max_iter!r}")
    par = parametrisation or parametrisation_for(initial, extent_bound)
    theta0 = np.asarray(par.from_flat(initial), dtype=float)
    n_par = theta0.size
    data = _validate_data(measured, n_par)
    exact_3d = contact == "3d" and initial.kind == "profile"  # traced Kalker table build
    if mode == "auto":
        mode = "forward" if n_par <= 4 and not exact_3d else "reverse"
    if mode == "forward" and exact_3d:
        raise ValueError("contact '3d' with a measured profile needs mode='reverse' "
                         "(its exact table's Kalker solves have custom_vjp gradients)")
    kw = dict(contact=contact, extent_bound=par.extent_bound, wheel=wheel, track=track,
              material=material, config=config, cache_dir=cache_dir)
    if isinstance(data, DetectorData):
        per_bay = data.peak.ndim == 2
        y = data.peak.ravel()
        x = np.repeat(data.speeds, data.peak.shape[1]) if per_bay else data.speeds
        kind = "detector"

        def build(ref):
            return detector_model(data.speeds, ref, data.detector, per_bay,
                                  impact_positions=([data.impact_position] if per_bay
                                                    else impact_positions),
                                  temperature=temperature, **kw)
    elif isinstance(data, MaxForceData):
        y, x, kind = data.max_force, data.speeds, "max_force"

        def build(ref):
            return max_force_model(data.speeds, ref, impact_positions=impact_positions,
                                   temperature=temperature, time_temperature=time_temperature,
                                   checkpoint=checkpoint, adjoint=mode == "reverse", **kw)
    else:
        y, x, kind = data.force, data.t, "history"

        def build(ref):
            return history_model(data.t, data.speed, ref, impact_position=data.impact_position,
                                 adjoint=mode == "reverse", **kw)
    scale = float(np.mean(np.abs(y)))
    y_j = jnp.asarray(y)

    def report(i, value, theta):
        if callback is not None:
            callback(i, value, par.to_flat(theta))

    # A 3D fit's family covers a box around its start; a fit that leaves the box is restarted
    # from where it left, on a box around that point (nodes are cached, so only new ones build).
    theta, history, gnorms = jnp.asarray(theta0), [], []
    for _ in range(MAX_FAMILY_ROUNDS):
        model = build(jax.tree_util.tree_map(np.asarray, par.to_flat(theta)))
        value_and_grad, loss_j, jacobian = _objective(model, par, y_j, scale, mode)
        theta, h, g, message, converged = _optimise(
            value_and_grad, loss_j, theta, method, int(max_iter) - len(history), learning_rate,
            gtol, ftol, xtol, max_step, report)
        restart = 1 if history else 0  # a restart's first entry repeats the last one
        history, gnorms = history + list(h[restart:]), gnorms + list(g[restart:])
        family = model.setup.family
        inside = family is None or _inside_family(family.spec, _concrete_flat(
            jax.tree_util.tree_map(np.asarray, par.to_flat(theta))))
        if inside or len(history) > int(max_iter):
            break

    # uncertainty (Gauss-Newton, force residuals in N)
    J_rel, r_rel = jacobian(theta)
    J = np.asarray(J_rel) * scale
    pred = np.asarray(r_rel) * scale + y
    r = pred - y
    G = np.asarray(jax.jacfwd(par.physical)(theta))
    cov = _gauss_newton(J, r, G)
    phys = np.asarray(par.physical(theta))
    flat = jax.tree_util.tree_map(np.asarray, par.to_flat(theta))
    flat = _concrete_flat(flat)
    names = par.names
    params = {n: float(v) for n, v in zip(names, phys, strict=True)}
    std = {n: float(math.sqrt(max(c, 0.0))) for n, c in zip(names, np.diag(cov), strict=True)}
    if flat.kind != "profile" and float(flat.length) / 2 > par.extent_bound + 1e-12:
        message += (f"; WARNING: fitted half length {float(flat.length) / 2 * 1e3:.1f} mm "
                    f"exceeds extent_bound {par.extent_bound * 1e3:.1f} mm, refit with a "
                    f"larger extent_bound")
        converged = False
    if not inside:
        lo, hi = family.spec.depth_range
        message += (f"; WARNING: after {MAX_FAMILY_ROUNDS} rounds the fitted flat lies outside "
                    f"the 3D family's range (depth {lo * 1e3:.3g}-{hi * 1e3:.3g} mm), where the "
                    "law is clamped: refit from a start closer to it")
        converged = False
    return FitResult(flat=flat, params=params, std=std, covariance=cov, theta=np.asarray(theta),
                     loss_history=np.asarray(history), grad_norm_history=np.asarray(gnorms),
                     n_iterations=len(history) - 1, converged=converged, message=message,
                     prediction=pred, measured=np.asarray(y), x=np.asarray(x),
                     residual_rms=float(np.sqrt(np.mean(r**2))), kind=kind, contact=contact,
                     wall_time=time.perf_counter() - start)


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

    jit = functools.partial(jax.jit, compiler_options=LOOP_COMPILER_OPTIONS)
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
