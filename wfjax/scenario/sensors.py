"""What instruments on the track read: rail and sleeper responses at fixed sensors, and a
strain-gauge wheel impact load detector (``docs/detector.md``).

Sensors are fixed rail positions x_s [m] (same coordinate as :mod:`wfjax.model.track`: x = 0 at the
middle sleeper). At each the time loop returns, from its own modal state (inside the same
``lax.scan``, no second pass over the history), the quantities of :data:`QUANTITIES`:

* ``rail_disp`` [m], ``rail_vel`` [m/s], ``rail_acc`` [m/s^2]: rail vertical displacement,
  velocity and acceleration at x_s (downwards positive, as everywhere in wfjax);
* ``shear`` [N], ``moment`` [N m]: rail shear force and bending moment at x_s from the
  Timoshenko element fields. Conventions: ``moment`` is positive sagging (rail foot in
  tension, as under a wheel between two sleepers); ``shear`` is the downward force that the
  rail right of x_s exerts on the rail left of it, so that d(moment)/dx = shear. It jumps by
  -F across a wheel load F and by +R across a sleeper with rail-seat force R;
* ``sleeper_disp`` [m], ``sleeper_vel`` [m/s], ``sleeper_acc`` [m/s^2], ``seat_force`` [N]:
  for the sleeper nearest to x_s (ties go to the right), its displacement, velocity and
  acceleration and the rail-seat (pad) force k_P (w_R - w_S) + c_P (w_R' - w_S'), positive in
  compression (the load the rail puts on the sleeper).

How each is evaluated
---------------------
Every quantity is a fixed linear functional o of the FE track's degrees of freedom. With the
track's complex modes u_r (weights w_r, poles lambda_r, modal states q_r of the time loop)
and the contact force F at X(t)::

    y(t) = Re sum_r w_r (o . u_r) q_r(t) + rho_o(X) F(t)                      (displacements)

where rho_o = [K^-1 - Re sum_kept w_r u_r u_r^T / (-lambda_r)] o is the static contribution
of the truncated modes, a rail nodal vector interpolated at X with the element shape functions
(so y is exact in statics: o . K^-1 b(X) F). Velocities use q_r' = lambda_r q_r + phi_r(X) F and
accelerations q_r'' ~ lambda_r q_r' (the F' term vanishes for the complete mode set), both over
the kept modes only. Shear and moment come from the element containing x_s (at a node: the
element to the right): its nodal forces K_e u_e give the homogeneous field (constant shear,
linear moment: exact for the Friedman-Kosmatka element's static shape functions); when the
wheel is inside that element the fixed-end (particular) solution of the point load is added,
so the shear jumps by F exactly at the load. Rail displacements are the FE interpolation (no
particular term).

Valid positions: |x_s| <= n_bays L_S / 2 - :func:`wfjax.scenario.guards.sensor_margin` (6 m
on the paper's track), where the clamped ends' reflections no longer move a seat force by
more than 3 % (docs/convergence.md). A scenario lengthens a track with scalar supports until
its sensors are valid (:meth:`wfjax.Scenario.lengthened`); per-sleeper supports fix it.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse.linalg

from ..fields import pytree
from ..model import beam as beam_mod
from ..model import fe as fe_mod
from ..model import track as track_mod
from ..model.sleepers import support_arrays
from ..model.supports import hanging_sleepers
from ..params import Track
from .guards import sensor_margin

__all__ = ["QUANTITIES", "SensorSpec", "sensor_spec", "evaluate", "check_positions",
           "Detector", "DetectorSpec", "detector_spec", "detector_load",
           "detector_gate"]

QUANTITIES = ("rail_disp", "rail_vel", "rail_acc", "shear", "moment", "sleeper_disp",
              "sleeper_vel", "sleeper_acc", "seat_force")
UNITS = {"rail_disp": "m", "rail_vel": "m/s", "rail_acc": "m/s^2", "shear": "N",
         "moment": "N m", "sleeper_disp": "m", "sleeper_vel": "m/s", "sleeper_acc": "m/s^2",
         "seat_force": "N"}


def allowed_range(track: Track) -> float:
    """Largest |x| [m] of a sensor on ``track``: n_bays L_S / 2 less the end margin
    (:func:`wfjax.scenario.guards.sensor_margin`), rounded down to the mm."""
    half = 0.5 * int(track.n_bays) * float(track.sleeper_spacing)
    return math.floor((half - sensor_margin(track)) * 1e3) / 1e3


def check_positions(positions, track: Track, name: str = "sensor position") -> np.ndarray:
    """``positions`` [m] as a 1-D float array; ValueError naming a bad one and the range."""
    x = np.atleast_1d(np.asarray(positions, dtype=float))
    half = allowed_range(track)
    if x.ndim != 1 or x.size == 0:
        raise ValueError(f"{name}s must be a non-empty 1-D list of positions in m, got "
                         f"{positions!r}")
    if half < 0:
        need = 2 * math.ceil(sensor_margin(track) / float(track.sleeper_spacing))
        raise ValueError(f"the {track.n_bays}-bay track leaves no room for a {name}: each "
                         f"keeps {sensor_margin(track):.2f} m clear of the ends, where their "
                         f"reflections have decayed; give Track(n_bays=...) >= {need}")
    for xi in x:
        if not math.isfinite(xi) or abs(xi) > half:
            raise ValueError(f"{name} {float(xi):g} m is outside the allowed range [-{half:g}, "
                             f"{half:g}] m ({sensor_margin(track):.2f} m clear of the "
                             f"ends of the {track.n_bays}-bay track, where their reflections "
                             "have decayed; docs/convergence.md)")
    return x


@pytree(static=("quantities",))
class SensorSpec:
    """Concrete observation data of a set of sensors (a pytree; build with
    :func:`sensor_spec`). Rows are quantity-major: row = i_quantity * n_sensors + i_sensor.

    Attributes:
        positions: [n_s] sensor positions [m].
        c_re, c_im: [n_rows, n_modes] real and imaginary parts of w_r (o . u_r) times
            1, lambda_r or lambda_r^2 (displacement, velocity, acceleration rows).
        direct: [n_nodes, 2, n_rows] rail nodal vectors multiplying F(t), interpolated at the
            contact point: truncated-mode statics (displacement-like rows) or the direct
            feed-through of the kept modes (velocity and acceleration rows).
        element_x0: [n_s] start [m] of the rail element containing each sensor.
        local_s: [n_s] sensor position within that element [m].
        support_direct: [n_rows, n_hanging] the same direct terms for a unit downward load on
            each hanging sleeper (:func:`wfjax.model.supports.hanging_sleepers`; their one-sided
            ballast pushes up with the loop's support forces); [n_rows, 0] when none hangs.
        quantities: names of the rows' quantities (static).
    """

    positions: jax.Array
    c_re: jax.Array
    c_im: jax.Array
    direct: jax.Array
    element_x0: jax.Array
    local_s: jax.Array
    support_direct: jax.Array
    quantities: tuple = QUANTITIES


def _nodal(rail_dofs: np.ndarray, n_nodes: int) -> np.ndarray:
    """Free rail DOF vector(s) [2 (n_nodes - 2), ...] -> nodal [n_nodes, 2, ...] (ends 0)."""
    out = np.zeros((n_nodes, 2) + rail_dofs.shape[1:])
    out[1:-1] = rail_dofs.reshape((n_nodes - 2, 2) + rail_dofs.shape[1:])
    return out


def sensor_spec(positions, track: Track, model, quantities=QUANTITIES) -> SensorSpec:
    """Observation rows of the sensors at ``positions`` [m] (concrete, outside ``jit``).

    Args:
        positions: [n_s] rail positions [m] (:func:`check_positions`).
        track: the track (concrete numbers; the FE model is assembled for the statics).
        model: its :class:`wfjax.model.track.ModalModel` (with ``sleeper_shapes``).
        quantities: subset of :data:`QUANTITIES`, in any order.

    Returns:
        :class:`SensorSpec`.
    """
    x = check_positions(positions, track)
    quantities = tuple(quantities)
    bad = [q for q in quantities if q not in QUANTITIES]
    if bad or not quantities:
        raise ValueError(f"quantities must be among {QUANTITIES}, got {quantities!r}")
    if model.sleeper_shapes is None:
        raise ValueError("the modal model has no sleeper_shapes (rebuild it with "
                         "wfjax.model.track.modal_model)")
    fe = fe_mod.assemble(track)
    n_nodes = np.asarray(model.shapes).shape[1]
    sleeper = np.clip(np.floor(x / float(track.sleeper_spacing) + 0.5).astype(int)
                      + int(track.n_bays) // 2 - 1, 0, int(track.n_bays) - 2)
    elem = np.clip(np.floor((x - fe.node_x[0]) / fe.element_length + 1e-9).astype(int), 0,
                   n_nodes - 2)
    local = x - fe.node_x[elem]
    o, kinds, damp = _observation_functionals(track, fe, quantities, x, sleeper, elem, local)
    sup = support_arrays(track)  # per sleeper [n_bays - 1]
    row_sleeper = np.tile(sleeper, len(quantities))  # the sleeper under each row's position
    rows, direct, sleepers = _modal_rows(model, fe, o, kinds, damp,
                                         sup["pad_stiffness"][row_sleeper],
                                         sup["pad_damping"][row_sleeper])
    return SensorSpec(jnp.asarray(x), jnp.asarray(rows.real.T), jnp.asarray(rows.imag.T),
                      jnp.asarray(direct), jnp.asarray(fe.node_x[elem]), jnp.asarray(local),
                      jnp.asarray(sleepers[hanging_sleepers(track)].T), quantities)


def _observation_functionals(track: Track, fe, quantities, x, sleeper, elem, local):
    """Each sensor row's observation functional o [n_dof, rows] on the FE DOFs (rows ordered
    quantity-major), its time-derivative order (0 displacement, 1 velocity, 2 acceleration)
    [rows] and whether it is a seat force (pad stiffness and damping applied) [rows]."""
    n_dof, n_rail = fe.stiffness.shape[0], fe.n_rail_dof
    ne = int(track.elements_per_bay)
    ke, _, _ = beam_mod.element_matrices(
        float(track.bending_stiffness), float(track.shear_stiffness), float(track.rail_mass),
        float(track.rail_rotary_inertia), fe.element_length)

    def unit(i):
        o = np.zeros(n_dof)
        o[i] = 1.0
        return o

    def element_functional(e, coeffs):
        o = np.zeros(n_dof)
        g = fe_mod.element_dofs(fe, e)
        ok = g >= 0
        o[g[ok]] = coeffs[ok]
        return o

    obs, kinds, damp = [], [], []
    for q in quantities:
        for i, xi in enumerate(x):
            rail_node = 2 * ((sleeper[i] + 1) * ne) - 2
            sl_dof = n_rail + sleeper[i]
            if q.startswith("rail_"):
                o = fe_mod.load_vector(fe, xi).toarray()[:, 0]
            elif q == "shear":
                o = element_functional(elem[i], -ke[0])
            elif q == "moment":
                o = element_functional(elem[i], ke[1] - local[i] * ke[0])
            elif q.startswith("sleeper_"):
                o = unit(sl_dof)
            else:  # seat force: k_P (w_R - w_S) + c_P (w_R' - w_S')
                o = unit(rail_node) - unit(sl_dof)
            obs.append(o)
            kinds.append({"vel": 1, "acc": 2}.get(q.rsplit("_", 1)[-1], 0))
            damp.append(q == "seat_force")
    return np.stack(obs, axis=1), np.array(kinds), np.array(damp)


def _modal_rows(model, fe, o, kinds, damp, kp, cp):
    """The modal observation rows [m, rows] (complex: w (o.u) lambda^k, seat forces with the
    pad's k_P and c_P) and the direct terms of a unit load: [n_nodes, 2, rows] on the rail,
    [n_sleepers, rows] on each sleeper (K symmetric: the reading of a unit load at DOF j is
    row j of K^-1 o), the statics of the truncated modes for displacements, the kept modes'
    feed-through for rates."""
    shapes = np.asarray(model.shapes)  # [m, n, 2]
    lam, wts = np.asarray(model.poles), np.asarray(model.weights)
    n_m, n_nodes, _ = shapes.shape
    u = np.concatenate([shapes[:, 1:-1, :].reshape(n_m, -1),
                        np.asarray(model.sleeper_shapes)], axis=1).T  # [dof, m]
    o = o[:u.shape[0]]  # the rail's interior nodes and the sleepers (sensors keep off the ends)
    c = u.T @ o  # [m, rows] complex: o . u_r
    scale = np.where(damp, kp, 1.0)
    rows = wts[:, None] * c * lam[:, None] ** kinds[None, :]
    rows = rows * scale + np.where(damp, cp, 0.0) * wts[:, None] * c * lam[:, None]
    static = scipy.sparse.linalg.splu(fe.stiffness.tocsc()).solve(
        np.pad(o, ((0, fe.stiffness.shape[0] - o.shape[0]), (0, 0))))[:o.shape[0]]
    static -= np.real(u @ (wts[:, None] * c / (-lam[:, None])))
    feed = np.real(u @ (wts[:, None] * c * lam[:, None] ** np.maximum(kinds - 1, 0)[None, :]))
    direct = np.where(kinds[None, :] == 0, static, feed)
    direct = direct * scale + np.where(damp, cp, 0.0) * np.real(u @ (wts[:, None] * c))
    return rows, _nodal(direct[:fe.n_rail_dof], n_nodes), direct[fe.n_rail_dof:]


def evaluate(spec: SensorSpec, model, q, force, x, support_force=None) -> jax.Array:
    """Sensor readings [n_quantities, n_s] from the track's modal state (pure ``jnp``).

    Args:
        spec: :func:`sensor_spec`. model: the track's :class:`~wfjax.model.track.ModalModel`.
        q: complex [n_modes] modal states at this instant; force: contact force F [N] (or
            [n_wheels] forces); x: rail position of the contact [m] (or [n_wheels]).
        support_force: None or [n_hanging] N, the hanging sleepers' ballast forces (upwards).
    """
    y = spec.c_re @ jnp.real(q) - spec.c_im @ jnp.imag(q)
    if support_force is not None:
        y = y - spec.support_direct @ support_force
    y = y.reshape(len(spec.quantities), spec.positions.shape[0])
    loads = jax.vmap(lambda f, xw: _load_terms(spec, model, f, xw))(jnp.atleast_1d(force),
                                                                    jnp.atleast_1d(x))
    return y + loads.sum(axis=0)


def _load_terms(spec: SensorSpec, model, force, x) -> jax.Array:
    """[n_quantities, n_s] the readings' parts proportional to one wheel's load ``force`` [N]
    at ``x`` [m]: the truncated modes' static part, and the fixed-end solution of a load
    inside a sensor's element (shear and moment)."""
    n_s = spec.positions.shape[0]
    y = (force * track_mod.interpolate_nodal(model, spec.direct, x)).reshape(
        len(spec.quantities), n_s)
    if "shear" not in spec.quantities and "moment" not in spec.quantities:
        return y
    le = model.node_x[1] - model.node_x[0]
    s_f = x - spec.element_x0
    inside = (s_f >= 0) & (s_f < le)
    n1, n2, _, _ = beam_mod.shape_functions(jnp.clip(s_f / le, 0.0, 1.0), model.element_phi,
                                             le)
    beyond = spec.local_s > s_f
    v_p = force * (n1 - beyond)
    m_p = force * (-n2 + n1 * spec.local_s - jnp.maximum(spec.local_s - s_f, 0.0))
    for name, part in (("shear", v_p), ("moment", m_p)):
        if name in spec.quantities:
            i = spec.quantities.index(name)
            y = y.at[i].add(jnp.where(inside, part, 0.0))
    return y


# -- wheel impact load detector ------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class Detector:
    """A strain-gauge wheel impact load detector: shear in the crib over consecutive bays.

    In every instrumented bay k (from the sleeper at k L_S to the one at (k + 1) L_S) two shear
    bridges sit ``gauge_offset`` from the bay's sleepers, at a_k = k L_S + g and
    b_k = (k + 1) L_S - g. No support lies between them, so while the wheel is between the
    bridges the shear difference shear(a_k) - shear(b_k) equals the wheel load in statics
    (the rail's inertia between the bridges is the dynamic error). The bay's estimate is
    ``calibration`` x that difference, read while a_k <= X(t) <= b_k; its peak over the
    passage is the bay's reading (``docs/detector.md``). The reading is within 0.5 % of the
    converged reference (0.45 %) with the settings a run that reads a detector resolves to
    (:data:`wfjax.params.READING_SETTINGS` through :meth:`wfjax.SimConfig.resolved`, on at
    least :data:`wfjax.params.READING_BAYS` bays); with the force's settings about
    1.1 % off.

    Attributes:
        n_bays: number of instrumented consecutive bays N (>= 1).
        first_bay: index k of the first bay (bay 0 is [0, L_S), where the impact is placed).
        gauge_offset: distance g [m] of the bridges from the sleeper centres, in (0, L_S / 2).
        calibration: factor on the shear difference (1: the static theory; see
            :func:`wfjax.detector.calibrate`).
    """

    n_bays: int = 3
    first_bay: int = -1
    gauge_offset: float = 0.1
    calibration: float = 1.0

    def __post_init__(self):
        if not isinstance(self.n_bays, (int, np.integer)) or self.n_bays < 1:
            raise ValueError(f"Detector.n_bays must be an integer >= 1, got {self.n_bays!r}")
        if not isinstance(self.first_bay, (int, np.integer)):
            raise ValueError(f"Detector.first_bay must be an integer, got {self.first_bay!r}")
        for name in ("gauge_offset", "calibration"):
            v = getattr(self, name)
            if not isinstance(v, (int, float, np.floating)) or not math.isfinite(v) or v <= 0:
                raise ValueError(f"Detector.{name} must be a number > 0, got {v!r}")

    def bays(self) -> np.ndarray:
        """[n_bays] bay indices k."""
        return self.first_bay + np.arange(self.n_bays)

    def gauges(self, sleeper_spacing: float) -> tuple[np.ndarray, np.ndarray]:
        """(a [n_bays], b [n_bays]): left and right bridge positions [m]."""
        if not 0 < self.gauge_offset < sleeper_spacing / 2:
            raise ValueError(f"Detector.gauge_offset must be in (0, {sleeper_spacing / 2:g}) m "
                             f"(half the sleeper spacing), got {self.gauge_offset!r} m")
        k = self.bays()
        return k * sleeper_spacing + self.gauge_offset, (k + 1) * sleeper_spacing - (
            self.gauge_offset)


@pytree
class DetectorSpec:
    """The detector's shear sensors (a pytree): ``sensors`` at [a_0.., b_0..], gates a, b [m]
    and the calibration factor."""

    sensors: SensorSpec
    left: jax.Array
    right: jax.Array
    calibration: jax.Array


def detector_spec(detector: Detector, track: Track, model) -> DetectorSpec:
    """Concrete :class:`DetectorSpec` of ``detector`` on ``track`` (bridge positions checked)."""
    a, b = detector.gauges(float(track.sleeper_spacing))
    spec = sensor_spec(np.concatenate([a, b]), track, model, quantities=("shear",))
    return DetectorSpec(spec, jnp.asarray(a), jnp.asarray(b),
                        jnp.asarray(float(detector.calibration)))


def detector_load(spec: DetectorSpec, model, q, force, x, support_force=None):
    """(estimate [n_bays] N, gate bool): calibrated shear difference per bay and whether the
    wheel (contact point ``x`` [m]) is between the bay's bridges: gate [n_bays] for a scalar
    ``x``, [n_wheels, n_bays] for wheels at ``x`` [n_wheels] with loads ``force`` [n_wheels];
    ``support_force`` as in :func:`evaluate`."""
    shear = evaluate(spec.sensors, model, q, force, x, support_force)[0]
    n = spec.left.shape[0]
    return spec.calibration * (shear[:n] - shear[n:]), detector_gate(spec, x)


def detector_gate(spec: DetectorSpec, x):
    """Whether the wheel at ``x`` [m] is between each bay's bridges: [n_bays] for a scalar
    ``x``, [n_wheels, n_bays] for ``x`` [n_wheels]."""
    x = jnp.asarray(x)[..., None]
    return (x >= spec.left) & (x <= spec.right)


def transfer_receptance(track: Track, model, freqs, x_force: float, x_sensor: float,
                        quantity: str = "rail_disp") -> np.ndarray:
    """A sensor's response per unit harmonic force on the rail, from the modal model.

    Args:
        track: the track (concrete numbers).
        model: its :class:`wfjax.model.track.ModalModel`.
        freqs: [n_f] frequencies [Hz].
        x_force: position of the force [m].
        x_sensor: position of the sensor [m] (:func:`check_positions`).
        quantity: one of :data:`QUANTITIES` (``"rail_disp"``: m/N, ``"shear"``: N/N, ...).

    Returns:
        complex [n_f] (convention exp(i omega t)): the kept modes plus the truncated modes'
        static part (the sensor's direct term), as the time loop evaluates the sensor.
    """
    spec = sensor_spec([x_sensor], track, model, quantities=(quantity,))
    s = 2j * np.pi * np.asarray(freqs, dtype=float)[:, None]
    a = ((np.asarray(spec.c_re) + 1j * np.asarray(spec.c_im))[0]
         * np.asarray(track_mod.mode_shapes_at(model, float(x_force))))
    lam, pair = np.asarray(model.poles), np.asarray(model.weights) > 1.5
    h = np.where(pair, 0.5 * (a / (s - lam) + np.conj(a) / (s - np.conj(lam))),
                 a / (s - lam)).sum(axis=1)
    return h + float(np.asarray(track_mod.interpolate_nodal(model, spec.direct,
                                                             float(x_force)))[0])
