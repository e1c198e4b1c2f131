"""The built-in contact laws and their prepare functions: ``prepare(contact, ...)`` -> a law.

Every contact model is a pytree implementing :class:`wfjax.contact.protocol.ContactLaw`,
built once by its prepare function (the concrete work: node sets, trajectory grids, 3D tables)
and evaluated inside the compiled time step. :func:`prepare` looks the model's prepare function
up by name in :mod:`wfjax.contact.registry`, where user-defined laws join the built-ins.

The flat's geometry enters every law as traced leaves (the flat itself, or arrays computed
from it by traced code), never as static Python values: the same compiled program serves a
batch of flats (``jax.vmap`` over :func:`prepare`'s traced part) and ``jax.grad`` reaches depth,
length and profile samples.

Models (``contact=``): ``"hertz-profile"`` (:class:`HertzProfileLaw`,
:func:`prepare_hertz_profile`), ``"hertz-trajectory"`` (:class:`HertzTrajectoryLaw`,
:func:`prepare_hertz_trajectory`), ``"2d"`` (:class:`WinklerLaw`, :func:`prepare_2d`) and
``"3d"`` (:func:`prepare_3d`): the exact table of one flat
(:class:`wfjax.contact.table_law.TableLaw`), the parametric family over depth and length
(:class:`ParametricLaw`, :mod:`wfjax.contact.family`) or a Kalker solve every step
(:class:`wfjax.contact.direct3d.Direct3DLaw`), chosen by ``SimConfig.contact_mode_3d``.
"""

from __future__ import annotations

import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ..fields import is_concrete, pytree
from ..model import geometry
from ..params import MAX_FLAT_DEPTH, Flat, Material, SimConfig, Track, Wheel
from . import hertz, interpolation, registry, winkler
from .direct3d import prepare_direct
from .protocol import ContactLaw
from .table_law import TableLaw, cached_table_3d

__all__ = [
    "FLAT_MARGIN",
    "HertzProfileLaw",
    "HertzTrajectoryLaw",
    "WinklerLaw",
    "ParametricLaw",
    "prepare",
    "prepare_3d",
    "prepare_2d",
    "prepare_hertz_trajectory",
    "prepare_hertz_profile",
    "prepare_family",
    "prepare_family_range",
    "resolve_mode_3d",
    "hertz_radius",
]

FLAT_MARGIN = 0.02  # m added to the flat's half extent on either side of its window
TRAJECTORY_SPACING = 2e-5  # m between the samples of the tabulated wheel-centre trajectory


def _hertz_law(c_h, compression):
    positive = compression > 0
    safe = jnp.where(positive, compression, 1.0)
    return jnp.where(positive, c_h * safe**1.5, 0.0)


@pytree
class HertzProfileLaw(ContactLaw):
    """Hertz spring driven by the flat's profile deviation: F = C_H (delta - z(s))^1.5.

    Attributes: c_h: Hertz constant C_H [N/m^1.5]; flat: the flat (traced geometry).
    """

    c_h: Any
    flat: Flat

    def point(self, s):
        return geometry.profile_deviation(self.flat, s)

    def point_force(self, point, delta):
        return _hertz_law(self.c_h, delta - point)


@pytree
class HertzTrajectoryLaw(ContactLaw):
    """Hertz spring driven by the rigid wheel-centre trajectory: F = C_H (delta - drop(s))^1.5.

    Attributes:
        c_h: Hertz constant C_H [N/m^1.5].
        s_grid: [n] flat positions [m] of the tabulated trajectory (2e-5 m apart).
        drop: [n] centre drop -H(s) >= 0 [m] (:func:`wfjax.model.geometry.centre_trajectory`),
            computed by traced code from the flat, so it carries the geometry's gradient.
        flat: the flat it was computed from.
    """

    c_h: Any
    s_grid: Any
    drop: Any
    flat: Flat

    def point(self, s):
        return jnp.interp(s, self.s_grid, self.drop, left=0.0, right=0.0)

    def point_force(self, point, delta):
        return _hertz_law(self.c_h, delta - point)


