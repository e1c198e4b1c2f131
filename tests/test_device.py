"""Sizing the batched program for the device: chunk widths, table batches, the benchmark."""

from __future__ import annotations

import json

import bench_scripts
import numpy as np
import pytest

import wfjax as wf
from wfjax.contact import table_law, tables
from wfjax.program import grid


class _Device:
    """A stand-in for a jax.Device with ``memory_stats`` (what a GPU reports)."""

    def __init__(self, platform: str, limit: int | None = None, in_use: int = 0):
        self.platform, self.limit, self.in_use = platform, limit, in_use

    def memory_stats(self):
        return None if self.limit is None else {"bytes_limit": self.limit,
                                                "bytes_in_use": self.in_use}


def test_chunk_width_follows_device_memory():
    per_run = grid.bytes_per_run(3000, 599)
    assert 250e3 < per_run < 300e3  # compiled on CPU: 215-262 KB per run (1000-4000 steps)
    assert grid.bytes_per_run(3000, 599, "float32") == per_run // 2
    gib = 2**30
    # a 16 GiB GPU with 6 GiB in use: half of the free 10 GiB, in runs, under the cap
    wide = grid.chunk_width(3000, 599, device=_Device("gpu", 16 * gib, 6 * gib))
    assert wide == min(grid.ACCELERATOR_CHUNK_CAP, int(0.5 * 10 * gib // per_run)) > 64
    small = grid.chunk_width(3000, 599, device=_Device("gpu", gib, gib - 100 * per_run))
    assert small == 50  # memory bound
    assert grid.chunk_width(3000, 599, device=_Device("gpu", gib, gib)) == 1
    huge = grid.chunk_width(3000, 599, device=_Device("gpu", 1000 * gib))
    assert huge == grid.ACCELERATOR_CHUNK_CAP
    assert grid.chunk_width(3000, 599, device=_Device("cpu")) == grid.CHUNK_CAP["cpu"]


def test_table_batch_size_by_platform_and_batched_build_agrees():
    assert table_law.table_batch_size("cpu") == 1
    assert table_law.table_batch_size("gpu") == table_law.ACCELERATOR_TABLE_BATCH_SIZE > 1
    flat = wf.Flat.rounded(0.9e-3, 0.1)
    one, four = (tables.build_table_3d(flat, 0.45, 0.30, element_size=2e-3, batch_size=b)
                 for b in (1, 4))
    force = np.asarray(one.force)
    assert force.max() > 5e5  # the table spans the 600 kN range
    # batch 1: windowed, float32 to tables.WINDOWED_TOL; batch 4: the whole grid, float64
    np.testing.assert_allclose(np.asarray(four.force), force, rtol=0,
                               atol=2 * tables.WINDOWED_TOL * force.max())
    np.testing.assert_array_equal(np.asarray(four.onset), np.asarray(one.onset))


def test_sweep_rejects_a_bad_chunk_size():
    with pytest.raises(ValueError, match="chunk_size"):
        wf.sweep(wf.Flat.rounded(0.9e-3, 0.1), [20.0], 1, contact="hertz-profile",
                 chunk_size=0, progress=False)


@pytest.mark.slow  # the default run must stay under 10 min (2 cores)
def test_bench_device_smoke(tmp_path, monkeypatch, capsys):
    """benchmarks/bench_device.py at its tiny size (the sections without 3D sweeps, which
    build tables or a family: tests/test_interaction.py and test_family.py cover those)."""
    monkeypatch.setenv("WFJAX_CACHE_DIR", str(tmp_path / "cache"))
    bench = bench_scripts.load("bench_device")
    out = tmp_path / "bench.json"
    sections = ["table", "gradient", "large-hertz"]
    assert bench.main(["--tiny", "--sections", ",".join(sections), "--json", str(out)]) == 0
    report = json.loads(out.read_text())
    rows = {r["section"]: r for r in report["rows"]}
    assert list(rows) == sections and report["header"]["backend"] == "cpu"
    assert rows["large-hertz"]["runs"] == 8 and rows["gradient"]["runs"] == 2
    for name, row in rows.items():
        f64 = row["float64"]
        assert f64["run_s"] > 0 and f64["runs_per_s"] > 0, name
        # the second call reuses the first's program (the first may find it compiled already)
        assert f64["recompile_s"] <= 0.5 * f64["compile_s"], name
        assert row["peak_mib"] > 100, name
        if name != "table":
            assert 0 < row["f32_max_rel_diff"] < 1e-3, name  # measured 3e-6 (gradient 3e-5)
            assert not row["loss_speed_changed"], name
    assert "f32 max rel. diff" in capsys.readouterr().out


@pytest.mark.slow  # a 1-wagon train identified twice in fresh processes: ~70 s
def test_bench_device_train_and_a_failing_section(tmp_path, monkeypatch, capsys):
    """A section that fails is reported and the next still runs (exit code 1); the train
    section (identify_train.py, 1 wagon, smoke-size table) flags its one flat, no round
    wheel, and its cold and warm runs agree; the JSON holds both rows."""
    monkeypatch.setenv("WFJAX_CACHE_DIR", str(tmp_path / "cache"))
    bench = bench_scripts.load("bench_device")

    def broken(n_speeds):
        raise RuntimeError("no such compile option")

    monkeypatch.setattr(bench, "gradient_section", broken)
    out = tmp_path / "bench.json"
    assert bench.main(["--tiny", "--sections", "gradient,train", "--json", str(out)]) == 1
    rows = json.loads(out.read_text())["rows"]
    assert [r["section"] for r in rows] == ["gradient", "train"]
    assert rows[0]["error"] == "RuntimeError: no such compile option"
    train = rows[1]
    assert train["runs"] == 4 and train["cold_and_warm_answers_equal"]
    assert train["score"]["flats_flagged"] == train["score"]["n_flats"] == 1
    assert train["score"]["round_flagged"] == []
    assert train["identify_warm_s"] > 0 and train["identify_cold_s"] > 0
    text = capsys.readouterr().out
    assert "| gradient | failed: RuntimeError" in text and "train (1 wagons, 4 wheels)" in text
