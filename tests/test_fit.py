"""Tests of wfjax.fit: gradients vs finite differences, parametrisations, fits, CLI, notebook.

Gradient checks use a coarser time step than the default (``COARSE``: 1 mm of travel and at
most 50 us per step) to halve the run time; they compare automatic and finite-difference
derivatives of the same discrete model, so the step size does not matter for them.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import wfjax as wf
from wfjax import fit
from wfjax.cli import main
from wfjax.commands.fit import parse_data
from wfjax.contact import laws
from wfjax.loop.run import run_scan
from wfjax.scenario.windows import simulation_window

COARSE = wf.SimConfig(max_travel_step=1e-3, max_time_step=5e-5)
SPEEDS = np.array([40.0, 100.0, 140.0]) / 3.6  # m/s; 140 km/h loses contact (asserted)
BOUND = 0.06  # m, extent bound of the differentiated flats
TH0 = np.array([0.9e-3, 0.1])  # depth, length [m]
REL_TOL = 0.01


def _rounded(th):
    return wf.Flat("rounded", th[0], th[1], extent_bound=BOUND)


def _assert_matches_fd(f, jac, x0, steps):
    """Central differences of vector f at x0 (step per parameter) vs jac [n_out, n_par]."""
    jac = np.atleast_2d(np.asarray(jac).reshape(-1, len(steps)))
    for k, h in enumerate(steps):
        e = np.zeros(len(steps))
        e[k] = h
        fd = (np.asarray(f(x0 + e)) - np.asarray(f(x0 - e))).ravel() / (2 * h)
        col = jac[:, k]
        # relative to each entry, floored at 5 % of the column's largest entry (near-zero
        # sensitivities are compared in absolute terms)
        err = np.abs(fd - col) / np.maximum(np.abs(col), 0.05 * np.max(np.abs(col)))
        assert err.max() < REL_TOL, (k, fd, col, err)


def _min_force(model, speed_index, flat, position=0.1):
    setup, info = model.law, model.info
    law = laws.prepare(setup.contact, flat, setup.wheel, setup.track, setup.material,
                       setup.config)
    v = info["speeds"][speed_index]
    s0 = simulation_window(flat, v, setup.config)[0]
    hist = run_scan(law, model.program.data.struct, v, info["time_steps"][speed_index],
                    position + s0, position, info["n_steps"])
    return float(jnp.min(hist["force"][info["n_steps"] // 4:]))


@pytest.mark.parametrize("contact", ["hertz-trajectory", "hertz-profile", "2d"])
def test_max_force_gradient_matches_finite_differences(contact):
    ref = _rounded(TH0)
    model = fit.max_force_model(SPEEDS, ref, contact, impact_positions=[0.1], temperature=None,
                                config=COARSE)
    f = jax.jit(lambda th: model(_rounded(th)))
    jac = jax.jit(jax.jacfwd(f))(jnp.asarray(TH0))
    # steps well inside the max force's smooth piece: a 0.1 mm length step moved the peak
    # from one sample to the next for hertz-profile at 100 km/h (FD 6 % off, AD exact; the
    # 30 and 10 um steps agree with AD to 2e-6)
    _assert_matches_fd(f, jac, TH0, [1e-7, 1e-5])
    if contact == "hertz-profile":
        assert _min_force(model, 2, ref) == 0.0  # loss of contact at 140 km/h
        assert _min_force(model, 0, ref) > 0.0


@pytest.mark.slow
def test_reverse_mode_history_misfit_gradient():
    """jax.grad (reverse mode) of a force-history misfit w.r.t. depth and length."""
    v = 100 / 3.6
    t = np.linspace(-4e-3, 8e-3, 60)
    model = fit.history_model(t, v, _rounded(TH0), "hertz-trajectory", impact_position=0.2,
                              config=COARSE)
    target = np.asarray(model(_rounded(TH0 * np.array([1.1, 0.95]))))

    def misfit(th):
        return jnp.mean((model(_rounded(th)) - target) ** 2)

    grad = jax.jit(jax.grad(misfit))(jnp.asarray(TH0))
    _assert_matches_fd(jax.jit(misfit), grad[None, :], TH0, [1e-7, 1e-4])


@pytest.mark.slow
def test_profile_shape_gradient_and_smooth_max():
    """Gradient w.r.t. the profile basis coefficients, through a smooth max over positions."""
    par = fit.ProfileParam(half_length=0.06, n_basis=5)
    theta0 = par.from_flat(wf.Flat.rounded(0.9e-3, 0.1))
    ref = jax.tree_util.tree_map(np.asarray, par.to_flat(jnp.asarray(theta0)))
    model = fit.max_force_model([100 / 3.6], ref, "hertz-profile", impact_positions=2,
                                temperature=2e3, config=COARSE)
    f = jax.jit(lambda th: model(par.to_flat(th)))
    jac = jax.jit(jax.jacfwd(f))(jnp.asarray(theta0))
    assert np.all(np.isfinite(jac)) and np.max(np.abs(jac)) > 0
    _assert_matches_fd(f, jac, theta0, [1e-5] * theta0.size)


@pytest.mark.slow
def test_3d_gradient_matches_finite_differences():
    """3D (Kalker table) max force: reverse-mode depth derivative at one speed (~minutes)."""
    ref = _rounded(TH0)
    model = fit.max_force_model([100 / 3.6], ref, "3d", impact_positions=[0.1],
                                temperature=None, config=COARSE)

    def f(d):
        return model(_rounded(jnp.stack([d[0], TH0[1]])))[0]

    grad = jax.grad(f)(jnp.asarray(TH0[:1]))
    _assert_matches_fd(f, np.asarray(grad)[None, :], TH0[:1], [2e-6])


def test_smooth_max_bounds():
    x = jnp.array([100e3, 180e3, 179.5e3])
    s = fit.smooth_max(x, 1e3)
    assert 180e3 <= float(s) <= 180e3 + 1e3 * math.log(3)
    assert float(fit.smooth_max(x, None)) == 180e3
    g = jax.grad(lambda y: fit.smooth_max(y, 1e3))(x)
    assert abs(float(jnp.sum(g)) - 1) < 1e-12 and float(g[2]) > 0.1


def test_reparametrisations_keep_constraints():
    rng = np.random.default_rng(0)
    rounded = fit.RoundedFlatParam()
    new = fit.NewFlatParam()
    prof = fit.ProfileParam(half_length=0.05, n_basis=6)
    for theta in rng.normal(0, 3, size=(50, 6)):
        d, l = np.asarray(rounded.physical(jnp.asarray(theta[:2])))
        assert d > 0 and l >= math.pi / 2 * math.sqrt(8 * 0.45 * d) * (1 - 1e-12)
        assert float(new.to_flat(jnp.asarray(theta[:1])).depth) > 0
        flat = prof.to_flat(jnp.asarray(theta))
        z = np.asarray(flat.profile_z)
        assert np.all(z >= 0) and z[0] < 1e-15 and z[-1] < 1e-15
    # round trips
    flat = wf.Flat.rounded(1.1e-3, 0.12)
    d, l = np.asarray(rounded.physical(jnp.asarray(rounded.from_flat(flat))))
    assert abs(d - 1.1e-3) < 1e-15 and abs(l - 0.12) < 1e-12
    # the smoothing penalty prefers smooth amplitudes
    smooth, rough = np.zeros(6), np.array([0, 3, 0, 3, 0, 3.0])
    assert float(prof.penalty(jnp.asarray(rough))) > float(prof.penalty(jnp.asarray(smooth)))


@pytest.mark.slow
def test_fit_new_flat_recovers_truth_from_noisy_data():
    """Data from a 0.7 mm new flat (2 % noise), start 50 % off (1.05 mm): within 5 % and
    within 3 standard deviations (the notebook test is the fast rounded-flat version)."""
    speeds = np.array([40.0, 80.0, 120.0, 140.0]) / 3.6
    truth = wf.Flat.new(0.7e-3)
    start = wf.Flat.new(1.05e-3)
    par = fit.parametrisation_for(start)
    truth_b = wf.Flat("new", truth.depth, truth.length, extent_bound=par.extent_bound)
    model = fit.max_force_model(speeds, truth_b, impact_positions=[0.1], config=COARSE)
    clean = np.asarray(model(truth_b))
    data = clean * (1 + 0.02 * np.random.default_rng(3).standard_normal(clean.size))
    res = fit.fit_flat(fit.MaxForceData(speeds, data), start, impact_positions=[0.1],
                       config=COARSE, parametrisation=par)
    assert res.converged, res.message
    assert abs(res.params["depth"] / 0.7e-3 - 1) < 0.05, res.params
    assert 0 < res.std["depth"] < 0.1e-3
    assert abs(res.params["depth"] - 0.7e-3) < 3 * res.std["depth"], res.std
    assert res.loss_history[-1] < res.loss_history[0] / 10
    assert res.residual_rms < 0.05 * np.mean(data)


@pytest.mark.parametrize("bad, match", [
    ({"speeds": [10.0, 20.0, float("nan")], "max_force": [1e5, 2e5, 3e5]}, "NaN"),
    ({"speeds": [10.0, 20.0], "max_force": [1e5, 2e5]}, "at least 3"),
    ({"speeds": [-10.0, 20.0, 30.0], "max_force": [1e5, 2e5, 3e5]}, "speeds"),
    ({"speeds": [10.0, 20.0, 30.0], "max_force": [1e5, 2e5]}, "equal length"),
    ({"t": np.linspace(0, 1e-2, 5), "force": np.ones(5), "speed": 20.0}, "at least 10"),
    ({"t": -np.linspace(0, 1e-2, 20), "force": np.ones(20), "speed": 20.0}, "increasing"),
    ({"speeds": [10.0, 20.0, 30.0], "peak": np.full((3, 3), 2e5)}, "impact_position"),
    ({"speeds": [10.0, 20.0, 30.0], "peak": np.full((3, 2), 2e5)}, "n_bays"),
    ({"speeds": [10.0, 20.0, 30.0], "peak": [2e5, -1.0, 2e5]}, "> 0 N"),
])
def test_bad_data_raises(bad, match):
    with pytest.raises(ValueError, match=match):
        fit.fit_flat(bad, wf.Flat.rounded(0.9e-3, 0.1))


def test_bad_options_raise():
    data = fit.MaxForceData([10.0, 20.0, 30.0], [1e5, 2e5, 3e5])
    with pytest.raises(ValueError, match="contact"):
        fit.fit_flat(data, wf.Flat.rounded(0.9e-3, 0.1), contact="4d")
    with pytest.raises(ValueError, match="kind"):
        fit.fit_flat(data, wf.Flat.none())
    with pytest.raises(ValueError, match="method"):
        fit.fit_flat(data, wf.Flat.new(0.9e-3), method="sgd")


# -- CLI -----------------------------------------------------------------------------------
@pytest.mark.parametrize("text, match", [
    ("speed_kmh,force_kN\n40,200\n60,210\n80,220\n", "need columns"),
    ("speed_kmh,max_force_N\n40,200000\n60,210000\n80,220000\n", "kN"),
    ("speed_kmh,max_force_kN\n40,200000\n60,210000\n80,220000\n", "look like N"),
    ("speed_kmh,max_force_kN\n40,200\n60,nan\n80,220\n", "NaN"),
    ("speed_kmh,max_force_kN\n40,200\n60,210\n", "at least 3"),
    ("t_s,force_kN\n" + "".join(f"{i * 1e-3},100\n" for i in range(20)), "speed-kmh"),
])
def test_cli_data_errors(tmp_path, capsys, text, match):
    path = tmp_path / "measured.csv"
    path.write_text(text)
    assert main(["fit", "--data", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert match in err and len(err.splitlines()) == 1


def test_parse_data_units():
    d = parse_data("speed_kmh,max_force_kN\n36,200\n72,210\n108,230\n")
    np.testing.assert_allclose(d.speeds, [10, 20, 30])
    np.testing.assert_allclose(d.max_force, [200e3, 210e3, 230e3])
    h = parse_data("t_s,force_kN\n" + "".join(f"{i * 1e-4},100\n" for i in range(12)),
                   speed_kmh=72, impact_position_mm=100)
    assert h.speed == 20 and h.impact_position == 0.1 and h.force[0] == 100e3


@pytest.mark.slow
def test_cli_example_end_to_end(tmp_path):
    out = tmp_path / "out"
    assert main(["fit", "--example", "--out", str(out)]) == 0
    import json

    summary = json.loads((out / "fit.json").read_text())
    assert abs(summary["depth_mm"] / 0.9 - 1) < 0.05
    assert abs(summary["length_mm"] / 100 - 1) < 0.05
    for name in ("fit.csv", "fit.png", "loss.png", "example_data.csv"):
        assert (out / name).stat().st_size > 0


# -- notebook ------------------------------------------------------------------------------
def _run_notebook(name: str, monkeypatch) -> str:
    """Execute notebooks/<name> with WFJAX_FAST=1; returns the text it printed."""
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    monkeypatch.setenv("WFJAX_FAST", "1")
    path = Path(__file__).resolve().parents[1] / "notebooks" / name
    nb = nbformat.read(path, as_version=4)
    nbclient.NotebookClient(nb, timeout=900, kernel_name="python3",
                            resources={"metadata": {"path": str(path.parent)}}).execute()
    return "".join(o.get("text", "") for c in nb.cells if c.cell_type == "code"
                   for o in c.get("outputs", []))


@pytest.mark.slow
def test_notebook_fast_mode(monkeypatch):
    """Executes notebooks/fit_flat.ipynb with WFJAX_FAST=1: the reduced fit (4 speeds, rounded
    flat, 3 % noise, start 50 % off) asserts it recovers depth and length within 5 %."""
    text = _run_notebook("fit_flat.ipynb", monkeypatch)
    assert "depth:" in text and "length:" in text


@pytest.mark.slow  # 32-45 s; the default run keeps the Hertz notebook's end-to-end fit and
# test_adjoint's central-difference check of the 3D family's gradient (the 2-core CI's
# default run took 552 s of its 10 minutes with it)
def test_3d_notebook_fast_mode(monkeypatch):
    """Executes notebooks/fit_flat_3d.ipynb with WFJAX_FAST=1 (2.5 mm elements, 5 speeds, one
    position): truth from the exact per-flat 3D table with 3 % noise, start 50 % off; the
    notebook asserts the misfit gradient against central differences within 1 % (the speeds
    include loss of contact), depth within 3 % and length within 5 %."""
    text = _run_notebook("fit_flat_3d.ipynb", monkeypatch)
    assert "central difference" in text and "depth:" in text and "length:" in text


def _detector_truth(contact, speeds, truth, par, position, config, track=None):
    """Per-bay readings of the 3-bay detector from the full model (sweep) and 3 % noise."""
    from wfjax.scenario.sensors import Detector

    truth_b = wf.Flat(truth.kind, truth.depth, truth.length, extent_bound=par.extent_bound)
    cfg = config if contact != "3d" else dataclasses.replace(config, contact_mode_3d="table")
    res = wf.sweep([truth_b], speeds, [position], contact=contact, detector=Detector(),
                   config=cfg, track=track, progress=False)
    clean = res.detector_peak[0, :, 0, :]
    assert np.all(clean[:, 1] > 1.3 * 118e3)  # the impact bay reads the impact
    return clean * (1 + 0.03 * np.random.default_rng(7).standard_normal(clean.shape))


@pytest.mark.slow  # the default run must stay under 10 min (2 cores)
def test_fit_to_detector_readings_hertz():
    """Detector readings per bay (full model, 3 % noise), start 50 % off: depth and length
    within 5 %; the prediction is the detector's, not the contact force."""
    speeds = np.array([40.0, 70.0, 100.0, 140.0]) / 3.6
    truth, start = wf.Flat.rounded(0.9e-3, 0.1), wf.Flat.rounded(1.35e-3, 0.15)
    par = fit.parametrisation_for(start)
    data = _detector_truth("hertz-trajectory", speeds, truth, par, 0.3, COARSE)
    res = fit.fit_flat(fit.DetectorData(speeds, data, impact_position=0.3), start,
                       "hertz-trajectory", config=COARSE, parametrisation=par)
    assert res.converged, res.message
    assert res.kind == "detector" and res.prediction.shape == (speeds.size * 3,)
    for name, true in (("depth", 0.9e-3), ("length", 0.1)):
        assert abs(res.params[name] / true - 1) < 0.05, res.params
    assert res.residual_rms < 0.05 * np.mean(data)


