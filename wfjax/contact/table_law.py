"""The exact 3D table of one flat as a contact law, and the on-disk cache of such tables.

:class:`TableLaw` evaluates F3D(delta, s) from a :class:`wfjax.contact.interpolation.ContactTable`;
the parametric family (:class:`wfjax.contact.laws.ParametricLaw`) and the direct 3D mode
(:class:`wfjax.contact.direct3d.Direct3DLaw`) build on it. :func:`cached_table_3d` and
:func:`cached_tables_3d` build the tables through the on-disk cache (:mod:`wfjax._cache`).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import numpy as np

from .._xla import to_device
from ..fields import is_concrete, pytree
from ..params import Flat, Material
from . import interpolation, table_spec, tables
from .protocol import ContactLaw

__all__ = [
    "TableLaw",
    "cached_table_3d",
    "cached_tables_3d",
    "table_specs_3d",
    "table_batch_size",
    "TABLE_BUILDER_REVISION",
    "TABLE_BATCH_SIZE",
    "ACCELERATOR_TABLE_BATCH_SIZE",
]

# Part of every 3D table's cache key, so a change of the builder's results within one wfjax
# version is never served from an old cache: 2 = new-flat onsets include the chord ends;
# 3 = issue 20's faster CG and shared window sizes (forces within 1e-9 of revision 2's);
# 4 = a new flat's columns crowd at its centre (table_spec.NEW_FLAT_STRETCH); 5 = solves in
# float32 to 1e-6 (tables.WINDOWED_TOL; forces within 8e-7 of revision 4's).
TABLE_BUILDER_REVISION = 5
# Columns of a 3D table solved together (``tables.build_table_3d(batch_size=...)``), by JAX
# platform: one at a time on CPUs (a vmap over the columns was 4.5x slower on 2 cores: every
# batched Kalker while-loop runs until its slowest column); GPUs/TPUs fill their lanes.
TABLE_BATCH_SIZE = {"cpu": 1}
ACCELERATOR_TABLE_BATCH_SIZE = 32


@pytree
class TableLaw(ContactLaw):
    """3D contact through the exact table F3D(delta, s) of one flat (:mod:`.tables`).

    Attributes: table: :class:`wfjax.contact.interpolation.ContactTable`.
    """

    table: Any

    def point(self, s):
        return interpolation.table_column(self.table, s)

    def point_force(self, point, delta):
        return interpolation.column_force(point, delta)


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
    if not all(is_concrete(leaf) for leaf in leaves):
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
    """The layouts (:class:`wfjax.contact.table_spec.TableSpec`) of the tables
    :func:`cached_tables_3d` builds for ``flats`` (concrete; R_W, R_R [m], element size [m]),
    known before they are built: a sweep compiles its program for their shapes meanwhile."""
    return [table_spec.table_spec(f, wheel_radius, rail_head_radius, material, element_size)
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
    return [interpolation.ContactTable(**{k: to_device(v) for k, v in a.items()}) for a in arrays]
