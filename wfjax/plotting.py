"""Matplotlib figures of wfjax results (headless: the Agg backend is selected here, except
in a Jupyter kernel, whose inline backend shows the figures in the notebook)."""

from __future__ import annotations

import sys

import matplotlib

if "ipykernel" not in sys.modules:
    matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .model import geometry  # noqa: E402
from .params import Flat, new_flat_length  # noqa: E402


def flat_inputs_figure(flats: dict[str, Flat]):
    """Fig. 5 of the paper: profile deviation against rigid wheel-centre trajectory.

    Args:
        flats: label -> flat; one panel each.

    Returns:
        The matplotlib figure (x in mm along the circumference, r_eq in mm).
    """
    fig, axes = plt.subplots(1, len(flats), figsize=(5.2 * len(flats), 3.6), squeeze=False)
    for ax, (label, flat) in zip(axes[0], flats.items(), strict=True):
        half = 1.2 * flat.half_extent
        x = np.linspace(-half, half, 801)
        z = np.asarray(geometry.profile_deviation(flat, x))
        traj = np.asarray(geometry.centre_trajectory(flat, x))
        ax.plot(x * 1e3, -z * 1e3, "--", color="C0", label="wheel profile deviation")
        ax.plot(x * 1e3, traj * 1e3, "-", color="C3", label="wheel-centre trajectory")
        ax.set_title(label)
        ax.set_xlabel("distance from flat centre x [mm]")
        ax.set_ylabel("relative displacement input $-r_{eq}$ [mm]")
        ax.grid(alpha=0.3)
        ax.legend(loc="lower left", fontsize=8)
    fig.tight_layout()
    return fig


def default_fig5_flats(depth: float = 0.9e-3, wheel_radius: float = 0.45) -> dict[str, Flat]:
    """The flats of Fig. 5: new (depth d, length l0) and rounded (l = 1.76 l0)."""
    l0 = new_flat_length(depth, wheel_radius)
    return {
        f"(a) new flat, d = {depth * 1e3:g} mm, l0 = {l0 * 1e3:.1f} mm": Flat.new(
            depth, wheel_radius),
        f"(b) rounded flat, d = {depth * 1e3:g} mm, l = 1.76 l0": Flat.rounded_relative(
            depth, 1.76, wheel_radius
        ),
    }


