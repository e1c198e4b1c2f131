"""Sweep programs kept on disk (wfjax.program.exported): loaded without tracing, the same
results to the bit, and traced as before where they cannot be kept."""

from __future__ import annotations

import collections

import numpy as np
import pytest

import wfjax as wf
from wfjax.program import exported

CONFIG = wf.SimConfig(max_travel_step=2e-3, max_time_step=5e-5)
FLAT = wf.Flat.rounded(0.9e-3, 0.1)
SPEEDS = np.array([60.0, 140.0]) / 3.6


def _sweep(cache_dir):
    sw = wf.sweep(FLAT, SPEEDS, impact_positions=2, contact="hertz-trajectory",
                  track=wf.Track.comparison(), config=CONFIG, progress=False,
                  cache_dir=cache_dir)
    return np.stack([sw.max_force, sw.min_force, sw.loss_of_contact_duration])


def _entries(cache_dir):
    return sorted(p.name for p in cache_dir.glob("sweep-program-*"))


def _traced() -> list[bool]:
    """Whether this process traced each sweep program it holds."""
    return [p.traced for p in exported._LOADED.values() if isinstance(p, exported._Loaded)]


def test_a_kept_program_loads_without_tracing_and_gives_the_same_bits(tmp_path, monkeypatch):
    monkeypatch.setattr(exported, "_LOADED", collections.OrderedDict())
    first = _sweep(tmp_path)
    assert len(_entries(tmp_path)) == 1 and _traced() == [True]
    monkeypatch.setattr(exported, "_LOADED", collections.OrderedDict())  # as a new process

    def no_trace(*args):
        raise AssertionError("traced although the program was kept")

    monkeypatch.setattr(exported, "_flat_program", no_trace)
    second = _sweep(tmp_path)
    assert _traced() == [False]
    np.testing.assert_array_equal(second, first)
    assert np.all(first[0] > 1e5)  # max forces of a 0.9 mm flat: 100-300 kN


def test_a_program_without_serialization_is_traced(tmp_path, monkeypatch):
    """Without the flatbuffers package jax.export cannot serialize: the sweep traces its
    program as before and keeps nothing."""
    monkeypatch.setattr(exported, "_LOADED", collections.OrderedDict())

    def missing(self, *args, **kwargs):
        raise ModuleNotFoundError("No module named 'flatbuffers'")

    monkeypatch.setattr(exported.jax.export.Exported, "serialize", missing)
    result = _sweep(tmp_path)
    assert _entries(tmp_path) == [] and _traced() == [True]
    assert np.all(np.isfinite(result))


def test_without_flatbuffers_nothing_is_exported(tmp_path, monkeypatch):
    """Where flatbuffers is not installed the programs are traced once, as jits: no export
    is traced first only to fail at serialization."""
    monkeypatch.setattr(exported, "_LOADED", collections.OrderedDict())
    monkeypatch.setattr(exported, "_serializable", lambda: False)

    def no_export(*a, **k):
        raise AssertionError("exported although it cannot be serialized")

    monkeypatch.setattr(exported.jax.export, "export", no_export)
    assert np.all(np.isfinite(_sweep(tmp_path)))
    assert _entries(tmp_path) == [] and _traced() == [True]
    assert np.all(np.isfinite(_sweep(tmp_path)))  # the same process finds its program again
    assert _traced() == [True]


def test_a_structure_that_could_hide_a_value_is_not_keyed():
    """A pytree whose static part prints an array truncated ('...') or an object's address
    cannot key a kept program: two such structures could print alike."""
    import jax

    mesh = jax.sharding.Mesh(np.array(jax.devices()[:1]), ("runs",))
    closure = jax.tree_util.tree_structure(jax.tree_util.Partial(lambda x: x, np.zeros(3)))
    assert "0x" in str(closure)  # <function <lambda> at 0x...>
    assert exported._key(closure, [np.zeros(3)], mesh, ()) is None
    safe = jax.tree_util.tree_structure({"a": np.zeros(3)})
    key = exported._key(safe, [np.zeros(3)], mesh, (5, "float64"))
    assert key is not None and key["leaves"] == ["float64[3]"]


@pytest.mark.parametrize("change", ["sources", "statics", "devices"])
def test_the_key_changes_with_what_shapes_the_program(change, monkeypatch):
    import jax

    from wfjax._cache import key_hash

    mesh = jax.sharding.Mesh(np.array(jax.devices()[:1]), ("runs",))
    tree = jax.tree_util.tree_structure({"a": 0.0})
    base = key_hash("p", exported._key(tree, [np.zeros(2)], mesh, (1,)))
    if change == "sources":
        monkeypatch.setattr(exported, "sources_hash", lambda: "an edited package")
        other = exported._key(tree, [np.zeros(2)], mesh, (1,))
    elif change == "statics":
        other = exported._key(tree, [np.zeros(2)], mesh, (2,))
    else:
        other = exported._key(tree, [np.zeros(2)], mesh, (1,)) | {"devices": 2}
    assert key_hash("p", other) != base


