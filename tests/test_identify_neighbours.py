"""The neighbour correction marginalised over the neighbours' phase posteriors (fast: synthetic
tables, a stand-in for the coupled runs): the phase modes, the likelihood's mixture over the
neighbours' configurations, and the corrections' plumbing."""

from __future__ import annotations

import numpy as np
import pytest

from wfjax.identify import forward as fwd
from wfjax.identify import pipeline
from wfjax.identify.inference import CorrectionMixture, Prior, WheelPosterior, posterior
from wfjax.identify.passage import Passage

BAYS = np.arange(-1, 4)


def _table(slope=0.6e6):
    """A synthetic table: bay offset 0 reads 120 kN + slope * l, the others 120 kN."""
    lengths = np.linspace(0.0, 0.13, 14)
    reads = np.full((1, lengths.size, 4, 1, fwd.TABLE_BAYS), 120e3)
    reads[..., 0] += slope * lengths[None, :, None, None]
    return fwd.ResponseTable(100 / 3.6, 0.65, 0.45, (("new", 0.0),), lengths,
                             np.arange(4) * 0.65 / 4, reads, reads[..., 0])


def test_phase_points_are_the_posteriors_strata():
    """A point mass: one point of probability 1. Two point masses 0.3 and 0.7: 10 strata put
    3 and 7 tenths on them; 4 strata 1 and 3 quarters. A normal on a fine grid: 8 strata
    are its quantiles at (i + 1/2) / 8, each of probability 1/8."""
    from scipy.stats import norm

    x = np.arange(280) * 0.01
    w = np.zeros(280)
    w[97] = 1.0
    for n in (1, 8):
        xs, ps = pipeline.phase_points(x, w, n)
        np.testing.assert_allclose(xs, [0.97])
        np.testing.assert_allclose(ps, [1.0])
    w = np.zeros(280)
    w[50], w[200] = 0.3, 0.7
    for n, p in ((10, [0.7, 0.3]), (4, [0.75, 0.25])):
        xs, ps = pipeline.phase_points(x, w, n)
        np.testing.assert_allclose(xs, [2.0, 0.5])
        np.testing.assert_allclose(ps, p)
    x = np.arange(2800) * 1e-3
    xs, ps = pipeline.phase_points(x, norm.pdf(x, 1.4, 0.05), 8)
    np.testing.assert_allclose(np.sort(xs), 1.4 + 0.05 * norm.ppf((np.arange(8) + 0.5) / 8),
                               atol=1.5e-3)
    np.testing.assert_allclose(ps, np.full(8, 1 / 8))


def test_blur_phase_is_a_periodic_gaussian():
    """A point mass blurred by sigma: the normal's mass within 1 and 2 sigma (0.683, 0.954),
    symmetric, also across the circumference's ends; sigma 0 leaves the posterior as is."""
    circ = 2.8
    x = np.arange(2800) * 1e-3
    w = np.zeros(x.size)
    w[10] = 1.0  # at 0.010 m: the blur wraps to the far end
    b = pipeline.blur_phase(x, w, 0.05, circ)
    d = np.abs((x - 0.01 + circ / 2) % circ - circ / 2)
    assert b.sum() == pytest.approx(1.0)
    for k, normal in ((1, 0.6827), (2, 0.9545)):  # the grid's edge points count half
        inside = b[d < k * 0.05 - 1e-9].sum() + 0.5 * b[np.abs(d - k * 0.05) < 1e-9].sum()
        assert inside == pytest.approx(normal, abs=5e-4)
    assert b[2800 - 30] == pytest.approx(b[50], rel=1e-9)  # -0.04 m and +0.04 m
    np.testing.assert_allclose(pipeline.blur_phase(x, 2 * w, 0.0, circ), w)


def test_blurred_neighbour_runs_at_the_blurs_strata(monkeypatch):
    """A neighbour whose phase posterior is a point mass, blurred by 5 cm: its 8 runs are at
    the normal's stratified quantiles about the point, each of probability 1/8."""
    from scipy.stats import norm

    seen = []

    def fake(groups, positions, speed, det, **kw):
        seen.extend(impacts[1] for _, impacts in groups if len(impacts) > 1)
        return (np.full((len(groups), len(positions), det.n_bays), 120e3),
                np.zeros((len(groups), len(positions))))

    monkeypatch.setattr(fwd, "coupled_batch", fake)
    passage = Passage(100 / 3.6, np.array([0.0, 2.5]), BAYS, np.full((2, 5), 120e3))
    x = np.arange(2800) * 1e-3
    one = np.zeros(x.size)
    one[500] = 1.0
    settings = dict(seed=0, contact="hertz-trajectory", cache_dir=None, passage_index=0,
                    phase_modes=8, phase_error=0.05)
    out = pipeline._corrections(passage, [_post(x, one, 0.0), _post(x, one, 0.06)],
                                settings, 0.45)
    np.testing.assert_allclose(np.sort(seen), 0.5 + 0.05 * norm.ppf((np.arange(8) + 0.5) / 8),
                               atol=1.5e-3)
    np.testing.assert_allclose(out[0].weights, np.full(8, 1 / 8))


