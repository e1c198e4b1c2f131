"""Model parameters as JAX pytrees, with the defaults of Pieringer, Kropp & Nielsen (2014).

Every number is a pytree *leaf*, so ``jax.grad`` and ``jax.vmap`` reach it (flat depth and
length, every stiffness, ...). Choices that change the compiled program (flat kind, numerical
resolution) are *static* metadata.

Units are SI throughout: m, s, kg, N, Pa. Attribute names carry the unit where it is not
obvious from the physics (``depth`` is in m, ``speed`` in m/s).

Validation: constructing a parameter object from concrete numbers checks them and raises
``ValueError`` naming the parameter, the value and the allowed range. Objects rebuilt by JAX
transformations (with tracers as leaves) are not checked again.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from .fields import (
    Validated,
    check_finite,
    check_positive,
    is_concrete,
    option,
    positive_fields,
    pytree,
)
from .track_checks import MAX_BALLAST_GAP, check_ends, check_per_sleeper

__all__ = ["Material", "Wheel", "Track", "Flat", "SimConfig", "kmh", "mm", "FLAT_KINDS",
           "SUPPORT_FIELDS", "loop_precision", "FORCE_SETTINGS", "READING_SETTINGS"]

MAX_FLAT_DEPTH = 5e-3  # m; deeper "flats" are outside the model's validity (half-space, Eq. 1)
MAX_FLAT_LENGTH = 0.3  # m; about a tenth of a 0.45 m wheel's circumference
FLAT_KINDS = ("new", "rounded", "profile", "sections", "none")
CONTACT_MODES_3D = ("auto", "table", "parametric", "direct")
PRECISIONS = ("auto", "float64", "float32")
DEFAULT_EXTENT_BOUND = 0.1  # m; half extent assumed for flats whose length is traced
MAX_SPEED = 150.0  # m/s (540 km/h): the speed range of every entry point, (0, MAX_SPEED]
# SimConfig's auto settings: the least cost that keeps the force, the seat force and a Detector's
# reading (on at least READING_BAYS bays) within 0.5 % of the reference (docs/convergence.md;
# 15 and 20 kHz before the damper augmentation of 2026-12-05)
FORCE_SETTINGS = {"track_max_frequency": 12e3, "max_time_step": 40e-6}
READING_SETTINGS = {"track_max_frequency": 15e3, "max_time_step": 25e-6, "precision": "float64"}
READING_BAYS = 36
NETWORK_READING_BAYS = 24  # the same with end networks (scenario.guards, docs/convergence.md)
# the least bays of a track with absorbing or clamped ends (max force within 0.02 %, min force
# 0.32 %P of the reference; 20 bays 0.43 %P, 16 bays 0.55 %P: docs/convergence.md); end
# networks need none beyond the guards' margins (Track.n_bays, the least, is 4)
ABSORBING_BAYS = 24
TRACK_ENDS = ("auto", "network", "absorbing")


def loop_precision(precision: str, gradients: bool = False, direct: bool = False) -> str:
    """``"float64"`` or ``"float32"``: the time loop's dtype for a :attr:`SimConfig.precision`.

    ``"auto"`` resolves to float64 where gradients are taken (``gradients``: a fit's program,
    the adjoint; float32 gradients are only within 1e-3 of float64's) or a contact law solves
    its own steps (``direct``: the direct 3D mode), else to float32; the others are returned
    as they are.
    """
    if precision != "auto":
        return precision
    return "float64" if gradients or direct else "float32"


def kmh(speed_kmh: float) -> float:
    """Convert a speed in km/h to m/s."""
    return speed_kmh / 3.6


def mm(length_mm: float) -> float:
    """Convert a length in mm to m."""
    return length_mm * 1e-3


@pytree
class Material(Validated):
    """Linear elastic material of wheel and rail (the same for both, as in the paper).

    Attributes:
        youngs_modulus: E in Pa (default 210 GPa).
        poisson_ratio: nu, dimensionless, in (0, 0.5) (default 0.3).
    """

    youngs_modulus: Any = option(210e9, unit="Pa", low=1e9, high=1e12, positive=True,
                                 doc="Young's modulus E of wheel and rail")
    poisson_ratio: Any = option(0.3, low=0.0, high=0.5, high_open=True,
                                doc="Poisson's ratio nu")

    def __post_init__(self):
        super().__post_init__()
        nu = self.poisson_ratio
        if is_concrete(nu):
            check_finite("Material", "poisson_ratio", nu)
            if not 0.0 <= float(np.max(nu)) < 0.5 or float(np.min(nu)) < 0.0:
                raise ValueError(
                    f"Material.poisson_ratio must be in [0, 0.5), got {nu!r}"
                )

    @property
    def plane_strain_modulus(self):
        """E / (1 - nu^2) in Pa."""
        return self.youngs_modulus / (1.0 - self.poisson_ratio**2)


@pytree
class Wheel(Validated):
    """Two-degree-of-freedom wheel model of Table 1 (Fig. 3 of the paper).

    The contact force acts on the small mass ``small_mass`` (m_W), joined to half the wheelset
    mass ``wheelset_mass`` (M_W) by ``contact_stiffness`` (k_W) in parallel with
    ``contact_damping`` (c_W). M_W hangs from the vehicle, which is fixed and carries the static
    preload ``preload`` (P), through the primary suspension ``suspension_stiffness`` (k_S) and
    ``suspension_damping`` (c_S).

    Attributes (SI units): wheelset_mass [kg], suspension_stiffness [N/m],
    suspension_damping [N s/m], small_mass [kg], contact_stiffness [N/m],
    contact_damping [N s/m], radius [m], preload [N].
    """

    wheelset_mass: Any = option(593.0, unit="kg", low=50.0, high=5e3, positive=True,
                                doc="half the wheelset mass M_W")
    suspension_stiffness: Any = option(1.12e6, unit="N/m", low=1e4, high=1e9, positive=True,
                                       doc="primary suspension stiffness k_S")
    suspension_damping: Any = option(13.2e3, unit="N s/m", low=1e1, high=1e7, positive=True,
                                     doc="primary suspension damping c_S")
    small_mass: Any = option(3.0, unit="kg", low=1e-2, high=100.0, positive=True,
                             doc="small mass m_W at the contact")
    contact_stiffness: Any = option(2.4e9, unit="N/m", low=1e6, high=1e12, positive=True,
                                    doc="stiffness k_W between m_W and M_W")
    contact_damping: Any = option(155e3, unit="N s/m", low=1e1, high=1e8, positive=True,
                                  doc="damping c_W between m_W and M_W")
    radius: Any = option(0.45, unit="m", low=0.15, high=1.0, positive=True,
                         doc="wheel radius R_W (also the flat's wheel)", flag="--wheel-radius-m",
                         flag_commands=("sweep", "simulate", "fit", "geometry", "detector"))
    preload: Any = option(118e3, unit="N", low=1e3, high=1e6, positive=True,
                          doc="static wheel load P (axle load x g / 2)")


SUPPORT_FIELDS = ("pad_stiffness", "pad_damping", "sleeper_mass", "ballast_stiffness",
                  "ballast_damping", "ballast_gap")
"""Track fields that may vary from sleeper to sleeper (scalar or ``[n_bays - 1]`` array)."""
@pytree(static=("n_bays", "elements_per_bay", "absorbing_sleepers", "ends"))
class Track(Validated):
    """Discretely supported track of Table 2 (Nielsen & Igeland 1995).

    A 60E1 rail as Rayleigh-Timoshenko beam elements on rail pads, half-sleeper masses and
    ballast, ``n_bays`` sleeper bays long with clamped rail ends.

    Attributes (SI units):
        bending_stiffness: EI [N m^2]; shear_stiffness: kGA [N]; rail_mass: m' [kg/m];
        rail_rotary_inertia: rho I [kg m] (7850 kg/m^3 x 3.05e-5 m^4);
        rail_head_radius: transverse radius of the rail head R_R [m] (0.30 m; the paper's model
        comparison uses 0.45 m, see :meth:`comparison`);
        sleeper_spacing: L_S [m]; pad_stiffness: k_P [N/m]; pad_damping: c_P [N s/m];
        sleeper_mass: half sleeper m_SL [kg]; ballast_stiffness: k_B [N/m];
        ballast_damping: c_B [N s/m];
        ballast_gap: g [m] between a sleeper and its ballast at rest (default 0: every
        sleeper bonded to a linear ballast). A sleeper with g > 0 hangs: its ballast is a
        one-sided support that carries load only once the sleeper has moved down by g
        (:func:`wfjax.model.supports.hanging_sleeper`), solved in every time step with the contacts.
        n_bays (static): the least number of sleeper bays of the finite model. A scenario
            lengthens a track whose supports are scalars to what its wheels' paths, sensors
            and detector need, with the physics guards' margins from the ends
            (:meth:`wfjax.Scenario.lengthened`), a detector's to at least
            :data:`NETWORK_READING_BAYS` (:data:`READING_BAYS` with absorbing ends) and absorbing
            ends to at least :data:`ABSORBING_BAYS`; per-sleeper supports fix the length.
        elements_per_bay (static): rail beam elements per sleeper bay.
        absorbing_sleepers (static): with absorbing ends, the last n sleepers at each end,
            whose pad and ballast damping grow geometrically to 8 times the track's at the
            outermost (:func:`wfjax.model.fe.end_grading`): they absorb the waves the clamped
            ends would reflect back to the wheels (3 by default; the wheels and sensors keep
            their margins from the absorbing zone, :func:`wfjax.scenario.guards.end_margin`);
            0: the plain clamped ends of the paper's finite track.
        ends (static): how the finite track ends. ``"network"``: the rail continues at both
            ends by a fitted passive network, the semi-infinite track's boundary stiffness
            (:mod:`wfjax.model.ends`): the ends reflect nothing, so a few bays hold the
            forces and the receptances come within 0.6 % of the infinite track's beside the
            pinned-pinned band edge; it needs the same supports at every sleeper, and a track
            other than the default is fitted on first use (5-30 s on 2 cores) and cached.
            ``"absorbing"``: clamped ends with ``absorbing_sleepers`` graded sleepers.
            ``"auto"`` (default): a network where the supports are the same at every sleeper
            and bonded (no ``ballast_gap``) and its fit comes within tolerance, else absorbing
            ends (:func:`wfjax.model.ends.resolved`).

    Supports that vary from sleeper to sleeper: each of the five support fields
    (:data:`SUPPORT_FIELDS`) is a scalar (every sleeper alike, Table 2) or a float array
    ``[n_bays - 1]``, one value per interior sleeper, left to right (sleeper ``i`` at
    ``x = (i + 1 - n_bays // 2) L_S``). In an array, the pad damping and the ballast stiffness
    and damping may be 0 (a hanging sleeper, :func:`wfjax.model.supports.void_sleeper`); pad
    stiffness and sleeper mass stay > 0 (a sleeper must hang from the rail and have mass);
    ``ballast_gap`` is in [0, 0.05] m. Presets and random scatter: :mod:`wfjax.model.supports`.
    """

    bending_stiffness: Any = option(6.4e6, unit="N m^2", low=1e5, high=1e8, positive=True,
                                    doc="rail bending stiffness EI")
    shear_stiffness: Any = option(250e6, unit="N", low=1e6, high=1e10, positive=True,
                                  doc="rail shear stiffness kGA")
    rail_mass: Any = option(60.0, unit="kg/m", low=10.0, high=200.0, positive=True,
                            doc="rail mass per length m'")
    rail_rotary_inertia: Any = option(7850.0 * 3.05e-5, unit="kg m", low=1e-3, high=10.0,
                                      positive=True, doc="rail rotary inertia rho I")
    rail_head_radius: Any = option(0.30, unit="m", low=0.05, high=10.0, positive=True,
                                   doc="transverse rail head radius R_R",
                                   flag="--rail-head-radius-m",
                                   flag_commands=("sweep", "simulate", "fit", "detector"))
    sleeper_spacing: Any = option(0.65, unit="m", low=0.3, high=1.5, positive=True,
                                  doc="sleeper spacing L_S")
    pad_stiffness: Any = option(120e6, unit="N/m", low=1e6, high=1e10, positive=True,
                                doc="rail pad stiffness k_P")
    pad_damping: Any = option(16e3, unit="N s/m", low=1e1, high=1e7, positive=True,
                              doc="rail pad damping c_P")
    sleeper_mass: Any = option(125.0, unit="kg", low=10.0, high=1e3, positive=True,
                               doc="half sleeper mass m_SL")
    ballast_stiffness: Any = option(140e6, unit="N/m", low=1e6, high=1e10, positive=True,
                                    doc="ballast stiffness k_B")
    ballast_damping: Any = option(165e3, unit="N s/m", low=1e1, high=1e8, positive=True,
                                  doc="ballast damping c_B")
    ballast_gap: Any = option(0.0, unit="m", low=0.0, high=MAX_BALLAST_GAP,
                              doc="gap between sleeper and ballast at rest (0: bonded; one per "
                                  "sleeper: supports.void_gap)")
    n_bays: int = option(4, low=4, high=1000,
                         doc="least number of sleeper bays of the finite track model "
                             "(lengthened to what the case's wheels and sensors need; "
                             f"a detector's to {NETWORK_READING_BAYS}, {READING_BAYS} with "
                             f"absorbing ends, which need at least {ABSORBING_BAYS})")
    elements_per_bay: int = option(26, low=1, high=64, doc="rail beam elements per sleeper bay",
                                   flag="--elements-per-bay", flag_commands=("receptance",))
    absorbing_sleepers: int = option(3, low=0, high=40,
                                     doc="with absorbing ends, sleepers at each end with "
                                         "damping graded up to 8x (0: plain clamped)")
    ends: str = option("auto", choices=TRACK_ENDS,
                       doc="track ends: network (fitted, non-reflecting), absorbing (graded "
                           "damping), auto (network where supports are uniform and bonded)")

    def __post_init__(self):
        lows = {f.name: f.metadata["low"] for f in dataclasses.fields(self)}
        for name in ("n_bays", "elements_per_bay", "absorbing_sleepers"):
            value, low = getattr(self, name), lows[name]
            if not isinstance(value, (int, np.integer)) or value < low:
                raise ValueError(
                    f"Track.{name} must be an integer >= {low}, got {value!r}"
                )
        check_ends(self, SUPPORT_FIELDS, TRACK_ENDS)
        for name, unit in positive_fields(self).items():
            value = getattr(self, name)
            if not is_concrete(value):
                continue
            if name in SUPPORT_FIELDS and np.ndim(value) > 0:
                check_per_sleeper(name, value, unit, int(self.n_bays) - 1)
            else:
                check_positive("Track", name, value, unit)
        if is_concrete(self.ballast_gap):
            check_per_sleeper("ballast_gap", np.broadcast_to(
                np.asarray(self.ballast_gap, dtype=float), (int(self.n_bays) - 1,)), "m",
                int(self.n_bays) - 1)

    @classmethod
    def comparison(cls, **overrides) -> Track:
        """The track of the paper's contact-model comparison (Section 4.3): R_R = 0.45 m."""
        return cls(**{"rail_head_radius": 0.45, **overrides})


@pytree(static=("kind", "extent_bound"))
class Flat:
    """A wheel flat: its kind (static) and geometry (leaves).

    Build with :meth:`new`, :meth:`rounded`, :meth:`from_profile`, :meth:`from_sections` or
    :meth:`none`.

    Attributes:
        kind: ``"new"`` (sharp chord, Eq. 2), ``"rounded"`` (cosine, Eq. 3), ``"profile"``
            (measured deviation, linear interpolation), ``"sections"`` (a measured 3D surface:
            records at several lateral positions, :mod:`wfjax.model.surface`) or ``"none"``
            (smooth wheel).
        depth: d [m]. For ``"profile"`` the maximum of the profile; for ``"sections"`` the
            maximum of its centre line y = 0.
        length: flat length along the circumference [m]; l for rounded flats, the chord
            length l0 = sqrt(8 R d) for new flats (informative; geometry derives it from depth),
            the support of the measured profile for ``"profile"`` and ``"sections"``.
        wheel_radius: R_W [m] of the wheel carrying the flat.
        profile_x: [n] circumferential coordinates of a measured profile [m] (``"profile"``),
            or the records' nodes (``"sections"``); None otherwise. Centred on the flat.
        profile_z: [n] profile deviation (material removed, >= 0) at ``profile_x`` [m].
        extent_bound (static): an upper bound [m] of the flat's half extent, used to size
            numerical windows when depth and length are traced by ``jax.grad``/``vmap``;
            ``None`` uses the concrete values, or :data:`DEFAULT_EXTENT_BOUND` under tracing.
        section_y: [k] lateral positions of the records [m] (``"sections"`` only), increasing.
        section_z: [k, n] signed radial deviation of the records at ``profile_x`` [m]
            (``"sections"`` only; the surface is max(0, interpolant)).
    """

    kind: str = option(choices=FLAT_KINDS, doc="flat kind")
    depth: Any = option(unit="m", low=0.0, high=MAX_FLAT_DEPTH, low_open=True,
                        doc="flat depth d; sweep: a list of depths too", flag="--depth-mm",
                        aliases=("--depths-mm",), factor=1e-3, flag_unit="mm")
    length: Any = option(unit="m", low=0.0, high=MAX_FLAT_LENGTH, low_open=True,
                         doc="rounded flat length l (>= pi/2 l0); sweep: one per depth or one "
                             "for all", flag="--length-mm", aliases=("--lengths-mm",),
                         factor=1e-3, flag_unit="mm")
    wheel_radius: Any = option(0.45, unit="m", doc="radius R_W of the wheel with the flat")
    profile_x: Any = option(None, unit="m", doc="circumferential coordinates of a profile")
    profile_z: Any = option(None, unit="m", doc="profile deviation at profile_x")
    extent_bound: float | None = option(None, unit="m", doc="bound of the half extent")
    section_y: Any = option(None, unit="m", doc="lateral positions of measured sections")
    section_z: Any = option(None, unit="m", doc="deviation of the sections at profile_x")

    def __post_init__(self):
        if self.kind not in FLAT_KINDS:
            raise ValueError(f"Flat.kind must be one of {FLAT_KINDS}, got {self.kind!r}")

    # -- constructors -------------------------------------------------------------------
    @classmethod
    def new(cls, depth: float, wheel_radius: float = 0.45) -> Flat:
        """A newly formed flat: a chord of the wheel circle, depth ``depth`` [m]."""
        _validate_depth(depth)
        check_positive("Flat", "wheel_radius", wheel_radius, "m")
        return cls("new", depth=depth, length=new_flat_length(depth, wheel_radius),
                   wheel_radius=wheel_radius)

    @classmethod
    def rounded(cls, depth: float, length: float, wheel_radius: float = 0.45) -> Flat:
        """A rounded (cosine) flat of depth ``depth`` [m] and length ``length`` [m].

        Requires ``length >= pi/2 * l0`` with l0 = sqrt(8 R d) (the paper's condition that the
        rounded flat is everywhere at least as deep as the new flat of the same depth).
        """
        _validate_depth(depth)
        check_positive("Flat", "wheel_radius", wheel_radius, "m")
        check_positive("Flat", "length", length, "m")
        if float(np.max(np.asarray(length))) > MAX_FLAT_LENGTH:
            raise ValueError(
                f"Flat.length must be in (0, {MAX_FLAT_LENGTH * 1e3:g}] mm (a flat longer than "
                f"about a tenth of the circumference is not a wheel flat), got "
                f"{float(np.max(length)) * 1e3:g} mm"
            )
        l0 = new_flat_length(depth, wheel_radius)
        l_min = math.pi / 2 * l0
        if float(np.min(np.asarray(length) - l_min)) < -1e-12:
            raise ValueError(
                f"Flat.length of a rounded flat must be >= pi/2 * l0 = {l_min * 1e3:.2f} mm "
                f"for depth {float(np.max(depth)) * 1e3:.3f} mm, "
                f"got {float(np.min(length)) * 1e3:.2f} mm"
            )
        return cls("rounded", depth=depth, length=length, wheel_radius=wheel_radius)

    @classmethod
    def rounded_relative(cls, depth: float, length_factor: float = 1.76,
                         wheel_radius: float = 0.45) -> Flat:
        """A rounded flat of length ``length_factor * l0`` (Fig. 8 uses 1.76)."""
        return cls.rounded(depth, length_factor * new_flat_length(depth, wheel_radius),
                           wheel_radius)

    @classmethod
    def from_profile(cls, x, z, wheel_radius: float = 0.45) -> Flat:
        """A measured flat: profile deviation ``z`` [m] (>= 0) at circumferential ``x`` [m].

        ``x`` must be strictly increasing and finite, with support shorter than the wheel's
        circumference; the flat centre is taken at x = 0 (centre the data before calling).
        """
        x = np.asarray(x, dtype=float)
        z = np.asarray(z, dtype=float)
        if x.ndim != 1 or z.shape != x.shape or x.size < 3:
            raise ValueError(
                f"Flat.from_profile needs 1-D x and z of equal length >= 3, got shapes "
                f"{x.shape} and {z.shape}"
            )
        check_finite("Flat", "profile_x", x)
        check_finite("Flat", "profile_z", z)
        if np.any(np.diff(x) <= 0):
            raise ValueError("Flat.profile_x must be strictly increasing")
        if np.any(z < 0):
            raise ValueError(
                f"Flat.profile_z must be >= 0 (material removed), got min {z.min():.3g} m"
            )
        support = x[-1] - x[0]
        if support >= 2 * math.pi * wheel_radius:
            raise ValueError(
                f"Flat.profile_x support {support:.3f} m must be shorter than the wheel "
                f"circumference {2 * math.pi * wheel_radius:.3f} m"
            )
        depth = float(z.max())
        if depth > MAX_FLAT_DEPTH:
            raise ValueError(
                f"Flat.profile_z maximum {depth * 1e3:.3f} mm exceeds {MAX_FLAT_DEPTH * 1e3} mm"
            )
        return cls("profile", depth=depth, length=support, wheel_radius=wheel_radius,
                   profile_x=x, profile_z=z)

    @classmethod
    def from_sections(cls, x, y, z, wheel_radius: float = 0.45) -> Flat:
        """A measured 3D flat: records ``z`` [k, n] of radial deviation [m] at lateral ``y`` [k]
        [m], each at circumferential ``x`` [n] [m] (:mod:`wfjax.model.surface` interpolates).

        ``x`` strictly increasing, centred on the flat (x = 0 its centre), support shorter than
        the circumference; ``y`` strictly increasing, at least two lines, with y = 0 (the
        nominal contact line) inside [y_0, y_{k-1}]; ``z`` signed (positive: material
        missing), |z| <= 5 mm. The surface is max(0, interpolant): the deviation below zero
        is the wheel's roughness, not the flat's (:mod:`wfjax.sections` splits a record).
        """
        from .model.surface import centre_line

        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        z = np.asarray(z, dtype=float)
        _check_sections(x, y, z, wheel_radius)
        depth = float(np.max(centre_line(x, y, z, x)))
        if depth <= 0:
            raise ValueError("Flat.from_sections: the surface is nowhere below the nominal "
                             "circle on the centre line y = 0 (no flat)")
        return cls("sections", depth=depth, length=x[-1] - x[0], wheel_radius=wheel_radius,
                   profile_x=x, section_y=y, section_z=z)

    @classmethod
    def none(cls, wheel_radius: float = 0.45) -> Flat:
        """A smooth, undamaged wheel."""
        return cls("none", depth=0.0, length=0.0, wheel_radius=wheel_radius)

    @property
    def half_extent(self) -> float:
        """Half the circumferential extent [m] outside which the deviation is zero.

        A concrete float even when depth and length are traced: then ``extent_bound`` (or
        :data:`DEFAULT_EXTENT_BOUND`) is returned. Used only to size numerical windows.
        """
        if self.extent_bound is not None:
            return float(self.extent_bound)
        if self.kind in ("profile", "sections"):
            x = np.asarray(self.profile_x)
            return float(max(abs(x[0]), abs(x[-1])))
        if not is_concrete(self.length):
            return DEFAULT_EXTENT_BOUND
        return float(np.max(np.asarray(self.length))) / 2


def new_flat_length(depth, wheel_radius=0.45):
    """l0 = sqrt(8 R d) [m] (Eq. 1), the small-depth chord length of a new flat of depth d [m]."""
    return (8.0 * wheel_radius * depth) ** 0.5


def _check_sections(x, y, z, wheel_radius) -> None:
    """One-line ``ValueError`` for records that :meth:`Flat.from_sections` cannot take."""
    if x.ndim != 1 or x.size < 3 or y.ndim != 1 or y.size < 2 or z.shape != (y.size, x.size):
        raise ValueError(f"Flat.from_sections needs x [n >= 3], y [k >= 2] and z [k, n], got "
                         f"shapes {x.shape}, {y.shape} and {z.shape}")
    for name, v in (("x", x), ("y", y), ("z", z)):
        check_finite("Flat", f"section {name}", v)
    if np.any(np.diff(x) <= 0):
        raise ValueError("Flat.from_sections: x must be strictly increasing")
    if np.any(np.diff(y) <= 0):
        raise ValueError(f"Flat.from_sections: lateral positions must be strictly increasing, "
                         f"got {np.round(y * 1e3, 3).tolist()} mm")
    if not y[0] <= 0.0 <= y[-1]:
        raise ValueError(f"Flat.from_sections: the measured band [{y[0] * 1e3:g}, "
                         f"{y[-1] * 1e3:g}] mm must contain the contact line y = 0")
    if np.max(np.abs(z)) > MAX_FLAT_DEPTH:
        raise ValueError(f"Flat.from_sections: |deviation| {np.max(np.abs(z)) * 1e3:.3f} mm "
                         f"exceeds {MAX_FLAT_DEPTH * 1e3:g} mm")
    if x[-1] - x[0] >= 2 * math.pi * wheel_radius:
        raise ValueError(f"Flat.from_sections: support {x[-1] - x[0]:.3f} m must be shorter "
                         f"than the circumference {2 * math.pi * wheel_radius:.3f} m")


def _validate_depth(depth) -> None:
    if not is_concrete(depth):
        return
    check_finite("Flat", "depth", depth)
    d = np.asarray(depth, dtype=float)
    if np.any(d <= 0) or np.any(d > MAX_FLAT_DEPTH):
        raise ValueError(
            f"Flat.depth must be in (0, {MAX_FLAT_DEPTH * 1e3:g} mm], got {depth!r} m"
        )


@dataclasses.dataclass(frozen=True)
class SimConfig:
    """Numerical settings of a simulation (all static: they shape the compiled program).
    Settings left ``None`` (auto) are resolved by what a run reads (:meth:`resolved`):
    :data:`FORCE_SETTINGS`, or :data:`READING_SETTINGS` where a :class:`~wfjax.Detector` is
    read; every setting is checked against the case by the physics guards
    (:mod:`wfjax.scenario.guards`; docs/convergence.md holds the accuracy table, issue 33).

    Attributes:
        time_step: time step [s]; ``None`` picks ``min(max_time_step, max_travel_step / v)``.
        max_time_step: upper bound of the automatic time step [s]; auto: 40 us (max forces
            within 0.5 % of the converged reference), 25 us where a detector is read.
        max_travel_step: upper bound of the travel per step [m] (1 mm: Hertz-trajectory max
            forces move <= 0.3 % from 1 to 0.25 mm at 60 and 250 km/h).
        run_in, run_out: travel [m] from static equilibrium until the flat reaches the
            contact (the sleeper-passing transient settles), and after its centre passed.
        contact_element: side of the square 3D contact elements and 2D bedding elements [m].
        contact_mode_3d: the 3D contact as ``"table"`` (each flat's exact F(delta, s)),
            ``"parametric"`` (the family F(delta, s; depth, length) of
            :mod:`wfjax.contact.family`: traced, batched, differentiable), ``"direct"`` (a
            Kalker solve every step, the reference) or ``"auto"`` (the table for one flat of
            a kind, the family for a batch of geometries of one kind and for fits).
        track_max_frequency: track modes above it [Hz] enter by their static contribution;
            auto: 12 kHz (318 modes with the dampers' pseudo-modes on the default track, max
            force within 0.28 % of the reference), 15 kHz where a detector is read.
        newton_iterations: fixed iteration count of the per-step contact equation.
        precision: the time loop's dtype (modal propagation, contact law, per-step Newton
            solve; complex64 modes), ``"float64"``, ``"float32"`` or ``"auto"``: float32 for
            forward runs of point contact laws (0.58-0.65x the float64 time of the default
            sweep on a CPU; 0.61x on large batches on an H200 GPU), float64 where gradients
            are taken (fits, the adjoint), where a detector is read (float32 moves its
            reading up to 0.4 %) and for the direct 3D contact (Kalker solves converge to
            1e-10, below float32's resolution; :func:`loop_precision`). The setup (modes,
            tables, exp(pole dt)) and the process (``jax_enable_x64``) stay float64. float32
            max forces are within 2.0e-4 (Fig. 7) and 1.3e-4 (Fig. 8) of float64's, loss of
            contact unchanged (benchmarks/README.md, "Precision").
        allow_inaccurate: run settings that the physics guards refuse (max force not within
            3 % of the converged reference), each finding an
            :class:`~wfjax.scenario.guards.AccuracyWarning` recorded in the provenance.
    """

    time_step: float | None = option(None, unit="s", low=0.0, high=1e-3, low_open=True,
                                     doc="time step; auto: min(max_time_step, "
                                         "max_travel_step / v)")
    max_time_step: float | None = option(
        None, unit="s", low=0.0, high=1e-3, low_open=True, positive=True,
        doc="upper bound of the automatic time step; auto: "
            f"{FORCE_SETTINGS['max_time_step'] * 1e6:g} us, "
            f"{READING_SETTINGS['max_time_step'] * 1e6:g} us where a detector is read")
    max_travel_step: float = option(1e-3, unit="m", low=0.0, high=1e-2, low_open=True,
                                    positive=True,
                                    doc="upper bound of the travel per time step")
    run_in: float = option(0.2, unit="m", low=0.0, high=10.0,
                           doc="travel before the flat reaches the contact")
    run_out: float = option(0.2, unit="m", low=0.0, high=10.0,
                            doc="travel after the flat centre passed the contact")
    contact_element: float = option(1e-3, unit="m", low=1e-4, high=1e-2, positive=True,
                                    doc="side of the 3D/2D contact elements")
    contact_mode_3d: str = option("auto", choices=CONTACT_MODES_3D,
                                  doc="how the 3D contact law is evaluated")
    track_max_frequency: float | None = option(
        None, unit="Hz", low=100.0, high=1e6, positive=True,
        doc="track modes above this enter statically; auto: "
            f"{FORCE_SETTINGS['track_max_frequency'] / 1e3:g} kHz, "
            f"{READING_SETTINGS['track_max_frequency'] / 1e3:g} kHz where a detector is read")
    newton_iterations: int = option(30, low=1, high=1000,
                                    doc="iterations of the per-step contact equation")
    precision: str = option("auto", choices=PRECISIONS, flag="--precision",
                            flag_commands=("sweep", "simulate", "fit", "detector"),
                            doc="dtype of the time loop (auto: float32 forward, float64 for "
                                "gradients, detector readings and direct 3D); setup stays "
                                "float64 (environment: WFJAX_PRECISION)")
    allow_inaccurate: bool = option(False, flag="--allow-inaccurate",
                                    flag_commands=("sweep", "simulate", "fit", "detector"),
                                    doc="run settings the physics guards refuse, with a "
                                        "warning recorded in the provenance "
                                        "(docs/convergence.md)")

    def __post_init__(self):
        for name, unit in {"time_step": "s", **positive_fields(self)}.items():
            if getattr(self, name) is not None:  # None: auto
                check_positive("SimConfig", name, getattr(self, name), unit)
        for name in ("run_in", "run_out"):
            v = getattr(self, name)
            check_finite("SimConfig", name, v)
            if v < 0:
                raise ValueError(f"SimConfig.{name} must be >= 0 m, got {v!r}")
        for name, allowed in (("contact_mode_3d", CONTACT_MODES_3D),
                              ("precision", PRECISIONS)):
            if getattr(self, name) not in allowed:
                raise ValueError(f"SimConfig.{name} must be one of {allowed}, "
                                 f"got {getattr(self, name)!r}")
        if self.precision == "float32" and self.contact_mode_3d == "direct":
            raise ValueError(
                "SimConfig.precision='float32' does not support contact_mode_3d='direct': "
                "its per-step Kalker solves converge to a relative 1e-10, below float32's "
                "resolution (1.2e-7); use 'table' or 'parametric' 3D contact, or float64"
            )
        if self.newton_iterations < 1:
            raise ValueError(f"SimConfig.newton_iterations must be >= 1, "
                             f"got {self.newton_iterations!r}")

    def resolved(self, reading: bool = False) -> SimConfig:
        """This config with every auto setting (``None``; ``precision="auto"`` where a reading
        fixes it) given its number: :data:`READING_SETTINGS` where ``reading`` (a
        :class:`~wfjax.Detector` is read), else :data:`FORCE_SETTINGS`. Settings given stay."""
        defaults = READING_SETTINGS if reading else FORCE_SETTINGS
        given = {k: v for k, v in defaults.items() if getattr(self, k) in (None, "auto")}
        return dataclasses.replace(self, **given) if given else self

    def time_step_for(self, speed: float) -> float:
        """Time step [s] used at ``speed`` [m/s] (an auto step cap: :data:`FORCE_SETTINGS`'s,
        unless :meth:`resolved` gave it)."""
        if self.time_step is not None:
            return float(self.time_step)
        return float(min(self.resolved().max_time_step, self.max_travel_step / speed))
