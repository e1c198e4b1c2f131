"""Matplotlib figures of wfjax results (headless: the Agg backend is selected here)."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from . import geometry  # noqa: E402
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
        f"(a) new flat, d = {depth * 1e3:g} mm, l0 = {l0 * 1e3:.1f} mm": Flat.new(depth, wheel_radius),
        f"(b) rounded flat, d = {depth * 1e3:g} mm, l = 1.76 l0": Flat.rounded_relative(
            depth, 1.76, wheel_radius
        ),
    }
