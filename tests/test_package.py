"""The built wheel works anywhere (issue 34, item 1).

A wheel and an sdist are built (``python -m build``, offline: ``--no-isolation`` with the
test environment's setuptools) from a copy of the package's files, so the build writes
nothing into the source tree. The wheel goes into a clean virtual environment outside the
source tree, without dependencies (``--no-deps --no-index``): they come from the test
environment, which ``--system-site-packages`` reaches only when that is the system's Python,
so its site-packages is linked by a ``.pth`` file as well (a link, not an install: the
environment's ``wfjax`` is the wheel's). Then the README's commands run from an empty
directory: ``wfjax sweep``, ``wfjax figures --only 7``, the case-file and the
measured-profile examples after ``wfjax examples``, and ``wfjax --version`` /
``python -m wfjax``.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import tarfile
import venv
import zipfile
from pathlib import Path

import pytest

import wfjax

ROOT = Path(__file__).resolve().parents[1]
SOURCES = ("pyproject.toml", "README.md", "CHANGELOG.md", "wfjax")
EXAMPLES = ("fig7.toml", "measured_profile.csv", "measured_sections.csv",
            "soft_pads_heavy_axle.toml")
README = (ROOT / "README.md").read_text()


def _run(argv, cwd, timeout=600, env=None) -> subprocess.CompletedProcess:
    """``argv`` in ``cwd``; fails the test with its output unless it exits 0."""
    proc = subprocess.run([str(a) for a in argv], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=timeout)
    assert proc.returncode == 0, f"{argv}: exit {proc.returncode}\n{proc.stdout}\n{proc.stderr}"
    return proc


@pytest.fixture(scope="module")
def dist(tmp_path_factory) -> Path:
    """The directory holding the built wheel and sdist."""
    src = tmp_path_factory.mktemp("source")
    for name in SOURCES:
        if (ROOT / name).is_dir():
            shutil.copytree(ROOT / name, src / name,
                            ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
        else:
            shutil.copy2(ROOT / name, src / name)
    out = tmp_path_factory.mktemp("dist")
    _run([sys.executable, "-m", "build", "--no-isolation", "--outdir", out, src], cwd=src)
    return out


@pytest.fixture(scope="module")
def env(dist, tmp_path_factory) -> dict:
    """A clean environment with the wheel installed: its bin directory and process env."""
    root = tmp_path_factory.mktemp("venv") / "wfjax-env"
    venv.create(root, system_site_packages=True, with_pip=False)
    python = root / "bin" / "python"
    purelib = _run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                   cwd=root).stdout.strip()
    ours = dict.fromkeys(sysconfig.get_paths()[k] for k in ("purelib", "platlib"))
    (Path(purelib) / "_test_dependencies.pth").write_text("\n".join(ours) + "\n")
    (wheel,) = dist.glob("*.whl")
    _run([sys.executable, "-m", "pip", "--python", python, "install", "-q", "--no-deps",
          "--no-index", wheel], cwd=root)
    environ = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "XLA_FLAGS")}
    environ["PATH"] = f"{root / 'bin'}{os.pathsep}{environ.get('PATH', '')}"
    assert shutil.which("wfjax", path=environ["PATH"]) == str(root / "bin" / "wfjax")
    return {"bin": root / "bin", "python": python, "environ": environ}


@pytest.fixture(scope="module")
def empty_dir(env, tmp_path_factory) -> Path:
    """An empty directory outside the source tree with the examples copied out."""
    where = tmp_path_factory.mktemp("user")
    assert not list(where.iterdir())
    proc = _run(["wfjax", "examples"], cwd=where, env=env["environ"])
    assert sorted(p.name for p in (where / "examples").iterdir()) == list(EXAMPLES)
    assert proc.stdout.count("wrote examples/") == len(EXAMPLES)
    return where


def test_wheel_and_sdist_hold_the_package_data_and_the_version(dist):
    version = wfjax.__version__
    (wheel,) = dist.glob("*.whl")
    (sdist,) = dist.glob("*.tar.gz")
    assert wheel.name == f"wfjax-{version}-py3-none-any.whl"
    assert sdist.name == f"wfjax-{version}.tar.gz"
    names = set(zipfile.ZipFile(wheel).namelist())
    assert {f"wfjax/examples/{n}" for n in EXAMPLES} | {"wfjax/__main__.py",
                                                        "wfjax/commands/examples.py"} <= names
    metadata = zipfile.ZipFile(wheel).read(f"wfjax-{version}.dist-info/METADATA").decode()
    assert f"\nVersion: {version}\n" in metadata
    with tarfile.open(sdist) as tar:
        members = set(tar.getnames())
    assert {f"wfjax-{version}/wfjax/examples/{n}" for n in EXAMPLES} <= members
    assert f"wfjax-{version}/pyproject.toml" in members


def test_installed_package_is_the_wheel_not_the_source_tree(env, tmp_path):
    out = _run([env["python"], "-c", "import wfjax; print(wfjax.__file__)"], cwd=tmp_path,
               env=env["environ"]).stdout.strip()
    assert Path(out).is_relative_to(env["bin"].parent) and not Path(out).is_relative_to(ROOT)
    for name in EXAMPLES:  # the copies are the shipped files, byte for byte
        shipped = Path(out).parent / "examples" / name
        assert shipped.read_bytes() == (ROOT / "wfjax" / "examples" / name).read_bytes()


def test_version_and_python_dash_m(env, tmp_path):
    expected = f"wfjax {wfjax.__version__}\n"
    assert _run(["wfjax", "--version"], tmp_path, env=env["environ"]).stdout == expected
    assert _run([env["python"], "-m", "wfjax", "--version"], tmp_path,
                env=env["environ"]).stdout == expected
    assert "sweep" in _run([env["python"], "-m", "wfjax", "--help"], tmp_path,
                           env=env["environ"]).stdout


def test_examples_refuses_to_overwrite(env, tmp_path):
    (tmp_path / "examples").mkdir()
    (tmp_path / "examples" / "fig7.toml").write_text("# mine\n")
    proc = subprocess.run(["wfjax", "examples"], cwd=tmp_path, env=env["environ"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "already exist" in proc.stderr
    assert [p.name for p in (tmp_path / "examples").iterdir()] == ["fig7.toml"]
    assert (tmp_path / "examples" / "fig7.toml").read_text() == "# mine\n"


def _summary(directory: Path, name: str) -> dict:
    return json.loads((directory / f"{name}.json").read_text())


def test_readme_first_command_wfjax_sweep(env, empty_dir):
    assert "pip install -q -e . && wfjax sweep\n" in README  # the first screen's command
    proc = _run(["wfjax", "sweep"], empty_dir, env=env["environ"])
    out = empty_dir / "out" / "sweep"
    assert {"sweep.csv", "sweep.json", "sweep.npz", "sweep.png"} <= {p.name for p in
                                                                     out.iterdir()}
    assert "peak max force" in proc.stdout
    assert _summary(out, "sweep")["case"]["flat"]["kind"] == "both"


def test_figures_only_7(env, empty_dir):
    _run(["wfjax", "figures", "--only", "7"], empty_dir, env=env["environ"])
    png = empty_dir / "out" / "figures" / "fig7_speed_sweep.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_readme_case_file_example(env, empty_dir):
    command = "wfjax sweep --config examples/soft_pads_heavy_axle.toml"
    assert command in README
    _run(command.split(), empty_dir, env=env["environ"])
    track = _summary(empty_dir / "out" / "sweep", "sweep")["case"]["track"]
    assert track["pad_stiffness"] == 60e6 and track["sleeper_spacing"] == 0.6


def test_readme_measured_profile_example(env, empty_dir):
    command = ("wfjax simulate --profile-csv examples/measured_profile.csv "
               "--contact hertz-trajectory")
    assert command in README
    _run(command.split(), empty_dir, env=env["environ"])
    case = _summary(empty_dir / "out" / "simulate", "simulate")["case"]
    assert case["flat"]["kind"] == "profile"
    assert Path(case["flat"]["profile_csv"]).name == "measured_profile.csv"