def test_one_configuration_is_the_plain_correction():
    """A mixture of one configuration (a neighbour whose phase posterior is a point mass),
    or of two equal ones, gives the posterior of the plain additive correction."""
    t = _table()
    y = np.array([120e3, 120e3, 140e3, 121e3, 119e3])
    c = np.array([0.0, 0.0, 5e3, 0.0, 0.0])
    plain = posterior([t], [BAYS], [y], prior=Prior(p_new=1.0), corrections=[c])
    for mix in (CorrectionMixture(np.ones(1), c[None]),
                CorrectionMixture(np.array([0.3, 0.7]), np.stack([c, c]))):
        got = posterior([t], [BAYS], [y], prior=Prior(p_new=1.0), corrections=[mix])
        np.testing.assert_allclose(got.weights, plain.weights, rtol=1e-12, atol=1e-300)
        assert got.ppc_p == pytest.approx(plain.ppc_p, rel=1e-12)
        np.testing.assert_allclose(got.best_fit[0], plain.best_fit[0])


def test_mixture_spares_a_round_wheel_that_the_mode_flags():
    """A round wheel whose bay 1 reads 25 kN high because its neighbour struck there; the
    neighbour's phase posterior puts 0.6 on a phase that disturbs bay 3 and 0.4 on the true
    one. With the most probable phase only, the disturbance is explained as a 40 mm flat
    (flagged: P(l >= 20 mm) >= 0.9); marginalised over both phases, it is not."""
    t = _table()
    y = np.array([120e3, 120e3, 145e3, 120e3, 120e3])
    wrong, right = np.zeros(5), np.zeros(5)
    wrong[4], right[2] = 25e3, 25e3
    kw = dict(prior=Prior(p_new=1.0), noise=0.03, model=0.0)
    mode = posterior([t], [BAYS], [y], corrections=[wrong], **kw)
    mix = posterior([t], [BAYS], [y], corrections=[
        CorrectionMixture(np.array([0.6, 0.4]), np.stack([wrong, right]))], **kw)
    assert mode.p_length_at_least(0.02) >= 0.9
    assert mix.p_length_at_least(0.02) < 0.5
    assert mix.ppc_p > mode.ppc_p


def _post(phases, phase_w, length):
    """A WheelPosterior of one new flat of ``length`` [m] with this phase posterior."""
    lengths = Prior().lengths()
    w = np.zeros((1, lengths.size))
    w[0, int(np.argmin(np.abs(lengths - length)))] = 1.0
    best = (("new", 0.0), length, [float(phases[int(np.argmax(phase_w))])])
    return WheelPosterior((("new", 0.0),), lengths, 0.45, w, [phases], [phase_w], 0.5, [],
                          best)


def test_corrections_run_every_neighbour_mode(monkeypatch):
    """The corrections' plumbing, with a stand-in for the coupled runs whose wheel j reads
    1 kN x (the sum of the other wheels' impact coordinates [m]) in every bay: a neighbour
    with one phase point gives the single-phase correction; with two (0.25 and 0.75 of its
    posterior), one configuration each, at their impacts, with their probabilities; the
    corrected wheel is round in its runs."""
    calls = []

    def fake(groups, positions, speed, det, **kw):
        calls.append([[round(f.length, 4) for f in fl] for fl, _ in groups])
        out = np.zeros((len(groups), len(positions), det.n_bays))
        for g, (_, impacts) in enumerate(groups):
            for j in range(len(positions)):
                out[g, j] = 120e3 + 1e3 * (np.sum(impacts) - impacts[j])
        return out, np.zeros((len(groups), len(positions)))

    monkeypatch.setattr(fwd, "coupled_batch", fake)
    passage = Passage(100 / 3.6, np.array([0.0, 2.5]), BAYS, np.full((2, 5), 120e3))
    x = np.arange(280) * 0.01
    one, two = np.zeros(280), np.zeros(280)
    one[50] = 1.0
    two[50], two[200] = 0.25, 0.75
    settings = dict(seed=0, contact="hertz-trajectory", cache_dir=None, passage_index=0,
                    phase_error=0.0, phase_modes=4)
    round_post = _post(x, one, 0.0)
    out = pipeline._corrections(passage, [round_post, _post(x, one, 0.06)],
                                settings | {"phase_modes": 4}, 0.45)
    np.testing.assert_allclose(out[0].weights, [1.0])
    np.testing.assert_allclose(out[0].values, [[500.0] * 5])  # the neighbour at 0.50 m
    out = pipeline._corrections(passage, [round_post, _post(x, two, 0.06)],
                                settings | {"phase_modes": 4}, 0.45)
    np.testing.assert_allclose(out[0].weights, [0.75, 0.25])
    np.testing.assert_allclose(out[0].values[:, 0], [2000.0, 500.0])
    # the corrected wheel runs round (4 mm) beside the neighbour's estimated 60 mm flat;
    # the flat wheel's neighbour is round: no correction for it
    assert calls[-2] == [[0.004]] and calls[-1] == [[0.004, 0.06], [0.004, 0.06]]
    assert out[1] is None
    single = pipeline._corrections(passage, [round_post, _post(x, two, 0.06)],
                                   settings | {"phase_modes": 1}, 0.45)
    np.testing.assert_allclose(single[0].values, [[2000.0] * 5])
    np.testing.assert_allclose(single[0].weights, [1.0])
    # an all-round bogie: no runs, no correction
    n_calls = len(calls)
    out = pipeline._corrections(passage, [round_post, round_post], settings, 0.45)
    assert out == [None, None] and len(calls) == n_calls


