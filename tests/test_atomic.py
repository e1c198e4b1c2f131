"""Outputs appear as a whole set or not at all (wfjax.outputs, docs/outputs.md): ENOSPC mid-set,
SIGTERM and Ctrl-C to a real ``wfjax`` process paused mid-write, recovery of a killed commit,
stale temporaries, and the cache's temporaries and recorded keys.

Runs are tiny (hertz-trajectory contact, 1-2 speeds, 1 position).
"""

import errno
import hashlib
import importlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from wfjax import _cache, outputs
from wfjax.cli import main

SWEEPS = importlib.import_module("wfjax.sweeps")
TINY = ["--contact", "hertz-trajectory", "--speeds-kmh", "60,120", "--positions", "1",
        "--flat", "new"]
ROOT = Path(__file__).resolve().parents[1]


def _hashes(directory: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(directory.iterdir())}


def _error_lines(err: str) -> list[str]:
    """The error lines of stderr (progress lines left out); no traceback allowed."""
    assert "Traceback" not in err, err
    return [line for line in err.strip().splitlines() if ": error: " in line]


def _one_line(capsys) -> str:
    err = _error_lines(capsys.readouterr().err)
    assert len(err) == 1, err
    return err[0]


def _old_set(out: Path, command: str = "sweep") -> dict[str, str]:
    """A complete earlier set in ``out`` (written through the module's own commit) beside a
    foreign file that no set names; returns the directory's hashes."""
    out.mkdir(parents=True, exist_ok=True)
    (out / "notes.txt").write_text("mine\n")
    old = outputs.OutputSet(out, command).prepare()
    for name in ("sweep.csv", "sweep.json", "sweep.npz", "sweep.png", "case.toml"):
        old.stage(name, lambda target, name=name: Path(target).write_text(f"old {name}\n"))
    old.commit()
    assert outputs.verify(out, command)
    return _hashes(out)


def test_enospc_mid_set_leaves_the_old_set_intact(tmp_path, capsys, monkeypatch):
    out = tmp_path / "o"
    before = _old_set(out)
    real_savez = np.savez

    def full_disk(*args, **kwargs):  # the NPZ comes after the CSV: mid-set
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(np, "savez", full_disk)
    assert main(["sweep", *TINY, "--out", str(out)]) == 1
    line = _one_line(capsys)
    assert "No space left on device" in line and str(out / "sweep.npz") in line, line
    assert "nothing of this run was written" in line
    assert _hashes(out) == before  # old set intact, nothing new, no temporaries
    assert outputs.verify(out, "sweep")
    monkeypatch.setattr(np, "savez", real_savez)
    # the same command then succeeds: a whole new set, the foreign file untouched
    assert main(["sweep", *TINY, "--out", str(out)]) == 0
    assert outputs.verify(out, "sweep") and (out / "notes.txt").read_text() == "mine\n"
    after = _hashes(out)
    assert all(after[n] != before[n] for n in ("sweep.csv", "sweep.npz", "sweep.json"))
    assert not [p for p in os.listdir(out) if p.startswith(".")]


def test_a_dropped_file_of_the_old_set_is_removed_others_kept(tmp_path):
    out = tmp_path / "o"
    _old_set(out)
    new = outputs.OutputSet(out, "sweep").prepare()
    new.stage("sweep.csv", lambda t: Path(t).write_text("new\n"))
    assert new.commit() == ["sweep.csv"]
    assert sorted(os.listdir(out)) == ["notes.txt", "sweep.csv", "sweep.manifest.json"]
    assert outputs.verify(out, "sweep")


@pytest.mark.parametrize("signum, status, word", [(signal.SIGTERM, 143, "SIGTERM"),
                                                  (signal.SIGINT, 130, "Ctrl-C")])
