"""Every option of ``wfjax``, described once: its unit, range, meaning and command-line flag.

Two sources, one shape (:class:`Option`):

* the model parameters: the field metadata of the dataclasses in :mod:`wfjax.params`
  (:func:`wfjax.fields.option`), read by :func:`model_options` (the ``[wheel]``, ``[track]``,
  ``[material]`` and ``[config]`` tables, and the flat's depth and length);
* the run and output options (speeds, positions, flats, vehicle, roughness, joint,
  supports, detector, fit and compare settings, ``--out``, ...): the table :data:`RUN_OPTIONS`
  below. They describe a run, not a model object, so they have no dataclass of their own;
  this module is their one place (case.py reads and resolves cases, it does not describe them).

From these descriptions come the case-file keys (:data:`KEYS`), the flags of every subcommand
(:func:`flags_of`, turned into argparse options by :func:`wfjax.cli.add_options`), the checks
of every value (:func:`check_value`, one line naming what the user typed) and the
documentation (:mod:`wfjax.optdocs`, ``docs/case_files.md``).
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Callable
from typing import Any

import numpy as np

from . import params as P
from .contact import registry
from .scenario import joint as J
from .scenario import roughness as R

__all__ = ["Option", "CaseError", "COMMANDS", "OPTIONS", "KEYS", "SECTIONS", "MODEL_SECTIONS",
           "flags_of", "check_value", "from_text", "parse_number_list", "model_options"]

COMMANDS = ("sweep", "simulate", "fit", "compare", "figures", "receptance", "geometry",
            "detector", "identify")
MODEL_SECTIONS = {"wheel": P.Wheel, "track": P.Track, "material": P.Material,
                  "config": P.SimConfig}
MAX_SPEED_KMH = P.MAX_SPEED * 3.6  # the API's limit in the CLI's unit
# a joint's dip is rail roughness: the joint's own bound (5 mm) within what Roughness holds
JOINT_MAX_DEPTH = min(J.MAX_DEPTH, R.MAX_AMPLITUDE)


class CaseError(ValueError):
    """A bad case file, flag or environment value: one line naming key, value and range."""


@dataclasses.dataclass(frozen=True)
class Option:
    """One option: a case-file key and/or a command-line flag.

    Attributes:
        section, name: ``[section] name = ...`` in a case file.
        kind: ``"float"``, ``"int"``, ``"str"``, ``"path"`` (a file name, relative to the
            case file), ``"bool"``, ``"floats"`` (a number, a list of numbers, or a
            ``"start:stop:step"``/``"a,b,c"`` string), ``"strs"`` (a list of strings or an
            ``"a,b"`` string) or ``"float|auto"`` (a number or ``"auto"``).
        unit: SI unit of the value ("" when dimensionless or not a number).
        low, high: allowed range (None: unbounded); ``low_open``/``high_open``: excluded ends.
        choices: allowed strings, or a function returning them (read when used).
        doc: one-line meaning.
        commands: subcommands that read the key.
        flag, aliases: the command-line flag and its other spellings (None: no flag).
        flag_commands: subcommands offering the flag (None: ``commands``).
        factor, flag_unit: the flag's value x ``factor`` is SI; the flag's unit.
        case: False for command-line-only options (``--out``): no case key.
        default: a command-line-only option's default (a ``{command: value}`` dict allowed);
            case keys take theirs from :func:`wfjax.case.default_layer`.
        action: argparse action (``"store_true"``, ``"append"``); dest, metavar: argparse's.
    """

    section: str
    name: str
    kind: str
    unit: str = ""
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    choices: tuple[str, ...] | Callable[[], tuple[str, ...]] | None = None
    doc: str = ""
    commands: tuple[str, ...] = COMMANDS
    flag: str | None = None
    aliases: tuple[str, ...] = ()
    flag_commands: tuple[str, ...] | None = None
    factor: float = 1.0
    flag_unit: str | None = None
    case: bool = True
    default: Any = None
    action: str | None = None
    dest: str | None = None
    metavar: str | None = None

    @property
    def path(self) -> str:
        return f"{self.section}.{self.name}"

    @property
    def choice_list(self) -> tuple[str, ...] | None:
        """The allowed strings (None: any)."""
        return self.choices() if callable(self.choices) else self.choices

    @property
    def flag_dest(self) -> str:
        """The argparse destination of the flag."""
        return self.dest or self.flag.lstrip("-").replace("-", "_")

    def offers_flag(self, command: str) -> bool:
        """Whether ``wfjax command`` has this option's flag."""
        return self.flag is not None and command in (self.flag_commands or self.commands)

    def default_for(self, command: str):
        """The command-line-only default of ``command`` (None for case keys)."""
        return self.default.get(command) if isinstance(self.default, dict) else self.default

    def allowed(self, factor: float = 1.0, unit: str | None = None) -> str:
        """The allowed values in words, optionally in another unit (value = SI / factor)."""
        unit = self.unit if unit is None else unit
        choices = self.choice_list
        if choices is not None:
            text = " | ".join(choices)
            return text + (" (or a list of them)" if self.kind == "strs" else "")
        if self.kind == "bool":
            return "true | false"
        if self.kind in ("str", "path"):
            return "a file name" if self.kind == "path" else "a string"
        lo = "-inf" if self.low is None else f"{self.low / factor:g}"
        hi = "inf" if self.high is None else f"{self.high / factor:g}"
        left = "(" if self.low_open or self.low is None else "["
        right = ")" if self.high_open or self.high is None else "]"
        text = f"{left}{lo}, {hi}{right}" + (f" {unit}" if unit else "")
        if self.kind == "int":
            text = "an integer in " + text
        if self.kind == "float|auto":
            text = '"auto" or ' + text
        return text


