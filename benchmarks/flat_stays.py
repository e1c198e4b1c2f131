"""How far a reader travels to follow a flat through ``wf.simulate``: the modules it visits.

Traces every Python call made while ``wf.simulate`` runs (eager setup and the traced time
loop) and keeps the calls of wfjax functions that hold a :class:`wfjax.Flat` among their
arguments or locals, in call order. A *stay* is a maximal run of consecutive such calls in
one module; a *return* is a stay in a module that was already left before. Issue 30 asked for
at most 15 stays (the code before it: 13 modules, 45 stays, 32 returns).

    python benchmarks/flat_stays.py [--contact hertz-trajectory] [--list]
"""

from __future__ import annotations

import argparse
import sys

import wfjax as wf


def flat_calls(flat: wf.Flat, own_methods: bool = False, **kwargs) -> list[tuple[str, str]]:
    """(module, function) of every wfjax call that holds a Flat, in call order; the flat's
    own methods (``self`` a Flat, e.g. ``half_extent``, and its pytree flattening) count only
    with ``own_methods``."""
    calls: list[tuple[str, str]] = []

    def profile(frame, event, arg):
        if event != "call":
            return
        module = frame.f_globals.get("__name__", "")
        if not module.startswith("wfjax"):
            return
        local = frame.f_locals
        if not own_methods and isinstance(local.get("self", local.get("obj")), wf.Flat):
            return
        if any(isinstance(v, wf.Flat) for v in local.values()):
            calls.append((module, frame.f_code.co_name))

    sys.setprofile(profile)
    try:
        wf.simulate(flat, **kwargs)
    finally:
        sys.setprofile(None)
    return calls


def stays(calls: list[tuple[str, str]]) -> list[tuple[str, list[str]]]:
    """Consecutive calls in one module merged: [(module, [functions])]."""
    out: list[tuple[str, list[str]]] = []
    for module, fn in calls:
        if out and out[-1][0] == module:
            out[-1][1].append(fn)
        else:
            out.append((module, [fn]))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--contact", default="hertz-trajectory")
    ap.add_argument("--list", action="store_true", help="print every stay")
    ap.add_argument("--own-methods", action="store_true",
                    help="also count the flat's own methods (half_extent, pytree flattening)")
    args = ap.parse_args(argv)
    flat = wf.Flat.rounded(depth=0.9e-3, length=0.1)
    s = stays(flat_calls(flat, args.own_methods, speed=100 / 3.6, contact=args.contact))
    seen, returns = set(), 0
    for i, (module, fns) in enumerate(s):
        returns += module in seen and s[i - 1][0] != module
        seen.add(module)
        if args.list:
            print(f"{i + 1:3d} {module}: {', '.join(dict.fromkeys(fns))}")
    print(f"contact {args.contact}: {len(seen)} modules, {len(s)} stays, {returns} returns")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
