"""Several wheels on one rail: :class:`Vehicle` and the structure the coupled time loop needs.

A vehicle is a row of wheels on the same rail, ``positions`` metres behind the leading wheel
(a single wheel, a two-axle bogie, a four-axle wagon, or any layout), each with its own 2-DOF
wheel model (Table 1 by default), static load and flat (or a smooth wheel). All wheels roll
at the same speed, so their rail coordinates keep fixed offsets. The track's modal state is
shared: every wheel loads the modes through the mode shapes at its own position and reads the
rail through them, so the Green's functions between wheels are exact (the coupled loop of
:func:`wfjax.loop.run.time_loop`); within a step the wheels see an n x n compliance matrix.

One wheel is the **reference wheel** (``flat_wheel``): the flat that :func:`wfjax.simulate` and
:func:`wfjax.sweep` are given goes onto it, and ``impact_position`` places its impact within a
sleeper bay. The other wheels carry the vehicle's own ``flats`` (default: smooth) whose centres
meet their contact points ``flat_delays`` metres of rolling after the reference impact.

The vehicle is placed on the finite track so that its middle is over the track's middle: the
reference impact is at ``impact_position + k L_S`` with the integer ``k`` that centres the
wheelbase (:func:`placement`). The track must hold every wheel's path (:func:`check_on_track`),
with the margin to the clamped rail ends that the physics guards derive
(:func:`wfjax.scenario.guards.end_margin`); its length, mode count and cost grow with the
wheelbase (see :func:`required_bays`).

The bogie frame (the wheelsets hanging from a common frame with mass and pitch inertia) is not
modelled: every wheel hangs from a fixed point through its primary suspension, as in the
paper. The frame moves below about 10-20 Hz (its bounce and pitch on the primary
suspensions), far below the impact's 50-2000 Hz, so it changes the quasi-static load sharing
during long-wavelength motion, not the impact forces.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, NamedTuple

import numpy as np
import scipy.sparse.linalg

from .._xla import to_device
from ..params import Flat, Track, Wheel
from . import fe as fe_mod
from . import track as track_mod
from . import wheel as wheel_mod

__all__ = [
    "Vehicle",
    "VEHICLE_PRESETS",
    "WheelSet",
    "wheel_set",
    "placement",
    "check_on_track",
    "required_bays",
    "residual_pairs",
    "transfer_receptance",
]

DEFAULT_AXLE_SPACING = 2.5  # m, the bogie's
DEFAULT_BOGIE_DISTANCE = 17.5  # m between the wagon's bogie centres (a passenger coach's)
VEHICLE_PRESETS = ("single", "bogie", "wagon")


@dataclasses.dataclass(frozen=True)
class Vehicle:
    """Wheels on one rail: where they are, what they weigh and which carry flats.

    Attributes:
        positions: [n] distance of every wheel behind the leading wheel [m], the first 0,
            increasing (the train rolls towards +x, so wheel i is at x_lead - positions[i]).
        wheels: [n] :class:`Wheel` per wheel (2-DOF model, radius, static load P), or None:
            the ``wheel`` given to :func:`wfjax.simulate` for every wheel.
        flats: [n] the flat of every wheel other than the reference (None: smooth), or None:
            all smooth. The entry at ``flat_wheel`` is replaced by the simulated flat.
        flat_wheel: index of the reference wheel (the simulated flat's; ``impact_position``
            is its impact).
        flat_delays: [n] rolling distance [m] from the reference impact to the moment wheel
            i's flat centre meets its contact point, or None (all 0: the flats hit together).
        repeat_flats: every wheel's flat strikes once per revolution, every 2 pi R [m] of
            rolling (R the wheel's radius), as on a real wheel, instead of once per run (the
            paper's single impact, the default). It matters where a run rolls further than a
            circumference past a flat, as over a detector longer than 2 pi R (``wfjax
            detector``); before the run's start the wheel has not struck. (A
            wheel roughness is periodic in 2 pi R already and reads alike either way.)
    """

    positions: tuple = (0.0,)
    wheels: tuple | None = None
    flats: tuple | None = None
    flat_wheel: int = 0
    flat_delays: tuple | None = None
    repeat_flats: bool = False

    def __post_init__(self):
        pos = tuple(float(p) for p in np.atleast_1d(np.asarray(self.positions, dtype=float)))
        object.__setattr__(self, "positions", pos)
        n = len(pos)
        if not all(math.isfinite(p) for p in pos) or pos[0] != 0.0 or any(
                b <= a for a, b in zip(pos, pos[1:], strict=False)):
            raise ValueError(f"Vehicle.positions must start at 0 m and increase (distances "
                             f"behind the leading wheel), got {self.positions!r}")
        for name in ("wheels", "flats", "flat_delays"):
            value = getattr(self, name)
            if value is not None:
                value = tuple(value)
                object.__setattr__(self, name, value)
                if len(value) != n:
                    raise ValueError(f"Vehicle.{name} must have one entry per wheel ({n}), "
                                     f"got {len(value)}")
        if not isinstance(self.repeat_flats, bool):
            raise ValueError(f"Vehicle.repeat_flats must be True or False, got "
                             f"{self.repeat_flats!r}")
        if not isinstance(self.flat_wheel, (int, np.integer)) or not 0 <= self.flat_wheel < n:
            raise ValueError(f"Vehicle.flat_wheel must be a wheel index in [0, {n - 1}], got "
                             f"{self.flat_wheel!r}")
        for w in self.wheels or ():
            if not isinstance(w, Wheel):
                raise ValueError(f"Vehicle.wheels must be wfjax.Wheel objects, got {w!r}")
        for f in self.flats or ():
            if f is not None and not isinstance(f, Flat):
                raise ValueError(f"Vehicle.flats must be wfjax.Flat objects or None, got {f!r}")
        delays = np.asarray(self.flat_delays if self.flat_delays is not None else [0.0] * n,
                            dtype=float)
        if not np.all(np.isfinite(delays)):
            raise ValueError(f"Vehicle.flat_delays must be finite [m], got {self.flat_delays!r}")

    @property
    def n_wheels(self) -> int:
        """Number of wheels."""
        return len(self.positions)

    @classmethod
    def single(cls, wheel: Wheel | None = None) -> Vehicle:
        """The paper's single wheel."""
        return cls((0.0,), None if wheel is None else (wheel,))

    @classmethod
    def bogie(cls, axle_spacing: float = DEFAULT_AXLE_SPACING, flat_wheel: int = 0,
              wheel: Wheel | None = None) -> Vehicle:
        """A two-axle bogie: two wheels ``axle_spacing`` [m] apart on the rail."""
        return cls((0.0, float(axle_spacing)), None if wheel is None else (wheel,) * 2,
                   flat_wheel=flat_wheel)

    @classmethod
    def wagon(cls, axle_spacing: float = DEFAULT_AXLE_SPACING,
              bogie_distance: float = DEFAULT_BOGIE_DISTANCE, flat_wheel: int = 0,
              wheel: Wheel | None = None) -> Vehicle:
        """A four-axle wagon: two bogies (``axle_spacing`` [m]) with centres
        ``bogie_distance`` [m] apart."""
        a, b = float(axle_spacing), float(bogie_distance)
        return cls((0.0, a, b, a + b), None if wheel is None else (wheel,) * 4,
                   flat_wheel=flat_wheel)

    @classmethod
    def preset(cls, name: str, **kwargs) -> Vehicle:
        """:meth:`single`, :meth:`bogie` or :meth:`wagon` by name (``VEHICLE_PRESETS``)."""
        if name not in VEHICLE_PRESETS:
            raise ValueError(f"vehicle must be one of {VEHICLE_PRESETS}, got {name!r}")
        return getattr(cls, name)(**kwargs)

    def wheel_list(self, default: Wheel) -> list[Wheel]:
        """[n] wheel models (``default`` where the vehicle gives none)."""
        return list(self.wheels) if self.wheels is not None else [default] * self.n_wheels

    def flat_list(self, flat: Flat, radius_of) -> list[Flat]:
        """[n] flats: ``flat`` on the reference wheel, a smooth ``Flat.none`` on the wheel
        radius ``radius_of(i)`` [m] wherever the vehicle gives none."""
        own = self.flats or (None,) * self.n_wheels
        return [flat if i == self.flat_wheel else
                (own[i] if own[i] is not None else Flat.none(wheel_radius=radius_of(i)))
                for i in range(self.n_wheels)]

    def offsets(self) -> np.ndarray:
        """[n] rail coordinate of every wheel relative to the reference wheel [m]."""
        pos = np.asarray(self.positions)
        return pos[self.flat_wheel] - pos

    def delays(self) -> np.ndarray:
        """[n] the flats' delays [m] (zeros by default)."""
        if self.flat_delays is None:
            return np.zeros(self.n_wheels)
        return np.asarray(self.flat_delays, dtype=float)

    def check_spacing(self, wheels: list[Wheel]) -> None:
        """ValueError if two neighbouring wheels are closer than a wheel diameter."""
        for i in range(self.n_wheels - 1):
            gap = self.positions[i + 1] - self.positions[i]
            need = float(wheels[i].radius) + float(wheels[i + 1].radius)
            if gap < need:
                raise ValueError(
                    f"Vehicle wheels {i} and {i + 1} are {gap:g} m apart: wheels must be at "
                    f"least a wheel diameter apart (>= {need:g} m)")


