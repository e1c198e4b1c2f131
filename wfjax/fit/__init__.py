"""Gradient-based fitting of a wheel flat's geometry to measured impact forces (optax).

The force models (:mod:`wfjax.fit.models`) stand on the program core (:mod:`wfjax.program`), so a
fit takes whatever a simulation takes: a vehicle (the flat on its reference wheel), rail and
wheel roughness, a track with varying supports, a detector. Modules: :mod:`~wfjax.fit.data`
(the measured data), :mod:`~wfjax.fit.parametrisations`, :mod:`~wfjax.fit.models`,
:mod:`~wfjax.fit.optimise` (:func:`fit_flat`).

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
    detector's load estimate (:class:`wfjax.Detector`, the rail's shear difference
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
returns the Jacobian used by Gauss-Newton. Reverse mode (``jax.grad`` through the hand-written
adjoint of the time loop, :mod:`wfjax.loop.adjoint`, for every kind of data: about 1.3-1.4 forward
evaluations per gradient, ``max_force_model(adjoint=True)``) otherwise, and always
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

from .data import DetectorData, HistoryData, MaxForceData
from .models import (
    ForceModel,
    TracedLaw,
    detector_model,
    fit_range,
    history_model,
    max_force_model,
    smooth_max,
)
from .optimise import FitResult, fit_flat
from .parametrisations import (
    D_REF,
    NewFlatParam,
    ProfileParam,
    RoundedFlatParam,
    parametrisation_for,
)

__all__ = ["D_REF", "MaxForceData", "HistoryData", "DetectorData", "detector_model",
           "NewFlatParam", "RoundedFlatParam", "ProfileParam", "parametrisation_for",
           "smooth_max", "fit_range", "TracedLaw", "ForceModel", "max_force_model",
           "history_model", "FitResult", "fit_flat"]
