"""Contact laws behind one interface: what the time loop needs from a contact model.

Every contact model is a pytree built once by :func:`prepare` (the concrete work: node sets,
trajectory grids, 3D tables) and evaluated inside the compiled time step through one small
protocol (:class:`ContactLaw`):

* ``law.point(s)``: the work that depends only on the flat position s [m] (a gap at the
  bedding nodes, an interpolated 3D table column, the trajectory's drop), done once per step;
* ``law.point_force(point, delta)``: the force F [N] at approach delta [m], evaluated at every
  Newton iterate of the step;
* ``law.force(delta, s)``: both at once (static equilibrium, plots, tests);
* ``law.init_state()`` and ``law.step(delta_free, compliance, s, state, max_iter)``: the
  step's scalar contact equation (:mod:`wfjax.contact.newton`); only the per-step direct 3D
  solve, which warm-starts Kalker's solver from the previous pressures, overrides them.

The flat's geometry enters every law as traced leaves (the flat itself, or arrays computed
from it by traced code), never as static Python values: the same compiled program serves a
batch of flats (``jax.vmap`` over :func:`prepare`'s traced part) and ``jax.grad`` reaches depth,
length and profile samples. The law's class and its static fields (grid shapes) select the
compiled program; the time loop never sees a model's name.

Models (``contact=``): ``"hertz-profile"`` (:class:`HertzProfileLaw`), ``"hertz-trajectory"``
(:class:`HertzTrajectoryLaw`), ``"2d"`` (:class:`WinklerLaw`) and ``"3d"``: the exact table
of one flat (:class:`TableLaw`), the parametric family over depth and length
(:class:`ParametricLaw`, :mod:`wfjax.contact.family`) or a Kalker solve every step
(:class:`wfjax.contact.direct3d.Direct3DLaw`), chosen by ``SimConfig.contact_mode_3d``.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .. import geometry
from .._xla import to_device
from ..params import (
    MAX_FLAT_DEPTH,
    Flat,
    Material,
    SimConfig,
    Track,
    Wheel,
    _is_concrete,
    _pytree,
)
from . import hertz, tables, winkler
from .newton import solve_contact_step

__all__ = [
    "CONTACT_MODELS",
    "FLAT_MARGIN",
    "ContactLaw",
    "HertzProfileLaw",
    "HertzTrajectoryLaw",
    "WinklerLaw",
    "TableLaw",
    "ParametricLaw",
    "prepare",
    "prepare_family",
    "prepare_family_range",
    "resolve_mode_3d",
    "cached_table_3d",
    "cached_tables_3d",
    "table_specs_3d",
    "table_batch_size",
]

CONTACT_MODELS = ("3d", "2d", "hertz-trajectory", "hertz-profile")
FLAT_MARGIN = 0.02  # m added to the flat's half extent on either side of its window
TRAJECTORY_SPACING = 2e-5  # m between the samples of the tabulated wheel-centre trajectory
# Part of every 3D table's cache key, so a change of the builder's results within one wfjax
# version is never served from an old cache: 2 = new-flat onsets include the chord ends;
# 3 = issue 20's faster CG and shared window sizes (forces within 1e-9 of revision 2's).
TABLE_BUILDER_REVISION = 3
# Columns of a 3D table solved together (``tables.build_table_3d(batch_size=...)``), by JAX
# platform: one at a time on CPUs (a vmap over the columns was 4.5x slower on 2 cores: every
# batched Kalker while-loop runs until its slowest column); GPUs/TPUs fill their lanes.
TABLE_BATCH_SIZE = {"cpu": 1}
ACCELERATOR_TABLE_BATCH_SIZE = 32


class ContactLaw:
    """The protocol every contact law implements (see the module docstring)."""

    def point(self, s):
        """The s-dependent part of the law at flat position ``s`` [m] (a pytree)."""
        raise NotImplementedError

    def point_force(self, point, delta):
        """Contact force F [N] at approach ``delta`` [m] for a :meth:`point` result."""
        raise NotImplementedError

    def force(self, delta, s):
        """Contact force F [N] at approach ``delta`` [m] and flat position ``s`` [m]."""
        return self.point_force(self.point(s), delta)

    def init_state(self):
        """Initial per-step solver state carried by the time loop (``None``: stateless)."""
        return None

    def rough_nodes(self):
        """[n] offsets x' [m] from the nominal contact point (travel direction) where the law
        reads rail and wheel roughness element by element, or None: a point-contact law,
        to whose approach the time loop adds the contact-filtered roughness instead."""
        return None

    def rough_point(self, s, roughness):
        """:meth:`point` with ``roughness`` [n] [m] (positive = surface raised) at
        :meth:`rough_nodes` taken off the gap (laws with :meth:`rough_nodes` only)."""
        raise NotImplementedError

    def step(self, delta_free, compliance, s, state, max_iter: int = 30, roughness=None):
        """Solve the step's contact equation delta = delta_free - compliance F(delta, s).

        Args:
            delta_free: approach if F were zero [m]. compliance: structure's c > 0 [m/N].
            s: flat position [m]. state: solver state (:meth:`init_state`).
            max_iter: Newton iteration cap (static).
            roughness: None, or for a law with :meth:`rough_nodes` the pair (roughness at
                the nodes [n] m, its contact-filtered value [m]).

        Returns:
            (delta [m], F [N], |r| [m], state); differentiable by the implicit function
            theorem (:func:`wfjax.contact.newton.solve_contact_step`).
        """
        frozen = jax.lax.stop_gradient(self)
        point = self.point(s) if roughness is None else self.rough_point(s, roughness[0])
        point_ng = jax.lax.stop_gradient(point)
        delta, f, r = solve_contact_step(
            lambda d: self.point_force(point, d), delta_free, compliance, max_iter,
            loop_force_fn=lambda d: frozen.point_force(point_ng, d))
        return delta, f, r, state


def _hertz_law(c_h, compression):
    positive = compression > 0
    safe = jnp.where(positive, compression, 1.0)
    return jnp.where(positive, c_h * safe**1.5, 0.0)


@_pytree
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


@_pytree
class HertzTrajectoryLaw(ContactLaw):
    """Hertz spring driven by the rigid wheel-centre trajectory: F = C_H (delta - drop(s))^1.5.

    Attributes:
        c_h: Hertz constant C_H [N/m^1.5].
        s_grid: [n] flat positions [m] of the tabulated trajectory (2e-5 m apart).
        drop: [n] centre drop -H(s) >= 0 [m] (:func:`wfjax.geometry.centre_trajectory`),
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


