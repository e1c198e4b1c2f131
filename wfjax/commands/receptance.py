"""``wfjax receptance``: wheel and track receptances (CSV, JSON summary, PNG)."""

from __future__ import annotations

import argparse

import numpy as np

from . import _common

HELP = "Wheel and track receptances (dB re 1 m/N, phase) above a sleeper and at midspan."


def _db(h):
    return 20 * np.log10(np.abs(h))


def _long(track):
    """``track`` lengthened to ``guards.RECEPTANCE_BAYS`` (scalar supports only): a receptance
    needs a long track at the lightly damped pinned-pinned peak (docs/convergence.md)."""
    from wfjax.scenario import guards

    if not guards.extendable(track):
        return track
    return guards.at_least(track, 0.5 * guards.RECEPTANCE_BAYS * float(track.sleeper_spacing))


def _track_receptances(track, f, preload: float):
    """(receptances [m/N] above a sleeper and at midspan at ``f`` [Hz], static deflections
    [m] there under ``preload`` [N], the track model's label): the infinite periodic track
    where ``track`` is periodic, else the finite track lengthened to RECEPTANCE_BAYS."""
    from wfjax import track as T
    from wfjax.model.sleepers import is_periodic

    ls = float(track.sleeper_spacing)
    if is_periodic(track):
        h = T.periodic_receptance(track, np.concatenate([[0.0], f]), 0.0)
        m = T.periodic_receptance(track, np.concatenate([[0.0], f]), ls / 2)
        return (h[1:], m[1:]), (h[0].real * preload, m[0].real * preload), "infinite periodic"
    track = _long(track)
    return ((T.receptance(track, f, 0.0), T.receptance(track, f, ls / 2)),
            (T.static_deflection(track, preload, 0.0), T.static_deflection(track, preload, ls / 2)),
            f"finite, {track.n_bays} bays")


def run(args: argparse.Namespace) -> int:
    """Compute, write receptance.csv / receptance.json / receptance.png, print a summary."""
    from wfjax import wheel as W

    case = _common.resolve_case(args, "receptance")  # checks --fmin-hz, --fmax-hz, --points
    if not args.fmax_hz > args.fmin_hz:
        raise ValueError(f"--fmax-hz {args.fmax_hz:g}: must be > --fmin-hz ({args.fmin_hz:g} "
                         "Hz)")
    wheel, track, _, _ = case.model()
    preload = float(wheel.preload)
    out = _common.prepare_out(args.out)
    f = np.geomspace(args.fmin_hz, args.fmax_hz, args.points)
    (sleeper, midspan), static, model = _track_receptances(track, f, preload)
    curves = {"wheel": W.receptance(wheel, f), "track_sleeper": sleeper,
              "track_midspan": midspan}
    cols = ["frequency_hz"]
    data = [f]
    for name, h in curves.items():
        cols += [f"{name}_db_re_1m_per_N", f"{name}_phase_deg", f"{name}_re_m_per_N",
                 f"{name}_im_m_per_N"]
        data += [_db(h), np.degrees(np.angle(h)), h.real, h.imag]
    table = np.column_stack(data)
    lines = [",".join(cols)] + [",".join(f"{v:.9g}" for v in row) for row in table]
    _common.write_atomic(out / "receptance.csv", "\n".join(lines) + "\n")

    def peak(h, lo, hi):
        sel = (f >= lo) & (f <= hi)
        if not np.any(sel):
            return None
        return float(f[sel][np.argmax(np.abs(h[sel]))])

    summary = {
        "elements_per_bay": int(track.elements_per_bay),
        "track_model": model,
        "preload_kN": preload / 1e3,
        "static_deflection_mm": {"sleeper": static[0] * 1e3, "midspan": static[1] * 1e3},
        "track_resonance_hz": peak(curves["track_sleeper"], 50, 200),
        "rail_on_pad_resonance_hz": peak(curves["track_sleeper"], 200, 500),
        "pinned_pinned_hz": peak(curves["track_midspan"], 700, 1200),
        "wheel_static_displacement_mm": W.static_displacement(wheel) * 1e3,
    }
    _common.write_summary(out / "receptance.json", summary, case)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(8, 7), sharex=True)
    labels = {"wheel": "wheel (contact point)", "track_sleeper": "rail above a sleeper",
              "track_midspan": "rail at midspan"}
    for name, h in curves.items():
        ax1.semilogx(f, _db(h), label=labels[name])
        ax2.semilogx(f, np.degrees(np.angle(h)), label=labels[name])
    ax1.set_ylabel("receptance [dB re 1 m/N]")
    ax2.set_ylabel("phase [deg]")
    ax2.set_xlabel("frequency [Hz]")
    ax1.grid(True, which="both", alpha=0.3)
    ax2.grid(True, which="both", alpha=0.3)
    ax1.legend()
    ax1.set_title(f"Receptances (track: {model}, {track.elements_per_bay} el./bay)")
    _common.save_figure(fig, out / "receptance.png")

    s = summary
    print(f"track: resonances {s['track_resonance_hz']:.0f} Hz (track on ballast), "
          f"{s['rail_on_pad_resonance_hz']:.0f} Hz (rail on pads), "
          f"pinned-pinned {s['pinned_pinned_hz']:.0f} Hz (midspan)")
    print(f"static rail deflection at {s['preload_kN']:g} kN: "
          f"{s['static_deflection_mm']['sleeper']:.3f} mm above a sleeper, "
          f"{s['static_deflection_mm']['midspan']:.3f} mm at midspan")
    print(f"wrote {out / 'receptance.csv'}, receptance.json, receptance.png, case.toml")
    return 0
