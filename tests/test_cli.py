"""The command line with case files: precedence, errors before work, provenance, permissions.

Runs are tiny (hertz-trajectory contact, 2 speeds, 1 position) so the file stays fast.
"""

import csv
import importlib
import json
import os
import stat

import numpy as np
import pytest

import wfjax as wf
from wfjax import case as C
from wfjax.cli import build_parser, main
from wfjax.optdocs import markdown_table

SWEEP = importlib.import_module("wfjax.sweeps")  # the module (wfjax.sweep is the function)
TINY = ["--contact", "hertz-trajectory", "--speeds-kmh", "60,120", "--positions", "1"]


@pytest.fixture(name="umask022")
def _umask022():
    old = os.umask(0o022)
    yield
    os.umask(old)



def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert "error" in err[0]
    return err[0]


def test_tiny_sweep_from_config_files_ordinary_permissions_and_round_trip(tmp_path, capsys,
                                                                           umask022):
    """Flags override the file; outputs are 0644; --config sweep.json repeats the run exactly."""
    cfg = tmp_path / "case.toml"
    cfg.write_text('[run]\ncontact = "2d"\nspeeds_kmh = [60, 120]\nimpact_positions = 3\n'
                   '[flat]\nkind = "new"\n[track]\npad_stiffness_MN_per_m = 100\n'
                   'ends = "absorbing"\n')  # no network fit for these pads (test_end_network)
    out = tmp_path / "a"
    assert main(["sweep", "--config", str(cfg), "--contact", "hertz-trajectory",
                 "--positions", "1", "--out", str(out)]) == 0
    summary = json.loads((out / "sweep.json").read_text())
    case = summary["case"]
    assert case["run"]["contact"] == "hertz-trajectory"  # flag over file
    assert case["run"]["impact_positions"] == 1
    assert case["run"]["speeds_kmh"] == [60.0, 120.0]  # file over default
    assert case["track"]["pad_stiffness"] == 100e6 and case["track"]["ends"] == "absorbing"
    assert case["wheel"] == {f: getattr(wf.Wheel(), f) for f in case["wheel"]}  # defaults too
    prov = summary["provenance"]
    assert prov["wfjax_version"] == wf.__version__ and prov["precision"] == "auto"
    assert prov["jax_device_count"] >= 1 and prov["command"] == "sweep"
    for name in ("sweep.csv", "sweep.json", "sweep.png", "sweep.npz", "case.toml"):
        assert stat.S_IMODE((out / name).stat().st_mode) == 0o644, name
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no temporary left
    first = wf.SweepResult.load_npz(out / "sweep.npz")
    for source in (out / "sweep.json", out / "case.toml"):
        again = tmp_path / source.suffix[1:]
        assert main(["sweep", "--config", str(source), "--out", str(again)]) == 0
        assert (again / "sweep.csv").read_text() == (out / "sweep.csv").read_text()
        second = wf.SweepResult.load_npz(again / "sweep.npz")
        np.testing.assert_array_equal(second.max_force, first.max_force)
        np.testing.assert_array_equal(second.min_force, first.min_force)
        assert json.loads((again / "sweep.json").read_text())["case"] == case


def test_depth_list_is_one_sweep_call_one_csv(tmp_path, monkeypatch):
    calls = []
    real = SWEEP.sweep

    def counted(flats, *args, **kwargs):
        calls.append(len(flats))
        return real(flats, *args, **kwargs)

    monkeypatch.setattr(SWEEP, "sweep", counted)
    out = tmp_path / "d"
    assert main(["sweep", *TINY, "--flat", "rounded", "--depths-mm", "0.5:1.0:0.5",
                 "--length-factor", "1.76", "--out", str(out)]) == 0
    assert calls == [2]
    rows = list(csv.DictReader(open(out / "sweep.csv")))
    assert len(rows) == 2 * 2 * 1
    assert {r["flat"] for r in rows} == {"rounded d=0.50mm l=74.7mm",
                                         "rounded d=1.00mm l=105.6mm"}
    assert wf.SweepResult.load_npz(out / "sweep.npz").max_force.shape == (2, 2, 1)
    assert json.loads((out / "sweep.json").read_text())["case"]["flat"]["length_factor"] == 1.76


