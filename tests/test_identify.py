"""wfjax.identify's pieces (fast): the passage reader and its bad-input checks, the command's
exit status, the rules, the table shift, and the grid posterior against an independent
quadrature and in a calibration check (coverage inside a Clopper-Pearson band)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import beta

from wfjax.identify import forward as fwd
from wfjax.identify import prediction, rules
from wfjax.identify.inference import Prior, posterior
from wfjax.identify.passage import Passage, PassageError, check_layout, passages_csv, read_passages

BAYS = np.arange(-1, 4)
STEP = 0.65 / 4  # m: the synthetic table's positions
CIRCUMFERENCE = 17 * STEP  # m: a whole number of them
RADIUS = CIRCUMFERENCE / (2 * np.pi)


def _passage(n=2, speed=100 / 3.6):
    rng = np.random.default_rng(1)
    return Passage(speed, np.array([0.0, 2.5, 17.5, 20.0][:n]), BAYS,
                   120e3 + 30e3 * rng.random((n, BAYS.size)), 0.1, 1.0)


def _csv(tmp_path, text):
    path = tmp_path / "p.csv"
    path.write_text(text)
    return path


def test_round_trip(tmp_path):
    p = _passage(4)
    (q,) = read_passages(_csv(tmp_path, passages_csv([p])))
    assert q.speed == pytest.approx(p.speed)
    np.testing.assert_allclose(q.readings, p.readings, rtol=1e-6)
    np.testing.assert_array_equal(q.bays, BAYS)
    assert q.detector().n_bays == 5 and q.detector().first_bay == -1
    check_layout([q], [0.0, 2.5, 17.5, 20.0])


def _lines(tmp_path, edit):
    lines = passages_csv([_passage(2)]).splitlines()
    return _csv(tmp_path, "\n".join(edit(lines)) + "\n")


@pytest.mark.parametrize("edit, words", [
    (lambda ls: [ls[0], ls[1]] + [ls[2].replace(",1,2.5000,", ",2,2.5000,")],
     ["row 3", "wheel 1 is missing"]),
    (lambda ls: [ls[0], ls[1], ",".join(ls[2].split(",")[:-1] + [""])],
     ["row 3", "reading_bay3_kN", "missing reading"]),
    (lambda ls: [ls[0].replace("reading_bay1_kN", "reading_bay7_kN")] + ls[1:],
     ["missing bay column reading_bay1_kN"]),
    (lambda ls: [ls[0], ls[1].rsplit(",", 1)[0] + ",nan", ls[2]],
     ["row 2", "reading_bay3_kN", "not finite"]),
    (lambda ls: [ls[0], ls[1].rsplit(",", 1)[0] + ",125000.0", ls[2]],
     ["row 2", "125000.0", "in N, not kN"]),
    (lambda ls: [ls[0]] + [r.replace(",100,", ",400,") for r in ls[1:]],
     ["row 2", "speed_kmh", "400", "[5, 300] km/h"]),
    (lambda ls: [ls[0].replace("position_m", "pos")] + ls[1:], ["missing column 'position_m'"]),
])
def test_bad_input(tmp_path, edit, words):
    with pytest.raises(PassageError) as err:
        read_passages(_lines(tmp_path, edit))
    msg = str(err.value)
    assert "\n" not in msg
    for w in words:
        assert w in msg


def test_layout_mismatch():
    with pytest.raises(PassageError, match="4 wheels, but the readings have 2"):
        check_layout([_passage(2)], [0.0, 2.5, 17.5, 20.0])
    with pytest.raises(PassageError, match="wheel 1 at 2.6 m"):
        check_layout([_passage(2)], [0.0, 2.6])


def test_command_bad_input_exit_2_nothing_written(tmp_path, capsys):
    from wfjax.cli import main

    bad = _lines(tmp_path, lambda ls: [ls[0], ls[1].rsplit(",", 1)[0] + ",inf", ls[2]])
    out = tmp_path / "out"
    assert main(["identify", "--readings", str(bad), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not finite" in err[0] and "reading_bay3_kN" in err[0]
    assert not out.exists()
    good = _csv(tmp_path, passages_csv([_passage(2)]))
    assert main(["identify", "--readings", str(good), "--layout", "wagon", "--out",
                 str(out)]) == 2
    assert "4 wheels, but the readings have 2" in capsys.readouterr().err
    assert not out.exists()


def test_rules():
    p_short, p_long = (lambda x: 0.1), (lambda x: 0.95)
    assert rules.decide(rules.TRAFIKVERKET, 360e3, p_short) == "stop train"
    assert rules.decide(rules.TRAFIKVERKET, 200e3, p_long) == "remove wheel"
    assert rules.decide(rules.TRAFIKVERKET, 349e3, p_short) == "ok"
    assert rules.decide(rules.FRA, 401e3, p_short).startswith("replace wheel (in service")
    assert rules.decide(rules.FRA, 380e3, p_short).startswith("replace wheel in shop")
    assert rules.decide(rules.FRA, 355e3, p_long) == "ok"  # 80 kips = 355.9 kN
    user = rules.user_rule(length=0.05, probability=0.8)
    assert rules.decide(user, 1e3, lambda x: 0.79) == "ok"
    assert rules.decide(user, 1e3, lambda x: 0.81) == "act (length)"
    assert rules.flagged(0.9) and not rules.flagged(0.899)


def _table(slope=2.5e6, n_j=4, n_r=1, shapes=(("new", 0.0),)):
    """A synthetic table: bay offset 0 reads P + slope * l, the others P (phase-free). Its
    wheel's circumference is 17 table positions (4.25 bays), so every strike lies on one."""
    lengths = np.linspace(0.0, 0.13, 14)
    reads = np.full((len(shapes), lengths.size, n_j, n_r, fwd.TABLE_BAYS), 120e3)
    reads[..., 0] += slope * lengths[None, :, None, None]
    return fwd.ResponseTable(100 / 3.6, 0.65, RADIUS, shapes, lengths,
                             np.arange(n_j) * 0.65 / n_j, reads, reads[..., 0])