def test_a_kept_laws_batch_loads_without_tracing(tmp_path, monkeypatch):
    """prepare_batch's compiled batch of laws (kept_jit): the second process loads it, its
    output pytree (wfjax law types) rebuilt, the same bits."""
    import jax

    from wfjax.program.laws import prepare_batch

    flats = [wf.Flat.rounded(0.6e-3, 0.08), wf.Flat.rounded(0.9e-3, 0.1)]
    args = ("hertz-trajectory", flats, wf.Wheel(), wf.Track(), wf.Material(), CONFIG,
            tmp_path)
    monkeypatch.setattr(exported, "_LOADED", collections.OrderedDict())
    first, _ = prepare_batch(*args)
    assert len(list(tmp_path.glob("program-*"))) == 1
    monkeypatch.setattr(exported, "_LOADED", collections.OrderedDict())

    def no_export(*a, **k):
        raise AssertionError("traced although the program was kept")

    monkeypatch.setattr(exported.jax.export, "export", no_export)
    second, _ = prepare_batch(*args)
    assert jax.tree.structure(second) == jax.tree.structure(first)
    for a, b in zip(jax.tree.leaves(first), jax.tree.leaves(second), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_the_tree_unpickler_admits_only_tree_types():
    """A kept output structure is read back only if it names JAX's tree classes and wfjax's
    types: anything else (here a class of this test module) is refused."""
    import pickle

    import jax

    @jax.tree_util.register_static
    class Foreign:
        def __hash__(self):
            return 0

        def __eq__(self, other):
            return isinstance(other, Foreign)

    globals()["Foreign"] = Foreign  # picklable by name
    Foreign.__qualname__ = "Foreign"
    ok = jax.tree.structure({"a": (1.0, [2.0])})
    assert exported._out_tree(np.frombuffer(pickle.dumps(ok), np.uint8)) == ok
    law = jax.tree.structure(wf.Flat.rounded(0.9e-3, 0.1))
    assert exported._out_tree(np.frombuffer(pickle.dumps(law), np.uint8)) == law
    foreign = jax.tree.structure({"x": Foreign()})
    assert exported._out_tree(np.frombuffer(pickle.dumps(foreign), np.uint8)) is None


def test_a_kept_simulation_loads_without_tracing(tmp_path, monkeypatch):
    """wf.simulate's run (Program.history) is kept too: loaded without export, the same
    histories to the bit, with the loop's compiler options."""
    def run():
        r = wf.simulate(FLAT, float(SPEEDS[0]), contact="hertz-trajectory",
                        impact_position=0.1, track=wf.Track.comparison(), config=CONFIG,
                        cache_dir=tmp_path)
        return np.stack([r.force, r.rail_disp])

    monkeypatch.setattr(exported, "_LOADED", collections.OrderedDict())
    first = run()
    assert len(list(tmp_path.glob("program-*"))) == 1
    monkeypatch.setattr(exported, "_LOADED", collections.OrderedDict())

    def no_export(*a, **k):
        raise AssertionError("traced although the program was kept")

    monkeypatch.setattr(exported.jax.export, "export", no_export)
    np.testing.assert_array_equal(run(), first)
    assert np.max(first[0]) > 1e5  # the impact's force [N]


def test_loaded_programs_are_bounded(tmp_path, monkeypatch):
    """A process keeps at most MAX_LOADED_PROGRAMS programs, the least recently used dropped:
    each holds its machine code in memory maps, and simulating speed after speed (each a
    program of its own step count) grew a process by ~300 maps a speed, towards the kernel's
    65,530. Counted here in kept programs and in the process's memory maps (24 small
    programs: about 260 more maps if all are kept, under 20 with two)."""
    import jax.numpy as jnp

    monkeypatch.setattr(exported, "_LOADED", collections.OrderedDict())
    monkeypatch.setattr(exported, "MAX_LOADED_PROGRAMS", 2)

    def kept(n):  # host arrays in and out: no op-by-op compilation in the count
        return exported.kept_jit(lambda a: {"y": jnp.cumsum(a) * 2.0}, (np.zeros(n),), (n,),
                                 tmp_path)

    def maps():
        with open("/proc/self/maps") as f:
            return sum(1 for _ in f)

    first = kept(3)
    assert float(first(np.ones(3))["y"][-1]) == 6.0
    kept(4)(np.ones(4))
    assert kept(3) is first  # used again: now the most recent
    kept(5)(np.ones(5))  # drops n = 4, the least recently used
    assert len(exported._LOADED) == 2 and kept(3) is first
    before = maps()
    for n in range(6, 30):
        kept(n)(np.ones(n))
    assert len(exported._LOADED) == 2
    assert maps() - before < 120
