"""The contact laws, structure inputs and roughness of a program, prepared on the host.

A program batches the flats of a scenario along a leading flat axis in groups that each
compile once (:func:`batch_groups`): a kind's flats through a law whose geometry is a traced
leaf (:func:`prepare_batch`), or every flat with an exact 3D table (:func:`table_laws`, their
tables widened to one shape). The other wheels of a vehicle keep their own fixed laws
(:func:`vehicle_laws`). Support realisations are one padded modal model
(:func:`padded_models`); roughness realisations are a leading axis of the loop's roughness
(:func:`loop_roughness`, :func:`realisation`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._xla import to_device
from ..contact.interpolation import ContactTable, pad_columns
from ..contact.laws import prepare, prepare_family, resolve_mode_3d
from ..contact.table_law import TableLaw, table_specs_3d
from ..params import Flat, Material, SimConfig, Track, Wheel
from ..scenario import patch
from .exported import kept_jit

__all__ = ["BatchGroup", "batch_groups", "common_extent", "prepare_batch", "stack",
           "table_laws", "table_laws_like", "padded_models", "pick_model", "realisation",
           "loop_roughness", "vehicle_laws"]


class BatchGroup(NamedTuple):
    """Flats of a sweep that share one compiled program.

    Attributes:
        indices: the flats' indices in the sweep's list.
        tables: the flats' exact 3D tables, widened to one shape (:func:`table_laws`).
    """

    indices: list[int]
    tables: bool = False


def batch_groups(flats: Sequence[Flat], contact: str, config: SimConfig) -> list[BatchGroup]:
    """The flats' groups, each one compiled program.

    Laws whose geometry is a traced leaf (Hertz, 2D bedding, the parametric 3D family) batch
    every new or rounded flat of one kind. The exact 3D tables (``contact_mode_3d="table"``,
    measured profiles and smooth wheels with 3D contact, and under ``"auto"`` a kind with one
    geometry) batch all together, whatever their kinds: their tables are widened to one shape.
    The direct 3D mode, and measured profiles and smooth wheels with the other models, run
    one flat per program.
    """
    mode = config.contact_mode_3d if contact == "3d" else None
    kinds: dict[str, list[int]] = {}
    tables, singles = [], []
    for i, flat in enumerate(flats):
        if mode == "direct":
            singles.append(i)
        elif flat.kind in ("new", "rounded") and mode != "table":
            kinds.setdefault(flat.kind, []).append(i)
        elif contact == "3d":
            tables.append(i)
        else:
            singles.append(i)
    if mode == "auto":  # a kind with one geometry uses its exact table
        for kind in [k for k, members in kinds.items() if len(members) == 1]:
            tables += kinds.pop(kind)
    return ([BatchGroup(members) for members in kinds.values()]
            + ([BatchGroup(sorted(tables), tables=True)] if tables else [])
            + [BatchGroup([i]) for i in singles])


def common_extent(flats: Sequence[Flat]) -> list[Flat]:
    """``flats`` with the largest half extent as ``extent_bound``: the same simulation windows
    for every flat, as :func:`prepare_batch` gives a batch (geometry unchanged)."""
    bound = max(f.half_extent for f in flats)
    return [dataclasses.replace(f, extent_bound=bound) for f in flats]


def prepare_batch(contact: str, flats: Sequence[Flat], wheel: Wheel, track: Track,
                  material: Material, config: SimConfig, cache_dir=None,
                  progress: bool = False):
    """Contact laws of ``flats`` (one kind, or one flat) stacked along a leading flat axis.

    The concrete work (node sets, trajectory grids, the 3D family) is done once for the whole
    batch; the geometry enters through ``jax.vmap`` over the stacked flats, so the laws'
    geometry leaves are traced and one compiled program serves every flat. Windows are sized
    by the largest flat of the batch (``extent_bound``). (A group of exact 3D tables is
    stacked by :func:`table_laws`.)

    Returns:
        (laws with leaves [n_flats, ...], [n_flats] the flats that size each one's
        simulation windows).
    """
    sized = common_extent(flats)
    family = None
    if contact == "3d":
        if resolve_mode_3d(config, batched=len(flats) > 1) != "parametric":
            (flat,) = flats  # the direct mode: batch_groups gives one flat per group
            law = prepare(contact, flat, wheel, track, material, config, cache_dir)
            return stack([law]), [flat]
        family = prepare_family(flats, wheel, track, material, config, cache_dir, progress)
    max_depth = max(float(np.max(np.asarray(f.depth))) for f in flats)
    stacked = stack(sized)

    def prepare_one(flat, family):
        return prepare(contact, flat, wheel, track, material, config, cache_dir, family=family,
                       max_depth=max_depth)

    # Compiled (kept on disk: wfjax.program.exported) rather than run op by op: the
    # parametric law reads the family at a few hundred positions per flat (7.6 s eagerly for
    # the Fig. 8 set).
    program = kept_jit(jax.vmap(prepare_one, in_axes=(0, None)), (stacked, family),
                       (contact, wheel, track, material, config, max_depth), cache_dir)
    return program(stacked, family), [sized[0]] * len(flats)


def stack(trees):
    """Pytrees of equal structure and shapes stacked along a new leading (flat) axis."""
    return jax.tree.map(lambda *xs: jnp.stack([jnp.asarray(x) for x in xs]), *trees)


def table_laws(tables) -> TableLaw:
    """The laws of a group's exact 3D tables ([n_flats] :class:`ContactTable`), each widened
    to the most columns among them (:func:`wfjax.contact.interpolation.pad_columns`), stacked."""
    n_s = max(int(t.onset.shape[0]) for t in tables)
    return jax.tree.map(lambda *xs: to_device(np.stack([np.asarray(x) for x in xs])),
                        *[TableLaw(pad_columns(t, n_s)) for t in tables])


def table_laws_like(flats: Sequence[Flat], wheel: Wheel, track: Track, material: Material,
                     config: SimConfig):
    """Zeros shaped as :func:`table_laws` of the flats' tables (for compiling ahead: the
    tables' layouts, :func:`wfjax.contact.table_law.table_specs_3d`, are known before they are
    built)."""
    specs = table_specs_3d(flats, float(wheel.radius), float(track.rail_head_radius), material,
                           config.contact_element)
    n, n_s, n_t = len(flats), max(sp.n_s for sp in specs), specs[0].n_t
    scalar = np.zeros(n)
    return TableLaw(ContactTable(s_min=scalar, ds=scalar, c_max=scalar,
                                 onset=np.zeros((n, n_s)), force=np.zeros((n, n_s, n_t)),
                                 slope=np.zeros((n, n_s, n_t)), converged=scalar,
                                 stretch=scalar))


def padded_models(tracks, config: SimConfig, cache_dir=None):
    """The modal models of support realisations ``tracks`` [R] stacked along a leading axis,
    every one padded to the largest mode count with zero-weight, zero-shape modes (pole -1
    rad/s: they carry no load and add nothing), so one compiled program serves them.

    The rails must share their mesh and residual table layout (same ``n_bays``,
    ``elements_per_bay``, ``sleeper_spacing``; all uniform or all varying supports).

    Returns:
        :class:`wfjax.model.track.ModalModel` with array fields [R, ...] (``sleeper_spacing`` and
        ``element_phi`` shared).
    """
    from ..model import track as track_mod

    models = [track_mod.modal_model(tr, max_frequency=config.resolved().track_max_frequency,
                                    cache_dir=cache_dir) for tr in tracks]
    first = models[0]
    for i, m in enumerate(models):
        if (m.node_x.shape != first.node_x.shape or m.residual_x.shape != first.residual_x.shape
                or float(m.sleeper_spacing) != float(first.sleeper_spacing)
                or not np.allclose(np.asarray(m.residual_x), np.asarray(first.residual_x))):
            raise ValueError(f"tracks[{i}]: support realisations must share the rail mesh and "
                             f"residual table of tracks[0] (n_bays, elements_per_bay, "
                             f"sleeper_spacing; all uniform or all varying supports)")
    n = max(int(m.poles.shape[0]) for m in models)

    def pad(a, fill):
        a = np.asarray(a)
        extra = np.full((n - a.shape[0],) + a.shape[1:], fill, dtype=a.dtype)
        return np.concatenate([a, extra])

    def stack(name, fill):
        return to_device(np.stack([pad(getattr(m, name), fill) for m in models]))

    sleeper = (None if first.sleeper_shapes is None else stack("sleeper_shapes", 0.0))
    return first._replace(
        poles=stack("poles", -1.0 + 0j), weights=stack("weights", 0.0),
        shapes=stack("shapes", 0.0), sleeper_shapes=sleeper,
        node_x=to_device(np.stack([np.asarray(m.node_x) for m in models])),
        residual_x=to_device(np.stack([np.asarray(m.residual_x) for m in models])),
        residual=to_device(np.stack([np.asarray(m.residual) for m in models])))


_MODEL_BATCHED = ("poles", "weights", "shapes", "sleeper_shapes", "node_x", "residual_x",
                  "residual")


def pick_model(models, index):
    """Realisation ``index`` of :func:`padded_models`' stack."""
    return models._replace(**{k: getattr(models, k)[index] for k in _MODEL_BATCHED
                              if getattr(models, k) is not None})