# -- the model parameters: from the dataclasses' field metadata ------------------------------
_MODEL_CMDS = ("sweep", "simulate", "fit", "compare", "figures", "receptance", "detector")
_FLAT_CMDS = ("sweep", "simulate", "fit", "geometry", "detector")
_SECTION_CMDS = ("sweep", "simulate", "geometry")  # a measured 3D flat (docs/measured_flats.md)
_VEHICLE_CMDS = ("sweep", "simulate", "fit")
_MODEL_CMDS_EARLY = _VEHICLE_CMDS  # the commands that build varying supports


def _kind_of(default) -> str:
    if default is None:
        return "float|auto"
    if isinstance(default, bool):
        return "bool"
    if isinstance(default, int):
        return "int"
    return "str" if isinstance(default, str) else "float"


def _from_field(section: str, f: dataclasses.Field, **overrides) -> Option:
    """The option of dataclass field ``f`` of ``[section]``, from its metadata."""
    m = f.metadata
    overrides.setdefault("action", "store_true" if isinstance(f.default, bool) else None)
    return Option(section, f.name, overrides.pop("kind", _kind_of(f.default)), m["unit"],
                  m["low"], m["high"], m["low_open"], m["high_open"], m["choices"], m["doc"],
                  flag=m["flag"], aliases=m["aliases"], flag_commands=m["flag_commands"],
                  factor=m["factor"], flag_unit=m["flag_unit"], **overrides)


def model_options() -> list[Option]:
    """The ``[wheel]``, ``[track]``, ``[material]`` and ``[config]`` keys, one per field."""
    out = []
    for section, cls in MODEL_SECTIONS.items():
        for f in dataclasses.fields(cls):
            cmds = _MODEL_CMDS + ("geometry",) if f"{section}.{f.name}" == "wheel.radius" \
                else _MODEL_CMDS
            out.append(_from_field(section, f, commands=cmds))
    return out


def _flat_field(name: str) -> Option:
    """``flat.depth``/``flat.length`` from :class:`wfjax.params.Flat`'s field (sweep: lists)."""
    field = {f.name: f for f in dataclasses.fields(P.Flat)}[name]
    return _from_field("flat", field, kind="floats", commands=_FLAT_CMDS)


def _speeds(section: str, **kw) -> Option:
    return Option(section, "speeds_kmh", "floats", "km/h", 0.0, MAX_SPEED_KMH, low_open=True,
                  flag="--speeds-kmh", **kw)


