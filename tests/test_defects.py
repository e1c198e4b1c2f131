"""The smaller defects of issue 32, each refused with one line naming what the user typed:
keys without their companion, fit CSVs (BOM, units), profile smoothing's area, case.toml
escapes, Python names in errors, a rerun whose input changed."""

import json
import tomllib

import numpy as np
import pytest

import wfjax as wf
from wfjax import case as C
from wfjax.cli import main
from wfjax.commands._common import user_words
from wfjax.commands.fit import EXAMPLE_CSV, parse_data
from wfjax.datafiles import file_sha256, read_profile_csv

HT = ["--contact", "hertz-trajectory"]



def _one_error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


# -- keys that need a companion ----------------------------------------------------------------
PAIRS = [  # (command, flags without the companion, what the error names, the companion)
    ("sweep", ["--realisations", "5"], "--realisations", ["--roughness", "iso3095"]),
    ("sweep", ["--seed", "3"], "--seed", ["--roughness", "iso3095"]),
    ("simulate", ["--void-gap-mm", "2"], "--void-gap-mm",
     ["--void-sleepers", str(wf.Track().n_bays // 2 - 1)]),
    ("sweep", ["--support-realisations", "3"], "--support-realisations",
     ["--scatter-cv", "0.2"]),
    ("simulate", ["--joint-shape", "v"], "--joint-shape", ["--joint-depth-mm", "0.5"]),
    ("simulate", ["--joint-length-m", "0.4"], "--joint-length-m", ["--joint-depth-mm", "0.5"]),
    ("simulate", ["--joint-position-m", "0.1"], "--joint-position-m",
     ["--joint-depth-mm", "0.5"]),
    ("simulate", ["--axle-spacing-m", "3"], "--axle-spacing-m", ["--vehicle", "bogie"]),
    ("simulate", ["--bogie-distance-m", "12"], "--bogie-distance-m", ["--vehicle", "wagon"]),
    ("simulate", ["--flat", "new", "--length-mm", "120"], "--length-mm",
     ["--flat", "rounded"]),
    ("simulate", ["--profile-smoothing-mm", "2"], "--profile-smoothing-mm", None),
    ("sweep", ["--set", "roughness.length=8"], "--set roughness.length",
     ["--roughness", "iso3095"]),
    ("detector", ["--train", "bogie"], "--train", None),
    ("simulate", ["--section-window-mm=-10,10"], "--section-window-mm", None),
]


@pytest.mark.parametrize("command, flags, named, companion", PAIRS,
                         ids=[p[2] for p in PAIRS])
def test_a_flag_without_its_companion_is_refused(command, flags, named, companion, tmp_path,
                                                 capsys, no_work):
    out = tmp_path / "o"
    assert main([command, *HT, *flags, "--out", str(out)]) == 2
    line = _one_error(capsys)
    assert named in line and "has no effect without" in line, line
    assert not out.exists()
    if companion is not None:  # with its companion the same flag is accepted
        from wfjax.cli import build_parser
        from wfjax.commands._common import resolve_case

        args = build_parser().parse_args([command, *HT, *flags, *companion])
        resolve_case(args, command)


def test_a_companion_less_key_in_a_case_file_is_named_with_the_file(tmp_path, capsys, no_work):
    path = tmp_path / "case.toml"
    path.write_text("[supports]\nvoid_gap_mm = 2.0\n")
    assert main(["simulate", *HT, "--config", str(path), "--out", str(tmp_path / "o")]) == 2
    line = _one_error(capsys)
    assert f"{path}: supports.void_gap" in line and "--void-sleepers" in line, line


@pytest.mark.parametrize("command", ["sweep", "simulate", "fit", "compare", "detector",
                                     "geometry", "receptance", "figures"])
def test_written_case_files_still_repeat(command, tmp_path):
    """A case.toml holds every key at its default: nothing counts as given alone."""
    path = tmp_path / "case.toml"
    path.write_text(C.default_case(command).to_toml())
    C.resolve(command, str(path), environ={})


# -- fit data -----------------------------------------------------------------------------------
def test_fit_csv_with_a_utf8_bom_is_read():
    plain = parse_data(EXAMPLE_CSV, "d.csv")
    bom = parse_data("\ufeff" + EXAMPLE_CSV, "d.csv")
    np.testing.assert_array_equal(plain.max_force, bom.max_force)


def test_fit_csv_bom_from_a_file(tmp_path, capsys, monkeypatch):
    path = tmp_path / "d.csv"
    path.write_bytes(b"\xef\xbb\xbf" + b"speed_kmh,max_force_kN\n40,-1\n60,200\n80,210\n")
    assert main(["fit", "--data", str(path), "--out", str(tmp_path / "o")]) == 2
    line = _one_error(capsys)  # read past the BOM: the bad value is named, not the header
    assert "line 2" in line and "max_force_kN" in line, line


@pytest.mark.parametrize("rows, words", [
    ([(40, 210.0), (60, 205000.0), (80, 190.0), (100, 230.0)], ["line 3", "205000", "in N"]),
    ([(40, 0.21), (60, 0.205), (80, 0.19)], ["0.21", "MN", "1000"]),
    ([(40, 210.0), (60, 0.2), (80, 190.0)], ["line 3", "0.2"]),
    ([(40, 2.1e5), (60, 2.05e5), (80, 1.9e5)], ["look like N"]),
])
def test_fit_csv_unit_checks_name_the_row(rows, words):
    text = "speed_kmh,max_force_kN\n" + "".join(f"{v},{f}\n" for v, f in rows)
    with pytest.raises(ValueError) as info:
        parse_data(text, "d.csv")
    for word in words:
        assert word in str(info.value), str(info.value)


def test_fit_history_in_mn_is_refused():
    t = np.linspace(-0.005, 0.005, 20)
    text = "t_s,force_kN\n" + "".join(f"{a},{0.1 + 0.05 * np.exp(-(a / 1e-3) ** 2)}\n"
                                      for a in t)
    with pytest.raises(ValueError, match="MN"):
        parse_data(text, "h.csv", speed_kmh=100.0)


# -- profile smoothing keeps the area ----------------------------------------------------------
@pytest.mark.parametrize("sigma_mm", [1.0, 5.0, 20.0])
def test_profile_smoothing_keeps_the_missing_area(sigma_mm, tmp_path):
    x = np.linspace(-20.0, 20.0, 81)  # a short profile: the ends close to the flat
    z = 0.9 * np.cos(np.pi * x / 40) ** 2
    path = tmp_path / "p.csv"
    path.write_text("x_mm,z_mm\n" + "".join(f"{a},{b}\n" for a, b in zip(x, z, strict=True)))
    x0, z0 = read_profile_csv(path)
    xs, zs = read_profile_csv(path, sigma_mm)
    assert np.sum(zs) == pytest.approx(np.sum(z0), rel=1e-4)  # was down to 8 % at 20 mm
    assert zs.max() < z0.max() and zs[0] == zs[-1] == 0.0
    assert abs(np.sum(xs * zs) / np.sum(zs)) < 1e-9


# -- case.toml ----------------------------------------------------------------------------------
def test_case_toml_round_trips_characters_outside_the_basic_plane(tmp_path):
    name = str(tmp_path / "profil \U0001f600 \u00e9\x7f.csv")
    case = C.Case("simulate", {"flat.kind": "profile", "flat.profile_csv": name})
    text = case.to_toml(comments=False)
    assert "\\ud83d" not in text
    assert tomllib.loads(text)["flat"]["profile_csv"] == name


# -- errors in the user's words ---------------------------------------------------------------
def test_errors_name_flags_not_python_objects(tmp_path, capsys, no_work):
    assert main(["simulate", *HT, "--wheel-positions-m", "0,2,1", "--out",
                 str(tmp_path / "o")]) == 2
    line = _one_error(capsys)
    assert "--wheel-positions-m" in line and "Vehicle.positions" not in line, line
    assert user_words("use Track(n_bays=108)") == "use --set track.n_bays=108"
    assert user_words("SimConfig.time_step too large") == "config.time_step too large"
    assert user_words("Flat.length of a rounded flat") == "flat.length of a rounded flat"


# -- a rerun whose input changed ---------------------------------------------------------------
def test_rerun_from_a_summary_refuses_a_changed_profile(tmp_path, capsys, no_work):
    profile = tmp_path / "p.csv"
    x = np.linspace(-60.0, 60.0, 121)
    z = np.where(np.abs(x) < 50, 0.45 * (1 + np.cos(np.pi * x / 50)), 0.0)
    profile.write_text("x_mm,z_mm\n" + "".join(f"{a},{b}\n" for a, b in zip(x, z, strict=True)))
    case = C.resolve("geometry", None, {"flat.profile_csv": str(profile)}, environ={})
    summary = tmp_path / "geometry.json"
    summary.write_text(json.dumps({"case": case.to_dict(), "provenance": {
        "inputs_sha256": {str(profile): file_sha256(profile)}}}))
    C.load_layer(summary)  # unchanged: accepted
    profile.write_text(profile.read_text().replace("0.45", "0.46", 1) + "\n")
    assert main(["geometry", "--config", str(summary), "--out", str(tmp_path / "o")]) == 2
    line = _one_error(capsys)
    assert str(summary) in line and str(profile) in line and "changed since the run" in line


def test_provenance_records_every_file_of_a_records_directory(tmp_path):
    from wfjax.commands._common import provenance

    records = tmp_path / "records"
    records.mkdir()
    for i in range(2):
        (records / f"line{i}.txt").write_text(f"position_mm,deviation_um\n0,{i}\n")
    case = C.resolve("geometry", None, {}, environ={})
    recorded = provenance(case, {"flat.sections": str(records), "unset": None})["inputs_sha256"]
    assert recorded == {str(records / f"line{i}.txt"): file_sha256(records / f"line{i}.txt")
                        for i in range(2)}
    summary = {"provenance": {"inputs_sha256": recorded}}
    (records / "line1.txt").write_text("position_mm,deviation_um\n0,7\n")
    from wfjax.datafiles import check_recorded_inputs

    with pytest.raises(Exception, match="changed since the run"):
        check_recorded_inputs(summary, "s.json")
