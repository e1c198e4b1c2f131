"""Build (and time) the identification's response tables of ``wfjax identify`` for a contact
law at several speeds, as :func:`wfjax.identify.identify` asks for them with its defaults
(a 5-bay detector's gauge offset 0.1 m, calibration 1, 3 roughness realisations, seed 0),
into the wfjax cache (``identify-table`` entries).

    python benchmarks/identify_tables.py --contact 3d --speeds-kmh 100,60,140

Appends to ``benchmarks/results/identify_tables_<contact>.json`` one row per speed: the wall
time [s] (a few seconds when the table was already cached), the table's shape, the date and
the load average (the CPU is shared).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--contact", default="3d")
    ap.add_argument("--speeds-kmh", default="100,60,140")
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    from wfjax.cli import enable_compilation_cache
    from wfjax.identify import forward as fwd

    enable_compilation_cache()
    out = Path(args.out or ROOT / "benchmarks" / "results" /
               f"identify_tables_{args.contact.replace('-', '_')}.json")
    rows = json.loads(out.read_text())["tables"] if out.exists() else []
    for v_kmh in (float(v) for v in args.speeds_kmh.split(",")):
        t0 = time.perf_counter()
        table = fwd.build_table(v_kmh / 3.6, contact=args.contact,
                                progress=lambda d, t: print(f"  {d}/{t}", file=sys.stderr,
                                                            flush=True))
        wall = time.perf_counter() - t0
        row = {"speed_kmh": v_kmh, "contact": args.contact, "wall_s": wall,
               "shape": list(table.readings.shape),
               "date": time.strftime("%Y-%m-%d %H:%M", time.gmtime()),
               "load": list(os.getloadavg())}
        print(json.dumps(row), flush=True)
        rows.append(row)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps({"tables": rows}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