# -- the run and output options --------------------------------------------------------------
RUN_OPTIONS: tuple[Option, ...] = (
    Option("run", "contact", "str", choices=registry.names, doc="contact model",
           commands=("sweep", "simulate", "fit", "detector"), flag="--contact"),
    _speeds("run", doc='train speeds: a list, or "start:stop:step" (inclusive) or "v1,v2,..."',
            commands=("sweep", "compare", "detector")),
    Option("run", "impact_positions", "int", "", 1, 1000,
           doc="impact positions evenly covering one sleeper bay",
           commands=("sweep", "fit", "compare", "detector"), flag="--positions",
           aliases=("--impact-positions",)),
    Option("run", "sensors", "floats", "m", -500.0, 500.0,
           doc="fixed rail sensor positions (x = 0 at the middle sleeper; docs/detector.md)",
           commands=("detector", "simulate"), flag="--sensors-m"),
    Option("run", "allow_large_output", "bool",
           doc="write outputs predicted above the 1 GB limit (docs/case_files.md, Limits)",
           commands=("sweep", "simulate", "detector"), flag="--allow-large-output",
           action="store_true"),
    Option("detector", "n_bays", "int", "", 1, 56,  # more never fit the default track
           doc="instrumented consecutive sleeper bays of the detector", commands=("detector",),
           flag="--bays"),
    Option("detector", "first_bay", "int", "", -30, 29,
           doc="index of the first bay (bay 0 spans [0, L_S), where impacts are placed)",
           commands=("detector",), flag="--first-bay"),
    Option("detector", "gauge_offset", "float", "m", 0.0, 0.75, low_open=True, high_open=True,
           doc="shear bridges' distance from the sleeper centres, < L_S / 2",
           commands=("detector",), flag="--gauge-offset-m"),
    Option("detector", "calibration", "float", "", 0.0, 10.0, low_open=True,
           doc="factor on the shear difference (1: static theory; docs/detector.md)",
           commands=("detector",), flag="--calibration"),
    Option("run", "speed_kmh", "float", "km/h", 0.0, MAX_SPEED_KMH, low_open=True,
           doc="train speed of one run (fit: of a force-history dataset)",
           commands=("simulate", "fit"), flag="--speed-kmh"),
    Option("run", "impact_position", "float", "m", -50.0, 50.0,
           doc="impact position from a sleeper centre, in [0, track.sleeper_spacing); on a "
               "track whose supports vary an absolute rail coordinate (docs/real_track.md)",
           commands=("simulate", "fit"), flag="--impact-position-mm", factor=1e-3,
           flag_unit="mm"),
    Option("flat", "kind", "str", choices=("both", "rounded", "new", "profile", "sections"),
           doc="flat kind; both = a rounded and a new flat (sweep); profile = flat.profile_csv; "
               "sections = flat.sections",
           commands=_FLAT_CMDS, flag="--flat"),
    _flat_field("depth"),
    _flat_field("length"),
    Option("flat", "length_factor", "float", "", math.pi / 2, 10.0,
           doc="rounded flat length as a multiple of l0 = sqrt(8 R d) (Fig. 8: 1.76); "
               "replaces flat.length", commands=_FLAT_CMDS, flag="--length-factor"),
    Option("flat", "profile_csv", "path",
           doc="measured profile, columns x_mm,z_mm (docs/case_files.md); relative to the "
               "case file; implies flat.kind = profile", commands=_FLAT_CMDS,
           flag="--profile-csv", metavar="FILE"),
    Option("flat", "profile_smoothing_mm", "float", "mm", 0.0, 20.0,
           doc="Gaussian smoothing (standard deviation) of the measured profile; 0: none",
           commands=_FLAT_CMDS, flag="--profile-smoothing-mm"),
    Option("flat", "sections", "path",
           doc="a gauge's records across the tread: a directory (a file per lateral line) or "
               "one CSV (a column per line) (docs/measured_flats.md); implies flat.kind = "
               "sections; the rest of the circumference is the wheel's roughness",
           commands=_SECTION_CMDS, flag="--sections", metavar="DIR_OR_CSV"),
    Option("flat", "section_positions_mm", "floats", "mm", -100.0, 100.0,
           doc="lateral position of each record, increasing, 0 on the nominal contact line "
               "(flag: --section-positions-mm=-20,-6,0,...)", commands=_SECTION_CMDS,
           flag="--section-positions-mm"),
    Option("flat", "section_window_mm", "floats", "mm", -1e4, 1e4,
           doc="the flat's window in the records, start,end (default: located)",
           commands=_SECTION_CMDS, flag="--section-window-mm"),
    Option("vehicle", "preset", "str", choices=("single", "bogie", "wagon"),
           doc="wheels on the rail: the paper's single wheel, a two-axle bogie or a four-axle "
               "wagon (docs/vehicle.md)", commands=_VEHICLE_CMDS, flag="--vehicle"),
    Option("vehicle", "axle_spacing", "float", "m", 0.3, 10.0,
           doc="distance between a bogie's axles", commands=_VEHICLE_CMDS,
           flag="--axle-spacing-m"),
    Option("vehicle", "bogie_distance", "float", "m", 1.0, 30.0,
           doc="distance between the wagon's bogie centres", commands=_VEHICLE_CMDS,
           flag="--bogie-distance-m"),
    Option("vehicle", "positions", "floats", "m", 0.0, 36.0,  # the default track's span
           doc="any layout: every wheel's distance behind the leading wheel (0 first, "
               "increasing); replaces vehicle.preset", commands=_VEHICLE_CMDS,
           flag="--wheel-positions-m"),
    Option("vehicle", "flat_wheel", "int", "", 0, 31,
           doc="the wheel that carries the flat (0 = the leading wheel)",
           commands=_VEHICLE_CMDS, flag="--flat-wheel"),
    Option("roughness", "rail_csv", "path",
           doc="rail roughness CSV, columns x_m|x_mm, roughness_m|roughness_mm|roughness_um "
               "(docs/real_track.md); relative to the case file", commands=_VEHICLE_CMDS,
           flag="--roughness-csv", metavar="FILE"),
    Option("roughness", "wheel_csv", "path",
           doc="wheel roughness CSV over one circumference 2 pi R (same columns)",
           commands=_VEHICLE_CMDS, flag="--wheel-roughness-csv", metavar="FILE"),
    Option("roughness", "preset", "str", choices=("none", "iso3095"),
           doc="random rail roughness: iso3095 = the ISO 3095 limit spectrum (replaces "
               "roughness.rail_csv)", commands=_VEHICLE_CMDS, flag="--roughness"),
    Option("roughness", "realisations", "int", "", 1, 100000,
           doc="random rail roughness realisations (sweep: Monte Carlo percentiles in "
               "sweep_percentiles.csv; simulate: 1)", commands=_VEHICLE_CMDS,
           flag="--realisations", flag_commands=("sweep",)),
    Option("roughness", "seed", "int", "", 0, 2**31 - 1,
           doc="seed of the random roughness", commands=_VEHICLE_CMDS, flag="--seed"),
    Option("roughness", "length", "float", "m", 0.5, 200.0,
           doc="length of the random rail profile, centred on x = 0", commands=_VEHICLE_CMDS),
    Option("joint", "position", "float", "m", -J.MAX_POSITION, J.MAX_POSITION,
           doc="rail coordinate of a dipped rail joint's centre (x = 0 above the middle "
               "sleeper; docs/joint.md)", commands=_VEHICLE_CMDS, flag="--joint-position-m"),
    Option("joint", "depth", "float", "m", 0.0, JOINT_MAX_DEPTH, low_open=True,
           doc="depth of the joint's dip, positive (the rail top goes down by it); unset: no "
               "joint", commands=_VEHICLE_CMDS, flag="--joint-depth-mm", factor=1e-3,
           flag_unit="mm"),
    Option("joint", "length", "float", "m", J.MIN_LENGTH, J.MAX_LENGTH,
           doc="total length of the joint's dip (its steepest slope at most 0.05 rad)",
           commands=_VEHICLE_CMDS, flag="--joint-length-m"),
    Option("joint", "shape", "str", choices=J.SHAPES,
           doc="dip shape: cosine = smooth (1 + cos) / 2, v = two ramps meeting at the joint "
               "(Jenkins' total angle 2 alpha = 4 depth / length)", commands=_VEHICLE_CMDS,
           flag="--joint-shape"),
    Option("supports", "void_sleepers", "floats", "", 0, 10000,
           doc="indices of hanging sleepers (0 = leftmost modelled; n_bays // 2 - 1 above "
               "x = 0)", commands=_VEHICLE_CMDS, flag="--void-sleepers"),
    Option("supports", "void_remaining", "float", "", 0.0, 1.0,
           doc="fraction of the ballast stiffness and damping left under a void sleeper",
           commands=_VEHICLE_CMDS),
    Option("supports", "void_gap", "float", "m", 0.0, P.MAX_BALLAST_GAP,
           doc="gap under the void sleepers: > 0 makes their ballast one-sided (it carries "
               "load once the gap has closed; void_remaining unused), 0 = no ballast at all",
           commands=_VEHICLE_CMDS, flag="--void-gap-mm", factor=1e-3, flag_unit="mm"),
    Option("supports", "scatter_cv", "float", "", 0.0, 2.0,
           doc="lognormal scatter of pad and ballast stiffness, coefficient of variation "
               "(0: none)", commands=_VEHICLE_CMDS, flag="--scatter-cv"),
    Option("supports", "scatter_seed", "int", "", 0, 2**31 - 1,
           doc="seed of the support scatter", commands=_VEHICLE_CMDS),
    Option("supports", "realisations", "int", "", 1, 10000,
           doc="support scatter realisations (sweep: Monte Carlo, seeds scatter_seed + k, one "
               "modal model each; with random roughness: as many)", commands=("sweep",),
           flag="--support-realisations"),
    Option("fit", "data", "path", doc="measured CSV (speed_kmh,max_force_kN or t_s,force_kN, "
           "the latter with run.speed_kmh); relative to the case file", commands=("fit",),
           flag="--data", metavar="FILE"),
    Option("fit", "example", "bool", doc="fit the embedded synthetic dataset instead of data",
           commands=("fit",), flag="--example", action="store_true"),
    Option("fit", "profile_basis", "int", "", 0, 64,
           doc="fit a profile of this many smooth bumps (0: the flat's depth/length; 8 with "
               "flat.profile_csv)", commands=("fit",), flag="--profile-basis"),
    Option("fit", "temperature_kN", "float", "kN", 0.0, 1e3,
           doc="smooth-max temperature over impact positions (0: hard max)",
           commands=("fit",), flag="--temperature-kN"),
    Option("fit", "method", "str", choices=("lbfgs", "adam"), doc="optimiser",
           commands=("fit",), flag="--method"),
    Option("fit", "max_iter", "int", "", 1, 10000, doc="iteration cap", commands=("fit",),
           flag="--max-iter"),
    Option("compare", "depths_mm", "floats", "mm", 0.0, P.MAX_FLAT_DEPTH * 1e3, low_open=True,
           doc="depths of the compared flats (a rounded and a new flat each)",
           commands=("compare",), flag="--depths-mm"),
    Option("compare", "models", "strs", choices=registry.names,
           doc="contact models to compare (must include 3d)", commands=("compare",),
           flag="--models"),
) + (
    # wfjax identify (docs/identify.md); unset keys take the defaults named in their doc
    Option("identify", "readings", "path", doc="passage CSV of detector readings (docs/"
           "identify.md); relative to the case file", commands=("identify",),
           flag="--readings", metavar="FILE"),
    Option("identify", "contact", "str", choices=registry.names,
           doc="contact law of the response tables (default hertz-trajectory; 3d: exact)",
           commands=("identify",), flag="--contact", aliases=("--id-contact",)),
    Option("identify", "layout", "str", choices=("file", "single", "bogie", "wagon"),
           doc="train layout the readings must match (default file: the CSV's positions)",
           commands=("identify",), flag="--layout"),
    Option("identify", "noise", "float", "", 0.0, 0.5, low_open=True, commands=("identify",),
           flag="--noise", doc="relative standard deviation of a reading (default 0.03)"),
    Option("identify", "model_error", "float", "", 0.0, 0.5,
           doc="relative error of the forward model, added in quadrature (default 0.02)",
           commands=("identify",), flag="--model-error"),
    Option("identify", "flag_length", "float", "m", 0.0, 0.13,
           doc="flag rule: flagged when P(length >= this) >= flag_probability (default "
               "20 mm)", commands=("identify",), flag="--flag-length-mm", factor=1e-3,
           flag_unit="mm"),
    Option("identify", "flag_probability", "float", "", 0.0, 1.0, low_open=True,
           doc="flag rule's probability (default 0.9)", commands=("identify",),
           flag="--flag-probability"),
    Option("identify", "line_speed_kmh", "float", "km/h", 5.0, 300.0,
           doc="line speed of P(peak contact force > force_level) (default: the passage's)",
           commands=("identify",), flag="--line-speed-kmh"),
    Option("identify", "force_level", "float", "N", 0.0, 5e6, low_open=True,
           doc="peak contact force level (default 350 kN)", commands=("identify",),
           flag="--force-level-kN", factor=1e3, flag_unit="kN"),
    Option("identify", "user_reading", "float", "N", 0.0, 5e6, low_open=True,
           doc="user rule: act when the highest reading exceeds this (unset: no reading "
               "level)", commands=("identify",), flag="--user-reading-kN", factor=1e3,
           flag_unit="kN"),
    Option("identify", "user_length", "float", "m", 0.0, 0.13, low_open=True,
           doc="user rule: act when P(length > this) >= 0.5 (unset: no length level)",
           commands=("identify",), flag="--user-length-mm", factor=1e-3, flag_unit="mm"),
    Option("identify", "coupling_iterations", "int", "", 0, 5, commands=("identify",),
           flag="--coupling-iterations", doc="neighbour-correction sweeps (default 1)"),
    Option("identify", "phase_modes", "int", "", 1, 32, flag="--phase-modes",
           commands=("identify",), doc="a flat neighbour's configurations averaged (default 8)"),
    Option("identify", "phase_error", "float", "m", 0.0, 0.3, factor=1e-3, flag_unit="mm",
           doc="blur (standard deviation) of a neighbour's phase posterior (default 50 mm)",
           commands=("identify",), flag="--phase-error-mm"),
    Option("identify", "realisations", "int", "", 1, 64, commands=("identify",),
           flag="--table-realisations", doc="rail roughness realisations of the table (default 3)"),
    Option("identify", "seed", "int", "", 0, 2**31 - 1, commands=("identify",),
           doc="seed of the identification's nuisance realisations (default 0)"),
    # wfjax detector --passage-csv: a passage of a train with chosen flats
    Option("passage", "csv", "path", doc="write a passage CSV of the train (passage.* keys) "
           "over the detector instead of the sweep", commands=("detector",),
           flag="--passage-csv", metavar="FILE"),
    Option("passage", "train", "str", choices=("single", "bogie", "wagon"),
           doc="the passing train's layout (default wagon)", commands=("detector",),
           flag="--train"),
    Option("passage", "flats", "str", doc='flat wheels, "wheel:kind:length_mm[:l/l0]" comma '
           'separated, e.g. "1:new:60,2:rounded:80" (default none)', commands=("detector",),
           flag="--train-flats"),
    Option("passage", "speed_kmh", "float", "km/h", 5.0, 300.0,
           doc="the passage's speed (default 100)", commands=("detector",),
           flag="--passage-speed-kmh"),
    Option("passage", "noise", "float", "", 0.0, 0.5, commands=("detector",), flag=(
        "--passage-noise"), doc="relative Gaussian noise on every reading (default 0.03)"),
    Option("passage", "seed", "int", "", 0, 2**31 - 1, flag="--passage-seed", doc="seed of "
           "its impacts, roughness, supports, noise (default 0)", commands=("detector",)),
    Option("passage", "contact", "str", choices=registry.names, commands=("detector",),
           flag="--passage-contact", doc="its contact law (default hertz-trajectory)"),
)