@pytest.mark.parametrize("text, argv, words", [
    ("[track]\npad_stifness = 60e6\n", [], ["track.pad_stifness", "did you mean"]),
    ("[track]\nn_bays = \"70\"\n", [], ["track.n_bays", "wrong type", "[4, 1000]"]),
    ("[wheel]\npreload = 118\n", [], ["wheel.preload = 118", "[1000, 1e+06] N"]),
    ("[run]\nspeeds = [60]\n", [], ["missing unit", "run.speeds_kmh"]),
    ("", ["--flat", "rounded", "--length-mm", "5000"], ["--length-mm", "(0, 300] mm"]),
    ("", ["--depth-mm", "-1"], ["--depth-mm", "(0, 5] mm"]),
    ("", ["--set", "track.sleeper_spacing=65"], ["track.sleeper_spacing = 65", "[0.3, 1.5] m"]),
    ("", ["--profile-csv", "missing.csv"], ["missing.csv", "cannot read"]),
])
def test_bad_case_fails_before_work_with_one_line(tmp_path, capsys, no_work, text, argv, words):
    cfg = tmp_path / "case.toml"
    cfg.write_text(text)
    out = tmp_path / "out"
    assert main(["sweep", "--config", str(cfg), *argv, "--out", str(out)]) == 2
    line = _one_line_error(capsys)
    for w in words:
        assert w in line, (w, line)
    assert not out.exists()  # nothing written


def test_simulate_profile_csv_records_the_file(tmp_path, capsys, umask022):
    x = np.arange(0.0, 80.01, 0.5)
    z = np.where(np.abs(x - 40) < 30, 0.3 * (1 + np.cos(np.pi * (x - 40) / 30)), 0.0)
    profile = tmp_path / "profile.csv"
    profile.write_text("x_mm,z_mm\n" + "".join(f"{a},{b:.5f}\n" for a, b in zip(x, z,
                                                                              strict=True)))
    out = tmp_path / "s"
    assert main(["simulate", "--profile-csv", str(profile), "--contact", "hertz-trajectory",
                 "--speed-kmh", "80", "--out", str(out)]) == 0
    summary = json.loads((out / "simulate.json").read_text())
    assert summary["flat"] == "profile" and summary["depth_mm"] == pytest.approx(0.6, rel=1e-3)
    assert summary["case"]["flat"]["profile_csv"] == str(profile)
    assert str(profile) in summary["provenance"]["inputs_sha256"]
    assert stat.S_IMODE((out / "simulate.csv").stat().st_mode) == 0o644
    assert 118 < summary["max_force_kN"] < 400


def test_profile_csv_error_is_one_line(tmp_path, capsys, no_work):
    bad = tmp_path / "p.csv"
    bad.write_text("x_mm,z_mm\n0,0\n1,0.2\n1,0.3\n2,0.1\n3,0\n")
    assert main(["simulate", "--profile-csv", str(bad), "--out", str(tmp_path / "o")]) == 2
    assert "strictly increasing" in _one_line_error(capsys)


def test_config_print_defaults_reloads_to_the_defaults(tmp_path, capsys):
    assert main(["config", "--print-defaults"]) == 0
    path = tmp_path / "case.toml"
    path.write_text(capsys.readouterr().out)
    case = C.resolve("sweep", str(path), environ={})
    assert case.values == C.default_layer("sweep")
    assert case.model() == (wf.Wheel(), wf.Track(), wf.Material(), wf.SimConfig())


def test_console_script_exits_at_once_with_its_output_and_status(tmp_path, capsys):
    """``entry_point`` skips Python's teardown (``os._exit``): piped output must still arrive
    whole (it flushes first) and the exit status must be main's."""
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}  # a buffered pipe
    env["WFJAX_CACHE_DIR"] = str(tmp_path)

    def console(*argv):
        code = f"import sys; sys.argv = ['wfjax', *{list(argv)!r}]; " \
               "from wfjax.cli import entry_point; entry_point()"
        return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                              cwd=tmp_path, env=env)

    assert main(["config", "--print-defaults"]) == 0
    done = console("config", "--print-defaults")
    assert done.returncode == 0 and done.stdout == capsys.readouterr().out
    done = console("sweep", "--speeds-kmh", "-5")
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr.count("\n") == 1 and "--speeds-kmh" in done.stderr


