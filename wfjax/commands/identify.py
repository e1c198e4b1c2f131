"""``wfjax identify``: every wheel's flat from a wayside detector's readings of a passing
train (``docs/identify.md``).

Reads the passage CSV (``--readings``), identifies every wheel
(:func:`wfjax.identify.identify`) and writes ``identify.csv`` (one row per wheel),
``identify.json`` (settings, wheels, case and provenance), ``identify.png`` (readings against
the fitted model, length and depth posteriors) and ``case.toml``; one line per wheel on the
terminal, a progress bar on stderr.
"""

from __future__ import annotations

import sys
import time

from ._common import prepare_out, resolve_case, save_figure, write_atomic, write_summary

HELP = "identify every wheel's flat from detector readings of a passing train (CSV, JSON, PNG)"

LAYOUTS = {"single": (0.0,), "bogie": (0.0, 2.5), "wagon": (0.0, 2.5, 17.5, 20.0)}


def _progress(stage: str, done: int, total: int) -> None:
    bar = "#" * int(20 * done / max(total, 1))
    end = "\n" if done >= total else "\r"
    print(f"  {stage}: [{bar:<20}] {done}/{total}", end=end, file=sys.stderr, flush=True)


def _settings(case) -> dict:
    """identify()'s keyword arguments from the case (the documented defaults when unset)."""
    from ..identify.pipeline import PHASE_ERROR, PHASE_MODES
    from ..identify.rules import user_rule

    def get(key, default):
        value = case.get(f"identify.{key}")
        return default if value is None else value

    line = case.get("identify.line_speed_kmh")
    return dict(contact=get("contact", "hertz-trajectory"), noise=get("noise", 0.03),
                model=get("model_error", 0.02), flag_length=get("flag_length", 0.02),
                flag_probability=get("flag_probability", 0.9),
                line_speed=None if line is None else line / 3.6,
                force_level=get("force_level", 350e3),
                user_rule=user_rule(case.get("identify.user_reading"),
                                    case.get("identify.user_length")),
                coupling_iterations=get("coupling_iterations", 1),
                phase_modes=get("phase_modes", PHASE_MODES),
                phase_error=get("phase_error", PHASE_ERROR),
                table_options={"n_roughness": get("realisations", 3)}, seed=get("seed", 0))


def _read(case):
    from ..identify.passage import check_layout, read_passages

    path = case.get("identify.readings")
    if path is None:
        raise ValueError("--readings FILE (identify.readings) is required: the passage CSV")
    passages = read_passages(path)
    layout = case.get("identify.layout") or "file"
    if layout != "file":
        check_layout(passages, LAYOUTS[layout])
    return passages, path


def run(args) -> int:
    case = resolve_case(args, "identify")
    from ..identify import identify
    from ..identify.report import identify_csv, report_figure, summary, wheel_line

    passages, path = _read(case)  # every bad input before any work
    kw = _settings(case)
    out = prepare_out(args.out)
    print(f"wfjax identify: {len(passages)} passage(s), {passages[0].n_wheels} wheels, "
          f"{passages[0].speed * 3.6:.0f} km/h, {kw['contact']} contact")
    t0 = time.perf_counter()
    result = identify(passages, progress=_progress, **kw)
    elapsed = time.perf_counter() - t0
    write_atomic(out / "identify.csv", identify_csv(result))
    body = summary(result) | {"wall_time_s": elapsed}
    write_summary(out / "identify.json", body, case, {"readings": path})
    save_figure(report_figure(result), out / "identify.png")
    for row in result.rows():
        print(wheel_line(row))
    misfits = [r["wheel"] for r in result.rows() if r["misfit"]]
    if misfits:
        print(f"  wheels {misfits}: the model cannot explain their readings (posterior-"
              "predictive p < 0.001): no flat size is reported for them with confidence")
    print(f"  {elapsed:.1f} s; wrote {out}/identify.csv, identify.json, identify.png, "
          "case.toml")
    return 0
