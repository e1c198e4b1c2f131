""":func:`identify`: every wheel's flat from the passages, factorised over the wheels.

Iteration 0: every wheel on its own grid (shape x length x phase x nuisance realisation,
:mod:`wfjax.identify.inference`), its neighbours absent. Iterations 1..``coupling_iterations``:
every wheel with a probable flat among its bogie's other wheels (wheels closer than
``GROUP_GAP``) is run round, coupled on one track with those neighbours at their current
estimates, and round alone, batched over the bogies
(:func:`wfjax.identify.forward.coupled_batch`: a train is a batch of bogies, each on its own
track window); their difference, the neighbours' effect on the wheel's readings, is added
to that wheel's prediction and its grid posterior recomputed. A neighbour's flat is not
one estimate: the coupled runs cover its phase posterior, blurred by the phase error its
readings leave (:func:`blur_phase`), at a few stratified points (:func:`phase_points`) and,
where its kind is uncertain, the most probable flat of each kind (:func:`kind_modes`), and
each wheel's likelihood is marginalised over them with their probabilities
(:class:`wfjax.identify.inference.CorrectionMixture`). After the sweep a flat wheel none of
whose neighbours is still a probable flat loses its correction (:func:`explained_away`: it
was run with a phantom, a round neighbour's reading of this wheel's ringing), and a
corrected wheel whose flag is in doubt (:func:`in_doubt`) is corrected again over twice the
configurations. No joint grid over the wheels is ever formed.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from ..params import Wheel
from . import forward as fwd
from . import prediction
from . import rules as rules_mod
from .inference import CorrectionMixture, Prior, WheelPosterior, posterior
from .passage import Passage

__all__ = ["identify", "Identification", "WheelResult", "GROUP_GAP", "MISFIT_P",
           "correction_roughness"]

GROUP_GAP = 4.0  # m: wheels closer than this are coupled (a bogie)
MISFIT_P = 1e-3  # posterior-predictive p-value below which a passage is not explained
ROUND_LENGTH = 0.015  # m: a bogie none of whose wheels has P(l >= this) >= 0.5 is not corrected
KIND_MIN_P = 0.2  # a neighbour's kind (new, rounded) below this probability is not run
# m: a flat wheel's phase posterior blurred by this is calibrated (its ranks of the true
# impact closest to uniform, Kolmogorov-Smirnov 0.066 of 285 wheel-passages, 0.150 unblurred;
# benchmarks/identify_phase_error.py on the Hertz study's seed 41, docs/identify.md)
PHASE_ERROR = 0.05
# A flat neighbour's configurations (phase points x kinds) its correction averages: 16 for
# every wheel take 1.8x the passage time (benchmarks/identify_ab.py --compare networks16),
# past the 20 s a passage may take on two of five hard wagons, so 16 only where a flag is in
# doubt (below); docs/identify.md "Neighbour phase", "Refined where in doubt".
PHASE_MODES = 8
# A corrected wheel whose P(flag) lies in [flag_p - REFINE_BELOW, flag_p + REFINE_ABOVE)
# after a sweep is corrected again over REFINE_FACTOR x PHASE_MODES configurations. From the
# Hertz study run at 8 and at 16 (252 wheels, docs/identify.md "Refined where in doubt"):
# P(flag) moved by at most 0.14 below 0.6 and 0.007 at 0.95 and above, by up to 0.58 between.
REFINE_FACTOR = 2
REFINE_BELOW = 0.3
REFINE_ABOVE = 0.05


@dataclasses.dataclass
class WheelResult:
    """One wheel's answer (SI units; see :meth:`row` for the reported fields)."""

    wheel: int
    post: WheelPosterior
    max_reading: float
    flagged: bool
    p_flag: float
    p_exceed: float | None
    decisions: dict
    misfit: bool

    def row(self) -> dict[str, Any]:
        """The wheel's line of ``identify.csv`` (mm, kN, probabilities)."""
        p = self.post
        lq = p.length_quantiles([0.05, 0.5, 0.95]) * 1e3
        dq = p.depth_quantiles([0.05, 0.5, 0.95]) * 1e3
        x, px = p.phase(0)
        out = {"wheel": self.wheel, "flagged": self.flagged, "p_flag": self.p_flag,
               "p_new": p.p_kind("new"), "p_rounded": p.p_kind("rounded"),
               "length_median_mm": lq[1], "length_5_mm": lq[0], "length_95_mm": lq[2],
               "depth_median_mm": dq[1], "depth_5_mm": dq[0], "depth_95_mm": dq[2],
               "impact_x_m": x, "p_impact_x": px, "max_reading_kN": self.max_reading / 1e3,
               "p_peak_exceeds": self.p_exceed, "ppc_p": p.ppc_p, "misfit": self.misfit}
        out.update({f"decision_{k}": v for k, v in self.decisions.items()})
        return out


