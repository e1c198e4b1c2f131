"""Multi-host for real: two processes joined by jax.distributed.initialize over localhost.

Each process runs ``benchmarks/multihost_example.py --worker`` (one CPU device each, gloo
collectives, the coordinator on a free localhost port): one sweep sharded across the two
global devices, in two chunks (chunk_size 4: 8 runs as 2 x 4, every chunk split 2 + 2 over
the processes), every process gathering the full result. It must equal this process's own
single-device sweep to 1e-12.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path

import bench_scripts
import numpy as np
import pytest

EXAMPLE = Path(__file__).resolve().parents[1] / "benchmarks" / "multihost_example.py"


def _example():
    return bench_scripts.load("multihost_example")


@pytest.mark.slow
def test_two_processes_equal_one(tmp_path):
    with socket.socket() as s:
        s.bind(("localhost", 0))
        port = s.getsockname()[1]
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    env["JAX_PLATFORMS"] = "cpu"
    procs = [subprocess.Popen(
        [sys.executable, str(EXAMPLE), "--worker", "--coordinator", f"localhost:{port}",
         "--num-processes", "2", "--process-id", str(i), "--chunk-size", "4",
         "--save", str(tmp_path / f"p{i}.npy")],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for i in range(2)]
    try:
        outs = [p.communicate(timeout=240) for p in procs]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
    for p, (out, err) in zip(procs, outs, strict=True):
        assert p.returncode == 0, err[-3000:]
        assert "1 local of 2 global devices" in out, out
    single = _example().sweep_case(chunk_size=4)
    assert single.shape == (4, 1, 4, 2)
    assert np.all(single[0] > 1.5e5) and single[3].any()  # 180-270 kN; 160 km/h loses contact
    for i in range(2):
        multi = np.load(tmp_path / f"p{i}.npy")
        np.testing.assert_allclose(multi[:2], single[:2], rtol=1e-12)  # max, min force
        np.testing.assert_array_equal(multi[2:], single[2:])  # loss-of-contact time and flag
