"""``wfjax examples [DIR]``: copy the example files that ship with the package into ``DIR``.

The case files of the README and ``docs/case_files.md`` (``fig7.toml``,
``soft_pads_heavy_axle.toml``) and the measured profile (``measured_profile.csv``) are package
data (``wfjax/examples/``), so an installed wheel has them. After ``wfjax examples`` (default
``DIR``: ``./examples``) the documented commands such as
``wfjax sweep --config examples/soft_pads_heavy_axle.toml`` run from any directory.
"""

from __future__ import annotations

import sys
from importlib import resources
from pathlib import Path

HELP = "copy the example case files and measured profile into DIR (default ./examples)"
SUFFIXES = (".toml", ".csv")


def example_files() -> dict[str, bytes]:
    """Every shipped example file, ``name -> contents``, in name order."""
    root = resources.files("wfjax") / "examples"
    return {f.name: f.read_bytes() for f in sorted(root.iterdir(), key=lambda f: f.name)
            if f.name.endswith(SUFFIXES)}


def copy_examples(directory: str | Path) -> list[Path]:
    """Copy the examples into ``directory`` (created); returns the files written.

    Refuses (ValueError, nothing written) when any of them already exists there, so an
    edited copy is never overwritten.
    """
    target = Path(directory)
    files = example_files()
    existing = [name for name in files if (target / name).exists()]
    if existing:
        raise ValueError(f"{target}: {', '.join(existing)} already exist(s); nothing copied "
                         "(choose another DIR or remove them)")
    target.mkdir(parents=True, exist_ok=True)
    written = []
    for name, data in files.items():
        (target / name).write_bytes(data)
        written.append(target / name)
    return written


def run(args) -> int:
    from ._common import flag_layer

    flag_layer(args, "examples")
    for path in copy_examples(args.dir):
        sys.stdout.write(f"wrote {path}\n")
    return 0