def realisation(rough, index):
    """The loop roughness of realisation ``index`` (a rail profile's ``values [R, n]``)."""
    if rough is None:
        return None
    rail = rough.rail
    if rail is not None and jnp.ndim(rail.values) == 2:
        rail = dataclasses.replace(rail, values=rail.values[index])
    wheel = rough.wheel
    if wheel is not None and jnp.ndim(wheel.values) == 2:
        wheel = dataclasses.replace(wheel, values=wheel.values[index])
    return rough._replace(rail=rail, wheel=wheel)



def loop_roughness(rail=None, wheel=None, wheels=None, track: Track | None = None,
                   material: Material | None = None):
    """The time loop's :class:`wfjax.scenario.patch.LoopRoughness` (None when both are None) of
    a rail and a wheel roughness checked by :class:`wfjax.scenario.description.Scenario`.

    The contact filter's length (point-contact laws) is each wheel's static Hertz contact
    length (:func:`~wfjax.scenario.patch.static_contact_length` at its preload, on the Hertz
    radius sqrt(R_W R_R)), 13.1 mm for the default wheel and track: the patch the wheel rolls on
    between impacts, where roughness excites it.

    Args:
        rail: rail :class:`wfjax.Roughness` (``values [n]`` or, for
            :func:`wfjax.sweep`'s Monte Carlo, ``[R, n]``) or None.
        wheel: wheel roughness (periodic) or None. wheels: [n_wheels] :class:`Wheel`
            (default: one default wheel). track, material: as :func:`wfjax.simulate`.
    """
    if rail is None and wheel is None:
        return None
    from ..contact.laws import hertz_radius

    wheels = wheels or [Wheel()]
    track, material = track or Track(), material or Material()
    length = np.array([float(patch.static_contact_length(
        float(w.preload), material, float(hertz_radius(w, track)))) for w in wheels])
    return patch.LoopRoughness(rail, wheel, jnp.asarray(length))



def vehicle_laws(contact: str, flats: list, wheels: list[Wheel], track: Track,
                 material: Material, config: SimConfig, cache_dir=None) -> tuple:
    """[n] contact laws of the vehicle's wheels (one per distinct flat and wheel radius;
    None where the flat is None)."""
    laws, done = [], {}
    for f, w in zip(flats, wheels, strict=True):
        if f is None:
            laws.append(None)
            continue
        key = (id(f), float(w.radius)) if f.kind != "none" else ("none", float(w.radius))
        if key not in done:
            done[key] = prepare(contact, f, w, track, material, config, cache_dir)
        laws.append(done[key])
    return tuple(laws)