def _strike_bays(x: float) -> set:
    """The bays of a flat's strikes x + k 2 pi R near the detector (synthetic table)."""
    return {int(np.floor(round((x + k * CIRCUMFERENCE) / STEP) * STEP / 0.65 + 1e-9))
            for k in range(-3, 4)}


def test_refined_phases_interpolate_linearly():
    t = _table()
    t.readings[0, :, :, 0, :] += np.arange(4)[None, :, None] * 1e3
    fine = prediction.predict_refined(t, BAYS, [0.1], 4)[0, 0, :, 0]
    native = prediction.predict(t, BAYS, [0.1], prediction.phase_grid(t, BAYS))[0, 0, :, 0]
    np.testing.assert_allclose(fine[::4], native)
    np.testing.assert_allclose(fine[1:-4:4], 0.75 * native[:-1] + 0.25 * native[1:])


def test_predict_shifts_the_table():
    """Every bay reads the table at the flat's last strike at or before it: its bay offset
    (0..4) and in-bay position; a bay more than 4 bays after it the shortest flat."""
    t = _table()
    t.readings[0, :, :, 0, :] += np.arange(5)[None, None, :] * 1e3 + np.arange(4)[None, :,
                                                                                 None] * 10
    phases = prediction.phase_grid(t, BAYS)
    assert phases.size == 17
    mu = prediction.predict(t, BAYS, [0.13], phases)[0, 0, :, 0]  # [P, n_bays]
    seen_two = 0
    for p, x in enumerate(phases):
        strikes = [int(round((x + k * CIRCUMFERENCE) / STEP)) for k in range(-3, 4)]
        seen_two += sum(BAYS[0] <= i // 4 <= BAYS[-1] for i in strikes) == 2
        for b, k in enumerate(BAYS):
            last = max(i for i in strikes if i // 4 <= k)
            rel, j = k - last // 4, last % 4
            expect = 120e3 + (2.5e6 * 0.13 if rel == 0 else 0) + min(rel, 4) * 1e3 + j * 10
            assert mu[p, b] == pytest.approx(expect)
    assert seen_two > 0  # the 5-bay detector holds two strikes of some phases


def test_every_strike_rule_reads_as_runs_with_every_strike():
    """The prediction's rule (each bay read at the flat's last strike at or before it, from
    one-strike runs of the table's layout) against runs in which a new 80 mm flat strikes
    every revolution, 140 km/h (the largest difference of benchmarks/identify_every_strike.py),
    every 6th table position of a circumference: within 1 %, where the one-strike rule is
    more than 10 % off."""
    import bench_scripts

    out = bench_scripts.load("identify_every_strike").compare("new", 0.0, 0.08, 140.0, every=6)
    assert out["every strike"]["max_pct"] < 1.0, out
    assert out["one strike"]["max_pct"] > 10.0, out


def test_posterior_matches_quadrature(monkeypatch):
    """One phase-free reading, one shape: the grid posterior equals the normalised
    likelihood x prior computed directly (on the table's own phase points)."""
    from wfjax.identify import inference

    monkeypatch.setattr(inference, "PHASE_REFINE", 1)
    t = _table()
    prior = Prior(p_new=1.0)
    y = np.array([120e3, 120e3, 120e3 + 2.5e6 * 0.05, 120e3, 120e3])
    # the impact bay is bay 1 for every phase in [0.65, 1.3): the grid puts phases in all
    # bays, so compute the expectation over the phase grid independently
    post = posterior([t], [BAYS], [y], prior=prior, noise=0.03, model=0.0)
    lengths, sigma = prior.lengths(), 0.03
    phases = prediction.phase_grid(t, BAYS)
    lik = np.zeros(lengths.size)
    for x in phases:
        struck = _strike_bays(x)
        for i, ln in enumerate(lengths):
            mu = np.array([120e3 + (2.5e6 * ln if k in struck else 0.0) for k in BAYS])
            lik[i] += np.exp(-0.5 * np.sum(((y - mu) / (sigma * mu)) ** 2)) / np.prod(mu)
    np.testing.assert_allclose(post.weights[0], lik / lik.sum(), rtol=1e-6, atol=1e-12)
    lo, hi = post.interval("length", 0.9)
    assert lo < 0.05 < hi


def test_posterior_calibrated_on_its_own_model():
    """Truth drawn from the prior, readings from the model with 3 % noise: the 90 % length
    intervals cover at a rate inside the 95 % Clopper-Pearson band of the observed count."""
    t = _table(slope=0.6e6)  # posterior sd about 6 mm: several grid steps
    prior = Prior(p_new=1.0)
    rng = np.random.default_rng(7)
    n, hits = 120, 0
    phases = prediction.phase_grid(t, BAYS)
    for _ in range(n):
        ln = rng.uniform(0.0, 0.13)  # continuous: the grid's cells read as uniform
        x = rng.choice(phases)
        mu = prediction.predict(t, BAYS, [ln], [x])[0, 0, 0, 0]
        y = mu * (1 + 0.03 * rng.standard_normal(mu.shape))
        lo, hi = posterior([t], [BAYS], [y], prior=prior, noise=0.03, model=0.0).interval(
            "length", 0.9)
        hits += lo <= ln <= hi
    lo_cp = beta.ppf(0.025, hits, n - hits + 1)
    hi_cp = beta.ppf(0.975, hits + 1, n - hits)
    assert lo_cp <= 0.9 <= hi_cp, (hits, n)


def test_misfit_flagged():
    """Readings no flat explains (a dip far below the static load in every bay): the
    posterior-predictive p-value is below the threshold."""
    t = _table()
    y = np.full(BAYS.size, 60e3)
    post = posterior([t], [BAYS], [y], noise=0.03, model=0.0)
    assert post.ppc_p < 1e-3
    y_ok = np.array([120e3, 120e3, 220e3, 120e3, 120e3])
    assert posterior([t], [BAYS], [y_ok], noise=0.03, model=0.0).ppc_p > 1e-3


def test_command_writes_outputs(tmp_path, capsys, monkeypatch):
    """wfjax identify on a synthetic table (monkeypatched, no simulation): identify.csv,
    identify.json with case and provenance, identify.png, case.toml, one line per wheel."""
    import json

    from wfjax.cli import main

    t = _table(slope=1.0e6, shapes=(("new", 0.0), ("rounded", 1.6)))
    monkeypatch.setattr(fwd, "build_table", lambda *a, **k: t)
    y = np.full((2, 5), 120e3)
    y[0, 2] = 200e3  # wheel 0: a flat of about 80 mm in bay 1
    path = _csv(tmp_path, passages_csv([Passage(100 / 3.6, np.array([0.0, 2.5]), BAYS, y)]))
    out = tmp_path / "out"
    assert main(["identify", "--readings", str(path), "--out", str(out),
                 "--coupling-iterations", "0", "--user-length-mm", "50"]) == 0
    text = capsys.readouterr().out
    lines = [ln for ln in text.splitlines() if ln.strip().startswith("wheel")]
    assert len(lines) == 2 and "FLAT" in lines[0] and "FLAT" not in lines[1]
    rows = (out / "identify.csv").read_text().splitlines()
    assert len(rows) == 3 and rows[0].startswith("wheel,flagged,p_flag,p_new")
    summary = json.loads((out / "identify.json").read_text())
    assert summary["case"]["identify"]["readings"] == str(path)
    assert "provenance" in summary and summary["wheels"][0]["flagged"] is True
    assert summary["wheels"][0]["decision_user"] == "act (length)"
    assert 60 < summary["wheels"][0]["length_median_mm"] < 100
    assert (out / "identify.png").stat().st_size > 1000 and (out / "case.toml").exists()


def _command_kwargs(tmp_path, monkeypatch, *flags) -> dict:
    """The keyword arguments `wfjax identify --readings ... --out ... *flags` gives identify()
    (stopped there) for a two-wheel passage."""
    import wfjax.identify as identify_pkg
    from wfjax.cli import main

    seen = {}

    def fake(passages, **kw):
        seen.update(kw)
        raise SystemExit(0)

    monkeypatch.setattr(identify_pkg, "identify", fake)
    y = np.full((2, 5), 120e3)
    path = _csv(tmp_path, passages_csv([Passage(100 / 3.6, np.array([0.0, 2.5]), BAYS, y)]))
    with pytest.raises(SystemExit):
        main(["identify", "--readings", str(path), "--out", str(tmp_path / "out"), *flags])
    return seen


def test_command_passes_the_phase_modes(tmp_path, monkeypatch):
    """--phase-modes and --phase-error-mm reach identify() (in its units: m)."""
    seen = _command_kwargs(tmp_path, monkeypatch, "--phase-modes", "1",
                           "--phase-error-mm", "30")
    assert seen["phase_modes"] == 1 and seen["phase_error"] == pytest.approx(0.03)


def test_command_defaults_are_identifys(tmp_path, monkeypatch):
    """Without the flags, the command passes identify()'s own defaults (one place for each):
    PHASE_MODES configurations per flat neighbour, the phase blur PHASE_ERROR."""
    import inspect

    from wfjax.identify.pipeline import PHASE_MODES, identify

    seen = _command_kwargs(tmp_path, monkeypatch)
    defaults = inspect.signature(identify).parameters
    for name in ("phase_modes", "phase_error", "coupling_iterations", "seed"):
        assert seen[name] == defaults[name].default, name
    assert seen["phase_modes"] == PHASE_MODES


def test_site_factors_pooled_over_passages_of_one_site():
    """Passages over the same bays share one site factor per bay: the median over every
    wheel of every passage of reading / the wheel's modelled reading; other bays: per
    passage. Impacts the model explains do not move a factor, even in most of a bay's
    wheels (a median over a round wheel's reading would read them as the site's)."""
    from wfjax.identify.pipeline import pooled_site_factors, site_factors

    a, b = _passage(4), _passage(4, speed=60 / 3.6)
    b = Passage(b.speed, b.positions, b.bays, b.readings * 1.1, 0.1, 1.0)
    fit = np.full(a.readings.shape, 120e3)
    got = pooled_site_factors([a, b], [fit, fit])
    want = np.median(np.concatenate([a.readings, b.readings]) / 120e3, axis=0)
    np.testing.assert_allclose(got[0], want)
    np.testing.assert_allclose(got[1], want)
    c = Passage(b.speed, b.positions, BAYS + 1, b.readings, 0.1, 1.0)
    got = pooled_site_factors([a, c], [fit, fit])
    np.testing.assert_allclose(got[1], site_factors(c, fit))
    struck = np.full((4, BAYS.size), 120e3)
    struck[:3, 2] = 250e3  # three of four wheels read an impact in the middle bay
    hit = Passage(a.speed, a.positions, a.bays, 1.04 * struck, 0.1, 1.0)
    np.testing.assert_allclose(site_factors(hit, struck), 1.04)
    assert site_factors(hit, np.full_like(struck, 120e3))[2] > 2.0


def test_parametric_flats_share_one_extent_bound():
    """Every new or rounded flat of a coupled run is sized by the same extent bound (one
    compiled program for every length); a measured-profile flat is left alone."""
    import wfjax as wf

    bound = fwd.extent_bound(0.45)
    assert bound == pytest.approx(0.065)
    for flat in (fwd.flat_of("new", 0.03, 1.0, 0.45), fwd.flat_of("rounded", 0.09, 1.8, 0.45)):
        assert fwd._bounded(flat, 0.45).extent_bound == bound
    x = np.linspace(-0.03, 0.03, 31)
    prof = wf.Flat.from_profile(x, 1e-4 * (1 - np.abs(x) / 0.03))
    assert fwd._bounded(prof, 0.45) is prof


def test_train_of_80_wheels_round_trips_and_is_a_batch_of_bogies(tmp_path):
    """A 20-wagon train's passage (80 wheels) goes through the CSV and back, and the
    pipeline sees it as 40 bogies of one layout (one batched coupled run, not 40)."""
    from wfjax.identify.pipeline import _groups, _layouts

    rng = np.random.default_rng(2)
    pos = np.concatenate([25.0 * k + np.array([0.0, 2.5, 17.5, 20.0]) for k in range(20)])
    p = Passage(100 / 3.6, pos, BAYS, 120e3 + 30e3 * rng.random((pos.size, BAYS.size)))
    (q,) = read_passages(_csv(tmp_path, passages_csv([p])))
    assert q.n_wheels == 80
    np.testing.assert_allclose(q.positions, pos, atol=1e-4)
    np.testing.assert_allclose(q.readings, p.readings, rtol=1e-6)
    groups = _groups(q.positions)
    assert groups == [[2 * k, 2 * k + 1] for k in range(40)]
    assert list(_layouts(q.positions, groups)) == [(0.0, 2.5)]


def test_batch_padding():
    assert [fwd._padded(n) for n in (1, 2, 3, 5, 8, 9, 34, 40)] == [1, 2, 4, 8, 8, 16, 40, 40]


def test_compiled_batches_are_bounded(monkeypatch):
    """Once the batch function holds MAX_BATCH_PROGRAMS compiled programs they are dropped
    (each holds its machine code in memory maps: a long identification ran out of them)."""
    import jax
    import jax.numpy as jnp

    batch = jax.jit(lambda x: 2 * x)
    monkeypatch.setattr(fwd, "_bogie_batch", batch)
    monkeypatch.setattr(fwd, "MAX_BATCH_PROGRAMS", 3)
    for n in (1, 2):
        batch(jnp.zeros(n))
    fwd._bounded_programs()
    assert batch._cache_size() == 2  # under the bound: kept
    batch(jnp.zeros(3))
    fwd._bounded_programs()
    assert batch._cache_size() == 0


@pytest.mark.slow
def test_coupled_batch_equals_coupled_runs():
    """Bogies batched (:func:`coupled_batch`, mixed flat kinds: two batches) read what each
    bogie's own coupled run reads."""
    from wfjax.params import Wheel
    from wfjax.scenario.sensors import Detector

    r, det = float(Wheel().radius), Detector(5, -1)
    smooth = fwd.round_wheel(r)
    groups = [([fwd.flat_of("new", 0.06, 1.0, r), smooth], [0.3, 0.9]),
              ([smooth, smooth], [0.5, 1.7]),
              ([smooth, fwd.flat_of("rounded", 0.08, 1.8, r)], [1.0, 0.2])]
    peaks, force = fwd.coupled_batch(groups, [0.0, 2.5], 100 / 3.6, det)
    for k, (flats, impacts) in enumerate(groups):
        p, f = fwd.coupled_readings(flats, impacts, [0.0, 2.5], 100 / 3.6, det)
        np.testing.assert_allclose(peaks[k], p, rtol=1e-9)
        np.testing.assert_allclose(force[k], f, rtol=1e-9)
    # the same batches with another group first compile nothing new (the first group's
    # flat kinds once entered every batch's program signature: one program per order)
    programs = fwd._bogie_batch._cache_size()
    again, _ = fwd.coupled_batch(groups[::-1], [0.0, 2.5], 100 / 3.6, det)
    assert fwd._bogie_batch._cache_size() == programs
    np.testing.assert_array_equal(again[::-1], peaks)


@pytest.mark.slow
@pytest.mark.parametrize("speed_kmh", [60.0, 140.0])
def test_corrections_on_the_least_track_read_as_on_70_bays(speed_kmh):
    """The neighbour corrections' track (``CORRECTION_TRACK``: end networks, lengthened by
    the guards to what the detector's reading needs, 24 bays) gives a round wheel's
    correction (the bogie's run minus the wheel alone, 80 mm new neighbour at 6 phases,
    either wheel first, rough rail) within 0.5 % of the largest reading of the 70-bay
    ``TRACK``'s (2026-12-06, 8 phases: 0.10 % at 60 km/h, 0.23 % at 140), and the
    correction itself is not small (a neighbour's effect the test could miss)."""
    from wfjax.identify.pipeline import correction_roughness
    from wfjax.scenario.sensors import Detector

    r, det, speed = 0.45, Detector(5, -2), speed_kmh / 3.6
    smooth, flat = fwd.round_wheel(r), fwd.flat_of("new", 0.08, 1.0, r)
    phases = np.linspace(0.0, 2 * np.pi * r, 6, endpoint=False)
    groups = ([([smooth, flat], [0.3, ph]) for ph in phases]
              + [([flat, smooth], [ph, 0.3]) for ph in phases])
    kw = dict(roughness=correction_roughness(0))
    out = {}
    for name, track in (("least", fwd.CORRECTION_TRACK), ("70", fwd.TRACK)):
        both, _ = fwd.coupled_batch(groups, [0.0, 2.5], speed, det, track=track, **kw)
        alone, _ = fwd.coupled_batch([([smooth], [0.3])], [0.0], speed, det, track=track, **kw)
        out[name] = (np.concatenate([both[:6, 0], both[6:, 1]]) - alone[0, 0], alone[0, 0])
    scale = out["70"][1].max()
    assert np.abs(out["70"][0]).max() > 0.1 * scale
    assert np.abs(out["least"][0] - out["70"][0]).max() < 5e-3 * scale


def _study_draws(study, monkeypatch, **args) -> dict:
    """{wagon: (flats, site)} that ``study.run`` (benchmarks/identify_study.py) draws with
    ``args``, every wagon's simulation and identification stubbed out."""
    import argparse

    seen = {}

    def fake_run_wagon(k, rng, args):
        seen[k] = study.draw_wagon(rng, args.sites)
        row = {"kind": "new", "length": 0.05, "length_median": 0.05, "flagged": True}
        return [row], {"simulate_s": 0.0, "identify_s": 0.0}

    monkeypatch.setattr(study, "run_wagon", fake_run_wagon)
    study.run(argparse.Namespace(**{"flats": 100, "sites": 4, "wagons_chosen": None} | args))
    return seen


def test_study_wagons_option_draws_the_whole_runs_wagons(monkeypatch):
    """benchmarks/identify_study.py --wagons: the chosen wagons get the flats and site they
    get in the whole run (the others drawn and skipped), and nothing after the last."""
    import bench_scripts

    study = bench_scripts.load("identify_study")
    whole = _study_draws(study, monkeypatch, max_wagons=8, seed=41)
    seen = _study_draws(study, monkeypatch, max_wagons=8, seed=41, wagons_chosen="2,5")
    assert sorted(seen) == [2, 5]
    for k in (2, 5):
        assert repr(seen[k]) == repr(whole[k])


def test_study_median_interval_covers_the_median():
    """benchmarks/identify_study.py's distribution-free 95 % interval of the median error:
    over 2000 samples of 50 (and of 100) from a skewed law, it covers the true median in
    at least 95 % and at most 98 % of them (its exact coverage 96.7 % / 96.5 %), and it
    holds the sample median."""
    import bench_scripts

    study = bench_scripts.load("identify_study")
    rng = np.random.default_rng(3)
    for n in (50, 100):
        hits = 0
        for _ in range(2000):
            x = rng.lognormal(-2.5, 1.0, n)  # true median exp(-2.5)
            lo, hi = study.median_interval(x)
            assert lo <= np.median(x) <= hi
            hits += lo <= np.exp(-2.5) <= hi
        assert 0.95 <= hits / 2000 <= 0.98, (n, hits)


def test_study_merge_replaces_a_rerun_wagons_rows(tmp_path):
    """identify_study.py --merge: a later run's wagons replace their rows of the earlier
    runs (a rerun of chosen wagons); the other wagons' rows are kept, in wagon order."""
    import json

    import bench_scripts

    study = bench_scripts.load("identify_study")

    def row(wagon, median):
        iv = [0.04, 0.06]
        return {"wagon": wagon, "kind": "new", "length": 0.05, "depth": 1e-4,
                "length_median": median, "depth_median": 1e-4, "flagged": True,
                "misfit": False, "p_new": 1.0, **{f"{q}_{lv}": iv if q == "length" else
                                                  [5e-5, 2e-4] for q in ("length", "depth")
                                                  for lv in study.LEVELS}}

    meta = {"flats": 2, "speeds_kmh": "60", "sites": 1, "seed": 1, "date": "d", "wagons": 2,
            "wall_s": 1.0, "simulate_s": 0.0, "identify_s": 1.0,
            "identify_median_s_per_wagon": 1.0}
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    a.write_text(json.dumps({"meta": meta, "wheels": [row(0, 0.05), row(1, 0.07)]}))
    b.write_text(json.dumps({"meta": meta, "wheels": [row(1, 0.051)]}))
    out = tmp_path / "m.json"
    study.merge([str(a), str(b)], str(out), docs=False)
    got = json.loads(out.read_text())
    assert [(r["wagon"], r["length_median"], r["run"]) for r in got["wheels"]] == [
        (0, 0.05, 0), (1, 0.051, 1)]
    assert got["summary"]["median_abs_rel_error_length"] == pytest.approx(0.01)


def test_masking_script_draws_the_studys_wagon(monkeypatch):
    """benchmarks/identify_masking.py re-simulates study wagon k with the flats and site the
    study draws for it (its own replay of the study's draws)."""
    import bench_scripts

    monkeypatch.syspath_prepend(str(bench_scripts.BENCHMARKS))  # its import, as when run
    study = bench_scripts.load("identify_study")
    masking = bench_scripts.load("identify_masking")
    seen = _study_draws(study, monkeypatch, max_wagons=6, seed=43)
    for k in (0, 3, 5):
        assert repr(masking.wagon_draw(k, 43, 4)) == repr(seen[k])


def test_severity_script_interpolates_the_tables_peak_force():
    """benchmarks/identify_severity.py: a flat's impact excess is its shape's mean peak force
    less the round wheel's, linear in the length and, for a rounded flat, in l / l0 between
    the table's rounded shapes (clamped); the flag table counts each flat in one cell."""
    import bench_scripts

    severity = bench_scripts.load("identify_severity")
    shapes = (("new", 0.0), ("rounded", 1.6), ("rounded", 1.8), ("rounded", 2.0))
    table = _table(shapes=shapes)
    slopes = np.array([4e6, 3e6, 2e6, 1e6])  # N/m per shape
    peak = 125e3 + slopes[:, None] * table.lengths[None, :]
    table = fwd.ResponseTable(table.speed, 0.65, RADIUS, shapes, table.lengths, table.offsets,
                              table.readings, np.broadcast_to(peak[:, :, None, None],
                                                              table.peak.shape).copy())
    length = 0.05

    def depth(factor):
        return (length / factor) ** 2 / (8 * RADIUS)

    assert severity.impact_excess(table, "new", length, 0.0) == pytest.approx(4e6 * length)
    assert severity.impact_excess(table, "rounded", length, depth(1.7)) == pytest.approx(
        2.5e6 * length)
    assert severity.impact_excess(table, "rounded", length, depth(2.4)) == pytest.approx(
        1e6 * length)
    rows = [{"kind": "new", "length": 0.035, "flagged": True},
            {"kind": "rounded", "length": 0.032, "flagged": False},
            {"kind": "rounded", "length": 0.08, "flagged": True}]
    cells = severity.flag_table(rows, [150e3, 10e3, 150e3])
    got = {(tuple(c["length_mm"]), tuple(c["excess_kN"])): (c["flagged"], c["n"])
           for c in cells if c["n"]}
    assert got == {((30.0, 40.0), (100.0, np.inf)): (1, 1), ((30.0, 40.0), (0.0, 20.0)): (0, 1),
                   ((60.0, 101.0), (100.0, np.inf)): (1, 1)}


def test_severity_script_finds_the_new_flat_that_reads_alike():
    """benchmarks/identify_severity.py's nearest_new: a rounded flat whose table reads as a
    new flat of half its length is found at that length, at distance 0; a gentler reading
    than every new flat under the bound lies at the bound, at the distance of its excess."""
    import bench_scripts

    severity = bench_scripts.load("identify_severity")
    shapes = (("new", 0.0), ("rounded", 1.6), ("rounded", 2.0))
    base = _table(shapes=shapes)
    reads = base.readings.copy()
    reads[1:, ..., 0] = 120e3 + 1.25e6 * base.lengths[None, :, None, None]  # rounded: l / 2
    table = fwd.ResponseTable(base.speed, 0.65, RADIUS, shapes, base.lengths, base.offsets,
                              reads, reads[..., 0])
    length = 0.03
    depth = (length / 1.8) ** 2 / (8 * RADIUS)
    ln, d = severity.nearest_new([table], "rounded", length, depth, bays=BAYS)
    assert ln == pytest.approx(length / 2) and d == pytest.approx(0.0, abs=1e-9)
    ln, d = severity.nearest_new([table], "new", 0.05, 0.0, bays=BAYS, below=0.02)
    flat = 120e3 + 2.5e6 * 0.05
    assert ln == pytest.approx(0.02)
    # the most telling phase strikes twice over the 5 bays (a circumference is 4.25 bays)
    assert d == pytest.approx(np.sqrt(2) * 2.5e6 * 0.03 / (np.hypot(0.03, 0.02) * flat),
                              rel=1e-6)