def sweep_figure(result, title: str | None = None, preload: float = 118e3):
    """Fig. 7 style: max and min contact force [kN] against speed [km/h] for every flat.

    The band shows the spread over impact positions, the line the envelope (max of max,
    min of min); filled markers where loss of contact occurs at some position; a dotted line
    at the static wheel load.

    Args:
        result: a :class:`wfjax.SweepResult`.
        title: figure title (default: positions and contact model).
        preload: static wheel load P [N] of the sweep (the dotted line).
    """
    v = np.asarray(result.speeds) * 3.6
    fig, ax = plt.subplots(figsize=(8, 5))
    markers = ["o", "s", "^", "D", "v", "P", "X", "*"]
    for i, label in enumerate(result.flats):
        color = f"C{i}"
        mx = np.asarray(result.max_force[i]) / 1e3
        mn = np.asarray(result.min_force[i]) / 1e3
        lost = np.any(np.asarray(result.loss_of_contact[i]), axis=-1)
        ax.fill_between(v, mx.min(-1), mx.max(-1), color=color, alpha=0.2, lw=0)
        ax.fill_between(v, mn.min(-1), mn.max(-1), color=color, alpha=0.2, lw=0)
        m = markers[i % len(markers)]
        ax.plot(v, mx.max(-1), "-", marker=m, mfc="none", color=color, label=f"{label}: max")
        ax.plot(v, mn.min(-1), "--", marker=m, mfc="none", color=color, label=f"{label}: min")
        ax.plot(v[lost], mn.min(-1)[lost], m, color=color, ls="none")
    ax.axhline(float(preload) / 1e3, color="k", lw=0.8, ls=":", label="static load")
    ax.set_xlabel("train speed [km/h]")
    ax.set_ylabel("contact force [kN]")
    ax.set_title(title or f"Max/min contact force over {len(result.impact_positions)} impact "
                 f"positions ({result.contact} contact); filled: loss of contact")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def percentile_band_figure(result, preload: float = 118e3):
    """Monte Carlo band: the max contact force [kN] over roughness realisations against
    speed [km/h] for every flat: the 5-95 % band shaded, the 50, 95 and 99 % percentiles as
    lines and the realisations' extremes dotted (:meth:`wfjax.SweepResult.percentiles`)."""
    v = np.asarray(result.speeds) * 3.6
    worst = np.max(np.asarray(result.realisation_max_force), axis=2) / 1e3  # [f, v, R]
    pct = np.percentile(worst, [5, 50, 95, 99], axis=-1)
    fig, ax = plt.subplots(figsize=(8, 5))
    for i, label in enumerate(result.flats):
        color = f"C{i}"
        ax.fill_between(v, pct[0, i], pct[2, i], color=color, alpha=0.2, lw=0,
                        label=f"{label}: 5-95 %")
        ax.plot(v, pct[1, i], "-o", color=color, mfc="none", label=f"{label}: median")
        ax.plot(v, pct[2, i], "--", color=color, label=f"{label}: 95 %")
        ax.plot(v, pct[3, i], "-.", color=color, label=f"{label}: 99 %")
        ax.plot(v, worst[i].min(-1), ":", color=color, lw=0.8)
        ax.plot(v, worst[i].max(-1), ":", color=color, lw=0.8)
    ax.axhline(float(preload) / 1e3, color="k", lw=0.8, ls=":", label="static load")
    ax.set_xlabel("train speed [km/h]")
    ax.set_ylabel("max contact force [kN]")
    ax.set_title(f"Max contact force over {worst.shape[-1]} roughness realisations "
                 f"({result.contact} contact); dotted: min and max realisation")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def force_history_figure(result, flat: Flat | None = None, preload: float = 118e3):
    """Contact force [kN] against wheel position relative to the impact [mm].

    Loss-of-contact spans are shaded; the static load is a dotted line; when ``flat`` is given
    an inset shows its profile deviation and wheel-centre trajectory.

    Args:
        result: a :class:`wfjax.SimResult`.
    """
    s = np.asarray(result.s) * 1e3
    f = np.asarray(result.force) / 1e3
    fig, ax = plt.subplots(figsize=(9, 4.5))
    ax.plot(s, f, color="C0", lw=1.2)
    ax.axhline(preload / 1e3, color="k", ls=":", lw=0.8, label="static load P")
    lost = f <= 0
    if lost.any():
        edges = np.flatnonzero(np.diff(np.concatenate([[0], lost.astype(int), [0]])))
        for a, b in zip(edges[::2], edges[1::2], strict=True):
            ax.axvspan(s[a], s[max(b - 1, a)], color="C3", alpha=0.25, lw=0)
        ax.plot([], [], color="C3", alpha=0.4, lw=6, label="loss of contact")
    ax.set_xlabel("wheel position relative to the impact s [mm]")
    ax.set_ylabel("contact force [kN]")
    ax.set_title(f"v = {float(result.speed) * 3.6:.0f} km/h, impact at x = "
                 f"{float(result.impact_position) * 1e3:.0f} mm (a sleeper at x = 0): "
                 f"max {float(result.max_force) / 1e3:.1f} kN, min "
                 f"{float(result.min_force) / 1e3:.1f} kN")
    ax.grid(alpha=0.3)
    if getattr(result, "support_force", None) is not None:  # hanging sleepers' ballast
        for k, i in enumerate(np.asarray(result.hanging_sleepers)):
            ax.plot(s, np.asarray(result.support_force)[:, k] / 1e3, lw=1, ls="--",
                    color=f"C{2 + k % 6}", label=f"ballast force, hanging sleeper {int(i)}")
    ax.legend(loc="upper right", fontsize=8)
    if flat is not None and flat.kind != "none":
        inset = ax.inset_axes([0.03, 0.58, 0.28, 0.36])
        half = 1.2 * flat.half_extent
        x = np.linspace(-half, half, 401)
        inset.plot(x * 1e3, -np.asarray(geometry.profile_deviation(flat, x)) * 1e3, "--",
                   lw=1, label="profile")
        inset.plot(x * 1e3, np.asarray(geometry.centre_trajectory(flat, x)) * 1e3, lw=1,
                   label="trajectory")
        inset.set_xlabel("x [mm]", fontsize=7)
        inset.set_ylabel("input [mm]", fontsize=7)
        inset.tick_params(labelsize=6)
        inset.legend(fontsize=6)
    fig.tight_layout()
    return fig


