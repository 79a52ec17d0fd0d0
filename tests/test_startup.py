"""Start-up of the `moseg` command: what importing the CLI loads, and the garbage collector at start-up.

Timings live in benchmarks/speed.py (table (d)); these tests check the mechanisms behind them, which
fail the same way on any machine.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

SAMPLE_FRAMES = Path(__file__).resolve().parents[1] / "samples" / "rendered" / "frames"
HEAVY = ("torch", "sklearn", "scipy", "cv2", "rerun", "PIL", "av", "matplotlib", "pyarrow")

# Counts the full (generation 2) collections from here on; printed by the last exit handler to run
# (registered first), together with how many objects are frozen at that point.
_PROBE = """
import atexit, gc, sys
full = [0]
gc.callbacks.append(lambda phase, info: full.__setitem__(0, full[0] + (phase == "start" and info["generation"] == 2)))
atexit.register(lambda: print("AT_EXIT", full[0], gc.get_freeze_count(), file=sys.stderr))
"""


def _python(code: str, cwd: Path, *args: str) -> subprocess.CompletedProcess[str]:
    # cwd away from the checkout: `python -c` puts the working folder first on sys.path, where the
    # source tree's mosegpipe/ (without cli/, which is mapped in at install) would shadow the install.
    proc = subprocess.run(
        [sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=300, cwd=cwd, check=False
    )
    assert proc.returncode == 0, proc.stderr
    return proc


def _at_exit(stderr: str) -> tuple[int, int]:
    """(full collections, frozen objects) from the probe's line."""
    line = next(x for x in stderr.splitlines() if x.startswith("AT_EXIT"))
    full, frozen = line.split()[1:]
    return int(full), int(frozen)


def test_importing_the_cli_loads_no_heavy_library(tmp_path: Path) -> None:
    """Neither the CLI nor the config classes it reads its defaults from; `moseg --help` neither."""
    heavy = f"print(sorted({{m.split('.')[0] for m in sys.modules}} & set({HEAVY!r})))"
    code = f"import sys, mosegpipe.configs, mosegpipe.cli.main; {heavy}"
    assert _python(code, tmp_path).stdout.strip() == "[]"
    code = f"import atexit, sys\natexit.register(lambda: {heavy})\nfrom mosegpipe.cli.main import app\napp()\n"
    assert _python(code, tmp_path, "run", "--help").stdout.strip().endswith("[]")


@pytest.mark.slow
def test_setup_imports_with_the_collector_paused_and_freezes_them(tmp_path: Path) -> None:
    code = _PROBE + (
        "import gc, sys\n"
        "import mosegpipe.cli.main\n"
        "from mosegpipe.cli.app import setup_run\n"
        "setup_run(1, False, 'mosegpipe.apps.outputs')\n"
        "from mosegpipe.cli.clip import _import_ahead\n"  # what `run` imports on a thread of its own
        "from mosegpipe.pipeline import PipelineConfig\n"
        "import threading\n"
        "_import_ahead(PipelineConfig())\n"
        "[t.join() for t in threading.enumerate() if t.name == 'moseg-import']\n"
        "print(full[0], gc.isenabled(), gc.get_freeze_count(), *(m in sys.modules for m in ('torch', 'sklearn', "
        "'scipy.spatial', 'rerun.blueprint')))\n"
        "built_after = [[] for _ in range(20_000)]\n"  # alive at exit (lists are tracked; empty dicts are not)
    )
    proc = _python(code, tmp_path)
    full, enabled, frozen, *loaded = proc.stdout.split()
    # SciPy, Rerun (+ OpenCV): ~100 k objects; with the collector running they cost full collections.
    # Neither torch (a single-clip run embeds with NumPy, inference.py) nor scikit-learn (K-means is OpenCV's).
    assert (full, enabled, *loaded) == ("0", "True", "False", "False", "True", "True")
    assert int(frozen) > 50_000
    # At exit the lists are frozen too (a few hundred objects frozen at start-up may have gone since).
    assert _at_exit(proc.stderr)[1] >= int(frozen) + 10_000


@pytest.mark.slow
def test_moseg_run_starts_without_full_collections(tmp_path: Path) -> None:
    """The whole `moseg run` on 5 frames: full collections walking everything the imports built (about
    0.5-1 s here when it imported torch and scikit-learn) when the imports run with the collector on."""
    code = _PROBE + (
        "import atexit, sys\n"
        "atexit.register(lambda: print('LOADED', sorted({m.split('.')[0] for m in sys.modules} & {'sklearn', 'scipy'})))\n"
        "from mosegpipe.cli.main import app\nsys.argv[0] = 'moseg'\napp()\n"
    )
    proc = _python(code, tmp_path, "run", str(SAMPLE_FRAMES), "--frames", "5", "--no-rrd", "--out", str(tmp_path / "o"))
    assert (tmp_path / "o" / "labels.npz").is_file()
    assert "LOADED ['scipy']" in proc.stdout  # K-means is OpenCV's: no scikit-learn on a clip's way
    full, frozen = _at_exit(proc.stderr)
    assert full <= 1, f"{full} full collections during moseg run"
    assert frozen > 50_000
