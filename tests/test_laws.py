"""The contact-law interface: laws are pytrees, batch over geometry, and the loop is open."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import wfjax as wf
from wfjax.contact import interpolation, laws, table_law, tables
from wfjax.contact.protocol import ContactLaw
from wfjax.fields import pytree
from wfjax.loop.run import run_scan
from wfjax.loop.structure import structure
from wfjax.model.vehicle import Vehicle
from wfjax.program.laws import common_extent, prepare_batch
from wfjax.scenario.windows import n_steps_for, run_windows, simulation_window

COARSE = wf.SimConfig(max_travel_step=2e-3, max_time_step=5e-5,
                       precision="float64")  # batch = single runs to rounding: float64
MODEL = (wf.Wheel(), wf.Track.comparison(n_bays=24), wf.Material(), COARSE)
FLATS = [wf.Flat.rounded(0.6e-3, 0.08), wf.Flat.rounded(0.9e-3, 0.1),
         wf.Flat.rounded(1.2e-3, 0.12)]


@pytest.mark.parametrize("contact", ["hertz-trajectory", "hertz-profile", "2d"])
def test_batched_laws_equal_one_law_per_flat(contact):
    """vmap over prepare() gives, flat by flat, the law prepared for that flat alone."""
    laws_b, _ = prepare_batch(contact, FLATS, *MODEL)
    for i, flat in enumerate(common_extent(FLATS)):
        single = laws.prepare(contact, flat, *MODEL, max_depth=1.2e-3)
        picked = jax.tree.map(lambda a, i=i: a[i], laws_b)
        for delta in (50e-6, 0.2e-3, 0.6e-3):
            for s in (-0.06, -0.01, 0.0, 0.013, 0.05):
                assert float(picked.force(delta, s)) == pytest.approx(
                    float(single.force(delta, s)), rel=1e-9, abs=1e-6)


@pytest.mark.slow
def test_sweep_over_depths_is_one_program_equal_to_single_runs(monkeypatch):
    """A depth batch compiles once and each flat's result equals its own simulate()."""
    import importlib

    core = importlib.import_module("wfjax.program.core")
    speeds, positions = np.array([60.0, 140.0]) / 3.6, np.array([0.2])
    programs, program = [], core.sharded_program
    monkeypatch.setattr(core, "sharded_program",
                        lambda *args: programs.append(args) or program(*args))
    sw = wf.sweep(FLATS, speeds, positions, contact="hertz-trajectory", track=MODEL[1],
                  config=COARSE, progress=False)
    assert len(programs) == 1
    sized = common_extent(FLATS)
    for i, flat in enumerate(sized):
        for j, v in enumerate(speeds):
            r = wf.simulate(flat, float(v), contact="hertz-trajectory", impact_position=0.2,
                            track=MODEL[1], config=COARSE)
            assert sw.max_force[i, j, 0] == pytest.approx(float(r.max_force), rel=1e-9)
    assert np.allclose(sw.depths, [f.depth for f in FLATS])
    assert "depth_mm" in sw.to_csv().splitlines()[0]


def test_gradient_reaches_geometry_through_a_batched_law():
    """d(max force)/d(depth) of a vmapped batch of flats equals central finite differences."""
    wheel, track, material, config = MODEL
    struct = structure(Vehicle.single(), [wheel], track, config)
    v, pos = 100 / 3.6, 0.2
    ref = dataclasses.replace(FLATS[-1], extent_bound=0.07)
    n, dt = n_steps_for(ref, v, config)
    s0, _ = simulation_window(ref, v, config)

    def max_forces(depths):
        def one(depth):
            flat = wf.Flat("rounded", depth, 0.1, extent_bound=0.07)
            law = laws.prepare("hertz-profile", flat, wheel, track, material, config)
            return jnp.max(run_scan(law, struct, v, dt, pos + s0, pos, n)["force"])

        return jax.vmap(one)(depths)

    d = jnp.array([0.7e-3, 1.0e-3])
    jac = jax.jacfwd(max_forces)(d)
    h = 1e-7
    for k in range(2):
        e = jnp.zeros(2).at[k].set(h)
        fd = (max_forces(d + e) - max_forces(d - e)) / (2 * h)
        assert float(jac[k, k]) == pytest.approx(float(fd[k]), rel=2e-3)
        assert float(jac[1 - k, k]) == 0.0  # runs of a batch are independent


