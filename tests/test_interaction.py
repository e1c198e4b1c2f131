"""The time loop: static start, smooth wheel, kinematics, batching, gradients, convergence."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import wfjax as wf
from wfjax.contact import laws
from wfjax.loop.run import LOOP_BLOCK, run_scan
from wfjax.loop.structure import node_major_shapes, rail_terms, structure
from wfjax.model.vehicle import Vehicle
from wfjax.scenario.windows import RUN_IN_TIME, n_steps_for, run_windows, simulation_window

F64 = wf.SimConfig(precision="float64")  # identities to rounding: the float64 loop

ROUNDED = wf.Flat.rounded(0.9e-3, 0.1)
NEW = wf.Flat.new(0.9e-3)


def test_smooth_wheel_keeps_static_load_and_sleeper_passing_frequency():
    v = 50 / 3.6
    res = wf.simulate(wf.Flat.none(), v, contact="hertz-trajectory",
                      config=wf.SimConfig(run_in=1.3, run_out=1.3))
    t, f = np.asarray(res.t), np.asarray(res.force)
    assert f[0] == pytest.approx(118e3, rel=1e-12)  # starts in static equilibrium
    period = 0.65 / v
    settled = t > 0.05
    n_periods = int((t[settled][-1] - t[settled][0]) / period)
    window = settled & (t < t[settled][0] + n_periods * period)
    assert np.mean(f[window]) == pytest.approx(118e3, rel=1e-3)
    variation = np.ptp(f[window]) / 118e3
    assert 1e-4 < variation < 0.05  # small, but present (discrete supports)
    # the variation repeats every sleeper bay: f(t + L_S / v) = f(t), its frequency is v / L_S
    # (the strongest harmonic is the one nearest the track resonance, not necessarily the 1st)
    tw, fw = t[window], f[window]
    later = tw + period < tw[-1]
    shifted = np.interp(tw[later] + period, tw, fw)
    assert np.max(np.abs(shifted - fw[later])) < 0.1 * np.ptp(fw)
    half_shift = np.interp(tw[later] + 0.5 * period, tw, fw)
    assert np.max(np.abs(half_shift - fw[later])) > 0.3 * np.ptp(fw)  # not a shorter period


@pytest.mark.slow
def test_quasi_static_run_follows_rigid_trajectory():
    # at walking speed inertia is negligible: F stays ~P, so the contact compression is the
    # static one and the relative wheel/rail motion reproduces the wheel-centre trajectory
    res = wf.simulate(ROUNDED, 3 / 3.6, contact="hertz-trajectory",
                      config=wf.SimConfig(max_time_step=1e-4, allow_inaccurate=True))
    s = np.asarray(res.s)
    drop = -np.asarray(wf.geometry.centre_trajectory(ROUNDED, s))
    compression = np.asarray(res.approach) - drop
    assert np.ptp(compression) < 0.02 * 0.9e-3
    assert np.max(np.abs(np.asarray(res.force) / 118e3 - 1)) < 0.05


@pytest.mark.slow
def test_loss_of_contact_is_exact():
    res = wf.simulate(NEW, 100 / 3.6, contact="hertz-trajectory", config=F64)
    f = np.asarray(res.force)
    assert bool(res.loss_of_contact) and float(res.min_force) == 0.0
    lost = f == 0.0
    drop = -np.asarray(wf.geometry.centre_trajectory(NEW, np.asarray(res.s)))
    assert np.all(np.asarray(res.approach)[lost] - drop[lost] <= 1e-15)  # no compression
    assert float(res.loss_of_contact_duration) == pytest.approx(lost[
        np.asarray(res.t) >= 0.5 * RUN_IN_TIME].sum() * float(res.time_step))
    assert np.max(np.asarray(res.residual)) < 1e-12


@pytest.mark.slow
def test_sweep_equals_looped_simulate():
    speeds = np.array([40.0, 120.0]) / 3.6
    positions = np.array([0.1, 0.4])
    track = wf.Track(n_bays=24)  # every run's, as given (the default's is lengthened per run)
    sw = wf.sweep(ROUNDED, speeds, positions, contact="2d", progress=False, chunk_size=3,
                  config=F64, track=track)
    for j, v in enumerate(speeds):
        for k, p in enumerate(positions):  # each run in simulate's own window and time step
            r = wf.simulate(ROUNDED, float(v), contact="2d", impact_position=float(p), config=F64,
                            track=track)
            assert sw.max_force[0, j, k] == pytest.approx(float(r.max_force), rel=1e-9)
            assert sw.min_force[0, j, k] == pytest.approx(float(r.min_force), rel=1e-9,
                                                           abs=1e-6)


def test_a_loop_that_stops_early_equals_the_full_loop_on_its_steps():
    """time_loop(n_run=k) computes the steps of the blocks up to step k - 1, bit for bit those
    of the full scan, and leaves zeros after them (what a sweep's chunk skips)."""
    speed, cfg = 60 / 3.6, wf.SimConfig()
    n, dt = n_steps_for(ROUNDED, speed, cfg)
    s0, _ = simulation_window(ROUNDED, speed, cfg)
    struct = structure(Vehicle.single(), [wf.Wheel()], wf.Track(), cfg)
    law = laws.prepare("hertz-trajectory", ROUNDED, wf.Wheel(), wf.Track(), wf.Material(), cfg)
    full = run_scan(law, struct, speed, dt, 0.1 + s0, 0.1, n)
    k = n // 2
    part = run_scan(law, struct, speed, dt, 0.1 + s0, 0.1, n, n_run=k)
    done = 1 + -(-(k - 1) // LOOP_BLOCK) * LOOP_BLOCK  # steps computed, incl. t = 0
    assert k <= done < k + LOOP_BLOCK
    for key in ("force", "approach", "rail_disp", "axle_acc"):
        np.testing.assert_array_equal(np.asarray(part[key])[:done],
                                      np.asarray(full[key])[:done])
        assert not np.any(np.asarray(part[key])[done:])
    whole = run_scan(law, struct, speed, dt, 0.1 + s0, 0.1, n, n_run=n)
    np.testing.assert_array_equal(np.asarray(whole["force"]), np.asarray(full["force"]))


def _max_force_fn(contact, speed, position=0.1):
    cfg, wheel, track, mat = wf.SimConfig(), wf.Wheel(), wf.Track.comparison(), wf.Material()
    n, dt = n_steps_for(ROUNDED, speed, cfg)
    s0, _ = simulation_window(ROUNDED, speed, cfg)
    struct = structure(Vehicle.single(), [wheel], track, cfg)

    def max_force(depth):
        flat = wf.Flat("rounded", depth, 0.1, extent_bound=0.05)
        law = laws.prepare(contact, flat, wheel, track, mat, cfg)
        hist = run_scan(law, struct, speed, dt, position + s0, position, n)
        return jnp.max(hist["force"])

    return max_force


@pytest.mark.parametrize("contact, speed_kmh", [("hertz-trajectory", 60.0),
                                                ("2d", 140.0)])  # 140 km/h: loss of contact
def test_gradient_of_max_force_matches_finite_differences(contact, speed_kmh):
    f = _max_force_fn(contact, speed_kmh / 3.6)
    g = jax.grad(f)(0.9e-3)
    h = 2e-7
    fd = (f(0.9e-3 + h) - f(0.9e-3 - h)) / (2 * h)
    assert g == pytest.approx(float(fd), rel=1e-3)
    assert g > 0  # deeper flats hit harder


@pytest.mark.slow
def test_time_step_convergence_of_max_force():
    """Halving the time step at the defaults changes the max force by < 1 %."""
    values = []
    for scale in (1.0, 0.5, 0.25):
        cfg = wf.SimConfig(max_time_step=2.5e-5 * scale, max_travel_step=0.5e-3 * scale)
        values.append(float(wf.simulate(NEW, 100 / 3.6, contact="hertz-trajectory",
                                        config=cfg, impact_position=0.2).max_force))
    d1, d2 = abs(values[0] - values[1]), abs(values[1] - values[2])
    assert d1 / values[2] < 0.01
    assert d2 < d1  # converging; observed order log2(d1/d2) reported in docs


def test_angle_mapping():
    p = wf.impact_position_from_angle(0.1, start_position=-0.5, wheel_radius=0.45)
    assert p == pytest.approx((-0.5 + 0.045) % 0.65)
    res = wf.simulate(ROUNDED, 80 / 3.6, contact="hertz-profile", angle0=0.3)
    s_start, _ = simulation_window(ROUNDED, 80 / 3.6, wf.SimConfig())
    expected = wf.impact_position_from_angle(0.3, s_start, 0.45, 0.65)
    assert float(res.impact_position) == pytest.approx(float(expected))


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"speed": 0.0}, "speed"),
        ({"speed": float("nan")}, "speed"),
        ({"impact_position": 0.7}, "impact_position"),
        ({"impact_position": -0.1}, "impact_position"),
        ({"contact": "4d"}, "contact"),
        ({"wheel": wf.Wheel(radius=0.46)}, "wheel_radius"),
        ({"n_steps": 1}, "n_steps"),
    ],
)
def test_bad_input(kwargs, message):
    args = {"flat": ROUNDED, "speed": 20.0, "contact": "hertz-profile", **kwargs}
    with pytest.raises(ValueError, match=message):
        wf.simulate(**args)