@_pytree
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


@_pytree
class TableLaw(ContactLaw):
    """3D contact through the exact table F3D(delta, s) of one flat (:mod:`.tables`).

    Attributes: table: :class:`wfjax.contact.tables.ContactTable`.
    """

    table: Any

    def point(self, s):
        return tables.table_column(self.table, s)

    def point_force(self, point, delta):
        return tables.column_force(point, delta)


@_pytree
class ParametricLaw(TableLaw):
    """3D contact through the parametric family F3D(delta, s; depth, length) (:mod:`.family`).

    Evaluated like an exact table (:class:`TableLaw`), on a table that :func:`parametric_law`
    reads off the family once per flat at the element-spaced positions s_j = j h of the exact
    per-flat tables (traced, differentiable in depth and length), so a time step costs what
    the exact table costs.

    Attributes:
        table: :class:`wfjax.contact.tables.ContactTable` of the flat, from the family.
        depth, length: the flat's depth and length [m] (traced leaves: ``vmap`` and ``grad``).
    """

    table: Any
    depth: Any
    length: Any


def parametric_law(family, depth, length) -> ParametricLaw:
    """:class:`ParametricLaw` of the flat (depth [m], length [m]; may be traced).

    The family is evaluated at s_j = j h, |j| <= n (h the element size; n covers the family's
    largest flat and contact), onsets included (at s_j the family's onset is the continuum
    rigid onset there, as in the per-flat tables); beyond the range the end columns, the
    smooth wheel, apply. Pure jnp: no contact problem is solved here.
    """
    from . import family as family_mod

    spec = family.spec
    d_hi = spec.depth_range[1]
    half_hi = (spec.length_factor_range[1] * math.sqrt(8 * spec.wheel_radius * d_hi) / 2
               if spec.kind == "rounded" else math.sqrt(2 * spec.wheel_radius * d_hi))
    reach = half_hi + math.sqrt(2 * spec.wheel_radius * d_hi) + 4 * spec.element_size
    n = math.ceil(reach / spec.element_size)
    s_j = jnp.arange(-n, n + 1) * spec.element_size
    columns = jax.vmap(lambda sj: family_mod.family_column(family, sj, depth, length))(s_j)
    table = tables.ContactTable(
        s_min=jnp.asarray(-n * spec.element_size), ds=jnp.asarray(spec.element_size),
        c_max=family.c_max, onset=columns.onset, force=columns.force, slope=columns.slope,
        converged=family.converged)
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
        contact: one of :data:`CONTACT_MODELS`.
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
        A :class:`ContactLaw` pytree.
    """
    if contact not in CONTACT_MODELS:
        raise ValueError(f"contact must be one of {CONTACT_MODELS}, got {contact!r}")
    if contact == "hertz-profile":
        return HertzProfileLaw(hertz.hertz_constant(material, hertz_radius(wheel, track)), flat)
    if contact == "hertz-trajectory":
        half = flat.half_extent + FLAT_MARGIN
        grid = jnp.linspace(-half, half, int(2 * half / TRAJECTORY_SPACING) + 1)
        return HertzTrajectoryLaw(hertz.hertz_constant(material, hertz_radius(wheel, track)),
                                  grid, -geometry.centre_trajectory(flat, grid), flat)
    if contact == "2d":
        if max_depth is None and not _is_concrete(flat.depth):
            max_depth = MAX_FLAT_DEPTH
        deepest = None if max_depth is None else max_depth + winkler.DEFAULT_APPROACH_MARGIN
        half = winkler.default_half_window(flat, float(wheel.radius), deepest)
        nodes = jnp.asarray(winkler.bedding_nodes(half, config.contact_element))
        return WinklerLaw(flat, material, wheel.radius, nodes)
    mode = "parametric" if family is not None else resolve_mode_3d(config, batched=False)
    if mode == "parametric":
        if family is None:
            family = prepare_family([flat], wheel, track, material, config, cache_dir)
        return parametric_law(family, flat.depth, flat.length)
    if mode == "direct":
        from .direct3d import prepare_direct

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
    ``length_factors`` l / l0 (their ranges; see :func:`wfjax.contact.family.family_spec`)."""
    from . import family as family_mod

    spec = family_mod.family_spec(kind, depths, length_factors, wheel_radius=float(wheel.radius),
                                  rail_head_radius=float(track.rail_head_radius),
                                  material=material, element_size=config.contact_element)
    return family_mod.build_family(spec, material, cache_dir=cache_dir, progress=progress)


