"""Roughness in the time loop and Monte Carlo over its realisations (issue 18)."""

import dataclasses
import json
from pathlib import Path

import baselines
import numpy as np
import pytest
from fe_reference import newmark_wheels

import wfjax as wf
from wfjax.model import supports
from wfjax.program.laws import loop_roughness, padded_models
from wfjax.scenario import patch
from wfjax.scenario import roughness as rough_mod
from wfjax.scenario.description import Scenario
from wfjax.scenario.windows import check_impact_positions

F64 = wf.SimConfig(precision="float64")  # identities to rounding: the float64 loop

REFERENCE = Path(__file__).parent / "data" / "single_wheel_reference.npz"
ROUNDED = wf.Flat.rounded(depth=0.9e-3, length=0.1)
V = 100 / 3.6
DX = 2.5e-4
X = np.arange(-3.0, 3.0, DX)


def _sine(amplitude, wavelength=0.1, phase=0.0):
    return rough_mod.Roughness(float(X[0]), DX,
                               amplitude * np.sin(2 * np.pi * X / wavelength + phase))


def _fluctuation(contact, rough, flat=None, **kw):
    """(force [n], force minus the smooth run's [n], t [n]) of a run with ``rough``."""
    flat = flat or wf.Flat.none()
    base = wf.simulate(flat, V, contact=contact, impact_position=0.1, **kw, config=F64)
    res = wf.simulate(flat, V, contact=contact, impact_position=0.1, roughness=rough, **kw,
                      config=F64)
    return np.asarray(res.force), np.asarray(res.force) - np.asarray(base.force), res


def _amplitude(d, t):
    late = t >= 0.01
    return 0.5 * (d[late].max() - d[late].min())


@pytest.mark.parametrize("contact", ["hertz-profile", "hertz-trajectory", "2d",
                                     pytest.param("3d", marks=pytest.mark.slow)])
def test_zero_roughness_reproduces_the_smooth_loop(contact, tmp_path, monkeypatch):
    # tests/data: the histories before roughness existed, each contact's from an empty cache
    # (tests/baselines.py): the 3D table built alone, as here (one built beside other flats
    # differs by up to its float32 solves' tolerance); the 3D run is compared with the same
    # table's run without roughness as well
    if contact == "3d":
        monkeypatch.setenv("WFJAX_CACHE_DIR", str(tmp_path))
    ref = np.load(REFERENCE)
    track = wf.Track(n_bays=baselines.SINGLE_BAYS)
    res = wf.simulate(ROUNDED, V, contact=contact, impact_position=0.1, track=track,
                      roughness=_sine(0.0), config=F64)
    plain = wf.simulate(ROUNDED, V, contact=contact, impact_position=0.1, track=track,
                        config=F64)
    for key in ("force", "rail_disp", "wheel_disp", "approach"):
        got = np.asarray(getattr(res, key))
        for want, tol in ((np.asarray(getattr(plain, key)), 1e-9),
                          (ref[f"{contact}/{key}"], 1e-8 if contact == "3d" else 1e-9)):
            assert np.max(np.abs(got - want)) <= tol * np.max(np.abs(want)), key


@pytest.mark.parametrize("contact", ["hertz-profile", "2d"])
def test_force_fluctuation_is_linear_in_the_roughness_amplitude(contact):
    _, d1, res = _fluctuation(contact, _sine(1e-6))
    _, d2, _ = _fluctuation(contact, _sine(2e-6))
    t = np.asarray(res.t)
    a1, a2 = _amplitude(d1, t), _amplitude(d2, t)
    assert a1 > 100.0  # N: a real excitation (about 170 N per um at 278 Hz)
    assert a2 == pytest.approx(2 * a1, rel=0.01)