def test_result_files(tmp_path):
    res = wf.simulate(ROUNDED, 60 / 3.6, contact="hertz-profile")
    lines = res.to_csv().splitlines()
    assert lines[0].startswith("t_s,x_m,s_m,force_N")
    assert len(lines) == np.shape(res.t)[0] + 1
    summary = res.summary()
    assert summary["max_force_kN"] == pytest.approx(float(res.max_force) / 1e3)


@pytest.mark.slow
@pytest.mark.parametrize("flat", [ROUNDED, NEW], ids=["rounded", "new"])
@pytest.mark.parametrize("speed_kmh", [50.0, 100.0])
def test_table_and_direct_3d_agree(flat, speed_kmh):
    track = wf.Track.comparison()
    table = wf.simulate(flat, speed_kmh / 3.6, contact="3d", track=track)
    direct = wf.simulate(flat, speed_kmh / 3.6, contact="3d", track=track,
                         config=wf.SimConfig(contact_mode_3d="direct"))
    assert float(direct.max_force) == pytest.approx(float(table.max_force), rel=5e-3)


@pytest.mark.slow
def test_contact_element_convergence_3d():
    values = [float(wf.simulate(ROUNDED, 100 / 3.6, contact="3d", track=wf.Track.comparison(),
                                config=wf.SimConfig(contact_element=h)).max_force)
              for h in (1e-3, 0.5e-3)]
    assert abs(values[0] - values[1]) / values[1] < 0.01


