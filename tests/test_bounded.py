"""Bounded inputs and outputs (wfjax.limits, docs/case_files.md "Limits"): files that never end
(/dev/zero, a FIFO fed forever), huge lists, deep nesting, outputs predicted too large. Each
breach: one line, exit status 2, fast, nothing written, no computation."""

import os
import threading
import time

import pytest

from wfjax import case as C
from wfjax import limits
from wfjax.cli import main

TINY = ["--contact", "hertz-trajectory", "--speeds-kmh", "60", "--positions", "1"]



def _refused(capsys, argv, *words) -> str:
    t0 = time.monotonic()
    assert main(argv) == 2
    assert time.monotonic() - t0 < 10
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    for word in words:
        assert word in err[0], err[0]
    return err[0]


@pytest.mark.parametrize("flag", ["--config", "--profile-csv", "--roughness-csv"])
def test_dev_zero_is_refused_fast(flag, tmp_path, capsys, no_work):
    out = tmp_path / "o"
    _refused(capsys, ["sweep", *TINY, flag, "/dev/zero", "--out", str(out)], "/dev/zero",
             "larger than 64,000,000 bytes")
    assert not out.exists()


def test_fit_data_from_dev_zero_is_refused(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("WFJAX_MAX_INPUT_BYTES", "100000")
    _refused(capsys, ["fit", "--data", "/dev/zero", "--out", str(tmp_path / "o")],
             "--data /dev/zero", "larger than 100,000 bytes")


def test_readings_from_dev_zero_are_refused(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("WFJAX_MAX_INPUT_BYTES", "100000")
    _refused(capsys, ["identify", "--readings", "/dev/zero", "--out", str(tmp_path / "o")],
             "--readings /dev/zero", "larger than 100,000 bytes")
    assert not (tmp_path / "o").exists()


def test_an_endless_fifo_stops_after_the_limit(tmp_path, capsys, monkeypatch, no_work):
    limit = 200_000
    monkeypatch.setenv("WFJAX_MAX_INPUT_BYTES", str(limit))
    fifo = tmp_path / "case.toml"
    os.mkfifo(fifo)
    written = []

    def feed():  # a writer that would never stop
        block = b"# " + b"x" * 4094 + b"\n"
        fd = os.open(fifo, os.O_WRONLY)  # unbuffered: nothing left to flush at close
        try:
            while True:
                written.append(os.write(fd, block))
        except OSError:  # the reader closed the pipe: EPIPE
            pass
        finally:
            os.close(fd)

    writer = threading.Thread(target=feed, daemon=True)
    writer.start()
    time.sleep(0.2)  # the writer waits in open() for the reader
    _refused(capsys, ["sweep", *TINY, "--config", str(fifo), "--out", str(tmp_path / "o")],
             str(fifo), "larger than 200,000 bytes")
    writer.join(timeout=10)
    assert not writer.is_alive()
    # the reader stopped at limit + 1 bytes: the writer got no further than that and the
    # pipe's buffer (64 KiB on Linux)
    assert sum(written) <= limit + 4096 + (1 << 20)


def test_a_fifo_without_writer_does_not_block(tmp_path, capsys, no_work):
    fifo = tmp_path / "p.csv"
    os.mkfifo(fifo)
    _refused(capsys, ["simulate", "--contact", "hertz-trajectory", "--profile-csv", str(fifo),
                      "--out", str(tmp_path / "o")], str(fifo), "empty")


def test_a_million_entry_list_is_refused(tmp_path, capsys, no_work):
    path = tmp_path / "big.toml"
    path.write_text("[run]\nspeeds_kmh = [" + ", ".join(["60"] * 1_000_000) + "]\n")
    _refused(capsys, ["sweep", "--config", str(path), "--out", str(tmp_path / "o")],
             str(path), "run.speeds_kmh", "1,000,000 entries", "100,000")


def test_a_long_flag_list_is_refused(tmp_path, capsys, no_work):
    text = ",".join(["0.1"] * 100_001)
    _refused(capsys, ["simulate", "--contact", "hertz-trajectory", "--sensors-m", text,
                      "--out", str(tmp_path / "o")], "--sensors-m", "100,001 entries")


@pytest.mark.parametrize("suffix, text", [
    (".json", '{"case": ' + "[" * 50_000 + "]" * 50_000 + "}"),
    (".toml", "[run]\nspeeds_kmh = " + "[" * 40 + "]" * 40 + "\n"),
])
def test_deep_nesting_is_refused(suffix, text, tmp_path, capsys, no_work):
    path = tmp_path / f"deep{suffix}"
    path.write_text(text)
    _refused(capsys, ["sweep", "--config", str(path), "--out", str(tmp_path / "o")],
             str(path), "nested deeper than 32 levels")


def test_an_output_predicted_above_1_gb_is_refused(tmp_path, capsys, no_work):
    out = tmp_path / "o"
    _refused(capsys, ["simulate", "--contact", "hertz-trajectory", "--sensors-m=-16:16:0.001",
                      "--out", str(out)], "32,001 sensors", "1 GB", "--allow-large-output")
    _refused(capsys, ["sweep", *TINY[:2], "--speeds-kmh", "1:300:0.01", "--positions", "1000",
                      "--out", str(out)], "29,901 speeds", "--allow-large-output")
    _refused(capsys, ["detector", *TINY[:2], "--speeds-kmh", "1:300:0.01", "--positions", "100",
                      "--out", str(out)], "29,901 speeds", "1 GB")
    assert not out.exists()


def test_allow_large_output_lifts_the_output_limit():
    limits.check_output_size(2e9, "x", allowed=True)
    with pytest.raises(limits.InputError, match="2 GB"):
        limits.check_output_size(2e9, "x")
    case = C.resolve("simulate", None, {"run.allow_large_output": True,
                                        "run.sensors": [0.0]}, environ={})
    assert case["run.allow_large_output"] is True


def test_non_utf8_file_is_named(tmp_path, capsys, no_work):
    path = tmp_path / "p.csv"
    path.write_bytes(b"x_mm,z_mm\n0,0\n1,0.5\n2,\xe9\n")
    _refused(capsys, ["simulate", "--contact", "hertz-trajectory", "--profile-csv", str(path),
                      "--out", str(tmp_path / "o")], str(path), "not UTF-8", "line 4")


def test_read_bytes_reads_at_most_limit_plus_one(tmp_path):
    path = tmp_path / "f"
    path.write_bytes(b"a" * 100)
    assert limits.read_bytes(path, "f", limit=100) == b"a" * 100
    with pytest.raises(limits.InputError, match="larger than 99 bytes"):
        limits.read_bytes(path, "f", limit=99)
    with pytest.raises(limits.InputError, match="is a directory"):
        limits.read_bytes(tmp_path, "d")


def test_deep_nesting_in_set_is_refused(tmp_path, capsys, no_work):
    value = "[" * 5000 + "]" * 5000
    _refused(capsys, ["sweep", "--set", f"run.speeds_kmh={value}", "--out",
                      str(tmp_path / "o")], "--set run.speeds_kmh", "nested deeper than 32")