_ALL = COMMANDS + ("config",)
_OUT = {c: f"out/{c}" for c in COMMANDS} | {"receptance": "results/receptance"}
CLI_OPTIONS: tuple[Option, ...] = (
    Option("cli", "config", "path", doc="case file (TOML, or a JSON summary written by wfjax) "
           "with every parameter; flags override it (docs/case_files.md)", case=False,
           commands=_ALL, flag="--config", metavar="FILE"),
    Option("cli", "set", "str", doc="set one case key, e.g. --set track.pad_stiffness=60e6 "
           "(repeatable; wins over --config)", case=False, commands=_ALL, flag="--set",
           action="append", default=[], dest="set_values", metavar="SECTION.KEY=VALUE"),
    Option("cli", "out", "str", doc="output directory", case=False, commands=COMMANDS,
           flag="--out", default=_OUT, metavar="DIR"),
    Option("cli", "format", "strs", choices=("csv", "netcdf"),
           doc="result tables: csv = sweep.csv, netcdf = sweep.nc (labelled dimensions, units, "
           "case; needs wfjax[io]: docs/results.md) or csv,netcdf; JSON, NPZ, PNG always",
           case=False, commands=("sweep",), flag="--format", default="csv", metavar="FORMAT"),
    _speeds("figures", doc="speeds of every figure: 'start:stop:step' or 'v1,v2' (default "
            "20:300:10; --fast: 40,100,160)", case=False, commands=("figures",)),
    Option("figures", "fast", "bool", doc="tiny sweeps (3 speeds, 2 positions, fewer depths) "
           "for smoke tests", case=False, commands=("figures",), flag="--fast",
           action="store_true", default=False),
    Option("figures", "only", "str", doc="figures to make, comma separated (9 = Figs. 9+10)",
           case=False, commands=("figures",), flag="--only", default="5,7,8,9"),
    Option("receptance", "fmin_hz", "float", "Hz", 0.0, 1e6, low_open=True,
           doc="lowest frequency", case=False, commands=("receptance",), flag="--fmin-hz",
           default=20.0),
    Option("receptance", "fmax_hz", "float", "Hz", 0.0, 1e6, low_open=True,
           doc="highest frequency (> --fmin-hz)", case=False, commands=("receptance",),
           flag="--fmax-hz", default=5000.0),
    Option("receptance", "points", "int", "", 2, 100000, doc="log-spaced frequencies",
           case=False, commands=("receptance",), flag="--points", default=400),
    Option("config", "print_defaults", "bool", doc="write the complete commented default "
           "case to stdout", case=False, commands=("config",), flag="--print-defaults",
           action="store_true", default=False),
    Option("config", "print_table", "bool", doc="write the Markdown table of every key "
           "(docs/case_files.md)", case=False, commands=("config",), flag="--print-table",
           action="store_true", default=False),
    Option("config", "command", "str", choices=COMMANDS, doc="the subcommand whose case is "
           "printed or checked", case=False, commands=("config",), flag="--command",
           dest="case_command", default="sweep"),
    Option("config", "no_comments", "bool", doc="omit the unit/range comment after every key",
           case=False, commands=("config",), flag="--no-comments", action="store_true",
           default=False),
    # a positional argument (a flag without dashes): ``wfjax examples [DIR]``
    Option("examples", "dir", "str", doc="directory to copy the example case files and the "
           "measured profile into (created; an existing file is never overwritten)",
           case=False, commands=("examples",), flag="dir", default="examples", metavar="DIR"),
)

