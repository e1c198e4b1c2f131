"""Options and output helpers shared by the subcommands."""

from __future__ import annotations

import argparse
import json
import os
import secrets
import sys
import tomllib
from pathlib import Path

from .. import case as case_mod


class NonFiniteResult(RuntimeError):
    """A simulation returned NaN or infinite values: nothing is written (exit status 1)."""


def check_finite(what: str, **arrays) -> None:
    """Raise :class:`NonFiniteResult` if any of ``arrays`` holds NaN or inf."""
    import numpy as np

    bad = [name for name, a in arrays.items() if not np.all(np.isfinite(np.asarray(a)))]
    if bad:
        raise NonFiniteResult(f"{what}: non-finite {', '.join(bad)} (solver failure; try a "
                              "smaller config.max_time_step or more config.newton_iterations); "
                              "nothing written")


def sensor_positions(case: case_mod.Case, track) -> list[float] | None:
    """``run.sensors`` [m] as a list (None when not given), checked against ``track``."""
    from ..sensors import check_positions

    value = case.get("run.sensors")
    if value is None:
        return None
    if isinstance(value, str):
        value = case_mod.parse_number_list(value)
    return [float(x) for x in check_positions(value, track, "--sensors-m / run.sensors")]


VEHICLE_FLAGS = {"vehicle": ("vehicle.preset", 1.0),
                 "axle_spacing_m": ("vehicle.axle_spacing", 1.0),
                 "bogie_distance_m": ("vehicle.bogie_distance", 1.0),
                 "wheel_positions_m": ("vehicle.positions", 1.0),
                 "flat_wheel": ("vehicle.flat_wheel", 1.0)}


ROUGHNESS_FLAGS = {"roughness_csv": ("roughness.rail_csv", 1.0),
                   "wheel_roughness_csv": ("roughness.wheel_csv", 1.0),
                   "roughness": ("roughness.preset", 1.0),
                   "realisations": ("roughness.realisations", 1.0),
                   "seed": ("roughness.seed", 1.0),
                   "void_sleepers": ("supports.void_sleepers", 1.0),
                   "void_gap_mm": ("supports.void_gap", 1e-3),
                   "scatter_cv": ("supports.scatter_cv", 1.0),
                   "support_realisations": ("supports.realisations", 1.0)}


def add_roughness_arguments(parser: argparse.ArgumentParser, monte_carlo: bool) -> None:
    """Rail and wheel roughness and varying supports (docs/real_track.md); with
    ``monte_carlo`` the realisation count (sweep)."""
    parser.add_argument("--roughness-csv", metavar="FILE",
                        help="rail roughness, columns x_m|x_mm,roughness_m|_mm|_um")
    parser.add_argument("--wheel-roughness-csv", metavar="FILE",
                        help="wheel roughness over one circumference (same columns)")
    parser.add_argument("--roughness", choices=["none", "iso3095"],
                        help="random rail roughness of the ISO 3095 limit spectrum "
                             "(default none)")
    if monte_carlo:
        parser.add_argument("--realisations", type=int,
                            help="Monte Carlo over this many roughness realisations "
                                 "(percentiles in sweep_percentiles.csv; default 1)")
    parser.add_argument("--seed", type=int, help="seed of the random roughness (default 0)")
    parser.add_argument("--void-sleepers",
                        help="hanging sleepers 'i,j,...' (n_bays // 2 - 1 is above x = 0)")
    parser.add_argument("--void-gap-mm", type=float,
                        help="gap under the hanging sleepers in mm: > 0 makes their ballast "
                             "one-sided, closing under load (default 0: no ballast)")
    parser.add_argument("--scatter-cv", type=float,
                        help="lognormal scatter of pad and ballast stiffness (cv, e.g. 0.3)")
    if monte_carlo:
        parser.add_argument("--support-realisations", type=int,
                            help="Monte Carlo over this many support scatter realisations "
                                 "(one modal model each; default 1)")


def add_vehicle_arguments(parser: argparse.ArgumentParser) -> None:
    """``--vehicle``, ``--axle-spacing-m``, ``--bogie-distance-m``, ``--wheel-positions-m``,
    ``--flat-wheel``: several wheels on the rail (docs/vehicle.md)."""
    parser.add_argument("--vehicle", help="single (default) | bogie (2 axles) | wagon (4 axles)")
    parser.add_argument("--axle-spacing-m", type=float,
                        help="bogie axle spacing in m (default 2.5)")
    parser.add_argument("--bogie-distance-m", type=float,
                        help="wagon's bogie centre distance in m (default 17.5)")
    parser.add_argument("--wheel-positions-m",
                        help="any layout: 'p0,p1,...' distances behind the leading wheel in m "
                             "(0 first); replaces --vehicle")
    parser.add_argument("--flat-wheel", type=int,
                        help="the wheel that carries the flat, 0 = leading (default 0)")


def case_vehicle(case: case_mod.Case, wheel):
    """The case's vehicle (None: one wheel) with its wheel spacing checked."""
    vehicle = case.vehicle()
    if vehicle is not None:
        vehicle.check_spacing(vehicle.wheel_list(wheel))
    return vehicle


def add_out_argument(parser: argparse.ArgumentParser, default: str) -> None:
    """``--out DIR``: where CSV, JSON and PNG results go."""
    parser.add_argument("--out", default=default, help=f"output directory (default: {default})")


