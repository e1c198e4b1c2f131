"""Case files (wfjax/case.py): keys, checks, precedence, defaults, measured profiles, docs.

No simulation runs here: everything is resolved and checked before any work.
"""

import json
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

import wfjax as wf
from wfjax import case as C
from wfjax.datafiles import read_profile_csv
from wfjax.optdocs import markdown_table

ROOT = Path(__file__).resolve().parents[1]


def _write(tmp_path, text, name="case.toml"):
    path = tmp_path / name
    path.write_text(text)
    return str(path)


# -- defaults -------------------------------------------------------------------------------
@pytest.mark.parametrize("command", C.COMMANDS)
def test_printed_defaults_reload_to_the_dataclass_defaults(command, tmp_path):
    """The commented default case of every subcommand parses and rebuilds the defaults."""
    text = C.default_case(command).to_toml("header")
    path = _write(tmp_path, text)
    case = C.resolve(command, path, environ={})
    assert case.values == C.default_layer(command)
    wheel, track, material, config = case.model()
    expected_track = (wf.Track.comparison() if command in ("fit", "compare", "figures")
                      else wf.Track())
    # every command leaves the auto settings to the scenario (a detector's reading gets its own)
    assert wheel == wf.Wheel() and material == wf.Material() and config == wf.SimConfig()
    assert track == expected_track


def test_sweep_defaults_are_the_main_job():
    case = C.resolve("sweep", environ={})
    flats = case.flats()
    assert [f.kind for f in flats] == ["rounded", "new"]
    assert float(flats[0].depth) == 0.9e-3 and float(flats[0].length) == 0.1
    np.testing.assert_array_equal(case.speeds(), np.arange(20.0, 301.0, 10.0) / 3.6)
    assert case["run.impact_positions"] == 10 and case["run.contact"] == "3d"


def test_every_dataclass_field_is_a_key():
    for section, cls in C.MODEL_SECTIONS.items():
        for f in __import__("dataclasses").fields(cls):
            assert f"{section}.{f.name}" in C.KEYS


# -- bad input: one line naming key, value and range ----------------------------------------
@pytest.mark.parametrize("text, words", [
    ("[track]\npad_stifness = 60e6\n", ["unknown key track.pad_stifness", "pad_stiffness"]),
    ("[track]\nn_bays = 70.5\n", ["track.n_bays = 70.5", "wrong type", "[4, 1000]"]),
    ("[track]\npad_stiffness = 120\n", ["track.pad_stiffness = 120", "out of range",
                                        "[1e+06, 1e+10] N/m"]),
    ("[wheel]\npreload = \"110 kN\"\n", ["wheel.preload", "wrong type", "N"]),
    ("[wheel]\npreload = true\n", ["wheel.preload = true", "wrong type"]),
    ("[run]\nspeeds = [20, 30]\n", ["run.speeds", "missing unit", "run.speeds_kmh"]),
    ("[run]\nspeeds_kmh = [20, 600]\n", ["run.speeds_kmh", "out of range", "(0, 540] km/h"]),
    ("[run]\nspeeds_kmh = \"300:20:10\"\n", ["run.speeds_kmh", "start:stop:step"]),
    ("[run]\ncontact = \"5d\"\n", ["run.contact", "hertz-trajectory"]),
    ("[flat]\ndepth = 0.9\n", ["flat.depth = 0.9", "out of range", "(0, 0.005] m"]),
    ("[flat]\nlength_mm = 5000\n", ["flat.length_mm = 5000", "(0, 300] mm"]),
    ("[flat]\nlength = 0.1\nlength_factor = 1.76\n", ["flat.length", "flat.length_factor"]),
    ("[whel]\nradius = 0.45\n", ["unknown section [whel]"]),
    ("radius = 0.45\n", ["radius", "table"]),
    ("[wheel\n", ["not valid TOML", "line 1"]),
    ("[config]\ntime_step = -1e-5\n", ["config.time_step", '"auto" or (0, 0.001] s']),
    ("[material]\npoisson_ratio = 0.5\n", ["material.poisson_ratio", "[0, 0.5)"]),
    ("[flat]\nkind = \"rounded\"\ndepth_mm = 2.0\nlength_mm = 100\n", ["pi/2 * l0"]),
    ("[flat]\nkind = \"rounded\"\ndepth_mm = [0.5, 1, 1.5]\nlength_mm = [60, 120]\n",
     ["2 lengths for 3 depths"]),
])
def test_bad_case_file_is_one_line_naming_key_value_range(tmp_path, text, words):
    path = _write(tmp_path, text)
    with pytest.raises(C.CaseError) as err:
        C.resolve("sweep", path, environ={})
    message = str(err.value)
    assert "\n" not in message
    for w in words:
        assert w in message, (w, message)