OPTIONS: tuple[Option, ...] = RUN_OPTIONS + tuple(model_options()) + CLI_OPTIONS
KEYS: dict[str, Option] = {o.path: o for o in OPTIONS if o.case}
"""Every case-file key, ``"section.name" -> Option``."""
SECTIONS = tuple(dict.fromkeys(k.section for k in KEYS.values()))


def flags_of(command: str) -> list[Option]:
    """The options whose flag ``wfjax command`` offers, in the order of :data:`OPTIONS`."""
    return [o for o in OPTIONS if o.offers_flag(command)]


# -- checking values ------------------------------------------------------------------------
def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def fmt(value) -> str:
    """A value as the user would write it (JSON for strings, lists and booleans)."""
    return json.dumps(value) if isinstance(value, (str, list, bool)) or value is None \
        else repr(value)


def parse_number_list(text: str) -> list[float]:
    """Numbers from ``"start:stop:step"`` (inclusive) or ``"a,b,c"``; ValueError otherwise."""
    if ":" in text:
        start, stop, step = (float(p) for p in text.split(":"))
        if not (step > 0 and stop >= start and math.isfinite(stop)):
            raise ValueError(text)
        n = int(math.floor((stop - start) / step + 0.5)) + 1
        if n > 100000:
            raise ValueError(text)
        return [float(v) for v in start + step * np.arange(n)]
    return [float(p) for p in text.split(",")]


