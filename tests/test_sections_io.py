"""Reading and writing gauge records (wfjax.sections), splitting a measurement into its flat and
the wheel's out-of-roundness (wfjax.scenario.measured), and the refusals of bad input."""

from __future__ import annotations

import math
from importlib import resources

import numpy as np
import pytest

from wfjax.scenario import measured
from wfjax.sections import SectionsError, read_records, write_records

LINES = [-20.0, -13.0, -6.0, 0.0, 6.0, 13.0, 20.0]
N = int(round(2 * math.pi * 0.45 * 1e3))  # 2827 samples of 1 mm


def _example():
    return resources.files("wfjax") / "examples" / "measured_sections.csv"


def _write_lines(tmp_path, dev, x=None, decimal=".", encoding="utf-8", header="Gauge X\n"):
    x = np.arange(N, dtype=float) if x is None else x
    d = tmp_path / "rec"
    d.mkdir()
    sep = ";" if decimal == "," else ","
    for j, row in enumerate(dev):
        body = "\n".join(f"{float(a)!r}{sep}{float(b)!r}".replace(".", decimal)
                         for a, b in zip(x, row, strict=True))
        (d / f"l{j}.txt").write_bytes((header + "pos mm" + sep + "dev µm\n" + body
                                       + "\n").encode(encoding))
    return d


def _flat_dev(k=3, depth_um=400.0):
    x = np.arange(N, dtype=float)
    v = np.clip(1 - np.abs(x - 700) / 20, 0, None)
    return np.array([-depth_um * (1 - 0.2 * j) * v + 3 * np.sin(x / 50 + j) for j in range(k)])


def test_example_reads_and_splits():
    rec = read_records(_example(), LINES)
    assert rec.deviation_um.shape == (7, N) and rec.spacing_mm == 1.0
    m = measured.split(rec)
    assert m.window_mm[0] < 1000 < m.window_mm[1]
    assert abs(m.centre_mm - 1000) <= 3
    assert m.flat.kind == "sections" and 0.58e-3 < m.flat.depth < 0.63e-3
    r = np.asarray(m.wheel_roughness.values)
    assert m.wheel_roughness.periodic and r.shape == (N,)
    assert 10e-6 < r.std() < 25e-6  # 15 um RMS roughness + 10 um eccentricity, no flat in it
    # the window is cut out: zero around s = 0 (sample 0 is the flat centre)
    assert np.all(r[:20] == 0) and np.all(r[-20:] == 0)


@pytest.mark.parametrize("one_csv,decimal", [(True, "."), (True, ","), (False, "."),
                                             (False, ",")])
def test_round_trip_to_the_last_digit(tmp_path, one_csv, decimal):
    rec = read_records(_example(), LINES)
    target = tmp_path / ("out.csv" if one_csv else "dir")
    write_records(rec, target, one_csv=one_csv, decimal=decimal)
    back = read_records(target, LINES)
    assert np.array_equal(back.position_mm, rec.position_mm)
    assert np.array_equal(back.deviation_um, rec.deviation_um)
    # and the example's own digits: every value as written in the file
    text = _example().read_bytes().decode("latin-1").splitlines()[3]
    assert text.split(";")[1] == f"{rec.deviation_um[0, 0]:.1f}".replace(".", ",")


def test_directory_latin1_comma_decimals(tmp_path):
    dev = _flat_dev()
    d = _write_lines(tmp_path, dev, decimal=",", encoding="latin-1", header="Messung Rad ä\n")
    rec = read_records(d, [-5.0, 0.0, 5.0])
    assert np.array_equal(rec.deviation_um, dev)
    m = measured.split(rec)
    assert m.centre_mm == 700.0
    assert m.flat.depth == pytest.approx(0.4e-3 * 0.8, rel=0.02)


@pytest.mark.parametrize("case,match", [
    ("length", "different lengths"),
    ("spacing", "not on the uniform spacing"),
    ("start", "different starts or spacings"),
    ("order", "does not increase after"),
    ("open", "does not close"),
    ("deep", "beyond"),
    ("text", "not a number"),
])
def test_bad_records_one_line(tmp_path, case, match):
    dev = _flat_dev()
    x = np.arange(N, dtype=float)
    lateral = [-5.0, 0.0, 5.0]
    if case == "open":
        x, dev = x[:-3], dev[:, :-3]
    if case == "deep":
        dev[1, 40] = -5000.5
    d = _write_lines(tmp_path, dev, x=x)
    files = sorted(d.iterdir())
    if case in ("length", "spacing", "start", "text"):
        lines = files[2].read_text().splitlines()
        if case == "length":
            lines = lines[:-1]
        elif case == "spacing":
            lines[10] = "8.5," + lines[10].split(",")[1]
        elif case == "start":
            lines = lines[:2] + [f"{float(v.split(',')[0]) + 0.5!r},{v.split(',')[1]}"
                                 for v in lines[2:]]
        else:
            lines[100] = "98.0,abc"
        files[2].write_text("\n".join(lines) + "\n")
    if case == "order":
        lateral = [-5.0, 5.0, 0.0]
    with pytest.raises(SectionsError, match=match) as info:
        read_records(d, lateral)
    msg = str(info.value)
    assert "\n" not in msg
    if case != "order":
        assert "line " in msg and str(d) in msg
    if case == "deep":
        assert "l1.txt: line 43" in msg and "-5000.5" in msg


def test_window_missing_the_flat(tmp_path):
    rec = read_records(_write_lines(tmp_path, _flat_dev()), [-5.0, 0.0, 5.0])
    with pytest.raises(SectionsError, match="misses the flat.*700.0 mm"):
        measured.split(rec, window_mm=(100.0, 300.0))
    m = measured.split(rec, window_mm=(660.0, 740.0))
    assert m.window_mm == (660.0, 740.0) and m.centre_mm == 700.0


@pytest.mark.parametrize("extra,match", [
    (["--section-positions-mm=-20,-13,-6,0,6,20,13"], "does not increase after 20.0 mm"),
    (["--section-positions-mm=-20,-13,-6,0,6,13,20", "--section-window-mm=100,300"],
     "misses the flat: its deepest point is at 1002.0 mm"),
])
def test_cli_bad_input_exit_2_nothing_written(tmp_path, capsys, extra, match):
    from wfjax.cli import main

    out = tmp_path / "out"
    rc = main(["geometry", "--sections", str(_example()), *extra, "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and not out.exists()
    assert len(err.splitlines()) == 1 and match in err
    assert "measured_sections.csv" in err


def test_cli_geometry_of_the_example(tmp_path, capsys):
    from wfjax.cli import main

    out = tmp_path / "out"
    rc = main(["geometry", "--sections", str(_example()),
               "--section-positions-mm=-20,-13,-6,0,6,13,20", "--out", str(out)])
    assert rc == 0 and (out / "geometry.csv").exists()
    assert "sections flat: depth 0.606 mm" in capsys.readouterr().out


def test_case_values_give_flat_and_wheel_roughness():
    class _Case(dict):
        values = property(lambda self: dict(self))

    case = _Case({"flat.kind": "sections", "flat.sections": str(_example()),
                  "flat.section_positions_mm": "-20,-13,-6,0,6,13,20", "wheel.radius": 0.45})
    rough = measured.case_wheel_roughness(case, None)
    assert rough.periodic and np.asarray(rough.values).shape == (N,)
    assert measured.case_wheel_roughness(case, "given") == "given"
    assert measured.case_wheel_roughness(_Case({"flat.kind": "new"}), None) is None
    with pytest.raises(SectionsError, match="give two positions"):
        measured.from_values({**case, "flat.section_window_mm": [1.0]})