def detector_figure(result, flat_index: int = 0):
    """Detector reading (max over its bays) against the true peak contact force [kN].

    Left: both against speed [km/h], one line per impact position (reading solid, true peak
    dotted). Right: reading against true peak for every run, coloured by impact position,
    with the 1:1 line.

    Args:
        result: a :class:`wfjax.SweepResult` of ``sweep(..., detector=...)``.
    """
    v = np.asarray(result.speeds) * 3.6
    pos = np.asarray(result.impact_positions) * 1e3
    reading = np.asarray(result.detector_peak[flat_index]).max(axis=-1) / 1e3  # [v, pos]
    true = np.asarray(result.max_force[flat_index]) / 1e3
    fig, (a, b) = plt.subplots(1, 2, figsize=(12, 4.6))
    for k, p in enumerate(pos):
        color = plt.cm.viridis(k / max(len(pos) - 1, 1))
        a.plot(v, reading[:, k], "-o", ms=3, color=color, label=f"reading, impact {p:.0f} mm")
        a.plot(v, true[:, k], ":", color=color)
        b.scatter(true[:, k], reading[:, k], s=14, color=color, label=f"{p:.0f} mm")
    a.plot([], [], "k:", label="true peak contact force")
    a.set(xlabel="train speed [km/h]", ylabel="force [kN]",
          title=f"detector ({len(result.detector_bays)} bays, max over bays) vs true peak")
    a.grid(alpha=0.3)
    a.legend(fontsize=7)
    lim = [0.0, 1.05 * max(true.max(), reading.max())]
    b.plot(lim, lim, "k-", lw=0.8, label="1:1")
    b.set(xlim=lim, ylim=lim, xlabel="true peak contact force [kN]",
          ylabel="detector reading [kN]", title="reading vs true peak, by impact position")
    b.grid(alpha=0.3)
    b.legend(fontsize=7)
    fig.tight_layout()
    return fig


def vehicle_history_figure(result, vehicle, preload: float = 118e3):
    """Every wheel's contact force [kN] (top) and axle-box acceleration [m/s^2] (bottom)
    against time [ms] for a vehicle's :class:`wfjax.SimResult` (``simulate(vehicle=...)``).

    Args:
        result: the result (its ``wheel_force``, ``wheel_axle_acc``).
        vehicle: the :class:`wfjax.model.vehicle.Vehicle` (labels: wheel positions).
        preload: the static wheel load P [N] (dotted line).
    """
    t = np.asarray(result.t) * 1e3
    f = np.asarray(result.wheel_force) / 1e3
    acc = np.asarray(result.wheel_axle_acc)
    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(9, 6.5), sharex=True,
                                  gridspec_kw={"height_ratios": [3, 2]})
    for i in range(f.shape[1]):
        flat = " (flat)" if i == vehicle.flat_wheel else ""
        label = f"wheel {i}, {vehicle.positions[i]:g} m behind{flat}"
        ax.plot(t, f[:, i], lw=1.1, label=label)
        ax2.plot(t, acc[:, i], lw=0.9)
    ax.axhline(preload / 1e3, color="k", ls=":", lw=0.8, label="static load P")
    ax.set_ylabel("contact force [kN]")
    ax.set_title(f"{f.shape[1]} wheels at {float(result.speed) * 3.6:.0f} km/h: flat wheel max "
                 f"{float(result.max_force) / 1e3:.1f} kN, min "
                 f"{float(result.min_force) / 1e3:.1f} kN")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper right")
    ax2.set_xlabel("time [ms]")
    ax2.set_ylabel("axle-box acceleration [m/s$^2$]")
    ax2.grid(alpha=0.3)
    fig.tight_layout()
    return fig


def sweep_wheels_figure(result, preload: float = 118e3):
    """Every wheel's max (solid) and min (dashed) contact force [kN] over impact positions
    against speed [km/h], one panel per flat, for a vehicle sweep (``sweep(vehicle=...)``)."""
    v = np.asarray(result.speeds) * 3.6
    n_flats = len(result.flats)
    fig, axes = plt.subplots(1, n_flats, figsize=(6 * n_flats, 4.2), squeeze=False)
    for k, ax in enumerate(axes[0]):
        for i, p in enumerate(np.asarray(result.wheel_positions)):
            flat = " (flat)" if i == int(result.flat_wheel) else ""
            line, = ax.plot(v, np.max(result.wheel_max_force[k, ..., i], axis=-1) / 1e3,
                            lw=1.3, label=f"wheel {i}, {p:g} m{flat}")
            ax.plot(v, np.min(result.wheel_min_force[k, ..., i], axis=-1) / 1e3, "--",
                    color=line.get_color(), lw=1.0)
        ax.axhline(preload / 1e3, color="k", ls=":", lw=0.8)
        ax.set_xlabel("speed [km/h]")
        ax.set_ylabel("contact force [kN] (max solid, min dashed)")
        ax.set_title(result.flats[k], fontsize=9)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    return fig
