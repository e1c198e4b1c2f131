"""Which flats a validation study of ``wfjax identify`` flags, against how hard they strike
(issue 31, docs/identify.md "The criteria at a glance").

A flat's *impact excess* at a speed is its mean peak contact force over the response table's
impact positions and nuisance realisations, less a round wheel's (the same table, so the
same model as the study's identification: Hertz-trajectory or the exact 3D tables), taken at
the study's highest speed where it is largest. The study's flat wheels are binned by it and
by length; the flag rate per bin says whether the misses are the short flats (length) or the
gentle ones (severity).

    python benchmarks/identify_severity.py benchmarks/results/identify_study.json \
        benchmarks/results/identify_study_3d_id3d_all.json

Writes ``--out`` (JSON, default ``benchmarks/results/identify_severity.json``) and a PNG
beside it: each flat's P(l >= 20 mm) against its impact excess, a panel per study.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
EXCESS_BINS_KN = (0.0, 20.0, 40.0, 60.0, 100.0, np.inf)
LENGTH_BINS_MM = (20.0, 30.0, 40.0, 60.0, 101.0)
BAYS = np.arange(-1, 4)  # the studies' 5-bay detector


def _shape_weights(table, kind: str, length: float, depth: float) -> list[tuple[int, float]]:
    """[(shape row, weight)] of ``table`` standing for a flat of ``kind``, ``length`` [m] and
    ``depth`` [m]: the new shape, or the two rounded shapes around its l / l0 (linear,
    clamped to the table's rounded shapes)."""
    kinds = [k for k, _ in table.shapes]
    if kind == "new":
        return [(kinds.index("new"), 1.0)]
    rows = [i for i, k in enumerate(kinds) if k == "rounded"]
    f = np.array([table.shapes[i][1] for i in rows], float)
    w = np.interp(length / np.sqrt(8.0 * table.wheel_radius * depth), f, np.arange(f.size))
    i0 = int(min(np.floor(w), f.size - 2))
    return [(rows[i0], 1.0 - (w - i0)), (rows[i0 + 1], w - i0)]


def impact_excess(table, kind: str, length: float, depth: float) -> float:
    """[N] the mean peak contact force of a flat of ``kind``, ``length`` [m] and ``depth``
    [m] in ``table`` (linear in the length and, for a rounded flat, in l / l0 between the
    table's rounded shapes, clamped to them) less a round wheel's (the table's shortest flat)."""
    from wfjax.identify import prediction

    peaks = prediction.predict_peak(table, [length]).mean(axis=(2, 3))[:, 0]  # [S] N
    mixed = sum(w * peaks[s] for s, w in _shape_weights(table, kind, length, depth))
    return float(mixed) - float(table.peak[0, 0].mean())


def _readings(table, kind: str, lengths, depth: float, bays) -> np.ndarray:
    """[n_len, P, n_bays] N the mean readings (over the realisations) of flats of ``kind``,
    ``lengths`` [n_len] m and ``depth`` [m] (a rounded flat's: one length) at every phase of
    the table's refined grid (:func:`_shape_weights`)."""
    from wfjax.identify import prediction
    from wfjax.identify.inference import PHASE_REFINE

    mu = prediction.predict_refined(table, bays, lengths, PHASE_REFINE).mean(axis=3)
    return sum(w * mu[s] for s, w in _shape_weights(table, kind, float(lengths[0]), depth))


def nearest_new(tables: list, kind: str, length: float, depth: float, bays=BAYS,
                below: float = 0.02, sigma: float = float(np.hypot(0.03, 0.02))
                ) -> tuple[float, float]:
    """(length [m], distance) of the new flat shorter than ``below`` [m] whose readings lie
    closest to a flat's (``kind``, ``length`` [m], ``depth`` [m]) over ``tables`` (a
    ResponseTable per passage), each passage at the phase where they differ most: distance
    = sqrt(sum over passages of max over phases of sum over ``bays`` of ((new - flat) /
    (sigma flat))^2), in noise standard deviations. By Neyman-Pearson, a rule that flags
    that new flat at most 10 % of the time flags this one at most Phi(distance - 1.28) of
    the time, whatever its method."""
    news = np.arange(0.004, below + 1e-9, 0.0005)
    total = np.zeros(news.size)
    for table in tables:
        flat = _readings(table, kind, [length], depth, bays)  # [1, P, n_bays]
        z = (_readings(table, "new", news, 0.0, bays) - flat) / (sigma * flat)
        total += np.max(np.sum(z ** 2, axis=-1), axis=-1)
    k = int(np.argmin(total))
    return float(news[k]), float(np.sqrt(total[k]))


def excesses(rows: list[dict], tables: dict) -> list[float]:
    """[N] per flat row of a study (``kind``, ``length`` [m], ``depth`` [m]) its largest
    :func:`impact_excess` over ``tables`` ({speed [km/h]: ResponseTable})."""
    return [max(impact_excess(t, r["kind"], r["length"], r["depth"]) for t in tables.values())
            for r in rows]


def flag_table(rows: list[dict], excess_n: list[float]) -> list[dict]:
    """Per (length bin, excess bin): flats, flagged; the bins are ``LENGTH_BINS_MM`` x
    ``EXCESS_BINS_KN``."""
    length_mm = np.array([r["length"] for r in rows]) * 1e3
    ex_kn = np.asarray(excess_n) / 1e3
    flagged = np.array([bool(r["flagged"]) for r in rows])
    out = []
    for a, b in zip(LENGTH_BINS_MM[:-1], LENGTH_BINS_MM[1:], strict=True):
        for c, d in zip(EXCESS_BINS_KN[:-1], EXCESS_BINS_KN[1:], strict=True):
            m = (length_mm >= a) & (length_mm < b) & (ex_kn >= c) & (ex_kn < d)
            out.append({"length_mm": [a, b], "excess_kN": [c, d], "n": int(m.sum()),
                        "flagged": int(flagged[m].sum())})
    return out


def markdown(cells: list[dict]) -> str:
    """The flag table: rows by length, columns by impact excess, 'flagged / flats'."""
    cols = [(c, d) for c, d in zip(EXCESS_BINS_KN[:-1], EXCESS_BINS_KN[1:], strict=True)]
    head = ["length"] + [f"{c:.0f}-{d:.0f} kN" if np.isfinite(d) else f">= {c:.0f} kN"
                         for c, d in cols]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for a, b in zip(LENGTH_BINS_MM[:-1], LENGTH_BINS_MM[1:], strict=True):
        row = [c for c in cells if c["length_mm"] == [a, b]]
        text = [f"{c['flagged']} / {c['n']}" if c["n"] else "-" for c in row]
        lines.append(f"| {a:.0f}-{min(b, 100.0):.0f} mm | " + " | ".join(text) + " |")
    return "\n".join(lines)


def plot(studies: list[tuple[str, list[dict], list[float]]], path: Path) -> None:
    """One panel per study (title, flat rows, impact excesses [N]): P(l >= 20 mm) against the
    impact excess [kN], new and rounded flats apart, coloured by the true length."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(studies), figsize=(5.5 * len(studies) + 1, 4.2),
                             squeeze=False, sharey=True, layout="constrained")
    for ax, (title, rows, excess_n) in zip(axes[0], studies, strict=True):
        for kind, marker in (("new", "o"), ("rounded", "s")):
            pick = [i for i, r in enumerate(rows) if r["kind"] == kind]
            dots = ax.scatter([excess_n[i] / 1e3 for i in pick],
                              [rows[i]["p_flag"] for i in pick],
                              c=[rows[i]["length"] * 1e3 for i in pick], cmap="viridis",
                              vmin=20, vmax=100, marker=marker, label=kind, edgecolors="k",
                              linewidths=0.3)
        ax.axhline(0.9, color="r", lw=0.8, ls="--", label="flag threshold 0.9")
        ax.set_xscale("log")
        ax.set_xlabel("impact excess over a round wheel [kN]")
        ax.set_title(title, fontsize=9)
        ax.set_ylim(0, 1.03)
        ax.grid(alpha=0.3)
    axes[0, 0].set_ylabel("P(length >= 20 mm)")
    axes[0, 0].legend(loc="upper left", fontsize=8)
    fig.colorbar(dots, ax=axes[0].tolist(), label="true length [mm]")
    fig.savefig(path, dpi=110)
    plt.close(fig)


def one_study(path: str) -> dict:
    """A study's flat rows, their impact excesses [N] (the study's own tables) and flag
    table."""
    from wfjax.identify import forward as fwd

    study = json.loads(Path(path).read_text())
    meta = study["meta"][0] if isinstance(study["meta"], list) else study["meta"]
    contact = meta.get("identify_contact", "hertz-trajectory")
    speeds = [float(v) for v in str(meta["speeds_kmh"]).split(",")]
    tables = {v: fwd.build_table(v / 3.6, contact=contact) for v in set(speeds)}
    rows = [r for r in study["wheels"] if r["length"] > 0]
    ex = excesses(rows, tables)
    near = {i: nearest_new([tables[v] for v in speeds], r["kind"], r["length"], r["depth"])
            for i, r in enumerate(rows) if not r["flagged"] and r["length"] >= 0.03}
    return {"study": path, "contact": contact, "cells": flag_table(rows, ex),
            "flats": [{"wagon": r["wagon"], "kind": r["kind"], "length": r["length"],
                       "flagged": r["flagged"], "p_flag": r["p_flag"], "excess_N": e,
                       "nearest_new": near.get(i)}
                      for i, (r, e) in enumerate(zip(rows, ex, strict=True))]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("studies", nargs="+", help="studies' JSON (identify_study.py --out)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/identify_severity.json"),
                    help="JSON to write; the figure goes beside it (.png)")
    args = ap.parse_args(argv)
    from wfjax.cli import enable_compilation_cache

    enable_compilation_cache()
    got = [one_study(p) for p in args.studies]
    out = Path(args.out)
    out.write_text(json.dumps(got, indent=1))
    plot([(f"{Path(g['study']).name} ({g['contact']})", g["flats"],
           [f["excess_N"] for f in g["flats"]]) for g in got], out.with_suffix(".png"))
    for g in got:
        print(f"{g['study']} ({g['contact']}): flagged / flats by length and impact excess")
        print(markdown(g["cells"]))
        for f in sorted(g["flats"], key=lambda f: f["excess_N"]):
            if not f["flagged"] and f["length"] >= 0.03:
                ln, d = f["nearest_new"]
                print(f"missed: wagon {f['wagon'] + 1}, {f['kind']} {f['length'] * 1e3:.1f} "
                      f"mm, excess {f['excess_N'] / 1e3:.1f} kN, P {f['p_flag']:.2f}; "
                      f"a new {ln * 1e3:.1f} mm flat reads within {d:.2f} sigma")
    return 0


if __name__ == "__main__":
    sys.exit(main())
