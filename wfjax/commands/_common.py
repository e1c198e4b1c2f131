"""Options and output helpers shared by the subcommands."""

from __future__ import annotations

import argparse
import json
import os
import tempfile
from pathlib import Path


def add_out_argument(parser: argparse.ArgumentParser, default: str) -> None:
    """``--out DIR``: where CSV, JSON and PNG results go."""
    parser.add_argument("--out", default=default, help=f"output directory (default: {default})")


def prepare_out(path: str) -> Path:
    """Create the output directory and return it."""
    out = Path(path)
    out.mkdir(parents=True, exist_ok=True)
    return out


def write_atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file, so it is never half-written."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    with os.fdopen(fd, "w") as fh:
        fh.write(text)
    os.replace(tmp, path)


def write_json(path: Path, data: dict) -> None:
    """Write ``data`` as indented JSON, atomically."""
    write_atomic(path, json.dumps(data, indent=2, sort_keys=False) + "\n")


def save_figure(fig, path: Path) -> None:
    """Save a matplotlib figure as PNG atomically and close it."""
    import matplotlib.pyplot as plt

    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".png")
    os.close(fd)
    fig.savefig(tmp, dpi=130, bbox_inches="tight")
    plt.close(fig)
    os.replace(tmp, path)