def test_signal_mid_write_leaves_nothing_and_the_old_set(tmp_path, signum, status, word):
    out = tmp_path / "o"
    before = _old_set(out)
    flag = tmp_path / "paused"
    env = {**os.environ, outputs.PAUSE_ENV: str(flag)}
    proc = subprocess.Popen(
        [sys.executable, "-m", "wfjax", "sweep", "--contact", "hertz-trajectory",
         "--speeds-kmh", "80", "--positions", "1", "--flat", "new", "--out", str(out)],
        cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while not flag.exists():
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "the writer never paused"
            time.sleep(0.05)
        staged = [p for p in os.listdir(out) if p.startswith(outputs.TEMP_PREFIX)]
        assert staged  # mid-write: a staging file exists
        proc.send_signal(signum)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == status, err
    lines = _error_lines(err)
    assert len(lines) == 1 and word in lines[0] and "nothing of this run" in lines[0], err
    assert _hashes(out) == before
    assert outputs.verify(out, "sweep")


def test_a_killed_commit_is_completed_by_the_next_run(tmp_path, monkeypatch):
    out = tmp_path / "o"
    _old_set(out)
    new = outputs.OutputSet(out, "sweep").prepare()
    for name in ("sweep.csv", "sweep.json"):
        new.stage(name, lambda t, name=name: Path(t).write_text(f"new {name}\n"))
    calls = []
    real_replace = os.replace

    def killed_after_one(src, dst):  # the process dies after the journal and one rename
        if str(dst).endswith(("sweep.csv", "sweep.json")):
            calls.append(dst)
            if len(calls) == 2:
                raise KeyboardInterrupt
        return real_replace(src, dst)

    monkeypatch.setattr(os, "replace", killed_after_one)
    with pytest.raises(KeyboardInterrupt):
        new.commit()
    monkeypatch.setattr(os, "replace", real_replace)
    assert (out / new.journal.name).exists()
    assert not outputs.verify(out, "sweep")  # a mix: no manifest calls it complete
    outputs.OutputSet(out, "sweep").prepare()  # the next run rolls forward
    assert outputs.verify(out, "sweep")
    assert (out / "sweep.json").read_text() == "new sweep.json\n"
    assert not (out / "sweep.npz").exists()  # dropped by the new set
    assert not [p for p in os.listdir(out) if p.startswith(".")]


def test_stale_temporaries_are_removed_live_ones_and_foreign_files_kept(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True).stdout.strip()
    stale = tmp_path / f".wfjax-{dead}-0123abcd-sweep.csv"
    live = tmp_path / f".wfjax-{os.getpid()}-0123abcd-sweep.csv"
    foreign = tmp_path / ".wfjax-notes"
    for p in (stale, live, foreign):
        p.write_text("x")
    outputs.OutputSet(tmp_path, "sweep").prepare()
    assert not stale.exists() and live.exists() and foreign.exists()


def test_unique_temporary_names_and_save_npz_leaves_none(tmp_path):
    a = outputs.unique_temporary(tmp_path / "r.npz")
    b = outputs.unique_temporary(tmp_path / "r.npz")
    assert a != b and a.name.endswith("r.npz")
    a.unlink()
    b.unlink()
    res = SWEEPS.SweepResult(np.array([10.0]), np.zeros(1), np.ones((1, 1, 1)),
                             np.ones((1, 1, 1)), np.zeros((1, 1, 1), bool), np.ones((1, 1, 1)),
                             np.ones((1, 1, 1)), ("x",), "2d")
    res.save_npz(tmp_path / "r.npz")
    res.save_npz(tmp_path / "plain")  # no suffix: written as named, no ".npz" appended
    assert sorted(os.listdir(tmp_path)) == ["plain", "r.npz"]
    assert SWEEPS.SweepResult.load_npz(tmp_path / "plain").flats == ("x",)


def test_unwritable_out_is_refused_before_any_work(tmp_path, capsys, no_work):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert main(["sweep", *TINY, "--out", str(blocker / "o")]) == 2
    assert "--out" in _one_line(capsys)
    if os.geteuid() != 0:  # root writes anywhere
        ro = tmp_path / "ro"
        ro.mkdir(mode=0o555)
        assert main(["sweep", *TINY, "--out", str(ro)]) == 2
        assert "cannot write" in _one_line(capsys)


# -- the cache ---------------------------------------------------------------------------------
def test_cache_entry_renamed_to_another_key_is_not_trusted(tmp_path):
    calls = []

    def build(value):
        calls.append(value)
        return {"a": np.array([value])}

    one = _cache.load_or_build("unit", {"x": 1}, lambda: build(1.0), tmp_path)
    path_one = _cache.cache_path("unit", {"x": 1}, tmp_path)
    path_two = _cache.cache_path("unit", {"x": 2}, tmp_path)
    path_two.write_bytes(path_one.read_bytes())  # a copied entry under another key's name
    two = _cache.load_or_build("unit", {"x": 2}, lambda: build(2.0), tmp_path)
    assert one["a"][0] == 1.0 and two["a"][0] == 2.0 and calls == [1.0, 2.0]
    header = path_two.read_bytes().split(b"\n", 1)[0].split(b" ")
    assert header[1].decode() == _cache.key_hash("unit", {"x": 2})  # its own key recorded


def test_cache_write_removes_stale_temporaries_and_warns_once_when_unwritable(
        tmp_path, capsys, monkeypatch):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True).stdout.strip()
    stale = tmp_path / f".wfjax-{dead}-0123abcd-unit-x.npz.sha256"
    stale.write_bytes(b"half")
    legacy = tmp_path / ".unit-0123.npz.sha256.k2j3h4"  # an older version's temporary
    legacy.write_bytes(b"half")
    os.utime(legacy, (time.time() - 7200,) * 2)
    _cache.load_or_build("unit", {"x": 3}, lambda: {"a": np.ones(2)}, tmp_path)
    assert not stale.exists() and not legacy.exists()
    assert not [p for p in os.listdir(tmp_path) if p.startswith(".")]

    def no_space(*args, **kwargs):
        raise OSError(errno.EROFS, os.strerror(errno.EROFS))

    monkeypatch.setattr(_cache, "unique_temporary", no_space)
    for x in (4, 5):
        out = _cache.load_or_build("unit", {"x": x}, lambda: {"a": np.zeros(1)}, tmp_path)
        assert out["a"][0] == 0.0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot write the cache" in err[0] and str(tmp_path) in err[0]


