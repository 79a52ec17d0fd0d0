"""The built wheel installs and works on its own: built from this tree (`pip wheel --no-deps
--no-build-isolation`, no network), installed with `--no-deps` into a fresh virtual environment that sees
the current environment's packages (numpy, torch, ...) but not this checkout, it answers `moseg --version`
and `python -m mosegpipe --version` and segments a sample with the weights it ships."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import venv
from pathlib import Path

import pytest

import mosegpipe

ROOT = Path(__file__).resolve().parents[1]


def _run(args: list[str], cwd: Path, env: dict[str, str], timeout: float = 120) -> str:
    done = subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert done.returncode == 0, f"{args}: {done.stdout}\n{done.stderr}"
    return done.stdout


@pytest.mark.slow
def test_the_wheel_installs_offline_and_runs(tmp_path: Path) -> None:
    pytest.importorskip("setuptools", minversion="68")  # the build backend, from this environment
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
    env |= {"PIP_NO_INDEX": "1", "PIP_DISABLE_PIP_VERSION_CHECK": "1", "OMP_NUM_THREADS": "1"}
    # Built from a copy of what the wheel is made of: the build writes build/ and *.egg-info beside its sources.
    tree = tmp_path / "tree"
    for part in ("mosegpipe", "cli"):
        shutil.copytree(ROOT / part, tree / part, ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, tree / name)
    wheels = tmp_path / "wheels"
    pip = [sys.executable, "-m", "pip"]
    _run([*pip, "wheel", str(tree), "--no-deps", "--no-build-isolation", "-q", "-w", str(wheels)], tmp_path, env)
    (wheel,) = wheels.glob("mosegpipe-*.whl")

    fresh = tmp_path / "fresh"
    venv.create(fresh, with_pip=False)
    python = fresh / "bin" / "python"
    site = Path(
        _run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], tmp_path, env).strip()
    )
    _run([*pip, "--python", str(python), "install", "--no-deps", "-q", str(wheel)], tmp_path, env)
    # The dependencies come from this environment, after the fresh one's own site-packages (where the wheel went).
    # Only after the install: where this environment holds an installed (not editable) mosegpipe, pip would
    # otherwise see it and install nothing.
    here = dict.fromkeys([sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]])
    (site / "_moseg_test_deps.pth").write_text("\n".join(here) + "\n", encoding="utf-8")

    where = _run([str(python), "-c", "import mosegpipe; print(mosegpipe.__file__)"], tmp_path, env).strip()
    assert Path(where).is_relative_to(site), where  # the wheel's copy, not this checkout's
    version = f"moseg {mosegpipe.__version__}"
    assert _run([str(fresh / "bin" / "moseg"), "--version"], tmp_path, env).strip() == version
    assert _run([str(python), "-m", "mosegpipe", "--version"], tmp_path, env).strip() == version
    sample = ROOT / "samples" / "rendered" / "frames"
    _run([str(fresh / "bin" / "moseg"), "run", str(sample), "-o", "out", "--no-rrd"], tmp_path, env)
    summary = json.loads((tmp_path / "out" / "summary.json").read_text(encoding="utf-8"))
    assert summary["model"]["checkpoint"] is None and summary["k"] >= 2  # the shipped weights found the objects
    assert len(list((tmp_path / "out" / "masks").glob("*.png"))) == 5
