"""Execute the tutorial and paper-figure notebooks in fast mode (WFJAX_FAST=1) with nbclient.

The quickstart runs in the default suite; the figure notebooks compile several flats and
contact models each and are marked slow (``pytest -m slow``).
"""

import os
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")

NOTEBOOKS = Path(__file__).resolve().parent.parent / "notebooks"


def _execute(name: str, timeout: int = 600) -> None:
    nb = nbformat.read(NOTEBOOKS / name, as_version=4)
    env_before = os.environ.get("WFJAX_FAST")
    os.environ["WFJAX_FAST"] = "1"  # inherited by the kernel process
    try:
        client = nbclient.NotebookClient(nb, timeout=timeout, kernel_name="python3",
                                         resources={"metadata": {"path": str(NOTEBOOKS)}})
        client.execute()
    finally:
        if env_before is None:
            os.environ.pop("WFJAX_FAST", None)
        else:
            os.environ["WFJAX_FAST"] = env_before
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])
              if o.get("output_type") == "error"]
    assert not errors


def test_quickstart_notebook():
    _execute("quickstart.ipynb")


@pytest.mark.slow
@pytest.mark.parametrize("name", ["fig7_speed_sweep.ipynb", "fig8_depths.ipynb",
                                  "fig9_10_contact_models.ipynb"])
def test_figure_notebooks(name):
    _execute(name)