def from_text(option: Option, text):
    """A flag's text as the number it spells where ``option`` wants one (else unchanged, so
    :func:`check_value` reports the wrong type with the range)."""
    if not isinstance(text, str) or option.kind not in ("int", "float", "float|auto") \
            or text == "auto":
        return text
    for convert in (int, float):
        try:
            return convert(text)
        except ValueError:
            pass
    return text


def check_value(key: Option, value, source: str, factor: float = 1.0,
                unit: str | None = None, name: str | None = None):
    """``value`` (written in ``unit`` = SI / ``factor``) checked and converted to SI.

    Raises:
        CaseError: one line naming ``name`` (default the key's path; a flag as typed), the
            value and the allowed range.
    """
    name = name or key.path
    shown = f"{source}: {name} = {fmt(value)}" if source else f"{name} {fmt(value)}"

    def fail(why: str):
        raise CaseError(f"{shown}: {why}; allowed: {key.allowed(factor, unit)}")

    def number(v):
        if not _is_number(v):
            fail(f"wrong type ({type(v).__name__}), expected a number")
        v = float(v) * factor
        if not math.isfinite(v):
            fail("not finite")
        lo_bad = key.low is not None and (v < key.low or (key.low_open and v == key.low))
        hi_bad = key.high is not None and (v > key.high or (key.high_open and v == key.high))
        if lo_bad or hi_bad:
            fail("out of range")
        return v

    checker = _CHECKERS.get(key.kind, _check_number)
    return checker(key, value, fail, number)


