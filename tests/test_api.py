from __future__ import annotations

import subprocess
import sys

import pytest

import mosegpipe


@pytest.mark.parametrize("name", mosegpipe.__all__)
def test_every_public_name_resolves(name: str) -> None:
    assert getattr(mosegpipe, name) is not None


def test_unknown_name_raises_attribute_error() -> None:
    with pytest.raises(AttributeError, match="no_such_thing"):
        mosegpipe.no_such_thing  # noqa: B018


def test_import_is_light() -> None:
    code = "import sys, mosegpipe, mosegpipe.errors; print('torch' in sys.modules, 'cv2' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["False", "False"]