@dataclasses.dataclass
class Identification:
    """:func:`identify`'s answer: ``wheels`` [n] :class:`WheelResult` and the settings."""

    wheels: list
    settings: dict
    tables: list
    passages: list

    def rows(self) -> list[dict]:
        return [w.row() for w in self.wheels]


def _groups(positions: np.ndarray) -> list[list[int]]:
    """Wheels in bogies: consecutive wheels closer than :data:`GROUP_GAP`."""
    out = [[0]]
    for i in range(1, positions.size):
        if positions[i] - positions[i - 1] < GROUP_GAP:
            out[-1].append(i)
        else:
            out.append([i])
    return out


def _probably_flat(posts) -> list[bool]:
    """Per wheel: whether it probably has a flat (P(l >= :data:`ROUND_LENGTH`) >= 0.5), which
    makes it a neighbour the corrections run with its posterior's configurations."""
    return [p.p_length_at_least(ROUND_LENGTH) >= 0.5 for p in posts]


def refine_band(flag_p: float) -> tuple[float, float]:
    """[lo, hi): the P(flag) of a wheel in doubt around the flag probability ``flag_p``,
    [``flag_p`` - :data:`REFINE_BELOW`, ``flag_p`` + :data:`REFINE_ABOVE`)."""
    return flag_p - REFINE_BELOW, flag_p + REFINE_ABOVE


def in_doubt(posts, flag_length: float, flag_p: float) -> list[int]:
    """The wheels whose flag the neighbours' configurations may still turn: P(l >=
    ``flag_length``) within :func:`refine_band` of ``flag_p``."""
    lo, hi = refine_band(flag_p)
    return [i for i, p in enumerate(posts) if lo <= p.p_length_at_least(flag_length) < hi]


def explained_away(positions: np.ndarray, flat: list, corr: list) -> list[int]:
    """The wheels whose neighbour corrections ``corr`` [wheel][passage] are to be dropped
    after a sweep: a wheel still probably flat (``flat`` [wheel], after the sweep) none of
    whose bogie neighbours is. Its correction ran with a neighbour's flat that the
    neighbour's own correction has since explained as this wheel's ringing (a round wheel
    beside a flat reads the flat's impact in a gate and looks flat until corrected); kept,
    it would explain part of the wheel's own impact as that phantom's."""
    out = []
    for g in _groups(positions):
        for i in g:
            if (flat[i] and any(c is not None for c in corr[i])
                    and not any(flat[j] for j in g if j != i)):
                out.append(i)
    return out


def _layouts(positions: np.ndarray, groups: list[list[int]]) -> dict:
    """The ``groups`` (bogies) by their layout: (positions behind the group's first wheel,
    rounded to 0.1 mm) -> [groups]."""
    out: dict = {}
    for g in groups:
        key = tuple(np.round(positions[g] - positions[g[0]], 4).tolist())
        out.setdefault(key, []).append(g)
    return out


def _estimate_flat(post: WheelPosterior, radius: float):
    (kind, factor), length, _ = post.best
    return fwd.flat_of(kind, max(length, 0.005), factor or 1.0, radius)


