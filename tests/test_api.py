from __future__ import annotations

import importlib
import importlib.metadata
import subprocess
import sys

import pytest

import mosegpipe


@pytest.mark.parametrize("name", sorted(set(mosegpipe.__all__) - {"__version__"}))
def test_every_public_name_is_the_object_its_module_defines(name: str) -> None:
    where = mosegpipe._WHERE[name]
    value = getattr(mosegpipe, name)
    assert value is getattr(importlib.import_module(where), name)
    assert vars(mosegpipe)[name] is value  # kept after the first use: __getattr__ runs once per name
    assert isinstance(value, type) or callable(value)  # classes and functions only, no module state
    assert value.__module__.startswith("mosegpipe.")  # ours, not a third-party object passed through
    assert name in dir(mosegpipe)


def test_the_design_api_and_version_are_public() -> None:
    design = {"read_video", "track_klt", "build_trajectories", "SubspaceNet", "cluster_auto_k", "segment_clip"}
    assert design <= set(mosegpipe.__all__)
    assert mosegpipe.__version__ == importlib.metadata.version("mosegpipe")


def test_unknown_name_raises_attribute_error() -> None:
    with pytest.raises(AttributeError, match="no_such_thing"):
        mosegpipe.no_such_thing  # noqa: B018


def test_import_is_light() -> None:
    code = "import sys, mosegpipe, mosegpipe.errors; print('torch' in sys.modules, 'cv2' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["False", "False"]