@pytree
class WinklerLaw(ContactLaw):
    """2D Winkler bedding (:mod:`wfjax.contact.winkler`); ``point(s)`` is the gap at the nodes.

    Attributes: flat (traced geometry); material; radius: R_W [m]; nodes: [n] bedding nodes
    x' [m] relative to the nominal contact point.
    """

    flat: Flat
    material: Material
    radius: Any
    nodes: Any

    def point(self, s):
        return winkler.gap_at_nodes(self.flat, s, self.radius, self.nodes)

    def rough_nodes(self):
        return self.nodes

    def rough_point(self, s, roughness):
        return self.point(s) - roughness

    def point_force(self, point, delta):
        return winkler.force_from_gap(point, delta, self.material, self.nodes)


@pytree
class ParametricLaw(TableLaw):
    """3D contact through the parametric family F3D(delta, s; depth, length) (:mod:`.family`).

    Evaluated like an exact table (:class:`TableLaw`), on a table that :func:`parametric_law`
    reads off the family once per flat at the element-spaced positions s_j = j h of the exact
    per-flat tables (traced, differentiable in depth and length), so a time step costs what
    the exact table costs.

    Attributes:
        table: :class:`wfjax.contact.interpolation.ContactTable` of the flat, from the family.
        depth, length: the flat's depth and length [m] (traced leaves: ``vmap`` and ``grad``).
    """

    table: Any
    depth: Any
    length: Any


def parametric_law(family, depth, length) -> ParametricLaw:
    """:class:`ParametricLaw` of the flat (depth [m], length [m]; may be traced).

    The family is evaluated at the columns of a per-flat table, s_j with phi(s_j) = j h,
    |j| <= n (h the element size, phi the family's column coordinate,
    :func:`wfjax.contact.interpolation.column_coordinate`: s_j = j h for rounded flats,
    crowded at a new flat's centre; n covers the family's largest flat and contact), onsets
    included (at s_j the family's onset is the continuum rigid onset there, as in the
    per-flat tables); beyond the range the end columns, the smooth wheel, apply. Pure jnp: no
    contact problem is solved here.
    """
    from . import family as family_mod

    spec = family.spec
    d_hi = spec.depth_range[1]
    half_hi = (spec.length_factor_range[1] * math.sqrt(8 * spec.wheel_radius * d_hi) / 2
               if spec.kind == "rounded" else math.sqrt(2 * spec.wheel_radius * d_hi))
    reach = half_hi + math.sqrt(2 * spec.wheel_radius * d_hi) + 4 * spec.element_size
    n = math.ceil(interpolation.column_coordinate(reach, spec.stretch) / spec.element_size)
    s_j = jnp.asarray(interpolation.column_positions(
        np.arange(-n, n + 1) * spec.element_size, spec.stretch))
    columns = jax.vmap(lambda sj: family_mod.family_column(family, sj, depth, length))(s_j)
    table = interpolation.ContactTable(
        s_min=jnp.asarray(-n * spec.element_size), ds=jnp.asarray(spec.element_size),
        c_max=family.c_max, onset=columns.onset, force=columns.force, slope=columns.slope,
        converged=family.converged, stretch=jnp.full_like(family.c_max, spec.stretch))
    return ParametricLaw(table, depth, length)


def hertz_radius(wheel: Wheel, track: Track):
    """Equivalent radius [m] of the Hertz spring: sqrt(R_W R_R).

    The paper's Hertz spring assumes equal wheel and rail-head radii (Eq. 15). For unequal
    radii the geometric mean is the usual equivalent radius (exact for the contact area).
    """
    return jnp.sqrt(wheel.radius * track.rail_head_radius)


def resolve_mode_3d(config: SimConfig, batched: bool) -> str:
    """The 3D mode actually used: ``"auto"`` is the exact table for one flat of a kind and
    the parametric family for a batch of geometries (sweeps over depths, fits)."""
    mode = config.contact_mode_3d
    if mode == "auto":
        return "parametric" if batched else "table"
    return mode


