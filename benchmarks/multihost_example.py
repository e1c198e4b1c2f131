"""Multi-host (multi-process) sweep with ``jax.distributed.initialize`` -- runnable example.

Every process runs this same script: it calls :func:`jax.distributed.initialize`, after which
``jax.devices()`` lists the devices of *all* processes, and then calls :func:`wfjax.sweep`
with the same arguments everywhere. The sweep shards each chunk of runs over that global
device list (``jax.sharding.NamedSharding``) and every process receives the full result.

On a cluster, start one process per host (or per GPU) with the scheduler, e.g. with SLURM::

    srun -N 2 --ntasks-per-node=1 python benchmarks/multihost_example.py --worker

(``jax.distributed.initialize()`` reads the coordinator, process count and id from the SLURM,
Open MPI or Kubernetes environment). Anywhere else pass them explicitly::

    python benchmarks/multihost_example.py --worker --coordinator host0:12345 \\
        --num-processes 2 --process-id 0     # on host0
    python benchmarks/multihost_example.py --worker --coordinator host0:12345 \\
        --num-processes 2 --process-id 1     # on host1

Without ``--worker`` the script demonstrates this on one machine: it launches
``--num-processes`` local CPU processes (2 by default, 1 device each, talking through the
coordinator on localhost, gloo CPU collectives) and checks their result against a
single-process sweep. ``tests/test_multihost.py`` runs exactly these workers.
"""

from __future__ import annotations

import argparse
import os
import socket
import subprocess
import sys
import time


def sweep_case(chunk_size: int | None = None):
    """The example sweep: 0.9 mm rounded flat, Hertz-profile, 4 speeds x 2 positions.

    Returns:
        [4, 1, 4, 2]: max force [N], min force [N], loss-of-contact duration [s] and flag of
        every (flat, speed, position).
    """
    import numpy as np

    import wfjax as wf

    flat = wf.Flat.rounded(depth=0.9e-3, length=0.1)
    sw = wf.sweep(flat, np.array([40.0, 80.0, 120.0, 160.0]) / 3.6, impact_positions=2,
                  contact="hertz-profile", progress=False, chunk_size=chunk_size,
                  config=wf.SimConfig(precision="float64"))  # equal to 1e-12 across splits
    return np.stack([sw.max_force, sw.min_force, sw.loss_of_contact_duration,
                     sw.loss_of_contact])


def worker(args) -> None:
    import jax

    if args.coordinator is None:
        jax.distributed.initialize()  # cluster environment (SLURM, Open MPI, k8s) detected
    else:
        jax.distributed.initialize(coordinator_address=args.coordinator,
                                   num_processes=args.num_processes, process_id=args.process_id)
    import numpy as np

    t0 = time.perf_counter()
    out = sweep_case(args.chunk_size)
    print(f"process {jax.process_index()}/{jax.process_count()}: {len(jax.local_devices())} "
          f"local of {len(jax.devices())} global devices, sweep {time.perf_counter() - t0:.1f} s,"
          f" max force [kN] {np.array2string(out[0, 0] / 1e3, precision=2)}", flush=True)
    if args.save:
        np.save(args.save, out)
    jax.distributed.shutdown()


def demo(args) -> int:
    import numpy as np

    with socket.socket() as s:
        s.bind(("localhost", 0))
        port = s.getsockname()[1]
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    env.pop("XLA_FLAGS", None)
    procs = [subprocess.Popen(
        [sys.executable, __file__, "--worker", "--coordinator", f"localhost:{port}",
         "--num-processes", str(args.num_processes), "--process-id", str(i),
         "--save", f"/tmp/wfjax_multihost_{port}_{i}.npy"]
        + ([] if args.chunk_size is None else ["--chunk-size", str(args.chunk_size)]), env=env)
        for i in range(args.num_processes)]
    codes = [p.wait(timeout=600) for p in procs]
    if any(codes):
        print(f"worker exit codes {codes}", file=sys.stderr)
        return 1
    multi = [np.load(f"/tmp/wfjax_multihost_{port}_{i}.npy") for i in range(args.num_processes)]
    single = sweep_case(args.chunk_size)[0]
    diff = max(float(np.max(np.abs(m[0] - single) / single)) for m in multi)
    print(f"{args.num_processes} processes vs 1 process: max relative difference {diff:.2e}")
    return 0 if diff < 1e-12 else 1


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--worker", action="store_true", help="run as one process of the job")
    p.add_argument("--coordinator", help="host:port of process 0 (default: from the cluster)")
    p.add_argument("--num-processes", type=int, default=2)
    p.add_argument("--process-id", type=int, default=0)
    p.add_argument("--chunk-size", type=int, help="runs per chunk (default: wfjax's choice)")
    p.add_argument("--save", help="save this process's summaries (sweep_case) to this .npy")
    args = p.parse_args()
    if args.worker:
        worker(args)
        return 0
    return demo(args)


if __name__ == "__main__":
    sys.exit(main())