def test_impact_position_range_follows_the_sleeper_spacing(tmp_path):
    path = _write(tmp_path, "[track]\nsleeper_spacing = 0.6\n[run]\nimpact_position_mm = 620\n")
    with pytest.raises(C.CaseError, match=r"\[0, 0.6\) m"):
        C.resolve("simulate", path, environ={})


def test_lists_and_both_are_for_sweep_only(tmp_path):
    with pytest.raises(C.CaseError, match="sweep only"):
        C.resolve("simulate", _write(tmp_path, "[flat]\ndepth_mm = [0.5, 1.0]\n"), environ={})
    with pytest.raises(C.CaseError, match="sweep only"):
        C.resolve("simulate", _write(tmp_path, "[flat]\nkind = \"both\"\n"), environ={})


def test_keys_of_other_subcommands_are_noted_not_used(tmp_path):
    case = C.resolve("simulate", _write(tmp_path, "[run]\nspeeds_kmh = [60]\n"), environ={})
    assert case.unused == ("run.speeds_kmh",) and "run.speeds_kmh" not in case.values


# -- units and precedence -------------------------------------------------------------------
def test_unit_suffixed_keys_convert_to_si(tmp_path):
    path = _write(tmp_path, "[wheel]\npreload_kN = 110.4\n[track]\npad_stiffness_MN_per_m = 60\n"
                            "[material]\nyoungs_modulus_GPa = 205\n[flat]\ndepth_mm = 0.9\n"
                            "length_mm = 100\n")
    case = C.resolve("sweep", path, environ={})
    wheel, track, material, _ = case.model()
    assert float(wheel.preload) == pytest.approx(110.4e3)
    assert float(track.pad_stiffness) == 60e6 and float(material.youngs_modulus) == 205e9
    assert case["flat.depth"] == pytest.approx(0.9e-3) and case["flat.length"] == 0.1


def test_flag_beats_file_beats_environment_beats_default(tmp_path):
    path = _write(tmp_path, "[config]\nprecision = \"float64\"\n[run]\ncontact = \"2d\"\n"
                            "[track]\nrail_head_radius = 0.45\npad_stiffness = 60e6\n")
    env32 = {"WFJAX_PRECISION": "float32"}
    assert C.resolve("sweep", environ={})["config.precision"] == "auto"
    assert C.resolve("sweep", environ=env32)["config.precision"] == "float32"
    case = C.resolve("sweep", path, environ=env32)
    assert case["config.precision"] == "float64" and case["run.contact"] == "2d"
    case = C.resolve("sweep", path, {"config.precision": "float32", "track.rail_head_radius": 0.3},
                     environ=env32)
    assert case["config.precision"] == "float32"
    assert case["track.rail_head_radius"] == 0.3 and case["track.pad_stiffness"] == 60e6
    with pytest.raises(C.CaseError, match="WFJAX_PRECISION"):
        C.resolve("sweep", environ={"WFJAX_PRECISION": "float16"})
    assert C.resolve("compare", environ=env32).model()[3].precision == "float32"
    with pytest.raises(C.CaseError, match="now config.precision"):  # the old key, redirected
        C.resolve("sweep", _write(tmp_path, "[run]\nprecision = \"float32\"\n"), environ={})


