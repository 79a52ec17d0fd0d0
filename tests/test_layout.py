"""The direction of imports: inference never loads training, evaluation or data generation."""

from __future__ import annotations

import subprocess
import sys

import pytest

INFERENCE_MODULES = [
    "mosegpipe.pipeline",
    "mosegpipe.batch",
    "mosegpipe.batch_plan",
    "mosegpipe.batch_pool",
    "mosegpipe.batch_ray",
    "mosegpipe.io",
    "mosegpipe.io_write",
    "mosegpipe.track",
    "mosegpipe.match",
    "mosegpipe.trajectories",
    "mosegpipe.model",
    "mosegpipe.cluster",
    "mosegpipe.rigid",
    "mosegpipe.masks",
    "mosegpipe.viz",
    "mosegpipe.colours",
]
FORBIDDEN = ("mosegpipe.training", "mosegpipe.evaluation", "mosegpipe.studies", "mosegpipe.synth")


@pytest.mark.slow
def test_inference_loads_no_training_evaluation_or_synth() -> None:
    # One fresh interpreter for all of them: the check is about the union of what they import.
    code = (
        f"import sys, importlib; [importlib.import_module(m) for m in {INFERENCE_MODULES!r}]; "
        f"print('\\n'.join(m for m in sorted(sys.modules) if m.startswith({FORBIDDEN!r})))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == [], f"importing the inference modules loads {out}"
