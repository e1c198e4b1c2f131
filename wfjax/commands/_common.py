"""Options and output helpers shared by the subcommands."""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
import tomllib
from pathlib import Path

from .. import case as case_mod
from .. import limits, options, outputs
from ..datafiles import file_sha256
from ..scenario import guards

_SECTION_OF = {"Track": "track", "Wheel": "wheel", "Material": "material",
               "SimConfig": "config", "Flat": "flat", "Vehicle": "vehicle"}
_USER_WORDS = (
    (re.compile(r"\bVehicle\.positions\b"), "--wheel-positions-m (vehicle.positions)"),
    (re.compile(r"\bVehicle wheels\b"), "wheels"),
    (re.compile(r"\b(Track|Wheel|Material|SimConfig)\((\w+)=([^)]*)\)"),
     lambda m: f"--set {_SECTION_OF[m[1]]}.{m[2]}={m[3]}"),
    (re.compile(r"\b(Track|Wheel|Material|SimConfig|Vehicle|Flat)\.(\w+)\b"),
     lambda m: f"{_SECTION_OF[m[1]]}.{m[2]}"),
)


def user_words(message: str) -> str:
    """``message`` with the Python spellings of the library (``Track(n_bays=76)``,
    ``Vehicle.positions``) replaced by what a command-line user types (``--set
    track.n_bays=76``, ``--wheel-positions-m``)."""
    for pattern, words in _USER_WORDS:
        message = pattern.sub(words, message)
    return message


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
    from ..scenario.sensors import check_positions

    value = case.get("run.sensors")
    if value is None:
        return None
    if isinstance(value, str):
        value = case_mod.parse_number_list(value)
    track = guards.holding_instruments(track, value)
    return [float(x) for x in check_positions(value, track, "--sensors-m / run.sensors")]


def case_vehicle(case: case_mod.Case, wheel):
    """The case's vehicle (None: one wheel) with its wheel spacing checked."""
    vehicle = case.vehicle()
    if vehicle is not None:
        try:
            vehicle.check_spacing(vehicle.wheel_list(wheel))
        except ValueError as exc:
            raise case_mod.CaseError(f"[vehicle]: {exc}") from None
    return vehicle


def flag_layer(args: argparse.Namespace, command: str) -> dict:
    """Checked SI case values of the flags of ``wfjax command`` the user gave (and ``--set``).

    Every flag is checked against its option's description (:mod:`wfjax.options`): a bad
    value raises :class:`wfjax.case.CaseError` naming the flag as typed, the value and the
    allowed range in the flag's unit. Command-line-only options (``--out``, ``--fmin-hz``)
    are checked too and put back on ``args`` converted.
    """
    layer = set_layer(getattr(args, "set_values", None) or [])
    typed = getattr(args, "_typed", {})
    for option in options.flags_of(command):
        value = getattr(args, option.flag_dest, None)
        if value is None or option.action == "append":
            continue
        value = case_mod.check_value(option, options.from_text(option, value), "",
                                     option.factor, option.flag_unit or option.unit,
                                     name=typed.get(option.flag_dest, option.flag))
        try:
            listed = value.split(",") if isinstance(value, str) and option.kind in (
                "floats", "strs") else value
            limits.check_list(listed, typed.get(option.flag_dest, option.flag))
        except limits.InputError as exc:
            raise case_mod.CaseError(str(exc)) from None
        if not option.case:
            setattr(args, option.flag_dest, value)
            continue
        layer[option.path] = os.path.abspath(value) if option.kind == "path" else value
    return layer


def typed_names(args: argparse.Namespace, command: str) -> dict[str, str]:
    """``{case key: how the user typed it}`` for the flags given (``--void-gap-mm``) and
    ``--set`` (``--set supports.void_gap``), so errors name what the user typed."""
    typed = getattr(args, "_typed", {})
    names = {}
    for text in getattr(args, "set_values", None) or []:
        path = text.partition("=")[0].strip()
        try:
            names[case_mod.canonical_key(path, "--set")[0].path] = f"--set {path}"
        except case_mod.CaseError:
            continue
    for option in options.flags_of(command):
        if option.case and getattr(args, option.flag_dest, None) not in (None, False):
            names[option.path] = typed.get(option.flag_dest, option.flag)
    return names