@pytest.mark.slow
def test_fit_to_detector_readings_3d():
    """As the Hertz check with the paper's 3D contact in the notebook's reduced setting
    (2.5 mm elements, coarse steps, R_R = 0.45 m): truth from the exact 3D table, fit
    through the parametric family."""
    config = wf.SimConfig(contact_element=2.5e-3, max_travel_step=2e-3, max_time_step=5e-5,
                          allow_inaccurate=True)  # outside the element guard (2.1 mm)
    track = wf.Track.comparison()
    speeds = np.linspace(40.0, 140.0, 5) / 3.6
    truth, start = wf.Flat.rounded(0.9e-3, 0.1), wf.Flat.rounded(1.35e-3, 0.15)
    par = fit.parametrisation_for(start)
    data = _detector_truth("3d", speeds, truth, par, 0.3, config, track)
    res = fit.fit_flat(fit.DetectorData(speeds, data, impact_position=0.3), start, "3d",
                       config=config, track=track, parametrisation=par)
    assert res.converged, res.message
    for name, true in (("depth", 0.9e-3), ("length", 0.1)):
        assert abs(res.params[name] / true - 1) < 0.05, res.params


@pytest.mark.slow
def test_detector_model_max_over_bays_and_gradient():
    """Max-over-bays detector data: the model is the per-bay model's maximum (one position,
    hard max), and its forward-mode Jacobian matches central differences."""
    speeds = np.array([60.0, 120.0]) / 3.6
    ref = _rounded(TH0)
    per_bay = fit.detector_model(speeds, ref, per_bay=True, impact_positions=[0.3],
                                 config=COARSE)
    peak = fit.detector_model(speeds, ref, impact_positions=[0.3], temperature=None,
                              config=COARSE)
    bays = np.asarray(per_bay(ref)).reshape(speeds.size, 3)
    np.testing.assert_allclose(np.asarray(peak(ref)), bays.max(axis=1), rtol=1e-12)
    assert np.all(bays.argmax(axis=1) == 1)  # the impact bay reads the impact
    f = jax.jit(lambda th: peak(_rounded(th)))
    _assert_matches_fd(f, jax.jit(jax.jacfwd(f))(jnp.asarray(TH0)), TH0, [1e-7, 1e-4])