def placement(vehicle: Vehicle, sleeper_spacing: float) -> float:
    """Rail coordinate [m] of the reference wheel's impact bay: ``k L_S`` with the integer k
    that puts the middle of the wheelbase over the track's middle (x = 0)."""
    offsets = vehicle.offsets()
    middle = 0.5 * (offsets.min() + offsets.max())
    return -round(middle / sleeper_spacing) * sleeper_spacing


def check_on_track(vehicle: Vehicle, track: Track, x_ref_start: float,
                   x_ref_end: float) -> None:
    """ValueError if a wheel's path (the reference wheel from ``x_ref_start`` to ``x_ref_end``
    [m]) leaves the rail. How far from the clamped ends a path must stay for the ends not to
    matter is a physics guard (:func:`wfjax.scenario.guards.end_margin`)."""
    half = 0.5 * int(track.n_bays) * float(track.sleeper_spacing)
    offsets = vehicle.offsets()
    lo, hi = x_ref_start + offsets.min(), x_ref_end + offsets.max()
    if lo < -half or hi > half:
        raise ValueError(
            f"the wheels travel over [{lo:.2f}, {hi:.2f}] m, beyond the rail of track.n_bays = "
            f"{int(track.n_bays)} ([{-half:.2f}, {half:.2f}] m): use track.n_bays >= "
            f"{2 * math.ceil(max(-lo, hi) / float(track.sleeper_spacing) - 1e-9)}")