def test_a_length_flag_replaces_the_files_length_factor(tmp_path):
    path = _write(tmp_path, "[flat]\nkind = \"rounded\"\ndepth_mm = [0.5, 1.0]\n"
                            "length_factor = 1.76\n")
    case = C.resolve("sweep", path, environ={})
    l0 = [math.sqrt(8 * 0.45 * d) for d in (0.5e-3, 1.0e-3)]
    assert [float(f.length) for f in case.flats()] == pytest.approx([1.76 * x for x in l0])
    case = C.resolve("sweep", path, {"flat.length": 0.12}, environ={})
    assert "flat.length_factor" not in case.values
    assert [float(f.length) for f in case.flats()] == [0.12, 0.12]


def test_depth_range_with_lengths_per_depth_and_both_kinds(tmp_path):
    path = _write(tmp_path, "[flat]\nkind = \"both\"\ndepth_mm = \"0.5:1.0:0.25\"\n"
                            "length_mm = [80, 100, 120]\n")
    flats = C.resolve("sweep", path, environ={}).flats()
    assert [f.kind for f in flats] == ["rounded"] * 3 + ["new"] * 3
    assert [float(f.depth) for f in flats[:3]] == pytest.approx([0.5e-3, 0.75e-3, 1.0e-3])
    assert [float(f.length) for f in flats[:3]] == pytest.approx([0.08, 0.1, 0.12])


def test_json_summary_is_a_case_file(tmp_path):
    case = C.resolve("sweep", None, {"run.speeds_kmh": "60,120", "flat.kind": "new"},
                     environ={})
    path = _write(tmp_path, json.dumps({"contact": "x", "case": case.to_dict()}), "s.json")
    again = C.resolve("sweep", path, environ={})
    assert again.values == case.values and again.digest() == case.digest()
    with pytest.raises(C.CaseError, match='"case"'):
        C.resolve("sweep", _write(tmp_path, "{}", "bad.json"), environ={})


def test_written_toml_round_trips_exactly(tmp_path):
    """Floats are written with repr, so a resolved case reloads bit for bit."""
    flags = {"flat.depth": [0.1e-3 * 3, 0.7e-3], "flat.kind": "new",
             "wheel.preload": 110.4 * 1e3, "config.time_step": 1e-5 / 3}
    case = C.resolve("sweep", None, flags, environ={})
    path = _write(tmp_path, case.to_toml("x"))
    assert C.resolve("sweep", path, environ={}).values == case.values


# -- examples and docs ----------------------------------------------------------------------
EXAMPLES = ROOT / "wfjax" / "examples"  # package data: `wfjax examples DIR` copies them


def test_examples_resolve():
    fig7 = C.resolve("sweep", str(EXAMPLES / "fig7.toml"), environ={})
    assert fig7.model()[1] == wf.Track.comparison()
    soft = C.resolve("sweep", str(EXAMPLES / "soft_pads_heavy_axle.toml"), environ={})
    wheel, track, _, _ = soft.model()
    assert float(wheel.preload) == pytest.approx(22.5e3 * 9.81 / 2, rel=1e-3)
    assert float(track.sleeper_spacing) == 0.6 and float(track.pad_stiffness) == 60e6
    assert [f.kind for f in soft.flats()] == ["rounded", "new"]


def test_docs_table_is_generated_from_the_keys():
    """docs/case_files.md holds exactly the table of wfjax/case.py (wfjax config --print-table)."""
    assert markdown_table() in (ROOT / "docs" / "case_files.md").read_text()


def test_toml_output_is_valid_toml():
    data = tomllib.loads(C.default_case("fit").to_toml("a\nb"))
    assert data["track"]["rail_head_radius"] == 0.45 and data["config"]["time_step"] == "auto"