def test_manifest_lists_every_file_with_its_sha256(tmp_path):
    out = tmp_path / "o"
    assert main(["sweep", *TINY, "--out", str(out)]) == 0
    manifest = json.loads((out / "sweep.manifest.json").read_text())
    assert set(manifest["files"]) == {"sweep.csv", "sweep.json", "sweep.npz", "sweep.png",
                                      "case.toml"}
    (out / "sweep.csv").write_text("tampered\n")
    assert not outputs.verify(out, "sweep")


def test_sigterm_during_the_commit_waits_for_it(tmp_path, capsys, monkeypatch):
    """A signal that arrives while the renames run is delivered after them: the new set is
    whole, and the one line says so (exit status 143 all the same)."""
    out = tmp_path / "o"
    _old_set(out)
    roll = outputs.OutputSet._roll_forward

    def signalled(self):
        if self.journal.exists():  # the commit (not the recovery at the start)
            os.kill(os.getpid(), signal.SIGTERM)  # held: raised when the commit ends
        return roll(self)

    monkeypatch.setattr(outputs.OutputSet, "_roll_forward", signalled)
    assert main(["sweep", *TINY, "--out", str(out)]) == 143
    line = _one_line(capsys)
    assert "SIGTERM" in line and "are complete" in line, line
    assert outputs.verify(out, "sweep")
    assert (out / "sweep.csv").read_text().startswith("flat,")