def table_batch_size(platform: str | None = None) -> int:
    """Columns of a 3D table built at once on ``platform`` (default: JAX's default backend):
    ``TABLE_BATCH_SIZE`` (1 on CPU), else ``ACCELERATOR_TABLE_BATCH_SIZE``. The table is the
    same to the solver's tolerance either way (batch 4 against 1: 6e-3 N of up to 950 kN), so
    the disk cache does not key on it."""
    platform = platform or jax.default_backend()
    return TABLE_BATCH_SIZE.get(platform, ACCELERATOR_TABLE_BATCH_SIZE)


def cached_table_3d(flat: Flat, wheel_radius: float, rail_head_radius: float,
                    material: Material, element_size: float, cache_dir=None):
    """:func:`wfjax.contact.tables.build_table_3d` through the on-disk cache.

    The key holds every input of the table (flat kind and geometry, radii, material, element
    size, and the builder's defaults through the wfjax version). Flats with traced geometry
    (``grad``, ``vmap``) are built directly, so gradients flow through the solves.
    """
    leaves = jax.tree_util.tree_leaves((flat, material))
    if not all(_is_concrete(leaf) for leaf in leaves):
        return tables.build_table_3d(flat, wheel_radius, rail_head_radius, material,
                                     element_size=element_size, batch_size=table_batch_size())
    return cached_tables_3d([flat], wheel_radius, rail_head_radius, material, element_size,
                            cache_dir)[0]


def _own_extent(flats) -> list:
    """``flats`` without their window bounds: a concrete flat's table spans its own extent (a
    window bound, ``extent_bound``, sizes the simulation windows of batches) and must neither
    change the table nor alias its cache key."""
    return [dataclasses.replace(f, extent_bound=None) for f in flats]


def table_specs_3d(flats, wheel_radius: float, rail_head_radius: float, material: Material,
                   element_size: float) -> list:
    """The layouts (:class:`wfjax.contact.tables.TableSpec`) of the tables
    :func:`cached_tables_3d` builds for ``flats`` (concrete; R_W, R_R [m], element size [m]),
    known before they are built: a sweep compiles its program for their shapes meanwhile."""
    return [tables.table_spec(f, wheel_radius, rail_head_radius, material, element_size)
            for f in _own_extent(flats)]


def cached_tables_3d(flats, wheel_radius: float, rail_head_radius: float,
                     material: Material, element_size: float, cache_dir=None) -> list:
    """:func:`cached_table_3d` of several concrete flats: the tables missing from the cache
    are built together (:func:`wfjax.contact.tables.build_tables_3d`: one set of window
    sizes, compiled once, and every column spread over the CPU cores)."""
    from .. import _cache

    flats = _own_extent(flats)
    paths = [_cache.cache_path("table3d", {
        "flat_kind": f.kind, "flat": [np.asarray(v) for v in jax.tree_util.tree_leaves(
            (f, material))],
        "wheel_radius": wheel_radius, "rail_head_radius": rail_head_radius,
        "element_size": element_size, "builder_revision": TABLE_BUILDER_REVISION},
        cache_dir) for f in flats]
    arrays = [_cache._read(path) for path in paths]
    missing = [i for i, a in enumerate(arrays) if a is None]
    if missing:
        if table_batch_size() == 1:
            built = tables.build_tables_3d([flats[i] for i in missing], wheel_radius,
                                           rail_head_radius, material, element_size)
        else:
            built = [tables.build_table_3d(flats[i], wheel_radius, rail_head_radius, material,
                                           element_size=element_size,
                                           batch_size=table_batch_size()) for i in missing]
        for i, table in zip(missing, built, strict=True):
            arrays[i] = {k: np.asarray(v) for k, v in table._asdict().items()}
            _cache.store(paths[i], arrays[i])
    return [tables.ContactTable(**{k: to_device(v) for k, v in a.items()}) for a in arrays]