def _two_kinds(p_new: float, phases, phase_w):
    """A WheelPosterior split between a new 60 mm flat (``p_new``) and a rounded 90 mm one."""
    lengths = Prior().lengths()
    w = np.zeros((2, lengths.size))
    w[0, int(np.argmin(np.abs(lengths - 0.06)))] = p_new
    w[1, int(np.argmin(np.abs(lengths - 0.09)))] = 1 - p_new
    s_best = 0 if p_new >= 0.5 else 1
    best = ((("new", 0.0), ("rounded", 1.76))[s_best], (0.06, 0.09)[s_best],
            [float(phases[int(np.argmax(phase_w))])])
    return WheelPosterior((("new", 0.0), ("rounded", 1.76)), lengths, 0.45, w, [phases],
                          [phase_w], 0.5, [], best)


def test_corrections_cover_a_neighbours_kinds(monkeypatch):
    """A neighbour split between a new 60 mm flat (P 0.3) and a rounded 90 mm one (0.7), at
    one phase: the correction runs both flats, weighted 0.7 / 0.3 (the stand-in's wheel
    reads 1 kN per mm of its neighbour's flat); with P(new) under KIND_MIN_P, or with
    ``phase_modes`` 1, only the posterior mode's flat runs."""
    def fake(groups, positions, speed, det, **kw):
        out = np.zeros((len(groups), len(positions), det.n_bays))
        for g, (flats, _) in enumerate(groups):
            for j in range(len(positions)):
                out[g, j] = 120e3 + 1e6 * sum(f.length for m, f in enumerate(flats) if m != j)
        return out, np.zeros((len(groups), len(positions)))

    monkeypatch.setattr(fwd, "coupled_batch", fake)
    passage = Passage(100 / 3.6, np.array([0.0, 2.5]), BAYS, np.full((2, 5), 120e3))
    x = np.arange(280) * 0.01
    one = np.zeros(280)
    one[50] = 1.0
    settings = dict(seed=0, contact="hertz-trajectory", cache_dir=None, passage_index=0,
                    phase_modes=8, phase_error=0.0)
    round_post = _post(x, one, 0.0)
    out = pipeline._corrections(passage, [round_post, _two_kinds(0.3, x, one)], settings,
                                0.45)
    np.testing.assert_allclose(out[0].weights, [0.7, 0.3])
    np.testing.assert_allclose(out[0].values[:, 0], [90e3, 60e3], rtol=1e-6)
    assert pipeline.KIND_MIN_P > 0.1
    for post, cfg in ((_two_kinds(0.1, x, one), settings),
                      (_two_kinds(0.3, x, one), settings | {"phase_modes": 1})):
        out = pipeline._corrections(passage, [round_post, post], cfg, 0.45)
        np.testing.assert_allclose(out[0].weights, [1.0])
        np.testing.assert_allclose(out[0].values[:, 0], [90e3], rtol=1e-6)
    flats = pipeline.kind_modes(_two_kinds(0.3, x, one), 0.45)
    assert [(f.kind, round(f.length, 3), round(p, 6)) for f, p in flats] == [
        ("rounded", 0.09, 0.7), ("new", 0.06, 0.3)]