def test_loop_mode_shapes_equal_track_interpolation():
    model = wf.track.modal_model(wf.Track(),
                                 max_frequency=wf.SimConfig().resolved().track_max_frequency)
    node_major = node_major_shapes(model)
    for x in (-0.9, -0.0001, 0.0, 0.123, 0.325, 1.7):
        phi, res = rail_terms(model, node_major, x)
        np.testing.assert_allclose(phi, wf.track.mode_shapes_at(model, x), rtol=1e-13,
                                   atol=1e-13 * float(jnp.max(jnp.abs(phi))))
        assert float(res) == float(wf.track.residual_compliance_at(model, x))


@pytest.mark.parametrize(("n_runs", "chunk", "n_dev", "layout"),
                         [(80, 64, 1, (40, 40)), (290, 64, 1, (58, 58)), (64, 64, 1, (64, 64)),
                          (6, 4, 2, (3, 4)), (5, 64, 2, (5, 6)), (1, 64, 1, (1, 1))])
def test_chunks_spread_runs_evenly(n_runs, chunk, n_dev, layout):
    from wfjax.program.grid import chunk_layout

    step, width = chunk_layout(n_runs, chunk, n_dev)
    assert (step, width) == layout
    assert step <= chunk and width % n_dev == 0 and width >= step
    assert -(-n_runs // step) == -(-n_runs // chunk)  # no more chunks than needed


def test_sweep_progress_paces_its_eta_by_work(monkeypatch):
    """The ETA follows the work done (run-steps), not the runs: short chunks go first."""
    import io

    from wfjax.program import grid

    clock = iter([0.0, 2.0])
    monkeypatch.setattr(grid.time, "perf_counter", lambda: next(clock))
    out = io.StringIO()
    bar = grid.Progress(4, "runs", stream=out)
    bar.work_total = 10.0
    bar.update(2, 2.0)  # half the runs, a fifth of the work, in 2 s: 8 s to go
    assert "2/4 runs" in out.getvalue() and "ETA   8.0 s" in out.getvalue()


def test_planned_runs_are_sorted_by_steps_and_dealt_to_the_devices():
    """plan_runs sorts the runs by their own step count (each chunk's loop stops at its
    longest), deals every chunk's runs to the devices in turn, and ``order`` maps them back."""
    from wfjax.program import grid

    speeds = np.array([300.0, 40.0, 120.0, 20.0]) / 3.6
    struct = structure(Vehicle.single(), [wf.Wheel()], wf.Track(), wf.SimConfig())
    mesh = grid.device_mesh()
    runs = grid.plan_runs([ROUNDED], speeds, np.array([0.1, 0.3]), struct, wf.SimConfig(),
                             mesh, chunk_size=4)
    steps = runs.columns[6]
    own = run_windows(ROUNDED, speeds, wf.SimConfig())[0]
    np.testing.assert_array_equal(np.sort(steps), np.sort(np.repeat(own, 2)))
    chunks = [steps[lo:lo + runs.step] for lo in range(0, steps.size, runs.step)]
    assert all(a.max() <= b.min() for a, b in zip(chunks[:-1], chunks[1:], strict=True))
    speed_of_run = np.repeat(speeds, 2)  # results order: (flat, speed, position)
    np.testing.assert_array_equal(runs.columns[1], speed_of_run[runs.order])
    back = grid.unsorted(runs.columns[1], runs.order)
    np.testing.assert_array_equal(back, speed_of_run)