def add_speed_arguments(parser: argparse.ArgumentParser, speeds_kmh: str,
                        positions: int) -> None:
    """``--speeds-kmh`` and ``--positions`` (help text with the subcommand's defaults)."""
    parser.add_argument("--speeds-kmh",
                        help=f"speeds in km/h, 'start:stop:step' or 'v1,v2' (default {speeds_kmh})")
    parser.add_argument("--positions", type=int,
                        help=f"impact positions evenly covering one sleeper bay (default "
                             f"{positions})")


def add_case_arguments(parser: argparse.ArgumentParser) -> None:
    """``--config FILE`` and ``--set KEY=VALUE`` (every subcommand)."""
    parser.add_argument("--config", metavar="FILE",
                        help="case file (TOML, or a JSON summary written by wfjax) with every "
                             "parameter; flags override it (docs/case_files.md)")
    parser.add_argument("--set", metavar="SECTION.KEY=VALUE", action="append", default=[],
                        dest="set_values",
                        help="set one case key, e.g. --set track.pad_stiffness=60e6 "
                             "(repeatable; wins over --config)")


def flag_layer(args: argparse.Namespace, flags: dict[str, tuple[str, float]]) -> dict:
    """Checked SI case values of the flags the user gave.

    Args:
        args: parsed arguments; a flag not given is ``None``.
        flags: ``dest -> ("section.key", factor to SI)`` (e.g. ``depth_mm -> ("flat.depth",
            1e-3)``).
    """
    layer = {}
    for text in getattr(args, "set_values", []) or []:
        path, sep, raw = text.partition("=")
        if not sep:
            raise case_mod.CaseError(f"--set {text}: expected SECTION.KEY=VALUE")
        try:
            value = tomllib.loads(f"v = {raw}")["v"]
        except tomllib.TOMLDecodeError:
            value = raw
        key, factor, unit = case_mod.canonical_key(path.strip(), "--set")
        layer[key.path] = case_mod.check_value(key, value, "--set", factor, unit,
                                               name=path.strip())
    for dest, (path, factor) in flags.items():
        value = getattr(args, dest, None)
        if value is None:
            continue
        key = case_mod.KEYS[path]
        unit = "mm" if factor == 1e-3 else key.unit
        value = case_mod.check_value(key, value, "", factor, unit,
                                     name="--" + dest.replace("_", "-"))
        if key.name in case_mod.PATH_KEYS:
            value = os.path.abspath(value)
        layer[path] = value
    return layer


def resolve_case(args: argparse.Namespace, command: str,
                 flags: dict[str, tuple[str, float]]) -> case_mod.Case:
    """The resolved case of ``command``: defaults < environment < ``--config`` < flags.

    Notes on stderr the case-file keys ``command`` does not read. Raises
    :class:`wfjax.case.CaseError` (exit 2, one line) on any bad key or value.
    """
    case = case_mod.resolve(command, getattr(args, "config", None), flag_layer(args, flags))
    if case.unused:
        print(f"wfjax {command}: note: {args.config}: not used by {command}: "
              f"{', '.join(case.unused)}", file=sys.stderr)
    return case


def provenance(case: case_mod.Case, inputs: dict[str, str] | None = None) -> dict:
    """What made an output: wfjax and JAX versions, precision, devices, inputs' sha256."""
    import jax

    import wfjax

    return {
        "wfjax_version": wfjax.__version__,
        "jax_version": jax.__version__,
        "command": case.command,
        "precision": case.get("config.precision", "float64"),
        "jax_backend": jax.default_backend(),
        "jax_device_count": jax.device_count(),
        "case_sha256": case.digest(),
        "inputs_sha256": {str(p): case_mod.file_sha256(p) for p in (inputs or {}).values()
                          if p and Path(p).is_file()},
    }


def write_summary(path: Path, summary: dict, case: case_mod.Case,
                  inputs: dict[str, str] | None = None) -> None:
    """Write ``summary`` plus ``"case"`` and ``"provenance"`` as JSON, and ``case.toml``.

    ``wfjax <command> --config <path>`` (or ``--config case.toml``) repeats the run.
    """
    write_json(path, {**summary, "case": case.to_dict(),
                      "provenance": provenance(case, inputs)})
    header = (f"wfjax {case.command}: the resolved case of the run that wrote {path.name}\n"
              f"repeat it: wfjax {case.command} --config {path.parent / 'case.toml'}")
    write_atomic(path.parent / "case.toml", case.to_toml(header))


def prepare_out(path: str) -> Path:
    """Create the output directory and return it."""
    out = Path(path)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ValueError(f"--out {path}: cannot create the directory: "
                         f"{exc.strerror or exc}") from None
    return out


def _temporary(path: Path, suffix: str = "") -> Path:
    """A new empty file next to ``path``, created with mode 0666 less the umask (0644)."""
    for _ in range(100):
        tmp = path.with_name(f".{path.name}.{secrets.token_hex(4)}{suffix}")
        try:
            os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
            return tmp
        except FileExistsError:
            continue
    raise OSError(f"cannot create a temporary file next to {path}")


def write_atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file, so it is never half-written.

    The file gets the ordinary permissions of a new file (0666 less the umask).
    """
    path = Path(path)
    tmp = _temporary(path)
    try:
        with open(tmp, "w") as fh:
            fh.write(text)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_json(path: Path, data: dict) -> None:
    """Write ``data`` as indented JSON, atomically."""
    write_atomic(path, json.dumps(data, indent=2, sort_keys=False) + "\n")


def save_figure(fig, path: Path) -> None:
    """Save a matplotlib figure as PNG atomically and close it."""
    import matplotlib.pyplot as plt

    path = Path(path)
    tmp = _temporary(path, ".png")
    try:
        fig.savefig(tmp, dpi=130, bbox_inches="tight")
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    finally:
        plt.close(fig)