def _check_bool(key, value, fail, number):
    if not isinstance(value, bool):
        fail(f"wrong type ({type(value).__name__}), expected true or false")
    return value


def _check_str(key, value, fail, number):
    if not isinstance(value, str):
        fail(f"wrong type ({type(value).__name__}), expected a string")
    choices = key.choice_list
    if choices is not None and value not in choices:
        fail("not one of the choices")
    return value


def _check_strs(key, value, fail, number):
    items = [s.strip() for s in value.split(",")] if isinstance(value, str) else value
    if not isinstance(items, list) or not items or not all(
            isinstance(s, str) and s for s in items):
        fail("expected a list of strings or a comma-separated string")
    choices = key.choice_list
    if choices is not None and any(s not in choices for s in items):
        fail("not one of the choices")
    return list(items)


def _check_int(key, value, fail, number):
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if not isinstance(value, int) or isinstance(value, bool):
        fail(f"wrong type ({type(value).__name__}), expected an integer")
    return int(number(value))


def _check_auto(key, value, fail, number):
    return value if value == "auto" else number(value)


def _check_floats(key, value, fail, number):
    if isinstance(value, str):
        try:
            items = parse_number_list(value)
        except ValueError:
            fail('expected numbers: a list, "start:stop:step" or "a,b,c"')
        if key.section in ("run", "figures"):  # keep the text: it re-parses the same
            for v in items:
                number(v)
            return value
        value = items[0] if len(items) == 1 else items
    if isinstance(value, list):
        if not value:
            fail("empty list")
        return [number(v) for v in value]
    return number(value)


def _check_number(key, value, fail, number):
    return number(value)


_CHECKERS = {"bool": _check_bool, "str": _check_str, "path": _check_str, "strs": _check_strs,
             "int": _check_int, "float|auto": _check_auto, "floats": _check_floats}
