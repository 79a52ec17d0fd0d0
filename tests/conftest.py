from __future__ import annotations

import os
from pathlib import Path

import pytest

_DEFAULT_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.fixture(scope="session")
def data_root() -> Path:
    """The real benchmark folder: $MOSEG_DATA, else ../shared/data beside the repository."""
    root = Path(os.environ.get("MOSEG_DATA", _DEFAULT_DATA))
    if not root.is_dir():
        pytest.skip(f"benchmark data not found at {root} (set MOSEG_DATA)")
    return root
