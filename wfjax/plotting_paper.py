"""Figures of the paper's results (Figs. 8, 9 and 10) from :class:`wfjax.SweepResult` objects.

Fig. 5 (:func:`wfjax.plotting.flat_inputs_figure`) and Fig. 7
(:func:`wfjax.plotting.sweep_figure`) live in :mod:`wfjax.plotting`; this module adds the depth
family and the contact-model comparison. Forces are plotted in kN, speeds in km/h. The
Agg backend is selected by importing :mod:`wfjax.plotting`.
"""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

from . import plotting as _plotting  # noqa: F401  (selects the headless Agg backend)

__all__ = [
    "MODEL_LABELS",
    "MODEL_STYLES",
    "depth_family_figure",
    "model_forces_figure",
    "model_deviation_figure",
    "relative_deviation",
]

MODEL_LABELS = {
    "3d": "3D",
    "2d": "2D",
    "hertz-trajectory": "Hertz (wheel-centre trajectory)",
    "hertz-profile": "Hertz (profile deviation)",
}
MODEL_STYLES = {"3d": "-", "2d": "--", "hertz-trajectory": "-.", "hertz-profile": ":"}


def relative_deviation(results: dict, reference: str = "3d") -> dict[str, np.ndarray]:
    """Fig. 10's Delta_F = (F - F_3D) / F_3D of the max-over-positions maximum force.

    Args:
        results: contact model -> :class:`wfjax.SweepResult` of the same flats and speeds.
        reference: the model all others are compared with.

    Returns:
        model -> [n_flats, n_speeds] relative deviation (dimensionless, 0.1 = 10 %), for every
        model other than ``reference``.
    """
    if reference not in results:
        raise ValueError(f"relative_deviation needs the reference model {reference!r}")
    f_ref = results[reference].envelope()["max_force"]
    return {m: r.envelope()["max_force"] / f_ref - 1.0
            for m, r in results.items() if m != reference}


def depth_family_figure(result, depths_mm=None, title: str | None = None):
    """Fig. 8 style: max-over-positions maximum force [kN] against speed [km/h], one line per flat.

    Black circles mark speeds where loss of contact occurs at one of the impact positions.

    Args:
        result: :class:`wfjax.SweepResult` with one flat per depth (arrays [n_flats, ...]).
        depths_mm: [n_flats] legend values (default: the flat labels).
    """
    v = np.asarray(result.speeds) * 3.6
    env = result.envelope()
    fig, ax = plt.subplots(figsize=(8, 5.5))
    cmap = plt.get_cmap("viridis")
    n = len(result.flats)
    for i, label in enumerate(result.flats):
        f = env["max_force"][i] / 1e3
        lost = env["loss_of_contact"][i]
        name = f"d = {depths_mm[i]:.2f} mm" if depths_mm is not None else label
        ax.plot(v, f, "-", color=cmap(i / max(n - 1, 1)), label=name)
        ax.plot(v[lost], f[lost], "o", mfc="none", mec="k", ms=6)
    ax.plot([], [], "o", mfc="none", mec="k", label="loss of contact (any position)")
    ax.set_xlabel("train speed [km/h]")
    ax.set_ylabel("maximum contact force [kN]")
    ax.set_title(title or f"Rounded flats, l = 1.76 l0: max over {len(result.impact_positions)} "
                 f"impact positions ({result.contact} contact)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    fig.tight_layout()
    return fig


def _panel_grid(n_flats: int, n_cols: int):
    n_rows = int(np.ceil(n_flats / n_cols))
    fig, axes = plt.subplots(n_rows, n_cols, figsize=(5.0 * n_cols, 3.2 * n_rows),
                             squeeze=False, sharex=True)
    for ax in axes.flat[n_flats:]:
        ax.set_visible(False)
    return fig, list(axes.flat)


def _label_panels(axes: list, flat_labels, n_cols: int, y_label: str) -> None:
    """Title each panel (a), (b), ... with its flat, label the y axes and the bottom x axes."""
    n = len(flat_labels)
    for i, (ax, label) in enumerate(zip(axes, flat_labels, strict=False)):
        ax.set_title(f"({chr(97 + i)}) {label}", fontsize=9)
        ax.set_ylabel(y_label)
        ax.grid(alpha=0.3)
    for ax in axes[max(0, n - n_cols):n]:
        ax.set_xlabel("train speed [km/h]")
    axes[0].legend(fontsize=7)


def model_forces_figure(results: dict, n_cols: int = 2):
    """Fig. 9 style: max-over-positions maximum force [kN] against speed for every model.

    Args:
        results: contact model -> :class:`wfjax.SweepResult` of the same flats and speeds;
            one panel per flat, filled row by row (``n_cols`` panels a row).
    """
    first = next(iter(results.values()))
    v = np.asarray(first.speeds) * 3.6
    fig, axes = _panel_grid(len(first.flats), n_cols)
    for i, ax in enumerate(axes[:len(first.flats)]):
        for model, res in results.items():
            ax.plot(v, res.envelope()["max_force"][i] / 1e3, MODEL_STYLES.get(model, "-"),
                    color="k" if model == "3d" else None, label=MODEL_LABELS.get(model, model))
    _label_panels(axes, first.flats, n_cols, "max. force [kN]")
    fig.suptitle(f"Maximum impact force, max over {len(first.impact_positions)} impact positions")
    fig.tight_layout()
    return fig


def model_deviation_figure(results: dict, n_cols: int = 2):
    """Fig. 10 style: relative deviation (F - F_3D) / F_3D [%] against speed [km/h].

    Args:
        results: as for :func:`model_forces_figure`; must contain ``"3d"``.
    """
    dev = relative_deviation(results)
    first = results["3d"]
    v = np.asarray(first.speeds) * 3.6
    fig, axes = _panel_grid(len(first.flats), n_cols)
    for i, ax in enumerate(axes[:len(first.flats)]):
        for model, d in dev.items():
            ax.plot(v, 100 * d[i], MODEL_STYLES.get(model, "-"),
                    color=f"C{list(MODEL_STYLES).index(model)}" if model in MODEL_STYLES
                    else None, label=MODEL_LABELS.get(model, model))
        ax.axhline(0.0, color="k", lw=0.8)
    _label_panels(axes, first.flats, n_cols, r"$\Delta_F$ [%]")
    fig.suptitle(r"Relative difference to the 3D model $\Delta_F = (F - F_{3D}) / F_{3D}$")
    fig.tight_layout()
    return fig
