"""wfjax.identify end to end (slow: the response table at 100 km/h, minutes from an empty
cache): reduced versions of benchmarks/identify_study.py, the misspecified V-shaped flat and
the README's round trip."""

from __future__ import annotations

import json

import bench_scripts
import numpy as np
import pytest

from wfjax.identify import identify
from wfjax.identify.synthetic import TrainFlat, simulate_passage
from wfjax.scenario.sensors import Detector

pytestmark = pytest.mark.slow

WAGON = (0.0, 2.5, 17.5, 20.0)
SPEED = 100 / 3.6


def test_wagon_flats_recovered():
    """A wagon with a new 60 mm and a rounded 80 mm flat (the truth: coupled bogies on
    scattered supports, independent roughness, 3 % noise), each struck mid-bay: both flagged
    with the truth inside the 90 % interval and the median within 25 %; round wheels not
    flagged; no misfit."""
    flats = [TrainFlat(1, "new", 0.060, impact=0.95), TrainFlat(2, "rounded", 0.080, 1.6,
                                                                 impact=0.35)]
    passage, truth = simulate_passage(WAGON, flats, SPEED, Detector(5, -1), seed=5)
    res = identify([passage])
    for t, w in zip(truth, res.wheels, strict=True):
        assert not w.misfit, (t, w.post.ppc_p)
        if t["kind"] == "none":
            assert not w.flagged, (t, w.p_flag)
            continue
        lo, hi = w.post.interval("length", 0.9)
        med = float(w.post.length_quantiles([0.5])[0])
        assert w.flagged and lo <= t["length"] <= hi, (t, lo, hi)
        assert abs(med - t["length"]) <= 0.25 * t["length"], (t, med)


def test_round_wheel_beside_a_long_flat_not_flagged():
    """A false flag of the 2026-12-03 study (seed 31, wagon 11; its passages here as the study
    drew them): the round leading wheel reads 180 and 214 kN at 100 and 140 km/h in the last
    bay, where its neighbour's new 70 mm flat rings while it stands in the gate. With the
    neighbour correction at the neighbour's most probable phase it is flagged (a 43 mm flat);
    marginalised over the neighbour's phase modes it is not, and both flats are."""
    flats = [TrainFlat(1, "new", 0.0701598938889874), TrainFlat(3, "new", 0.08969659190266642)]
    passages = [simulate_passage(WAGON, flats, v / 3.6, Detector(5, -1), noise=0.03,
                                 seed=31 * 100003 + 101 * 11 + j + 1,
                                 site_seed=31 * 1009 + 2)[0]
                for j, v in enumerate((60, 100, 140))]
    res = identify(passages)
    assert [w.flagged for w in res.wheels] == [False, True, False, True], [
        w.p_flag for w in res.wheels]
    assert identify(passages, phase_modes=1).wheels[0].flagged


def test_study_reduced_meets_criteria():
    """benchmarks/identify_study.py reduced (seed 7, at least 6 flats, passages at 60, 100
    and 140 km/h over the study's sites): every flat >= 30 mm flagged, no round wheel flagged,
    median length error <= 10 %, and the 90 % intervals' coverage of length and depth with
    a 95 % Clopper-Pearson band containing 0.9. A strict xfail until 2026-12-05 (evening);
    with the neighbour's blurred phase at stratified points: 3 wagons, 6 flats (5 rounded),
    4 of 4 >= 30 mm flagged, 0 of 6 round wheels, 9.9 % (at the edge), 5 of 6 covered at
    90 % (5.1 min)."""
    study = bench_scripts.load("identify_study")
    args = study.main.__globals__["argparse"].Namespace(
        flats=6, max_wagons=8, speeds_kmh="60,100,140", sites=4, seed=7, site_seed=31,
        coupling=1)
    rows, _ = study.run(args)
    s = study.summarise(rows)
    assert s["flagged_30mm_or_longer"][0] == s["flagged_30mm_or_longer"][1], s
    assert s["round_flagged"][0] == 0, s
    assert s["median_abs_rel_error_length"] <= 0.10, s
    for t in s["calibration"]:
        if t["nominal"] == 0.9:
            assert t["calibrated"], t


def test_misspecified_v_flat_within_20_percent_or_rejected():
    """An asymmetric V-shaped flat (50 mm ramp in, 20 mm out, 1 mm deep: 70 mm long), not a
    parametric kind, on a single wheel: its length comes within 20 %, or the misfit test
    rejects the fit."""
    import wfjax as wf
    from wfjax.identify import forward as fwd
    from wfjax.identify.passage import Passage

    x = np.linspace(-0.05, 0.02, 141)
    z = np.where(x < 0, 1e-3 * (1 + x / 0.05), 1e-3 * (1 - x / 0.02))
    flat = wf.Flat.from_profile(x, np.clip(z, 0, None))
    det = Detector(5, -1)
    r, _ = fwd.coupled_readings([flat], [0.95], [0.0], SPEED, det)
    y = r * (1 + 0.03 * np.random.default_rng(3).standard_normal(r.shape))
    res = identify([Passage(SPEED, np.array([0.0]), det.bays(), y)])
    (w,) = res.wheels
    med = float(w.post.length_quantiles([0.5])[0])
    assert w.misfit or abs(med - 0.070) <= 0.2 * 0.070, (med, w.post.ppc_p)


def test_round_trip_two_commands(tmp_path, capsys):
    """The README's round trip: wfjax detector --passage-csv, then wfjax identify."""
    from wfjax.cli import main

    csv = tmp_path / "passage.csv"
    assert main(["detector", "--passage-csv", str(csv), "--train", "wagon", "--train-flats",
                 "1:new:60", "--bays", "5", "--passage-seed", "2"]) == 0
    truth = json.loads(csv.with_suffix(".truth.json").read_text())
    assert [t["kind"] for t in truth] == ["none", "new", "none", "none"]
    out = tmp_path / "out"
    assert main(["identify", "--readings", str(csv), "--layout", "wagon", "--out",
                 str(out)]) == 0
    rows = (out / "identify.csv").read_text().splitlines()
    assert len(rows) == 5
    text = capsys.readouterr().out
    assert sum(line.strip().startswith("wheel") for line in text.splitlines()) == 4
    summary = json.loads((out / "identify.json").read_text())
    assert not any(w["flagged"] for i, w in enumerate(summary["wheels"]) if i != 1)