@pytree
class LinearSpring(ContactLaw):
    """A test law outside wfjax.contact: F = k max(delta, 0) (no flat)."""

    stiffness: float

    def point(self, s):
        return jnp.zeros(())

    def point_force(self, point, delta):
        return self.stiffness * jnp.maximum(delta - point, 0.0)


def test_time_loop_takes_any_law():
    """The time loop knows only the protocol: a user-defined law runs and reaches statics."""
    wheel, track, _, config = MODEL
    struct = structure(Vehicle.single(), [wheel], track, config)
    law = LinearSpring(1.0e9)
    hist = run_scan(law, struct, 20 / 3.6, 1e-4, 0.1, 0.3, 200)
    force = np.asarray(hist["force"])
    assert np.allclose(force[0], 118e3)
    # a smooth contact on a discretely supported rail: the force stays near the preload
    assert np.max(np.abs(force / 118e3 - 1)) < 0.05
    assert float(hist["approach"][0]) == pytest.approx(118e3 / 1.0e9, rel=1e-9)


def test_prepare_rejects_unknown_models_and_mixed_family_kinds():
    with pytest.raises(ValueError, match="contact must be one of"):
        laws.prepare("4d", FLATS[0], *MODEL)
    with pytest.raises(ValueError, match="one kind"):
        laws.prepare_family([FLATS[0], wf.Flat.new(0.9e-3)], *MODEL)


def test_sweep_name_is_unambiguous():
    """``from wfjax import sweep`` is the function; the module is ``wfjax.sweeps``."""
    import wfjax.sweeps
    from wfjax import sweep

    assert callable(sweep) and sweep is wfjax.sweeps.sweep


@pytest.mark.slow  # the default run must stay under 10 min (2 cores)
def test_parametric_law_reads_the_family_and_batches():
    """ParametricLaw's table is the family at s_j = j h (exactly, onsets included), batched over
    depths, and close to it between the s_j."""
    from wfjax.contact import family

    wheel, track, material, _ = MODEL
    h = 2.5e-3
    config = wf.SimConfig(contact_element=h)
    fam = laws.prepare_family_range("rounded", [0.6e-3, 0.9e-3], [1.76], wheel, track,
                                    material, config)
    depths = jnp.array([0.6e-3, 0.75e-3, 0.9e-3])
    lengths = 1.76 * jnp.sqrt(8 * 0.45 * depths)
    batch = jax.vmap(lambda d, ln: laws.parametric_law(fam, d, ln))(depths, lengths)
    for i in range(3):
        law = jax.tree.map(lambda a, i=i: a[i], batch)
        for si in np.arange(-36, 37, 3) * h / 2:  # on and between the s_j
            ref = family.family_column(fam, si, depths[i], lengths[i])
            delta = ref.onset + 0.1e-3
            f_ref = float(family.family_force(fam, delta, si, depths[i], lengths[i]))
            if si / h == round(si / h):
                assert float(law.point(si).onset) == pytest.approx(float(ref.onset), abs=1e-15)
                assert float(law.force(delta, si)) == pytest.approx(f_ref, rel=1e-12)
            else:
                assert abs(float(law.force(delta, si)) - f_ref) < 0.01 * max(f_ref, 50e3)


@pytest.mark.slow
def test_parametric_fig8_subset_matches_exact_tables():
    """Fig. 8 flats between family nodes (0.75, 1.5 mm; l = 1.76 l0): batched through the
    parametric family, max force within 0.5 % of each flat's exact table and the same loss
    of contact (the full set is benchmarks/bench_fig8.py --accuracy)."""
    flats = common_extent([wf.Flat.rounded_relative(d, 1.76) for d in (0.75e-3, 1.5e-3)])
    speeds = np.array([40.0, 100.0, 160.0, 220.0]) / 3.6
    runs = {mode: wf.sweep(flats, speeds, 4, contact="3d", track=wf.Track.comparison(),
                           config=wf.SimConfig(contact_mode_3d=mode), progress=False)
            for mode in ("parametric", "table")}
    ratio = runs["parametric"].max_force / runs["table"].max_force
    assert np.max(np.abs(ratio - 1)) < 0.005, ratio
    assert np.array_equal(runs["parametric"].loss_of_contact, runs["table"].loss_of_contact)
    assert runs["table"].loss_of_contact.any()  # the comparison includes loss of contact