def test_raised_rail_adds_approach():
    # a constant 1 um raised rail is a static offset: the force does not change, the
    # kinematic approach xi_W - xi_R drops by the offset (the wheel rides 1 um higher)
    flat = wf.Flat.none()
    base = wf.simulate(flat, V, contact="hertz-profile", impact_position=0.1, config=F64)
    up = wf.simulate(flat, V, contact="hertz-profile", impact_position=0.1,
                     roughness=rough_mod.Roughness(float(X[0]), DX, np.full(X.size, 1e-6)),
                     config=F64)
    assert np.max(np.abs(np.asarray(up.force) - np.asarray(base.force))) < 1e-6 * 118e3
    assert np.asarray(up.approach) == pytest.approx(np.asarray(base.approach) - 1e-6,
                                                    abs=1e-12)
    assert np.asarray(up.wheel_disp) == pytest.approx(np.asarray(base.wheel_disp) - 1e-6,
                                                      abs=1e-12)


def test_wheel_roughness_equals_the_same_rail_roughness_under_one_wheel():
    # a wheel harmonic read at s = x - impact is the rail sinusoid shifted by the impact
    circ = 2 * np.pi * 0.45
    n = int(round(circ / DX))
    lam = circ / 28
    s = np.arange(n) * (circ / n)
    wheel = rough_mod.Roughness(0.0, circ / n, 1e-6 * np.sin(2 * np.pi * s / lam),
                                periodic=True)
    rail = _sine(1e-6, lam, phase=-2 * np.pi * 0.1 / lam)
    flat = wf.Flat.none()
    a = wf.simulate(flat, V, contact="hertz-profile", impact_position=0.1, roughness=rail,
                    config=F64)
    b = wf.simulate(flat, V, contact="hertz-profile", impact_position=0.1,
                    wheel_roughness=wheel, config=F64)
    fa, fb = np.asarray(a.force), np.asarray(b.force)
    assert np.max(np.abs(fa - fb)) < 1e-3 * np.ptp(fa)


@pytest.mark.slow
def test_roughness_response_agrees_with_a_direct_fe_time_integration():
    # independent reference: the full FE track by Newmark, Hertz on the point roughness times
    # the contact filter's response at the static Hertz contact length (what the loop's
    # point-contact laws see for a sinusoid)
    lam, amp = 0.1, 2e-6
    f, d, res = _fluctuation("hertz-profile", _sine(amp, lam),
                             track=wf.Track(n_bays=24))  # newmark_wheels' track
    length = float(loop_roughness(_sine(amp, lam)).contact_length[0])
    gain = float(patch.contact_filter_response(lam, length))
    x0, s0, dt = float(res.x[0]), float(res.s[0]), float(res.time_step)
    n = f.size
    smooth = newmark_wheels(wf.Flat.none(), V, x0, x0 - s0, [0.0], dt, n)[:, 0]
    rough = newmark_wheels(wf.Flat.none(), V, x0, x0 - s0, [0.0], dt, n,
                           rail_roughness=lambda x: gain * amp * np.sin(2 * np.pi * x / lam)
                           )[:, 0]
    t = np.asarray(res.t)
    want = _amplitude(rough - smooth, t)
    assert _amplitude(d, t) == pytest.approx(want, rel=0.03)
    late = t >= 0.01
    assert f[late].max() == pytest.approx(rough[late].max(), rel=0.03)


@pytest.mark.slow
def test_monte_carlo_percentiles_equal_a_loop_over_the_realisations():
    rough = rough_mod.generate(rough_mod.ISO3095_LIMIT, 3, 4.0, x_start=-2.0,
                               n_realisations=5)
    speeds = [V, 120 / 3.6]
    res = wf.sweep(ROUNDED, speeds, impact_positions=[0.1], contact="hertz-trajectory",
                   roughness=rough, progress=False, chunk_size=4, config=F64)
    loop = np.array([[wf.simulate(ROUNDED, v, contact="hertz-trajectory", impact_position=0.1,
                                  roughness=dataclasses.replace(rough, values=rough.values[r])
                                  , config=F64).max_force for r in range(5)]
                     for v in speeds])
    got = np.asarray(res.realisation_max_force)[0, :, 0, :]
    assert got == pytest.approx(loop, rel=1e-9)
    assert res.percentiles()[0] == pytest.approx(
        np.percentile(loop, [50, 95, 99], axis=-1).T, rel=1e-9)
    assert np.asarray(res.max_force)[0, :, 0] == pytest.approx(loop.max(axis=-1), rel=1e-9)
    csv_text = res.percentiles_to_csv()
    assert csv_text.splitlines()[0].endswith("p99_max_force_kN")
    assert res.summary()["realisations"] == 5