def prepare(contact: str, flat: Flat, wheel: Wheel, track: Track, material: Material,
            config: SimConfig, cache_dir=None, family=None,
            max_depth: float | None = None) -> ContactLaw:
    """Build the contact law of ``flat`` (concrete grids and tables; traced geometry leaves).

    Args:
        contact: a model name of :mod:`wfjax.contact.registry` (the built-ins ``"3d"``,
            ``"2d"``, ``"hertz-trajectory"``, ``"hertz-profile"`` or a registered law).
        flat: the flat; its depth, length and profile may be traced (``vmap``/``grad``) for
            every model except the exact 3D table and the direct 3D mode, which need a
            concrete flat (their grids depend on it). Traced flats need ``extent_bound``.
        wheel, track, material, config: model parameters.
        cache_dir: on-disk cache of 3D tables (default ``WFJAX_CACHE_DIR`` / ``~/.cache``).
        family: a built :class:`wfjax.contact.family.FlatFamily` for ``"3d"``: selects the
            parametric law (required when the flat is traced).
        max_depth: concrete bound [m] of a traced flat's depth; sizes the 2D bedding window
            (default: the flat's depth, or :data:`wfjax.params.MAX_FLAT_DEPTH` if traced).

    Returns:
        A :class:`wfjax.contact.protocol.ContactLaw` pytree, from the model's prepare function
        (given ``family`` and ``max_depth`` as keywords when they are not None).

    Raises:
        ValueError: ``contact`` is not a registered model (one line naming it).
    """
    prepare_fn = registry.get(registry.check(contact))
    options = {k: v for k, v in (("family", family), ("max_depth", max_depth))
               if v is not None}
    return prepare_fn(flat, wheel, track, material, config, cache_dir, **options)


_OPTIONS = ("family", "max_depth")  # the keywords prepare() may pass to a prepare function


def _check_options(contact: str, options: dict) -> None:
    """One-line ``ValueError`` for keywords that no built-in prepare function takes; the
    known ones (:data:`_OPTIONS`) that ``contact`` does not use are ignored."""
    unknown = sorted(set(options) - set(_OPTIONS))
    if unknown:
        raise ValueError(f"contact {contact!r}: unknown options {unknown}, known: "
                         f"{', '.join(_OPTIONS)}")


def prepare_hertz_profile(flat: Flat, wheel: Wheel, track: Track, material: Material,
                          config: SimConfig, cache_dir=None, **options) -> HertzProfileLaw:
    """``"hertz-profile"``: :class:`HertzProfileLaw` of ``flat`` with C_H [N/m^1.5] from
    ``material`` and the radius :func:`hertz_radius` [m]. ``config``, ``cache_dir`` and the
    options (``family``, ``max_depth``) are unused."""
    _check_options("hertz-profile", options)
    return HertzProfileLaw(hertz.hertz_constant(material, hertz_radius(wheel, track)), flat)


def prepare_hertz_trajectory(flat: Flat, wheel: Wheel, track: Track, material: Material,
                             config: SimConfig, cache_dir=None,
                             **options) -> HertzTrajectoryLaw:
    """``"hertz-trajectory"``: :class:`HertzTrajectoryLaw` of ``flat``: the rigid wheel
    centre's drop [m] tabulated every :data:`TRAJECTORY_SPACING` m over the flat's half extent
    plus :data:`FLAT_MARGIN` on either side (traced: differentiable in the geometry).
    ``config``, ``cache_dir`` and the options (``family``, ``max_depth``) are unused."""
    _check_options("hertz-trajectory", options)
    half = flat.half_extent + FLAT_MARGIN
    grid = jnp.linspace(-half, half, int(2 * half / TRAJECTORY_SPACING) + 1)
    return HertzTrajectoryLaw(hertz.hertz_constant(material, hertz_radius(wheel, track)),
                              grid, -geometry.centre_trajectory(flat, grid), flat)


