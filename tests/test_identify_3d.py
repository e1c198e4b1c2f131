"""The identification with the 3D law (``identify(contact="3d")``, ``wfjax identify --contact
3d``): the response table's 3D path against direct runs of the same flats with their exact 3D
tables, the cache key, the option's way to identify(), and a bad contact's one-line error."""

from __future__ import annotations

import bench_scripts
import numpy as np
import pytest

from wfjax.identify import forward as fwd
from wfjax.identify.passage import Passage, passages_csv
from wfjax.params import Wheel
from wfjax.scenario import roughness as rough_mod
from wfjax.scenario.sensors import Detector

SPEED = 100 / 3.6
SHAPES = (("new", 0.0), ("rounded", 1.8))
LENGTHS = np.array([0.03, 0.07])  # m


def _tiny(contact):
    """A 2 shapes x 2 lengths x 2 positions x 1 realisation table at 100 km/h (seconds)."""
    return fwd.build_table(SPEED, contact=contact, shapes=SHAPES, lengths=LENGTHS,
                           n_offsets=2, n_roughness=1, seed=5)


def test_3d_table_agrees_with_direct_runs_of_the_exact_tables():
    """Every entry of the 3D table (readings in the five bays, peak contact force) equals a
    single-wheel coupled run of that flat with its own exact 3D table (``contact="3d"``,
    ``contact_mode_3d`` auto), the same roughness realisation and impact: within 0.5 % (the
    runs' windows differ: the table's starts a run-in before its flat, the coupled run a
    bay and a circumference before the detector); and the 3D law is not Hertz-trajectory's:
    the 70 mm new flat's peak force lower by more than 5 %."""
    t3 = _tiny("3d")
    rough = rough_mod.generate(rough_mod.ISO3095_LIMIT, 5, fwd.ROUGHNESS_SPAN,
                               x_start=-fwd.ROUGHNESS_SPAN / 2, n_realisations=1)
    det, radius = Detector(fwd.TABLE_BAYS, 0), float(Wheel().radius)
    for s, (kind, factor) in enumerate(SHAPES):
        for i, length in enumerate(LENGTHS):
            for j, u in enumerate(t3.offsets):
                p, f = fwd.coupled_readings([fwd.flat_of(kind, float(length), factor, radius)],
                                            [float(u)], [0.0], SPEED, det, contact="3d",
                                            roughness=rough, repeat_flats=False)
                np.testing.assert_allclose(t3.readings[s, i, j, 0], p[0], rtol=5e-3)
                np.testing.assert_allclose(t3.peak[s, i, j, 0], f[0], rtol=5e-3)
    th = _tiny("hertz-trajectory")  # cached apart: the key holds the contact law
    assert np.all(t3.peak[0, 1] < 0.95 * th.peak[0, 1]), (t3.peak[0, 1], th.peak[0, 1])


def test_command_contact_reaches_identify(tmp_path, monkeypatch):
    """``wfjax identify --contact 3d`` (and the old spelling ``--id-contact``) reaches
    identify() as ``contact="3d"``; the default stays Hertz-trajectory."""
    import wfjax.identify as identify_pkg
    from wfjax.cli import main

    seen = []

    def fake(passages, **kw):
        seen.append(kw["contact"])
        raise SystemExit(0)

    monkeypatch.setattr(identify_pkg, "identify", fake)
    path = tmp_path / "p.csv"
    path.write_text(passages_csv([Passage(SPEED, np.array([0.0, 2.5]), np.arange(-1, 4),
                                          np.full((2, 5), 120e3))]))
    for extra in (["--contact", "3d"], ["--id-contact", "3d"], []):
        with pytest.raises(SystemExit):
            main(["identify", "--readings", str(path), "--out", str(tmp_path / "o")] + extra)
    assert seen == ["3d", "3d", "hertz-trajectory"]


def test_passage_contact_reaches_the_simulated_passage(tmp_path, monkeypatch):
    """``wfjax detector --passage-csv ... --passage-contact 3d`` simulates the passage with
    the 3D law (no silent substitution); the default is Hertz-trajectory."""
    import wfjax.identify.synthetic as synthetic
    from wfjax.cli import main

    seen = []

    def fake(*args, contact, **kw):
        seen.append(contact)
        raise SystemExit(0)

    monkeypatch.setattr(synthetic, "simulate_passage", fake)
    for extra in (["--passage-contact", "3d"], []):
        with pytest.raises(SystemExit):
            main(["detector", "--passage-csv", str(tmp_path / "p.csv"), "--train", "wagon",
                  "--out", str(tmp_path / "o")] + extra)
    assert seen == ["3d", "hertz-trajectory"]


def test_bad_contact_one_line_before_any_work():
    """identify(contact="4d") and build_table(contact="4d") refuse with one line naming it."""
    from wfjax.identify import identify

    p = Passage(SPEED, np.array([0.0]), np.arange(-1, 4), np.full((1, 5), 120e3))
    for call in (lambda: identify([p], contact="4d"),
                 lambda: fwd.build_table(SPEED, contact="4d")):
        with pytest.raises(ValueError, match="'4d'") as err:
            call()
        assert "\n" not in str(err.value)


@pytest.mark.slow
def test_study_3d_truth_identified_with_the_3d_law():
    """benchmarks/identify_study.py reduced with the 3D law in truth and identification
    (seed 43, its first 3 wagons: 5 flats of 45-91 mm; 5 min once the 3D tables at 60,
    100 and 140 km/h are cached, about 15 min more from an empty cache): every flat flagged,
    no round wheel flagged, none a misfit, and the median length error at most 8 % (2026-12-04:
    5 %; the Hertz-trajectory identification of the same passages: 10 %, its lengths short
    by 5-18 %)."""
    import argparse

    study = bench_scripts.load("identify_study")
    args = argparse.Namespace(flats=5, max_wagons=3, speeds_kmh="60,100,140", sites=4,
                              seed=43, site_seed=31, coupling=1, truth_contact="3d",
                              identify_contact="3d")
    rows, _ = study.run(args)
    s = study.summarise(rows)
    assert s["n_flats"] == 5, s
    assert s["flagged_30mm_or_longer"][0] == s["flagged_30mm_or_longer"][1] == 5, s
    assert s["round_flagged"][0] == 0 and s["misfit_passages"] == 0, s
    assert s["median_abs_rel_error_length"] <= 0.08, s