# -- measured profiles ----------------------------------------------------------------------
def _profile_text(x_mm, z_mm, header="x_mm,z_mm"):
    return header + "\n" + "".join(f"{a},{b}\n" for a, b in zip(x_mm, z_mm, strict=True))


def test_profile_csv_is_resampled_centred_and_checked(tmp_path):
    x = np.arange(0.0, 120.01, 0.5) + 1000.0  # any origin
    z = np.where(np.abs(x - 1060) < 50, 0.45 * (1 + np.cos(2 * np.pi * (x - 1060) / 100)), 0.0)
    z[3] = -0.01  # measurement noise below zero is clipped
    path = _write(tmp_path, "# comment line\n" + _profile_text(x, z), "p.csv")
    xm, zm = read_profile_csv(path)
    np.testing.assert_allclose(np.diff(xm), 0.1e-3, rtol=1e-9)
    assert abs(np.sum(xm * zm) / np.sum(zm)) < 1e-9  # centred on the missing area
    assert zm.min() == 0.0 and zm.max() == pytest.approx(0.9e-3)
    flat = wf.Flat.from_profile(xm, zm)
    assert flat.kind == "profile" and float(flat.depth) == pytest.approx(0.9e-3)
    xs, zs = read_profile_csv(path, smoothing_mm=2.0)
    assert zs.max() < zm.max() and np.sum(zs) == pytest.approx(np.sum(zm), rel=1e-3)
    case = C.resolve("simulate", None, {"flat.profile_csv": path}, environ={})
    assert case["flat.kind"] == "profile" and "flat.depth" not in case.values


@pytest.mark.parametrize("text, words", [
    ("x_m,z_m\n0,0\n", ["header must be x_mm,z_mm", "in mm"]),
    ("x,z,w\n0,0,0\n", ["header must be x_mm,z_mm"]),
    ("", ["empty"]),
    (_profile_text([0, 1, 2, 3], [0, 0.1, 0.1, 0]), ["at least 5 rows"]),
    (_profile_text([0, 1, 1, 3, 4], [0, 0.1, 0.2, 0.1, 0]), ["strictly increasing", "line 4"]),
    (_profile_text([0, 1, 2, 3, 4], [0, 0.1, "nan", 0.1, 0]), ["line 4", "NaN"]),
    (_profile_text([0, 1, 2, 3, 4], [0, 0.1, "abc", 0.1, 0]), ["line 4", "not a number"]),
    (_profile_text([0, 1, 2, 3, 4], [0, -0.3, -0.5, -0.3, 0]), ["flip the sign"]),
    (_profile_text([0, 1, 2, 3, 4], [0, 300, 900, 300, 0]), ["um instead of mm"]),
    (_profile_text([0, 1, 2, 3, 4], [0.4, 0.5, 0.9, 0.5, 0]), ["first row", "extend it"]),
    ("x_mm,z_mm\n0,0\n1,0.1,3\n", ["line 3 has 3 fields"]),
])
def test_profile_csv_errors_are_clear(tmp_path, text, words):
    path = _write(tmp_path, text, "p.csv")
    with pytest.raises(C.CaseError) as err:
        read_profile_csv(path)
    message = str(err.value)
    assert "\n" not in message and path in message
    for w in words:
        assert w in message, (w, message)


def test_profile_csv_relative_to_the_case_file(tmp_path):
    sub = tmp_path / "cases"
    sub.mkdir()
    (sub / "p.csv").write_text(_profile_text(np.arange(0, 60.1, 1.0),
                                             np.r_[0, np.full(59, 0.2), 0]))
    case = C.resolve("geometry", _write(sub, "[flat]\nprofile_csv = \"p.csv\"\n"), environ={})
    assert case["flat.profile_csv"] == str((sub / "p.csv").resolve())
    assert case.flat().kind == "profile"