def test_table_cache_key_holds_the_builder_revision(tmp_path, monkeypatch):
    """A builder change within one wfjax version is never served from an older cache file."""
    flat = wf.Flat.rounded(0.5e-3, 0.08)
    args = (flat, 0.45, 0.45, wf.Material(), 2.5e-3, tmp_path)
    table_law.cached_table_3d(*args)
    table_law.cached_table_3d(*args)  # loads
    assert len(list(tmp_path.glob("table3d-*"))) == 1
    monkeypatch.setattr(table_law, "TABLE_BUILDER_REVISION", table_law.TABLE_BUILDER_REVISION + 1)
    table_law.cached_table_3d(*args)  # a new key: built again, not the old file
    assert len(list(tmp_path.glob("table3d-*"))) == 2


def test_batch_groups_put_every_exact_table_in_one_group():
    """Exact 3D tables batch together whatever the flats' kinds; the family by kind; the
    direct mode and the other models' measured profiles one flat per program."""
    from wfjax.program.laws import BatchGroup, batch_groups

    x = np.linspace(-0.05, 0.05, 41)
    profile = wf.Flat.from_profile(x, 0.5e-3 * np.cos(np.pi * x / 0.1) ** 2)
    flats = [wf.Flat.rounded(0.9e-3, 0.1), wf.Flat.new(0.9e-3), profile,
             wf.Flat.new(0.5e-3), wf.Flat.new(0.7e-3)]
    auto, table = wf.SimConfig(), wf.SimConfig(contact_mode_3d="table")
    assert batch_groups(flats, "3d", auto) == [BatchGroup([1, 3, 4]), BatchGroup([0, 2], True)]
    assert batch_groups(flats, "3d", table) == [BatchGroup([0, 1, 2, 3, 4], True)]
    assert batch_groups(flats, "3d", wf.SimConfig(contact_mode_3d="direct")) == [
        BatchGroup([i]) for i in range(5)]
    assert batch_groups(flats, "2d", auto) == [BatchGroup([0]), BatchGroup([1, 3, 4]),
                                              BatchGroup([2])]


def test_widened_table_gives_the_same_forces():
    """pad_columns repeats the end columns: the same forces inside and beyond the s range."""
    table = table_law.cached_table_3d(wf.Flat.new(0.9e-3), 0.45, 0.3, wf.Material(), 2e-3)
    n = table.onset.shape[0]
    wide = interpolation.pad_columns(table, n + 13)
    assert wide.force.shape == (n + 13, table.force.shape[1])
    s = np.concatenate([np.linspace(-0.09, 0.09, 37), [0.0, 1e-3, -0.0317]])
    for delta in (0.05e-3, 0.2e-3, 0.5e-3):
        for si in s:
            f = float(interpolation.table_force(table, delta, si))
            assert float(interpolation.table_force(wide, delta, si)) == pytest.approx(
                f, rel=1e-12, abs=1e-9)
    with pytest.raises(ValueError, match="n_s"):
        interpolation.pad_columns(table, n - 1)