@pytest.mark.slow
def test_exact_3d_tables_widened_to_one_column_count():
    """The 3D truth's laws (exact tables of a new 40 mm and a rounded 80 mm flat): widened by
    ``_common_columns`` to one column count, at least the longest parametric flat's, with the
    same forces at every flat position and approach."""
    from wfjax.contact.laws import prepare
    from wfjax.params import Wheel
    from wfjax.scenario.description import Scenario

    r = float(Wheel().radius)
    flats = [fwd.flat_of("new", 0.04, 1.0, r), fwd.flat_of("rounded", 0.08, 1.8, r)]
    sc = Scenario.of(flats[0], "3d", track=fwd.TRACK, config=fwd.identification_config())
    laws = [(prepare("3d", f, sc.reference_wheel, sc.track, sc.material, sc.config), ())
            for f in flats]
    assert len({np.shape(w.table.onset)[0] for w, _ in laws}) == 2  # 87 and 127 columns
    wide = fwd._common_columns(laws, sc)
    sizes = {np.shape(w.table.onset)[0] for w, _ in wide}
    assert len(sizes) == 1 and sizes.pop() >= max(np.shape(w.table.onset)[0] for w, _ in laws)
    for (law, _), (big, _) in zip(laws, wide, strict=True):
        for s in np.linspace(-0.06, 0.06, 13):
            col = law.point(s)
            for c in (2e-5, 6e-5, 1.2e-4):  # compressions [m] beyond the rigid onset
                delta = float(col.onset) + c
                a = float(law.point_force(col, delta))
                b = float(big.point_force(big.point(s), delta))
                assert a > 1e3 and b == pytest.approx(a, rel=1e-9), (s, c)


def test_a_correction_run_with_a_phantom_flat_is_dropped():
    """``pipeline.explained_away``: after a sweep, a flat wheel whose bogie neighbour is no
    longer a probable flat (its apparent flat was this wheel's ringing) loses its
    correction; a round wheel corrected beside a flat keeps its; two flats keep theirs; a
    bogie whose wheels all came out round is left as corrected (no wheel is flat to clean);
    a wheel without a correction has nothing to drop."""
    positions = np.array([0.0, 2.5, 17.5, 20.0])
    c = np.zeros(5)
    corr = [[c, None], [c, c], [None, c], [c, None]]
    assert pipeline.explained_away(positions, [True, False, True, True], corr) == [0]
    assert pipeline.explained_away(positions, [False, False, True, True], corr) == []
    assert pipeline.explained_away(positions, [True, False, True, False],
                                   [[None, None], [c, c], [None, None], [c, c]]) == []


class _P:
    """A stand-in posterior: P(l >= any length) = ``p``."""

    def __init__(self, p):
        self.p = p

    def p_length_at_least(self, length):
        return self.p


def test_a_wheel_in_doubt_is_corrected_again_over_more_configurations(monkeypatch):
    """``pipeline.in_doubt`` takes P(flag) in [0.9 - 0.3, 0.9 + 0.05), the band where the
    Hertz study's P moved by more than 0.14 from 8 to 16 configurations. After a sweep only
    the corrected wheels in doubt have their corrections rerun, over twice the
    configurations, from the posteriors the sweep started with, and only their posteriors
    recomputed; a wheel in doubt without a correction is left alone."""
    flag = dict(flag_length=0.02, flag_p=0.9)
    assert pipeline.in_doubt([_P(p) for p in (0.599, 0.601, 0.949, 0.951, 1.0)],
                             0.02, 0.9) == [1, 2]
    runs = []

    def corrections(passage, posts, settings, radius, only=None):
        runs.append((settings["phase_modes"], only, posts))
        marker = np.full(5, float(settings["phase_modes"]))
        return [marker if i in (only or {0, 1, 3}) else None for i in range(4)]

    monkeypatch.setattr(pipeline, "_corrections", corrections)
    after = [_P(0.97), _P(0.85), _P(0.62), _P(0.1)]
    asked = []

    def wheel_posteriors(corr, wheels=None):
        asked.append(wheels)
        return list(after) if wheels is None else [_P(0.3) for _ in wheels]

    passage = Passage(100 / 3.6, np.array([0.0, 2.5, 17.5, 20.0]), np.arange(-1, 4),
                      np.full((4, 5), 125e3))
    start = [_P(0.9)] * 4
    corr = [[None, None] for _ in range(4)]
    posts = pipeline._sweeps([passage, passage], start, corr, wheel_posteriors,
                             dict(phase_modes=8, **flag), 0.45, 1, None)
    assert [(m, o) for m, o, _ in runs] == [(8, None), (8, None), (16, {1}), (16, {1})]
    assert all(p is start for _, _, p in runs)
    assert asked == [None, [1]]
    assert [c[0][0] for c in corr[:2]] == [8.0, 16.0] and corr[2] == [None, None]
    assert [p.p for p in posts] == [0.97, 0.3, 0.62, 0.1]