def test_a_second_process_compiles_nothing_anew(tmp_path):
    """The command line keeps every XLA compilation on disk however short
    (``enable_compilation_cache``): a second identical ``wfjax simulate`` finds each of its
    programs in the persistent cache (JAX's default 1 s threshold left sub-second programs to
    be compiled again in every process)."""
    import subprocess
    import sys

    env = dict(os.environ, WFJAX_CACHE_DIR=str(tmp_path), JAX_LOG_COMPILES="1")
    argv = ["wfjax", "simulate", "--contact", "hertz-trajectory", "--out", str(tmp_path / "o")]
    code = f"import sys; sys.argv = {argv!r}; from wfjax.cli import entry_point; entry_point()"

    def compiles():
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                              cwd=tmp_path, env=env)
        assert done.returncode == 0, done.stderr[-2000:]
        lines = done.stderr.splitlines()
        return (sum("Finished XLA compilation" in line for line in lines),
                sum("Persistent compilation cache hit" in line for line in lines))

    assert compiles()[0] > 0
    n, hits = compiles()
    assert n > 0 and hits == n, (n, hits)


def test_config_check_shows_environment_precision_and_flag_wins(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("WFJAX_PRECISION", "float32")
    cfg = tmp_path / "c.toml"
    cfg.write_text("[track]\nrail_head_radius = 0.45\n")
    assert main(["config", "--config", str(cfg), "--no-comments"]) == 0
    text = capsys.readouterr().out
    assert 'precision = "float32"' in text and "rail_head_radius = 0.45" in text
    assert main(["config", "--config", str(cfg), "--set", "config.precision=\"float64\""]) == 0
    assert 'precision = "float64"' in capsys.readouterr().out
    assert main(["config", "--print-table"]) == 0
    assert capsys.readouterr().out == markdown_table()


def test_fit_accepts_3d_contact_and_the_comparison_track(tmp_path):
    args = build_parser().parse_args(["fit", "--example", "--contact", "3d"])
    from wfjax.commands._common import resolve_case

    case = resolve_case(args, "fit")
    assert case["run.contact"] == "3d" and case["fit.example"] is True
    assert case.model()[1] == wf.Track.comparison()  # fit_flat's default track, stated


def test_argparse_errors_are_one_line(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["sweep", "--no-such-flag"])
    assert exc.value.code == 2
    assert "unrecognized arguments" in _one_line_error(capsys)


def test_a_bad_choice_gets_the_generated_one_line_error(capsys):
    """A name outside an option's choices is refused like every other bad value (status 2,
    the flag as typed, the value and the allowed names), not by argparse's own message."""
    assert main(["sweep", "--contact", "5d"]) == 2
    line = _one_line_error(capsys)
    assert '--contact "5d"' in line and "allowed: 3d | 2d | hertz-trajectory" in line


def test_non_finite_result_writes_nothing(tmp_path, capsys, monkeypatch):
    def nan_sweep(flats, speeds, positions, contact, **kwargs):
        shape = (len(flats), len(speeds), positions)
        nan = np.full(shape, np.nan)
        return wf.SweepResult(np.asarray(speeds), np.zeros(positions), nan, nan,
                              np.zeros(shape, bool), nan, nan, ("x",) * len(flats), contact)

    monkeypatch.setattr(SWEEP, "sweep", nan_sweep)
    out = tmp_path / "n"
    assert main(["sweep", *TINY, "--flat", "new", "--out", str(out)]) == 1
    assert "non-finite max_force" in _one_line_error(capsys)
    assert not out.exists()  # not even the directory the refused run created


def test_figure_flats_follow_the_case_wheel_radius():
    """figures/compare build their flats on the case's wheel (a 0.46 m wheel used to clash
    with flats made for the default 0.45 m one)."""
    from wfjax.commands.compare import comparison_flats
    from wfjax.commands.figures import fig7_flats, fig8_flats

    flats = fig7_flats(0.46) + fig8_flats((0.5, 1.0), 0.46) + comparison_flats([0.9], 0.46)
    assert all(float(f.wheel_radius) == 0.46 for f in flats)
    assert float(fig8_flats((1.0,), 0.46)[0].length) == pytest.approx(
        1.76 * np.sqrt(8 * 0.46 * 1e-3))


def test_sweep_figure_marks_the_sweeps_static_load():
    from wfjax.plotting import sweep_figure

    res = wf.sweep(wf.Flat.new(0.9e-3), [60 / 3.6], 1, contact="hertz-trajectory",
                   wheel=wf.Wheel(preload=90e3), progress=False)
    ax = sweep_figure(res, preload=90e3).axes[0]
    static = [line for line in ax.get_lines() if line.get_label() == "static load"]
    assert len(static) == 1 and static[0].get_ydata()[0] == pytest.approx(90.0)


def test_profile_fit_with_too_few_speeds_fails_before_work(tmp_path, capsys, no_work):
    """8 bump amplitudes need 9 speeds: a one-line error, nothing fitted or written."""
    data = tmp_path / "data.csv"
    data.write_text("speed_kmh,max_force_kN\n" + "".join(
        f"{v},{200 + v}\n" for v in (40, 60, 80, 100, 120)))
    out = tmp_path / "fit"
    assert main(["fit", "--data", str(data), "--flat", "new", "--profile-basis", "8",
                 "--out", str(out)]) == 2
    err = _one_line_error(capsys)
    assert "at least 9 speeds" in err
    assert not out.exists()


def test_detector_command_writes_files_and_rejects_bad_sensors(tmp_path, capsys):
    """``wfjax detector``: CSV/JSON/PNG; the case keys round-trip; bad sensors fail first."""
    out = tmp_path / "det"
    assert main(["detector", "--contact", "hertz-trajectory", "--speeds-kmh", "60",
                 "--positions", "1", "--sensors-m", "0,0.325", "--bays", "2",
                 "--out", str(out)]) == 0
    rows = list(csv.DictReader((out / "detector.csv").open()))
    assert [r["bay"] for r in rows] == ["-1", "0"]
    assert float(rows[1]["detector_peak_kN"]) > 118.0
    summary = json.loads((out / "detector.json").read_text())
    assert summary["case"]["detector"]["n_bays"] == 2
    # the case keeps "auto"; the summary states what it resolved to for a detector's reading
    assert summary["case"]["config"]["track_max_frequency"] == "auto"
    reading = wf.SimConfig().resolved(reading=True)
    assert {k: summary["settings"][k] for k in ("track_max_frequency_Hz", "max_time_step_s",
                                                  "precision", "n_bays")} \
        == {"track_max_frequency_Hz": reading.track_max_frequency,
            "max_time_step_s": reading.max_time_step, "precision": "float64", "n_bays": 24}
    assert reading.track_max_frequency > wf.SimConfig().resolved().track_max_frequency
    assert len((out / "sensors.csv").read_text().splitlines()) == 3
    assert (out / "detector.png").stat().st_size > 0
    capsys.readouterr()
    # a sensor lengthens the track to hold it with its margin, up to track.n_bays' bound
    assert main(["detector", "--sensors-m", "400", "--out", str(tmp_path / "x")]) == 2
    assert "more than track.n_bays allows (1000)" in _one_line_error(capsys)


def test_detector_longer_than_a_circumference_reads_the_next_strike(tmp_path):
    """``wfjax detector --bays 7`` (4.55 m from bay -1): a flat struck in bay 0 (at 162.5 and
    487.5 mm) strikes again 2 pi R (2.83 m) later, inside bay 4's and bay 5's gates, and those
    bays read the impact as bay 0 does, not a round wheel."""
    out = tmp_path / "det"
    assert main(["detector", "--contact", "hertz-trajectory", "--speeds-kmh", "100",
                 "--positions", "2", "--bays", "7", "--out", str(out)]) == 0
    rows = list(csv.DictReader((out / "detector.csv").open()))
    ls, c = wf.Track().sleeper_spacing, 2 * np.pi * float(wf.Wheel().radius)
    for x_mm in sorted({r["impact_position_mm"] for r in rows}):
        peak = {int(r["bay"]): float(r["detector_peak_kN"]) for r in rows
                if r["impact_position_mm"] == x_mm}
        again = int(np.floor((float(x_mm) / 1e3 + c) / ls))
        assert peak[again] > 0.9 * peak[0] > 1.3 * peak[again - 2], (x_mm, peak)


def test_simulate_sensors_csv(tmp_path):
    """``wfjax simulate --sensors-m``: the sensors' histories next to the force history."""
    out = tmp_path / "sim"
    assert main(["simulate", "--contact", "hertz-trajectory", "--speed-kmh", "80",
                 "--sensors-m", "0,0.325", "--out", str(out)]) == 0
    rows = list(csv.reader((out / "sensors.csv").open()))
    assert rows[0][:3] == ["t_s", "x_m", "rail_disp@0m"]
    assert len(rows[0]) == 2 + 2 * 9
    assert len(rows) == len((out / "simulate.csv").read_text().splitlines())
    seat = [float(r[rows[0].index("seat_force@0m")]) for r in rows[1:]]
    assert max(seat) > 0.3 * 118e3  # the sleeper under the first sensor carries the wheel
