"""What a person reads: ``identify.csv``, the JSON summary's body, the report PNG and one
terminal line per wheel."""

from __future__ import annotations

import csv
import io

import numpy as np

from .pipeline import Identification

__all__ = ["identify_csv", "summary", "wheel_line", "report_figure"]


def _fmt(v) -> str:
    if isinstance(v, (bool, np.bool_)):
        return str(bool(v)).lower()
    if isinstance(v, (float, np.floating)):
        return f"{float(v):.6g}"
    return "" if v is None else str(v)


def identify_csv(result: Identification) -> str:
    """One row per wheel: flag, P(kind), length and depth median and 90 % interval [mm],
    impact coordinate [m], highest reading [kN], P(peak > level), misfit, decisions."""
    rows = result.rows()
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(list(rows[0]))
    for r in rows:
        w.writerow([_fmt(v) for v in r.values()])
    return buf.getvalue()


def summary(result: Identification) -> dict:
    """The JSON body: settings and every wheel's row (JSON numbers)."""
    def clean(v):
        if isinstance(v, (np.floating, np.integer)):
            return v.item()
        return bool(v) if isinstance(v, np.bool_) else v

    return {"settings": result.settings,
            "passages": [{"speed_kmh": p.speed * 3.6, "n_wheels": p.n_wheels,
                          "bays": None if p.bays is None else [int(b) for b in p.bays]}
                         for p in result.passages],
            "wheels": [{k: clean(v) for k, v in r.items()} for r in result.rows()]}


def wheel_line(row: dict) -> str:
    """One terminal line of a wheel."""
    flag = "FLAT " if row["flagged"] else "ok   "
    kind = "new" if row["p_new"] >= 0.5 else "rounded"
    text = (f"  wheel {row['wheel']:2d}: {flag} P(l>=flag)={row['p_flag']:.2f}  "
            f"l={row['length_median_mm']:5.1f} [{row['length_5_mm']:5.1f}, "
            f"{row['length_95_mm']:5.1f}] mm  d={row['depth_median_mm']:.2f} mm  "
            f"{kind} (P={max(row['p_new'], row['p_rounded']):.2f})  "
            f"max {row['max_reading_kN']:.0f} kN")
    decisions = [f"{k[9:]}: {v}" for k, v in row.items() if k.startswith("decision_")
                 and v != "ok"]
    if decisions:
        text += "  -> " + "; ".join(decisions)
    if row["misfit"]:
        text += "  MISFIT: the model cannot explain these readings"
    return text


def report_figure(result: Identification):
    """Readings against the fitted model per bay and wheel (first passage), and the length
    and depth posteriors of the flagged wheels."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    wheels = result.wheels
    flagged = [w for w in wheels if w.flagged] or wheels[:1]
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    ax = axes[0]
    p0 = result.passages[0]
    bays = p0.detector_bays() if p0.bays is not None else np.array([0])
    for w in wheels:
        x = np.arange(bays.size) + w.wheel * (bays.size + 1)
        ax.plot(x, p0.readings[w.wheel] / 1e3, "o", color=f"C{w.wheel % 10}")
        ax.plot(x, np.asarray(w.post.best_fit[0]) / 1e3, "-", color=f"C{w.wheel % 10}",
                label=f"wheel {w.wheel}")
    ax.set(xlabel="wheel x bay", ylabel="reading [kN]",
           title="readings (dots) vs the posterior mode (lines)")
    ax.legend(fontsize=7)
    for w in flagged:
        post = w.post
        axes[1].plot(post.lengths * 1e3, post.weights.sum(axis=0), label=f"wheel {w.wheel}")
        d = post.depths().ravel() * 1e3
        hist, edges = np.histogram(d, bins=40, weights=post.weights.ravel())
        axes[2].step(edges[:-1], hist, where="post", label=f"wheel {w.wheel}")
    axes[1].set(xlabel="flat length [mm]", ylabel="posterior probability",
                title="length posterior (flagged wheels)")
    axes[2].set(xlabel="flat depth [mm]", ylabel="posterior probability",
                title="depth posterior (flagged wheels)")
    for a in axes[1:]:
        a.legend(fontsize=7)
    fig.tight_layout()
    return fig
