"""Sizing the batched program for the device: chunk widths, table batches, the benchmark."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import wfjax as wf
from wfjax import sweeps
from wfjax.contact import laws, tables

ROOT = Path(__file__).resolve().parents[1]


class _Device:
    """A stand-in for a jax.Device with ``memory_stats`` (what a GPU reports)."""

    def __init__(self, platform: str, limit: int | None = None, in_use: int = 0):
        self.platform, self.limit, self.in_use = platform, limit, in_use

    def memory_stats(self):
        return None if self.limit is None else {"bytes_limit": self.limit,
                                                "bytes_in_use": self.in_use}


def test_chunk_width_follows_device_memory():
    per_run = sweeps.bytes_per_run(3000, 599)
    assert per_run == 2 * (7 * 3000 * 8 + 12 * 599 * 16)
    assert sweeps.bytes_per_run(3000, 599, "float32") == per_run // 2
    gib = 2**30
    # a 16 GiB GPU with 6 GiB in use: half of the free 10 GiB, in runs, under the cap
    wide = sweeps.chunk_width(3000, 599, device=_Device("gpu", 16 * gib, 6 * gib))
    assert wide == min(sweeps.ACCELERATOR_CHUNK_CAP, int(0.5 * 10 * gib // per_run)) > 64
    small = sweeps.chunk_width(3000, 599, device=_Device("gpu", gib, gib - 100 * per_run))
    assert small == 50  # memory bound
    assert sweeps.chunk_width(3000, 599, device=_Device("gpu", gib, gib)) == 1
    huge = sweeps.chunk_width(3000, 599, device=_Device("gpu", 1000 * gib))
    assert huge == sweeps.ACCELERATOR_CHUNK_CAP
    assert sweeps.chunk_width(3000, 599, device=_Device("cpu")) == sweeps.CHUNK_CAP["cpu"]


def test_table_batch_size_by_platform_and_batched_build_agrees():
    assert laws.table_batch_size("cpu") == 1
    assert laws.table_batch_size("gpu") == laws.ACCELERATOR_TABLE_BATCH_SIZE > 1
    flat = wf.Flat.rounded(0.9e-3, 0.1)
    one, four = (tables.build_table_3d(flat, 0.45, 0.30, element_size=2e-3, batch_size=b)
                 for b in (1, 4))
    force = np.asarray(one.force)
    assert force.max() > 5e5  # the table spans the 600 kN range
    np.testing.assert_allclose(np.asarray(four.force), force, rtol=0, atol=1e-7 * force.max())
    np.testing.assert_array_equal(np.asarray(four.onset), np.asarray(one.onset))


def test_sweep_rejects_a_bad_chunk_size():
    with pytest.raises(ValueError, match="chunk_size"):
        wf.sweep(wf.Flat.rounded(0.9e-3, 0.1), [20.0], 1, contact="hertz-profile",
                 chunk_size=0, progress=False)
