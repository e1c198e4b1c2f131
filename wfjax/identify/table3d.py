"""The response table's runs with the exact 3D contact law (``build_table(contact="3d")``).

Every flat of the table (shape x length) gets its own exact 3D table F3D(delta, s) (Kalker,
elastic half-space; :func:`wfjax.contact.table_law.cached_tables_3d`, built once and cached
on disk, speed-independent), widened to one column count
(:func:`wfjax.contact.interpolation.pad_columns`: the same forces, the shape of a larger
table) so that a shape's tables stack along a leading axis [L] and its runs go as one
``lax.map`` over them, as the Hertz-trajectory path maps over lengths; one compiled batch
serves every shape. This is the law :func:`wfjax.identify.forward.coupled_batch` runs with
``contact="3d"`` (``contact_mode_3d="auto"``: one exact table per flat), so the table, the
neighbour corrections and the 3D truth of ``benchmarks/identify_study.py`` share it.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from ..contact.interpolation import pad_columns
from ..contact.table_law import TableLaw, cached_tables_3d, table_specs_3d
from ..program.core import Autodiff, Histories

__all__ = ["stacked_laws", "table_batch_3d", "column_count", "PROGRAMS"]


def column_count(flats, wheel_radius: float, track, material, config) -> int:
    """The most columns of ``flats``' exact 3D tables (concrete flats; R_W [m]), known before
    they are built."""
    specs = table_specs_3d(list(flats), wheel_radius, float(track.rail_head_radius),
                           material, config.contact_element)
    return max(int(sp.n_s) for sp in specs)


def stacked_laws(flats_by_shape, wheel_radius: float, track, material, config,
                 cache_dir=None, sizing=()) -> list[TableLaw]:
    """Per shape a :class:`TableLaw` whose arrays carry a leading axis [L]: the exact 3D
    tables of that shape's ``L`` flats (``flats_by_shape``: [S] lists of concrete
    :class:`wfjax.params.Flat`), widened to one column count: the most of theirs and of
    the ``sizing`` flats' tables (the longest parametric flats, as
    :func:`wfjax.identify.forward.coupled_batch` widens them, so that the table's batches
    and the neighbour corrections compile alike).

    The tables missing from the disk cache are built together (every flat of every shape at
    once: one set of window sizes, the columns spread over the CPU cores)."""
    flat_list = [f for shape in flats_by_shape for f in shape]
    tables = cached_tables_3d(flat_list, float(wheel_radius), float(track.rail_head_radius),
                              material, config.contact_element, cache_dir)
    n_s = max(column_count(flat_list + list(sizing), wheel_radius, track, material, config),
              *(int(np.shape(t.onset)[0]) for t in tables))
    wide = [pad_columns(t, n_s) for t in tables]
    out, i = [], 0
    for shape in flats_by_shape:
        group = wide[i:i + len(shape)]
        i += len(shape)
        out.append(TableLaw(jax.tree.map(lambda *a: jnp.stack([jnp.asarray(x) for x in a]),
                                         *group)))
    return out


# (contact, kind ("table": the exact 3D tables), radius, bound, statics, support scatter) ->
# (a program of them, its traced law or None): the table's jitted batches' static part
# (:func:`table_batch_3d`, ``forward._table_batch``); every program of one key shares the
# compiled batch
PROGRAMS: dict = {}


@functools.partial(jax.jit, static_argnames=("key",))
def table_batch_3d(data, runs, laws, key):
    """[L, B, n_bays] detector peaks and [L, B] peak contact forces [N] of the ``L`` flats
    whose exact 3D tables ``laws`` stacks (:func:`stacked_laws`), each over the ``B`` runs
    (impact positions x realisations); ``key`` names the program in
    :data:`PROGRAMS`."""
    program = PROGRAMS[key][0]

    def one(law):
        out = Autodiff().batch(program, data, law, runs, Histories(instruments=False))
        after = jnp.arange(out["force"].shape[1])[None, :] >= runs.run_in[:, None]
        return out["detector_peak"][:, 0], jnp.max(jnp.where(after, out["force"][..., 0], 0.0),
                                                    axis=-1)

    return jax.lax.map(one, laws)