def required_bays(vehicle: Vehicle, travel: float, track: Track, margin: float) -> int:
    """Smallest even ``n_bays`` whose rail holds the wheelbase plus ``travel`` [m] with
    ``margin`` [m] at each end.

    The track's length grows linearly with the wheelbase, and with it the number of modes
    below ``SimConfig.track_max_frequency`` (about 13 per bay at 12 kHz and 26 elements per
    bay with the dampers' pseudo-modes: 318 for 24 bays) and the per-step cost of the modal
    update (linear in the mode count).
    """
    offsets = vehicle.offsets()
    span = offsets.max() - offsets.min() + travel + 2 * margin
    # the placement rounds the middle to a sleeper: up to half a bay off centre
    n = math.ceil(span / float(track.sleeper_spacing)) + 1
    return max(int(track.n_bays), n + n % 2)


class WheelSet(NamedTuple):
    """The wheels' modal data, stacked along a leading wheel axis (a pytree).

    Fields:
        poles: complex [n, n_w] [rad/s]; residues: complex [n, n_w] [m/(N s)] of the contact
            point (small mass m_W); axle_residues: complex [n, n_w] [m/(N s)] of the wheelset
            mass M_W (the axle box) for a force at the contact; preload: [n] static loads [N].
            Wheels with fewer poles are padded with a pole at -1 rad/s and zero residues.
    """

    poles: Any
    residues: Any
    axle_residues: Any
    preload: Any


def wheel_set(wheels: list[Wheel]) -> WheelSet:
    """:class:`WheelSet` of ``wheels`` ([n] :class:`Wheel`)."""
    models = [wheel_mod.modal_model(w) for w in wheels]
    n_w = max(int(m.poles.shape[0]) for m in models)

    def pad(a, fill):
        a = np.asarray(a, dtype=complex)
        return np.concatenate([a, np.full(n_w - a.size, fill, dtype=complex)])

    return WheelSet(
        to_device(np.stack([pad(m.poles, -1.0) for m in models])),
        to_device(np.stack([pad(m.residues, 0.0) for m in models])),
        to_device(np.stack([pad(m.axle_residues, 0.0) for m in models])),
        to_device(np.asarray([float(w.preload) for w in wheels])))