def prepare_2d(flat: Flat, wheel: Wheel, track: Track, material: Material, config: SimConfig,
               cache_dir=None, max_depth: float | None = None, **options) -> WinklerLaw:
    """``"2d"``: :class:`WinklerLaw` of ``flat`` on bedding nodes ``config.contact_element``
    [m] apart over a window sized for approaches up to ``max_depth`` [m] (default: the flat's
    depth, or :data:`wfjax.params.MAX_FLAT_DEPTH` if traced) plus the bedding's margin.
    ``cache_dir`` and ``family`` are unused."""
    _check_options("2d", options)
    if max_depth is None and not is_concrete(flat.depth):
        max_depth = MAX_FLAT_DEPTH
    deepest = None if max_depth is None else max_depth + winkler.DEFAULT_APPROACH_MARGIN
    half = winkler.default_half_window(flat, float(wheel.radius), deepest)
    nodes = jnp.asarray(winkler.bedding_nodes(half, config.contact_element))
    return WinklerLaw(flat, material, wheel.radius, nodes)


def prepare_3d(flat: Flat, wheel: Wheel, track: Track, material: Material, config: SimConfig,
               cache_dir=None, family=None, **options) -> TableLaw:
    """``"3d"``: the 3D law of ``flat`` (Kalker, elastic half-space).

    With ``family`` (a built :class:`wfjax.contact.family.FlatFamily`; required for a traced
    flat) the parametric law read off it; else by ``config.contact_mode_3d``
    (:func:`resolve_mode_3d` for one flat): the exact table through the on-disk cache
    ``cache_dir``, the family of this flat alone, or the direct mode (a Kalker solve every
    step). ``max_depth`` is unused.
    """
    _check_options("3d", options)
    mode = "parametric" if family is not None else resolve_mode_3d(config, batched=False)
    if mode == "parametric":
        if family is None:
            family = prepare_family([flat], wheel, track, material, config, cache_dir)
        return parametric_law(family, flat.depth, flat.length)
    if mode == "direct":
        return prepare_direct(flat, wheel, track, material, config, cache_dir)
    return TableLaw(cached_table_3d(flat, float(wheel.radius), float(track.rail_head_radius),
                                    material, config.contact_element, cache_dir))


def prepare_family(flats, wheel: Wheel, track: Track, material: Material, config: SimConfig,
                   cache_dir=None, progress: bool = False):
    """The parametric 3D family covering ``flats`` (concrete, one kind: new or rounded).

    Node tables are cached on disk, so a later call over an overlapping range builds only the
    missing nodes (fits use :func:`prepare_family_range` over their search range).

    Returns:
        :class:`wfjax.contact.family.FlatFamily`.
    """
    from ..params import new_flat_length

    kinds = {f.kind for f in flats}
    if len(kinds) != 1 or not kinds <= {"new", "rounded"}:
        raise ValueError(f"the parametric 3D law needs flats of one kind, 'new' or 'rounded', "
                         f"got kinds {sorted(kinds)}; measured profiles use the exact table "
                         f"(SimConfig(contact_mode_3d='table'))")
    kind = kinds.pop()
    radius = float(wheel.radius)
    depths = [float(np.asarray(f.depth)) for f in flats]
    factors = None
    if kind == "rounded":
        factors = [float(np.asarray(f.length)) / float(new_flat_length(d, radius))
                   for f, d in zip(flats, depths, strict=True)]
    return prepare_family_range(kind, depths, factors, wheel, track, material, config,
                                cache_dir, progress)


def prepare_family_range(kind: str, depths, length_factors, wheel: Wheel, track: Track,
                         material: Material, config: SimConfig, cache_dir=None,
                         progress: bool = False):
    """The parametric 3D family of ``kind`` covering ``depths`` [m] and, for rounded flats,
    ``length_factors`` l / l0 (their ranges; see :func:`wfjax.contact.family_spec.family_spec`)."""
    from . import family_build as family_build_mod
    from .family_spec import family_spec

    spec = family_spec(kind, depths, length_factors, wheel_radius=float(wheel.radius),
                       rail_head_radius=float(track.rail_head_radius), material=material,
                       element_size=config.contact_element)
    return family_build_mod.build_family(spec, material, cache_dir=cache_dir, progress=progress)