@pytest.mark.slow
def test_exact_tables_of_two_kinds_run_as_one_program(tmp_path, monkeypatch):
    """A rounded and a new flat with exact 3D tables: one compiled program for both, and each
    flat's extremes equal its own simulate() in its own windows (the new flat's are shorter:
    the steps beyond them are not counted)."""
    import importlib

    core = importlib.import_module("wfjax.program.core")
    config = wf.SimConfig(contact_element=2e-3, max_travel_step=2e-3, max_time_step=5e-5,
                          precision="float64")
    track = wf.Track()
    flats = [wf.Flat.rounded(0.9e-3, 0.1), wf.Flat.new(0.9e-3)]
    speeds, position = np.array([120.0]) / 3.6, 0.2
    compiled = []
    program = core.sharded_program
    monkeypatch.setattr(core, "sharded_program",
                        lambda *args: compiled.append(args) or program(*args))
    sw = wf.sweep(flats, speeds, [position], contact="3d", track=track, config=config,
                  progress=False, cache_dir=tmp_path)
    assert len(compiled) == 1  # one program (compiled ahead for the tables' predicted shapes)
    own = [run_windows(flat, speeds, config)[0][0] for flat in flats]
    assert own[1] < own[0]
    for i, flat in enumerate(flats):
        for j, v in enumerate(speeds):
            r = wf.simulate(flat, float(v), contact="3d", impact_position=position,
                            track=track, config=config, cache_dir=tmp_path)
            assert sw.max_force[i, j, 0] == pytest.approx(float(r.max_force), rel=1e-9)
            assert sw.min_force[i, j, 0] == pytest.approx(float(r.min_force), rel=1e-9,
                                                          abs=1.0)


def test_tables_built_together_equal_tables_built_alone(tmp_path):
    """cached_tables_3d builds the missing tables together (one set of window sizes): each
    equals its table built alone within the solver's tolerance (relative, float32 solves:
    tables.WINDOWED_TOL), and lands in the cache."""
    flats = [wf.Flat.rounded(0.9e-3, 0.1), wf.Flat.new(0.9e-3)]
    together = table_law.cached_tables_3d(flats, 0.45, 0.3, wf.Material(), 2e-3, tmp_path)
    assert len(list(tmp_path.glob("table3d-*"))) == 2
    for flat, table in zip(flats, together, strict=True):
        alone = tables.build_table_3d(flat, 0.45, 0.3, wf.Material(), element_size=2e-3)
        assert float(table.converged) == 1.0
        np.testing.assert_allclose(table.force, alone.force, rtol=0,
                                   atol=2 * tables.WINDOWED_TOL * float(np.max(alone.force)))
        loaded = table_law.cached_table_3d(flat, 0.45, 0.3, wf.Material(), 2e-3, tmp_path)
        np.testing.assert_array_equal(loaded.force, table.force)


@pytest.mark.slow  # the default run must stay under 10 min (2 cores)
def test_direct_mode_windows_equal_the_whole_grid(tmp_path):
    """The direct 3D mode solves each iterate on a window of its overlap: the same forces as
    on the whole grid, through an impact, and beyond the table's compression range (where the
    window falls back to the whole grid)."""
    from wfjax.contact import direct3d, geometry3d, kalker

    wheel, track = wf.Wheel(), wf.Track.comparison()
    config = dataclasses.replace(wf.SimConfig(), contact_element=2.5e-3,
                                 contact_mode_3d="direct")
    flat = wf.Flat.rounded(0.9e-3, 0.1)
    law = direct3d.prepare_direct(flat, wheel, track, wf.Material(), config, tmp_path)
    assert max(w[0] * w[1] for w in law.window_sizes) < law.layout.nx * law.layout.ny
    whole = law.on_whole_grid()
    layout = law.layout
    for s, c in [(-0.06, 1e-4), (-0.02, 3e-4), (0.0, 2e-4), (0.03, 2 * layout.c_max)]:
        delta = float(interpolation.table_onset(law.table, s)) + c
        p0 = jnp.zeros((layout.nx, layout.ny))
        f_w = float(law._evaluate(s, delta, p0)[0])
        gap = geometry3d.gap_3d(flat, s, layout.x, layout.y, layout.wheel_radius,
                            layout.rail_head_radius)
        ref = kalker.solve(gap, layout.element_size, layout.element_size, wf.Material(),
                           approach=delta, tol=direct3d.KALKER_TOL, validate=False)
        assert f_w == pytest.approx(float(ref.force), rel=1e-8), (s, c)
    struct = structure(Vehicle.single(), [wheel], track, config)
    runs = [np.asarray(run_scan(lw, struct, 80 / 3.6, 1e-4, 0.0, 0.12, 150,
                                   config.newton_iterations)["force"]) for lw in (law, whole)]
    assert runs[0].max() > 1.3 * 118e3  # through the impact
    np.testing.assert_allclose(runs[0], runs[1], rtol=0, atol=1e-8 * runs[1].max())