def set_layer(texts: list[str]) -> dict:
    """Checked SI case values of ``--set SECTION.KEY=VALUE`` (VALUE in TOML, else a string)."""
    layer = {}
    for text in texts:
        path, sep, raw = text.partition("=")
        if not sep:
            raise case_mod.CaseError(f"--set {text}: expected SECTION.KEY=VALUE")
        try:
            value = tomllib.loads(f"v = {raw}")["v"]
            limits.check_tree(value, f"--set {path.strip()}")
        except tomllib.TOMLDecodeError:
            value = raw
        except (RecursionError, limits.InputError) as exc:
            raise case_mod.CaseError(str(exc) if isinstance(exc, limits.InputError) else
                                     f"--set {path.strip()}: nested deeper than "
                                     f"{limits.MAX_DEPTH} levels") from None
        key, factor, unit = case_mod.canonical_key(path.strip(), "--set")
        layer[key.path] = case_mod.check_value(key, value, "--set", factor, unit,
                                               name=path.strip())
    return layer


def resolve_case(args: argparse.Namespace, command: str) -> case_mod.Case:
    """The resolved case of ``command``: defaults < environment < ``--config`` < flags.

    Notes on stderr the case-file keys ``command`` does not read. Raises
    :class:`wfjax.case.CaseError` (exit 2, one line) on any bad key or value.
    """
    case = case_mod.resolve(command, getattr(args, "config", None), flag_layer(args, command),
                            typed=typed_names(args, command))
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
        "precision": case.get("config.precision", "auto"),
        "jax_backend": jax.default_backend(),
        "jax_device_count": jax.device_count(),
        "case_sha256": case.digest(),
        "inputs_sha256": {str(p): file_sha256(p) for p in _input_files(inputs)},
        "accuracy_warnings": guards.notes(),
    }


def _input_files(inputs: dict[str, str] | None) -> list[Path]:
    """The files behind ``inputs``' paths: a file itself, every file of a directory (a
    profilometer's records, one file per line), nothing for an unset key."""
    files: list[Path] = []
    for value in (inputs or {}).values():
        path = Path(value) if value else None
        if path is not None and path.is_file():
            files.append(path)
        elif path is not None and path.is_dir():
            files.extend(sorted(p for p in path.iterdir() if p.is_file()))
    return files


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
    """Create the output directory, check that it can be written and return it.

    In the ``wfjax`` command (:func:`wfjax.outputs.session`) this opens the run's output set:
    the files written below go to staging files, committed together when the command
    returns (``docs/outputs.md``); a killed earlier run's leftovers are cleaned up first.
    """
    out = Path(path)
    try:
        if outputs.open_set(out) is None:
            out.mkdir(parents=True, exist_ok=True)
    except outputs.OutputError as exc:
        raise ValueError(exc.strerror) from None
    except OSError as exc:
        raise ValueError(f"--out {path}: cannot create the directory: "
                         f"{exc.strerror or exc}") from None
    return out


def write_atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` as a file of the run's set (:func:`wfjax.outputs.stage`):
    never half-written, with the ordinary permissions of a new file (0666 less the umask)."""
    outputs.stage(path, lambda target: Path(target).write_text(text, encoding="utf-8"))


def write_json(path: Path, data: dict) -> None:
    """Write ``data`` as indented JSON, atomically."""
    write_atomic(path, json.dumps(data, indent=2, sort_keys=False) + "\n")


def save_figure(fig, path: Path) -> None:
    """Save a matplotlib figure as PNG into the run's set (atomically) and close it."""
    import matplotlib.pyplot as plt

    try:
        outputs.stage(path, lambda target: fig.savefig(target, dpi=130, bbox_inches="tight",
                                                        format="png"))
    finally:
        plt.close(fig)