def kind_modes(post: WheelPosterior, radius: float, min_p: float = KIND_MIN_P) -> list:
    """[(flat, probability)], most probable first, sum 1: for each kind (new, rounded) with
    P(kind) >= ``min_p``, its most probable grid flat (shape and length). A wheel whose
    posterior is split between a short new and a long rounded flat has two, as its phase
    posterior may have several modes (:func:`phase_points`)."""
    out = []
    for kind in ("new", "rounded"):
        p = post.p_kind(kind)
        rows = [s for s, (k, _) in enumerate(post.shapes) if k == kind]
        if not rows or p < min_p:
            continue
        s, n = np.unravel_index(int(np.argmax(post.weights[rows])), (len(rows),
                                                                     post.lengths.size))
        k, factor = post.shapes[rows[s]]
        out.append((fwd.flat_of(k, max(float(post.lengths[n]), 0.005), factor or 1.0,
                                radius), p))
    if not out:  # min_p above every kind's probability: the posterior mode alone
        return [(_estimate_flat(post, radius), 1.0)]
    total = sum(p for _, p in out)
    return sorted(((f, p / total) for f, p in out), key=lambda fp: -fp[1])


def neighbour_modes(post: WheelPosterior, passage: int, radius: float, n_max: int,
                    phase_error: float = 0.0) -> tuple[np.ndarray, np.ndarray, list]:
    """A probably flat neighbour's configurations for the correction: (impact coordinates
    [M] m, probabilities [M], flats [M]), M <= ``n_max``, the product of its kind modes
    (:func:`kind_modes`, K of them) and ``n_max // K`` phase points per kind
    (:func:`phase_points` of its phase posterior blurred by ``phase_error`` [m],
    :func:`blur_phase`), most probable first (``n_max`` 1: its posterior mode, the
    correction before 2026-12-04)."""
    if n_max <= 1:
        return (np.array([post.best[2][passage]]), np.ones(1),
                [_estimate_flat(post, radius)])
    kinds = kind_modes(post, radius)
    x = post.phases[passage]
    xs, ps = phase_points(x, blur_phase(x, post.phase_weights[passage], phase_error,
                                        circumference(radius)), max(n_max // len(kinds), 1))
    joint = sorted(((x, p * q, f) for x, p in zip(xs, ps, strict=True) for f, q in kinds),
                   key=lambda m: -m[1])
    return (np.array([m[0] for m in joint]), np.array([m[1] for m in joint]),
            [m[2] for m in joint])


def phase_points(phases, weights, n: int) -> tuple[np.ndarray, np.ndarray]:
    """A wheel's phase posterior as at most ``n`` points: (impact coordinates [M] m,
    probabilities [M], sum 1), M <= ``n``, most probable first.

    Stratified: the posterior's quantiles at (i + 1/2) / n, i = 0..n-1, along the
    circumference cut where the posterior is least, each of probability 1 / n; quantiles on
    one grid point merge. An unbiased average over the phase where a neighbour's effect
    steps within centimetres (a gate edge), which its few most probable points are not; a
    point mass gives one point of probability 1."""
    x, w = np.asarray(phases, float), np.asarray(weights, float)
    n = max(int(n), 1)
    order = np.roll(np.arange(x.size), -int(np.argmin(w)))
    cdf = np.cumsum(w[order]) / np.sum(w)
    idx = order[np.minimum(np.searchsorted(cdf, (np.arange(n) + 0.5) / n), x.size - 1)]
    keys, counts = np.unique(idx, return_counts=True)
    first = np.argsort(-counts, kind="stable")
    return x[keys[first]], counts[first] / n


def blur_phase(phases, weights, sigma: float, circ: float) -> np.ndarray:
    """A phase posterior ``weights`` [P] on impact coordinates ``phases`` [P] m, blurred by a
    periodic Gaussian of standard deviation ``sigma`` [m] over the circumference ``circ``
    [m] (the phase error its own readings leave unmodelled, :data:`PHASE_ERROR`); [P], sum 1.
    ``sigma`` 0: the posterior itself."""
    x, w = np.asarray(phases, float), np.asarray(weights, float)
    if sigma <= 0:
        return w / np.sum(w)
    d = (x[:, None] - x[None, :] + circ / 2) % circ - circ / 2
    out = np.exp(-0.5 * (d / sigma) ** 2) @ w
    return out / np.sum(out)


def _configurations(g: list[int], modes: dict, n_max: int) -> dict:
    """For every wheel i of bogie ``g``: [(the bogie's mode indices per wheel (i at its
    most probable phase, 0), probability)] over the product of its neighbours' phase modes
    (each neighbour at most ``n_max ** (1 / (n - 1))`` modes, so at most about ``n_max``
    configurations per wheel)."""
    import itertools

    per = max(1, int(math.floor(n_max ** (1.0 / max(len(g) - 1, 1)) + 1e-9)))
    out = {}
    for i in g:
        axes = [[(0, 1.0)] if j == i else list(enumerate(modes[j][1][:per])) for j in g]
        confs = []
        for combo in itertools.product(*axes):
            confs.append((tuple(c[0] for c in combo), float(np.prod([c[1] for c in combo]))))
        total = sum(c[1] for c in confs)
        out[i] = [(idx, p / total) for idx, p in confs]
    return out


def correction_roughness(seed: int = 0):
    """The rail roughness [one :class:`wfjax.Roughness` realisation of the ISO 3095 limit,
    ``forward.ROUGHNESS_SPAN`` m centred on x = 0] of the neighbour corrections' runs of
    ``identify(seed=seed)``."""
    from ..scenario import roughness as rough_mod

    return rough_mod.generate(rough_mod.ISO3095_LIMIT, int(seed) + 7919, fwd.ROUGHNESS_SPAN,
                              x_start=-fwd.ROUGHNESS_SPAN / 2)


def _corrections(passage: Passage, posts, settings: dict, radius: float,
                 only: set | None = None) -> list:
    """Per wheel a :class:`CorrectionMixture` of [n_bays] N, the neighbours' effect on its
    readings: the wheel **round** in its bogie with its neighbours at their estimates, minus
    the wheel round alone, over the neighbours' phase points (:func:`phase_points` of their
    posteriors in this passage blurred by ``settings["phase_error"]``, and its kinds:
    ``settings["phase_modes"]`` configurations at most, :func:`neighbour_modes`); None for
    a wheel none of whose neighbours probably has a flat (P(l >= :data:`ROUND_LENGTH`) >=
    0.5: a round wheel barely moves its neighbours' readings).

    The wheel is round in these runs, not at its own estimate: a neighbour's impact that
    rings while the wheel stands in a gate reads as a flat of its own at iteration 0, and
    a correction computed with that flat in place finds nothing left to correct (the gated
    peak is the larger of the two events, not their sum). The corrections add to the
    wheel's own modelled readings. The runs go as one batch per layout
    (:func:`wfjax.identify.forward.coupled_batch`), the wheels alone as one more: a train's
    bogies are not looped over. Both on :data:`wfjax.identify.forward.CORRECTION_TRACK`,
    the identification's track at the least length the detector's reading needs. ``only``:
    the wheels whose corrections are wanted (None: every wheel; the others stay None)."""
    det = passage.detector()
    rough = correction_roughness(settings["seed"])
    out: list = [None] * passage.n_wheels
    kw = dict(contact=settings["contact"], roughness=rough, cache_dir=settings["cache_dir"],
              track=fwd.CORRECTION_TRACK)
    k, n_max = settings["passage_index"], int(settings["phase_modes"])
    flat = dict(enumerate(_probably_flat(posts)))
    todo = [(g, i) for g in _groups(passage.positions) if len(g) > 1 for i in g
            if any(flat[j] for j in g if j != i) and (only is None or i in only)]
    if not todo:  # no wheel has a neighbour with a flat: no correction
        return out
    wheels = sorted({j for g, _ in todo for j in g})
    smooth = fwd.round_wheel(radius)
    blur = float(settings["phase_error"])
    modes = {i: neighbour_modes(posts[i], k, radius, n_max if flat[i] else 1, blur)
             for i in wheels}
    mine = sorted({i for _, i in todo})
    alone, _ = fwd.coupled_batch([([smooth], [modes[i][0][0]]) for i in mine], [0.0],
                                 passage.speed, det, **kw)
    single = dict(zip(mine, alone[:, 0], strict=True))
    for layout, members in _layouts(passage.positions, [g for g, _ in todo]).items():
        confs = {(tuple(g), i): _configurations(g, modes, n_max)[i] for g, i in todo
                 if g in members}
        runs = sorted({(key, idx) for key, c in confs.items() for idx, _ in c})
        both, _ = fwd.coupled_batch(
            [([smooth if j == key[1] else modes[j][2][m] for j, m in zip(key[0], idx,
                                                                      strict=True)],
              [modes[j][0][m] for j, m in zip(key[0], idx, strict=True)])
             for key, idx in runs], layout, passage.speed, det, **kw)
        got = dict(zip(runs, both, strict=True))
        for (g, i), c in confs.items():
            j = g.index(i)
            out[i] = CorrectionMixture(np.array([p for _, p in c]), np.stack(
                [got[((g, i), idx)][j] - single[i] for idx, _ in c]))
    return out


def _sweeps(passages: list[Passage], posts, corr, wheel_posteriors, settings: dict,
            radius: float, iterations: int, progress) -> list:
    """The wheels' posteriors after ``iterations`` neighbour-correction sweeps from
    ``posts``; ``corr`` [wheel][passage] is filled in place, ``wheel_posteriors(corr,
    wheels=None)`` recomputes the posteriors of ``wheels`` (None: every wheel). After each
    sweep, a corrected wheel whose flag is in doubt (:func:`in_doubt`) has its correction
    rerun over ``REFINE_FACTOR`` times the neighbours' configurations."""
    def rerun(before, settings, only=None):
        for k, p in enumerate(passages):
            c = _corrections(p, before, settings | {"passage_index": k}, radius, only)
            for i in (range(len(before)) if only is None else only):
                corr[i][k] = c[i]

    for it in range(iterations):
        before = posts
        rerun(before, settings)
        posts = wheel_posteriors(corr)
        dropped = explained_away(passages[0].positions, _probably_flat(posts), corr)
        for i in dropped:  # only these wheels' posteriors change
            corr[i] = [None] * len(passages)
        doubt = [i for i in in_doubt(posts, settings["flag_length"], settings["flag_p"])
                 if i not in dropped and any(c is not None for c in corr[i])]
        if doubt:
            rerun(before, settings | {"phase_modes": REFINE_FACTOR * settings["phase_modes"]},
                  set(doubt))
        for i, post in zip(dropped + doubt, wheel_posteriors(corr, dropped + doubt),
                           strict=True):
            posts[i] = post
        if progress:
            progress("neighbour corrections", it + 1, iterations)
    return posts


def _response_tables(passages: list[Passage], line: float, opts: dict, progress) -> dict:
    """{speed rounded to 1e-9 m/s: its :class:`~wfjax.identify.forward.ResponseTable`} for
    every passage's speed and the line speed ``line`` [m/s]."""
    out = {}
    for v in sorted({round(p.speed, 9) for p in passages} | {round(line, 9)}):
        out[v] = fwd.build_table(v, gauge_offset=passages[0].gauge_offset,
                                 calibration=passages[0].calibration,
                                 progress=progress and (lambda d, t, v=v: progress(
                                     f"response table {v * 3.6:.0f} km/h", d, t)), **opts)
    return out


def identify(passages: list[Passage], contact: str = "hertz-trajectory", noise: float = 0.03,
             model: float = 0.02, prior: Prior | None = None, flag_length: float = 0.02,
             flag_probability: float = 0.9, line_speed: float | None = None,
             force_level: float = 350e3, user_rule=None, coupling_iterations: int = 1,
             phase_modes: int = PHASE_MODES, phase_error: float = PHASE_ERROR,
             table_options: dict | None = None,
             wheel: Wheel | None = None, seed: int = 0, cache_dir=None,
             progress=None) -> Identification:
    """Every wheel's flat from detector ``passages`` (:func:`wfjax.identify.read_passages`).

    Args:
        passages: [n_p] :class:`Passage` of one train (the same wheels in each).
        contact: the contact law of the response tables and the neighbour corrections:
            ``"hertz-trajectory"`` (the default, fast) or ``"3d"`` (every tabulated flat's
            exact 3D table, Kalker: :mod:`wfjax.identify.table3d`; tables cached apart).
        noise: relative standard deviation of a reading (the detector's); model: the
            emulator's relative error; both enter the relative Gaussian noise model.
        prior: :class:`Prior` (kind probability, length grid [m]).
        flag_length [m], flag_probability: flagged when P(l >= flag_length) >= probability.
        line_speed: speed [m/s] of P(peak contact force > ``force_level`` [N]) (default: the
            first passage's speed).
        user_rule: a :class:`wfjax.identify.rules.RuleSet` or None.
        coupling_iterations: neighbour-correction sweeps (0: wheels independent).
        phase_modes: the most configurations of a flat neighbour (:func:`neighbour_modes`:
            phase points x kinds) the correction is marginalised over (1: its posterior
            mode only).
        phase_error: the blur [m] of a neighbour's phase posterior (:func:`blur_phase`).
        table_options: keyword arguments of :func:`wfjax.identify.forward.build_table`.
        progress: ``progress(stage: str, done, total)`` or None.

    Returns:
        :class:`Identification`.
    """
    from ..contact.registry import check

    check(contact, "identify: contact")  # one line naming the value, before any work
    wheel, prior = wheel or Wheel(), prior or Prior()
    opts = dict(table_options or {}, contact=contact, wheel=wheel, seed=seed,
                cache_dir=cache_dir)
    line = float(line_speed or passages[0].speed)
    tables = _response_tables(passages, line, opts, progress)
    ptables = [tables[round(p.speed, 9)] for p in passages]
    bays = [p.detector_bays() for p in passages]
    n = passages[0].n_wheels
    kw = dict(prior=prior, noise=noise, model=model, peak_only=passages[0].peak_only)
    corr = [[None] * len(passages) for _ in range(n)]

    def wheel_posteriors(corrections, wheels=None):
        return [posterior(ptables, bays, [p.readings[i] for p in passages],
                          corrections=corrections[i], **kw)
                for i in (range(n) if wheels is None else wheels)]

    posts = wheel_posteriors(corr)  # on the raw readings: the site factors' model
    factors = pooled_site_factors(passages, [np.stack([posts[i].best_fit[k] for i in range(n)])
                                             for k in range(len(passages))])
    passages = [dataclasses.replace(p, readings=p.readings / f[None, :])
                for p, f in zip(passages, factors, strict=True)]
    posts = wheel_posteriors(corr)
    settings = dict(contact=contact, seed=seed, cache_dir=cache_dir, phase_modes=phase_modes,
                    phase_error=phase_error, flag_length=flag_length, flag_p=flag_probability)
    posts = _sweeps(passages, posts, corr, wheel_posteriors, settings, float(wheel.radius),
                    coupling_iterations if n > 1 else 0, progress)
    line_table = tables[round(line, 9)]
    results = [_result(i, posts[i], passages, line_table, force_level, flag_length,
                       flag_probability, user_rule) for i in range(n)]
    return Identification(results, dict(
        contact=contact, noise=noise, model=model, prior=dataclasses.asdict(prior),
        flag_length_m=flag_length, flag_probability=flag_probability, line_speed_ms=line,
        force_level_N=force_level, coupling_iterations=coupling_iterations,
        phase_modes=phase_modes, phase_error_m=phase_error,
        refine_in_doubt=dict(factor=REFINE_FACTOR, band=list(refine_band(flag_probability))),
        misfit_p=MISFIT_P, seed=seed, site_factors=[f.tolist() for f in factors],
        table_options={k: v for k, v in opts.items() if k not in ("wheel", "cache_dir")},
        user_rule=None if user_rule is None else dataclasses.asdict(user_rule)),
        [tables[k] for k in sorted(tables)], passages)


def site_factors(passage: Passage, fit: np.ndarray) -> np.ndarray:
    """[n_bays] each bay's site factor: the median over the passage's wheels of the bay's
    reading over the wheel's modelled reading ``fit`` [n_wheels, n_bays] N (the posterior
    mode's, :attr:`WheelPosterior.best_fit`, from readings not divided by any factor); 1 with
    fewer than 3 wheels or peaks only.

    A bay's static response (its supports, the bridges' calibration) is common to every wheel
    that crosses it, so the median of the readings' ratios to the model isolates it. Over the
    model, not over a round wheel's reading: a 5-bay detector reads each flat in one or two
    bays and each neighbour's ringing in others, so in a four-axle passage a bay can read an
    impact in most of its wheels (seed 41, wagon 22 of the study: 7 of 12 readings of bay 2,
    a factor of 1.25 where the model's gives 1.01)."""
    n_bays = 1 if passage.peak_only else passage.readings.shape[1]
    if passage.peak_only or passage.n_wheels < 3:
        return np.ones(n_bays)
    return np.median(passage.readings / np.asarray(fit), axis=0)


def pooled_site_factors(passages: list[Passage], fits: list) -> list[np.ndarray]:
    """Per passage [n_bays] site factors (:func:`site_factors`, ``fits[p]`` [n_wheels,
    n_bays] N the wheels' modelled readings in passage p); when every passage reads the same
    bays (one site), the median runs over every wheel of every passage at once: a bay's
    supports are the same on every passage, and the more wheels the median sees, the less a
    poorly fitted wheel moves it."""
    same = all(not p.peak_only for p in passages) and len({tuple(p.bays) for p in passages}) == 1
    if not same or len(passages) == 1 or sum(p.n_wheels for p in passages) < 3:
        return [site_factors(p, f) for p, f in zip(passages, fits, strict=True)]
    ratios = np.concatenate([p.readings / np.asarray(f)
                             for p, f in zip(passages, fits, strict=True)])
    return [np.median(ratios, axis=0)] * len(passages)


def p_peak_exceeds(post: WheelPosterior, table: fwd.ResponseTable, level: float) -> float:
    """P(the wheel's peak contact force at the table's speed > ``level`` [N]) under the
    posterior (impact position and nuisance realisations averaged)."""
    peak = prediction.predict_peak(table, post.lengths)  # [S, L, J, R]
    return float(np.sum(post.weights * (peak > level).mean(axis=(2, 3))))


def _result(i, post, passages, line_table, level, flag_length, flag_p, user_rule):
    max_reading = float(max(np.max(p.readings[i]) for p in passages))
    p_flag = post.p_length_at_least(flag_length)
    sets = [rules_mod.TRAFIKVERKET, rules_mod.FRA] + ([user_rule] if user_rule else [])
    decisions = {r.name: rules_mod.decide(r, max_reading, lambda x: post.p_length_at_least(
        x + 1e-9)) for r in sets}
    return WheelResult(i, post, max_reading, rules_mod.flagged(p_flag, flag_p), p_flag,
                       p_peak_exceeds(post, line_table, level), decisions,
                       bool(post.ppc_p < MISFIT_P))


def circumference(radius: float) -> float:
    """2 pi R [m]."""
    return 2 * math.pi * radius