def test_impact_positions_are_absolute_on_a_track_whose_supports_vary():
    tr = wf.Track(n_bays=24)
    with pytest.raises(ValueError, match=r"\[0, 0.65\)"):
        check_impact_positions([0.7], tr)
    void = supports.void_sleeper(tr, tr.n_bays // 2)
    assert check_impact_positions([-0.65, 0.7, 1.95], void) == pytest.approx([-0.65, 0.7, 1.95])
    with pytest.raises(ValueError, match="absolute rail coordinates"):
        check_impact_positions([30.0], void)


def test_bad_roughness_inputs_are_refused():
    circ_wheel = rough_mod.generate_wheel(rough_mod.ISO3095_LIMIT, 0)
    with pytest.raises(ValueError, match="must not be periodic"):
        Scenario.of(wf.Flat.none(), roughness=circ_wheel)
    with pytest.raises(ValueError, match="must be periodic"):
        Scenario.of(wf.Flat.none(), wheel_roughness=_sine(1e-6))
    two = rough_mod.generate(rough_mod.ISO3095_LIMIT, 0, 4.0, n_realisations=2)
    three = rough_mod.generate_wheel(rough_mod.ISO3095_LIMIT, 0, n_realisations=3)
    with pytest.raises(ValueError, match="same number of realisations"):
        wf.sweep(ROUNDED, [V], impact_positions=[0.1], contact="hertz-trajectory",
                 roughness=two, wheel_roughness=three, progress=False)


def test_a_rail_profile_shorter_than_the_run_is_refused():
    short = rough_mod.Roughness(0.0, DX, np.zeros(400))  # 0.1 m
    with pytest.raises(ValueError, match="covers x in"):
        wf.simulate(ROUNDED, V, contact="hertz-trajectory", impact_position=0.1,
                    roughness=short)
    with pytest.raises(ValueError, match="covers x in"):
        wf.sweep(ROUNDED, [V], impact_positions=[0.1], contact="hertz-trajectory",
                 roughness=short, progress=False)


def test_static_contact_length_is_the_hertz_patch():
    length = float(loop_roughness(_sine(1e-6)).contact_length[0])
    assert 10e-3 < length < 14e-3


def test_cli_monte_carlo_writes_percentiles_and_the_band(tmp_path, capsys):
    from wfjax.cli import main

    out = tmp_path / "mc"
    assert main(["sweep", "--flat", "rounded", "--contact", "hertz-trajectory",
                 "--speeds-kmh", "80,120", "--positions", "1", "--roughness", "iso3095",
                 "--realisations", "3", "--seed", "2", "--out", str(out)]) == 0
    rows = (out / "sweep_percentiles.csv").read_text().splitlines()
    assert len(rows) == 3 and rows[0].split(",")[-3:] == [
        "p50_max_force_kN", "p95_max_force_kN", "p99_max_force_kN"]
    summary = json.loads((out / "sweep.json").read_text())
    assert summary["realisations"] == 3
    assert summary["case"]["roughness"]["preset"] == "iso3095"
    assert (out / "sweep_band.png").stat().st_size > 0
    assert "p50/p95/p99" in capsys.readouterr().out


@pytest.mark.parametrize("argv, words", [
    (["--roughness-csv", "missing.csv"], ["missing.csv"]),
    (["--roughness-csv", "BAD"], ["roughness_um", "5 mm"]),
    (["--void-sleepers", "99"], ["[supports]", "99"]),
    (["--realisations", "0"], ["--realisations", "[1, 100000]"]),
])
def test_bad_roughness_and_support_flags_fail_before_work(tmp_path, capsys, no_work, argv,
                                                         words):
    from wfjax.cli import main

    bad = tmp_path / "bad.csv"
    bad.write_text("x_mm,roughness_um\n0,1\n0.25,2\n0.5,6000\n0.75,1\n")  # 6 mm: absurd
    argv = [str(bad) if a == "BAD" else a for a in argv]
    out = tmp_path / "out"
    assert main(["sweep", "--contact", "hertz-trajectory", "--speeds-kmh", "80",
                 "--positions", "1", *argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    for w in words:
        assert w in err[0], (w, err[0])
    assert not out.exists()


@pytest.mark.slow  # three modal models and three compiles of the loop: ~50 s on 2 cores
def test_support_realisations_share_one_compile_and_equal_a_loop():
    base = wf.Track(n_bays=20)
    tracks = [supports.scatter(base, key=k, cv=0.3) for k in range(3)]
    models = padded_models(tracks, wf.SimConfig())
    f_max = wf.SimConfig().resolved().track_max_frequency
    counts = [int(wf.track.modal_model(t, max_frequency=f_max).poles.shape[0]) for t in tracks]
    assert models.poles.shape[:2] == (3, max(counts))
    rough = rough_mod.generate(rough_mod.ISO3095_LIMIT, 5, 4.0, x_start=-2.0,
                               n_realisations=3)
    res = wf.sweep(ROUNDED, [V], impact_positions=[0.1], contact="hertz-trajectory",
                   tracks=tracks, roughness=rough, progress=False, config=F64)
    loop = [float(wf.simulate(ROUNDED, V, contact="hertz-trajectory", impact_position=0.1,
                              track=tr, config=F64,
                              roughness=dataclasses.replace(rough, values=rough.values[r])
                              ).max_force) for r, tr in enumerate(tracks)]
    assert np.asarray(res.realisation_max_force)[0, 0, 0] == pytest.approx(loop, rel=1e-9)
    with pytest.raises(ValueError, match="must be as many"):
        wf.sweep(ROUNDED, [V], impact_positions=[0.1], contact="hertz-trajectory",
                 tracks=tracks[:2], roughness=rough, progress=False)


@pytest.mark.slow  # the default run must stay under 10 min (2 cores)
def test_every_wheel_of_a_vehicle_rolls_on_the_rough_rail():
    from wfjax.model.vehicle import Vehicle

    bogie = Vehicle.bogie()
    kw = dict(contact="2d", impact_position=0.1, vehicle=bogie)
    plain = wf.simulate(wf.Flat.none(), V, **kw)
    zero = wf.simulate(wf.Flat.none(), V, roughness=_sine(0.0), **kw)
    rough = wf.simulate(wf.Flat.none(), V, roughness=_sine(1e-6), **kw)
    f0, fz, fr = (np.asarray(r.wheel_force) for r in (plain, zero, rough))
    assert np.max(np.abs(fz - f0)) <= 1e-9 * np.max(f0)
    late = np.asarray(plain.t) >= 0.01
    for i in range(2):  # each wheel sees the 1 um sinusoid: ~170 N of force change
        change = 0.5 * np.ptp((fr - f0)[late, i])
        assert 100.0 < change < 300.0, (i, change)


@pytest.mark.slow  # two direct 3D runs: a Kalker solve per Newton iterate near the flat
def test_direct_3d_mode_with_zero_roughness_is_unchanged():
    config = wf.SimConfig(contact_mode_3d="direct")
    kw = dict(contact="3d", impact_position=0.1, track=wf.Track.comparison(), config=config)
    plain = wf.simulate(ROUNDED, V, **kw)
    zero = wf.simulate(ROUNDED, V, roughness=_sine(0.0), **kw)
    want = np.asarray(plain.force)
    assert np.max(np.abs(np.asarray(zero.force) - want)) <= 1e-9 * want.max()