def residual_pairs(track: Track, model: track_mod.ModalModel, offsets,
                   x_bay: float = 0.0) -> np.ndarray:
    """Static compliance [m/N] of the truncated modes between every pair of wheels.

    R_ij(x) = K^-1(x + o_i, x + o_j) - sum_kept Re(w phi_r(x + o_i) phi_r(x + o_j) / -lambda_r)
    for the reference wheel at x on the model's residual grid, the wheels at offsets o [n]
    [m]: across one bay from ``x_bay`` (x = x_bay + model.residual_x, read periodically) on a
    uniform track; along the whole rail (x = model.residual_x, absolute; ``x_bay`` unused) on
    a track whose supports vary, with wheel positions beyond the rail ends clamped to them
    (never read: the wheels stay on the rail). The diagonal is each wheel's own
    residual compliance, left at zero here: the loop reads it from the model's own table at
    each wheel's position (:func:`wfjax.loop.structure.residual_matrix`), whose points sit
    on the element nodes, as the load's in-element deflection needs; the off-diagonal the
    truncated modes' static coupling (exact static deflections under several wheels).

    Returns:
        float [n_res, n, n] (symmetric in the last two axes), read by
        :func:`wfjax.model.track.read_residual_table`.
    """
    fe = fe_mod.assemble(track)
    grid = np.asarray(model.residual_x)
    periodic = bool(track_mod.residual_table_is_periodic(model))
    x = (x_bay if periodic else 0.0) + grid[:, None] + np.asarray(offsets)[None, :]
    x = np.clip(x, fe.node_x[0], fe.node_x[-1])
    full = _static_pair_compliance(fe, x)
    phi = np.asarray(track_mod.mode_shapes_at(model, x))  # [n_res, n, m]
    w = np.asarray(model.weights) / (-np.asarray(model.poles))
    kept = np.real(np.einsum("rim,rjm,m->rij", phi, phi, w))
    # each wheel's own residual is read from the model's table, whose points sit on the
    # element nodes (offsets generally do not): zero here, added by the loop
    return (full - kept) * (1.0 - np.eye(x.shape[1]))


def _static_pair_compliance(fe, x: np.ndarray) -> np.ndarray:
    """K^-1(x_ri, x_rj) [m/N], [n_res, n, n], for rail positions ``x`` [n_res, n] [m]
    (:func:`wfjax.model.fe.static_solve` with the unit loads at every position)."""
    n_res, n = x.shape
    b = fe_mod.load_vector(fe, x.ravel())  # [n_dof, n_res * n], sparse
    u = fe_mod.static_solve(fe, b)
    return np.einsum("dri,drj->rij", b.toarray().reshape(-1, n_res, n),
                     u.reshape(-1, n_res, n))


def transfer_receptance(track: Track, model: track_mod.ModalModel, freqs, x_force: float,
                        x_response: float) -> np.ndarray:
    """Rail transfer receptance [m/N] from the modal model, complex [n_f] (freqs [Hz]):
    displacement at ``x_response`` [m] per unit harmonic force at ``x_force`` [m]
    (exp(i omega t)), with the truncated modes' static coupling between the two points.

    The modal part is symmetric in the two points by construction; the direct
    frequency-domain solve (:func:`wfjax.model.track.receptance` with ``x_response``) is the
    independent reference of both the values and the reciprocity.
    """
    h = track_mod.modal_sum(model, freqs, float(x_force), float(x_response))
    pa = np.asarray(track_mod.mode_shapes_at(model, float(x_force)))
    pb = np.asarray(track_mod.mode_shapes_at(model, float(x_response)))
    lam = np.asarray(model.poles)
    fe = fe_mod.assemble(track)
    b = fe_mod.load_vector(fe, [float(x_force), float(x_response)]).toarray()
    full = b[:, 1] @ scipy.sparse.linalg.splu(fe.stiffness).solve(b[:, 0])
    kept = np.real(np.sum(np.asarray(model.weights) * pa * pb / (-lam)))
    return h + (full - kept)
