"""A dipped rail joint: a dip in the rail top centred at a joint, and Jenkins' P2 estimate.

A dipped joint is the classic second source of impacts after wheel flats: the rail ends at
a (fished or insulated) joint sag under traffic, so the running surface dips by a depth ``d``
over a length ``l`` around the joint. :class:`Joint` describes the dip, adds it to a rail
:class:`wfjax.Roughness` (:meth:`Joint.add_to`), which every entry point already
reads (``wf.simulate(..., roughness=joint.add_to(None))``), and gives the classic P2 force
estimate of Jenkins et al. (1974) for comparison (:func:`jenkins_p2`, :meth:`Joint.p2`).
See ``docs/joint.md``.

Shapes (``Joint.shape``), with ``u = (x - position) / length`` in ``[-1/2, 1/2]`` and
**positive = surface raised** (the roughness convention), so the dip is negative:

* ``"cosine"`` (default): ``r = -d (1 + cos 2 pi u) / 2``: smooth (continuous slope), the
  shape of a rail end that has sagged elastically-plastically over the joint sleepers, with
  no slope break for the model to turn into a spurious high-frequency impact. Its steepest
  slope is ``pi d / l``, and its change of slope across the bottom ``2 pi d / l``.
* ``"v"``: ``r = -d (1 - 2 |u|)``: two straight ramps meeting at the joint, Jenkins'
  idealisation: the slope changes abruptly by the total joint angle ``2 alpha = 4 d / l`` at
  the joint, which excites both the P1 (wheel on rail mass, ~0.5-1 ms) and the P2 (unsprung
  mass on the track, ~70 Hz) force. Use it to compare with :func:`jenkins_p2`.

Bounds (the joint's own, not roughness's 1 mm): depth in ``(0, MAX_DEPTH]`` (5 mm, as for
flats: dipped joints are 0.5-3 mm deep), length in ``[MIN_LENGTH, MAX_LENGTH]`` (0.1-2 m),
steepest slope at most :data:`MAX_SLOPE` (0.05 rad). Reasons in ``docs/joint.md``.
:class:`wfjax.Roughness` itself holds profiles within ``roughness.MAX_AMPLITUDE``
(1 mm today): :meth:`Joint.add_to` says so in one line when a joint is deeper.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import numpy as np

from ..params import ABSORBING_BAYS, MAX_FLAT_DEPTH, MAX_SPEED, Track, Wheel

__all__ = ["Joint", "SHAPES", "MAX_DEPTH", "MIN_LENGTH", "MAX_LENGTH", "MAX_SLOPE",
           "MAX_POSITION", "SPACING", "MARGIN", "EquivalentTrack", "equivalent_track",
           "jenkins_p2", "rail_span"]

SHAPES = ("cosine", "v")
MAX_DEPTH = MAX_FLAT_DEPTH  # m (5 mm): the model's bound on flats, 1.7x the deepest joint
MIN_LENGTH = 0.1  # m: ~8 contact lengths; the contact filter passes 0.1 m waves to 2 %
MAX_LENGTH = 2.0  # m: ~3 sleeper bays; longer dips are track geometry (car body modes)
MAX_SLOPE = 0.05  # rad: the wheel centre then rides at most R theta^2 / 2 = 0.6 mm off
MAX_POSITION = 750.0  # m: half the longest model track (1000 bays x 1.5 m)
SPACING = 5e-4  # m: samples of a new rail profile (the roughness limit is 1 mm)
MARGIN = 0.1  # m: flat rail kept on either side of the dip when a profile is extended


def _number(name: str, value) -> float:
    """``value`` as a float, or a one-line ValueError naming ``Joint.<name>``."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(
            value, (int, float, np.integer, np.floating)):
        raise ValueError(f"Joint.{name} must be a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"Joint.{name} must be finite, got {value!r}")
    return v


@dataclasses.dataclass(frozen=True)
class Joint:
    """A dipped rail joint: a dip of ``depth`` over ``length`` centred at ``position``.

    Attributes:
        position: rail coordinate of the joint centre [m] (x = 0 above the middle sleeper
            of the model track), ``|x| <= MAX_POSITION`` (750 m).
        depth: dip depth d [m], in ``(0, MAX_DEPTH]`` (5 mm); the rail top goes *down* by d
            at the joint (its roughness is ``-d`` there).
        length: total dip length l [m], in ``[MIN_LENGTH, MAX_LENGTH]`` (0.1-2 m): the rail
            is level outside ``[position - l/2, position + l/2]``.
        shape: ``"cosine"`` (smooth, default) or ``"v"`` (Jenkins' kink of 2 alpha = 4 d / l);
            see the module docstring for the choice.

    Raises:
        ValueError: one line naming the field, the value given and the allowed range; the
            steepest slope (``pi d / l`` cosine, ``2 d / l`` v) must be <= ``MAX_SLOPE``.
    """

    position: float
    depth: float
    length: float
    shape: str = "cosine"

    def __post_init__(self):
        if not isinstance(self.shape, str) or self.shape not in SHAPES:
            raise ValueError(f"Joint.shape must be one of {', '.join(map(repr, SHAPES))}, "
                             f"got {self.shape!r}")
        x, d, l = (_number(n, getattr(self, n)) for n in ("position", "depth", "length"))
        if abs(x) > MAX_POSITION:
            raise ValueError(f"Joint.position must be in [-{MAX_POSITION:g}, {MAX_POSITION:g}] "
                             f"m (x = 0 above the middle sleeper), got {self.position!r}")
        if not 0 < d <= MAX_DEPTH:
            raise ValueError(f"Joint.depth must be in (0, {MAX_DEPTH:g}] m (0-"
                             f"{MAX_DEPTH * 1e3:g} mm, the dip positive), got {self.depth!r}")
        if not MIN_LENGTH <= l <= MAX_LENGTH:
            raise ValueError(f"Joint.length must be in [{MIN_LENGTH:g}, {MAX_LENGTH:g}] m, got "
                             f"{self.length!r}")
        steep = self._slope_factor() * d / l
        if steep > MAX_SLOPE:
            raise ValueError(
                f"Joint.length must be >= {self._slope_factor() * d / MAX_SLOPE:.4g} m for a "
                f"{d * 1e3:g} mm {self.shape} dip (steepest slope <= {MAX_SLOPE:g} rad), got "
                f"{self.length!r} (slope {steep:.3g} rad)")
        for name, value in (("position", x), ("depth", d), ("length", l)):
            object.__setattr__(self, name, value)

    def _slope_factor(self) -> float:
        """Steepest slope / (d / l): pi (cosine) or 2 (v)."""
        return math.pi if self.shape == "cosine" else 2.0

    # -- geometry ------------------------------------------------------------------------
    @property
    def start(self) -> float:
        """Rail coordinate [m] where the dip begins (``position - length / 2``)."""
        return self.position - 0.5 * self.length

    @property
    def end(self) -> float:
        """Rail coordinate [m] where the dip ends (``position + length / 2``)."""
        return self.position + 0.5 * self.length

    @property
    def max_slope(self) -> float:
        """Steepest slope of the dip [rad]: ``pi d / l`` (cosine) or ``2 d / l`` (v)."""
        return self._slope_factor() * self.depth / self.length

    @property
    def total_angle(self) -> float:
        """Change of slope across the dip's bottom [rad], Jenkins' total joint angle
        ``2 alpha``: ``4 d / l`` (v, at once at the joint) or ``2 pi d / l`` (cosine, spread
        over the middle half of the dip)."""
        return 2.0 * self.max_slope

    @property
    def min_radius(self) -> float:
        """Smallest radius of curvature of the dip's concave bottom [m]: ``l^2 / (2 pi^2 d)``
        (cosine); 0 for the v (a kink)."""
        if self.shape == "v":
            return 0.0
        return self.length**2 / (2 * math.pi**2 * self.depth)

    def profile(self, x) -> np.ndarray:
        """The dip [m] at rail positions ``x`` [m] (any shape; 0 outside the dip, negative in
        it: positive = surface raised). NumPy, vectorised."""
        u = (np.asarray(x, dtype=float) - self.position) / self.length
        inside = np.abs(u) <= 0.5
        if self.shape == "v":
            shape = 1.0 - 2.0 * np.abs(u)
        else:
            shape = 0.5 * (1.0 + np.cos(2 * np.pi * u))
        return np.where(inside, -self.depth * shape, 0.0)

    def check_wheel(self, wheel_radius: float) -> None:
        """A one-line ValueError unless a wheel of radius ``wheel_radius`` [m] can follow the
        cosine dip (its bottom's radius of curvature >= the wheel's: otherwise the wheel
        bridges the bottom, touching both flanks, which a single contact point cannot
        represent). A v dip always has a kink; the contact filter rounds it over the contact
        length (docs/joint.md)."""
        radius = float(wheel_radius)
        if self.shape == "cosine" and self.min_radius < radius:
            need = math.pi * math.sqrt(2 * self.depth * radius)
            raise ValueError(f"Joint.length must be >= {need:.4g} m for a {self.depth * 1e3:g} "
                             f"mm cosine dip under a {radius:g} m wheel (the dip's bottom "
                             f"radius l^2 / (2 pi^2 d) >= the wheel radius), got "
                             f"{self.length!r}")

    def check_track(self, track: Track | None = None, wheel_radius: float | None = None) -> None:
        """A one-line ValueError unless the dip lies on the model rail of ``track``
        (:func:`rail_span`) and, with ``wheel_radius`` [m], :meth:`check_wheel` passes."""
        if wheel_radius is not None:
            self.check_wheel(wheel_radius)
        lo, hi = rail_span(track)
        if self.start < lo or self.end > hi:
            raise ValueError(f"Joint.position must put the dip on the model rail [{lo:g}, "
                             f"{hi:g}] m, got {self.position!r} (length {self.length:g} m)")

    # -- as rail roughness ---------------------------------------------------------------
    def add_to(self, roughness=None, *, span: tuple[float, float] | None = None,
               spacing: float = SPACING):
        """The rail roughness with this dip added.

        Args:
            roughness: None, or a rail :class:`wfjax.Roughness` (``values [n]`` or
                ``[R, n]``, not periodic; concrete arrays: this is input preparation, before
                any ``jit``).
            span: None only: the rail span [m] ``(x_lo, x_hi)`` the new profile covers
                (default :func:`rail_span` of the default track, the whole model rail, so
                every run's contacts read it); widened to the dip plus :data:`MARGIN`.
            spacing: None only: the sample spacing [m] (default 0.5 mm, at most
                ``roughness.MAX_SPACING``); a sample sits on the joint centre.

        Returns:
            :class:`wfjax.Roughness`: None -> the dip alone, level rail elsewhere;
            a roughness -> the same grid (spacing, sample positions), extended by holding
            its end values (what it reads beyond its span) until it covers the dip plus
            :data:`MARGIN`, with the dip added to every realisation.

        Raises:
            ValueError: a wheel (periodic) profile, a bad span or spacing, or a rail deeper
                than ``roughness.MAX_AMPLITUDE`` with the dip (one line).
        """
        from . import roughness as R

        if roughness is None:
            lo, hi = rail_span() if span is None else _check_span(span)
            dx = R._check_spacing(spacing)
            lo, hi = min(lo, self.start - MARGIN), max(hi, self.end + MARGIN)
            below = math.ceil((self.position - lo) / dx - 1e-9)
            above = math.ceil((hi - self.position) / dx - 1e-9)
            x0 = self.position - below * dx
            return self._rail(R, x0, dx, self.profile(x0 + dx * np.arange(below + above + 1)))
        if not isinstance(roughness, R.Roughness) or roughness.periodic:
            raise ValueError("Joint.add_to needs a rail roughness (wfjax.Roughness "
                             f"with periodic=False) or None, got {type(roughness).__name__}"
                             + (" (a wheel profile)" if getattr(roughness, "periodic", 0)
                                else ""))
        dx, x0 = float(np.asarray(roughness.spacing)), float(np.asarray(roughness.x_start))
        values = np.asarray(roughness.values, dtype=float)
        n = values.shape[-1]
        pad_lo = max(0, math.ceil((x0 - (self.start - MARGIN)) / dx - 1e-9))
        pad_hi = max(0, math.ceil((self.end + MARGIN - (x0 + (n - 1) * dx)) / dx - 1e-9))
        if pad_lo or pad_hi:
            values = np.pad(values, [(0, 0)] * (values.ndim - 1) + [(pad_lo, pad_hi)],
                            mode="edge")
            x0 -= pad_lo * dx
        dip = self.profile(x0 + dx * np.arange(values.shape[-1]))
        return self._rail(R, x0, dx, values + dip)

    def _rail(self, R, x0: float, dx: float, values: np.ndarray):
        peak = float(np.max(np.abs(values)))
        if peak > R.MAX_AMPLITUDE:
            allowed = R.MAX_AMPLITUDE - (peak - self.depth)
            raise ValueError(
                f"Joint.depth = {self.depth!r} m: wfjax.Roughness holds rail profiles "
                f"within +-{R.MAX_AMPLITUDE * 1e3:g} mm (roughness.MAX_AMPLITUDE) and this rail "
                f"with the dip reaches {peak * 1e3:.4g} mm; allowed now: depth <= "
                f"{max(allowed, 0.0) * 1e3:.4g} mm (the joint's own bound is "
                f"{MAX_DEPTH * 1e3:g} mm: docs/joint.md)")
        return R.Roughness(x0, dx, values)

    # -- Jenkins' estimate ---------------------------------------------------------------
    def p2(self, speed, wheel: Wheel | None = None, track: Track | None = None) -> np.ndarray:
        """Jenkins' P2 force [N] of this joint at ``speed`` [m/s] (scalar or array): static
        load ``wheel.preload``, unsprung mass ``wheel.wheelset_mass + wheel.small_mass``, the
        track's equivalent mass, stiffness and damping from its own receptance at the joint
        (:func:`equivalent_track`), total angle :attr:`total_angle`. Meant for the v shape
        (Jenkins' kink); for the cosine it is an upper estimate (docs/joint.md)."""
        wheel = wheel or Wheel()
        unsprung = float(wheel.wheelset_mass) + float(wheel.small_mass)
        eq = equivalent_track(track, unsprung, x=self.position)
        return jenkins_p2(speed, self.total_angle, float(wheel.preload), unsprung, eq.mass,
                          eq.stiffness, eq.damping)


def _check_span(span) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in span)
    except (TypeError, ValueError):
        raise ValueError(f"span must be two rail coordinates (x_lo, x_hi) [m], got "
                         f"{span!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise ValueError(f"span must be finite with x_lo < x_hi [m], got {span!r}")
    return lo, hi


def rail_span(track: Track | None = None) -> tuple[float, float]:
    """The model rail's span [m]: ``(-n L_S / 2, n L_S / 2)`` (x = 0 above the middle
    sleeper), n = ``n_bays`` and at least :data:`wfjax.params.ABSORBING_BAYS` (the least a
    run's track is lengthened to with absorbing ends; with end networks the guards lengthen
    it to the wheels' paths, which :func:`wfjax.scenario.windows.check_rail_span` checks
    a profile covers); the default track's is (-7.8, 7.8) m."""
    track = track or Track()
    half = 0.5 * max(int(track.n_bays), ABSORBING_BAYS) * float(track.sleeper_spacing)
    return -half, half


# --------------------------------------------------------------------------------------------
# Jenkins et al. (1974): the P2 force
# --------------------------------------------------------------------------------------------
class EquivalentTrack(NamedTuple):
    """A track as one mass on a spring and damper, as Jenkins' P2 formula sees it.

    Fields: mass M_t [kg], stiffness K_t [N/m], damping C_t [N s/m], and frequency [Hz]: the
    P2 resonance ``sqrt(K_t / (M_u + M_t)) / 2 pi`` at which M_t and C_t were read.
    """

    mass: float
    stiffness: float
    damping: float
    frequency: float


def equivalent_track(track: Track | None = None, unsprung_mass: float | None = None,
                     x: float = 0.0, iterations: int = 20) -> EquivalentTrack:
    """The track's equivalent mass, stiffness and damping at rail position ``x`` [m], read
    from its own point receptance (:func:`wfjax.model.track.receptance`, the FE model's direct
    frequency-domain solve).

    The dynamic stiffness ``1 / alpha(f)`` of a mass on a spring and damper is
    ``K_t - omega^2 M_t + i omega C_t``. ``K_t = 1 / alpha(0)`` (static); ``M_t`` and ``C_t``
    come from ``1 / alpha`` at the P2 resonance ``f_2 = sqrt(K_t / (M_u + M_t)) / 2 pi`` (the
    unsprung mass bouncing on the track), found by fixed-point iteration (a few steps: M_t
    changes slowly with f). Default track and ``M_u`` = 596 kg: M_t ~ 66 kg, K_t ~ 135 MN/m,
    C_t ~ 69 kN s/m at ~72 Hz above a sleeper.

    Args:
        track: :class:`wfjax.Track` (default Table 2). unsprung_mass: M_u [kg] (default
            the default wheel's ``wheelset_mass + small_mass``). x: rail position [m].
        iterations: at most this many fixed-point steps (stops at 1e-9 relative change).
    """
    from ..model.track import receptance

    track = track or Track()
    if unsprung_mass is None:
        unsprung_mass = float(Wheel().wheelset_mass) + float(Wheel().small_mass)
    mu = _positive("unsprung_mass", unsprung_mass, "kg")
    stiffness = 1.0 / float(np.real(receptance(track, [0.0], x)[0]))
    mass, freq, damping = 0.0, 0.0, 0.0
    for _ in range(int(iterations)):
        freq = math.sqrt(stiffness / (mu + mass)) / (2 * math.pi)
        omega = 2 * math.pi * freq
        dyn = 1.0 / complex(receptance(track, [freq], x)[0])
        new = max((stiffness - dyn.real) / omega**2, 0.0)
        damping = dyn.imag / omega
        done = abs(new - mass) <= 1e-9 * max(new, 1.0)
        mass = new
        if done:
            break
    return EquivalentTrack(mass, stiffness, damping, freq)


def _positive(name: str, value, unit: str, zero: bool = False) -> np.ndarray:
    v = np.asarray(value, dtype=float)
    bad = ~np.isfinite(v) | ((v < 0) if zero else (v <= 0))
    if np.any(bad):
        rng = "[0, inf)" if zero else "(0, inf)"
        raise ValueError(f"{name} must be finite and in {rng} {unit}, got {value!r}")
    return v


def jenkins_p2(speed, total_angle, static_load, unsprung_mass, track_mass, track_stiffness,
               track_damping):
    """Jenkins et al.'s P2 force [N] at a dipped joint.

    ``P2 = P0 + 2 alpha v sqrt(Mu / (Mu + Mt)) [1 - C_t pi / (4 sqrt(K_t (Mu + Mt)))]
    sqrt(K_t Mu)`` (H. H. Jenkins, J. E. Stephenson, G. A. Clayton, G. W. Morland, D. Lyon,
    "The effect of track and vehicle parameters on wheel/rail vertical dynamic forces",
    Railway Engineering Journal 3 (1974) 2-16). Where it comes from: at the joint the
    wheel's vertical velocity changes by ``2 alpha v``; the unsprung mass shares that momentum
    with the track mass and the pair bounces on the track spring, whose force peaks at
    ``K_t (Mu 2 alpha v / (Mu + Mt)) / omega`` with ``omega = sqrt(K_t / (Mu + Mt))``, which is
    the formula's undamped term; damping lowers the first peak, a quarter period later, by
    ``exp(-zeta pi / 2) ~ 1 - zeta pi / 2`` with ``zeta = C_t / (2 sqrt(K_t (Mu + Mt)))``,
    the bracket.

    Args (numbers or arrays that broadcast; SI):
        speed: v [m/s] in (0, MAX_SPEED]. total_angle: 2 alpha [rad] >= 0 (a v dip:
            ``4 d / l``). static_load: P0 [N] > 0. unsprung_mass: Mu [kg] > 0 (per wheel).
        track_mass, track_stiffness, track_damping: M_t [kg] >= 0, K_t [N/m] > 0,
            C_t [N s/m] >= 0 (per rail; :func:`equivalent_track`).

    Returns:
        P2 [N] (float for scalar inputs).

    Raises:
        ValueError: one line naming the argument, the value and the allowed range.
    """
    v = _positive("speed", speed, "m/s")
    if np.any(v > MAX_SPEED):
        raise ValueError(f"speed must be in (0, {MAX_SPEED:g}] m/s, got {speed!r}")
    angle = _positive("total_angle", total_angle, "rad", zero=True)
    p0 = _positive("static_load", static_load, "N")
    mu = _positive("unsprung_mass", unsprung_mass, "kg")
    mt = _positive("track_mass", track_mass, "kg", zero=True)
    kt = _positive("track_stiffness", track_stiffness, "N/m")
    ct = _positive("track_damping", track_damping, "N s/m", zero=True)
    damping = 1.0 - ct * math.pi / (4.0 * np.sqrt(kt * (mu + mt)))
    p2 = p0 + angle * v * np.sqrt(mu / (mu + mt)) * damping * np.sqrt(kt * mu)
    return float(p2) if np.ndim(p2) == 0 else p2
