"""Shared fixtures and markers. Helpers that tests import (scenes, checkpoints, ...) are in helpers.py."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

_DEFAULT_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.fixture(scope="session", autouse=True)
def one_thread() -> None:
    """One torch / OpenCV / BLAS thread for the whole session: much faster on these small problems on 2 cores."""
    from mosegpipe.runtime import set_threads

    set_threads(1)


@pytest.fixture(scope="session", autouse=True)
def private_cache(tmp_path_factory: pytest.TempPathFactory) -> None:
    """A cache folder of the session's own (inference copies of weights, tracked windows), unless
    $MOSEG_CACHE names one: tests neither read nor fill the user's ~/.cache/mosegpipe."""
    if "MOSEG_CACHE" not in os.environ:
        os.environ["MOSEG_CACHE"] = str(tmp_path_factory.mktemp("moseg-cache"))


@pytest.fixture(scope="session")
def data_root() -> Path:
    """The real benchmark folder: $MOSEG_DATA, else ../shared/data beside the repository."""
    root = Path(os.environ.get("MOSEG_DATA", _DEFAULT_DATA))
    if not root.is_dir():
        pytest.skip(f"benchmark data not found at {root} (set MOSEG_DATA)")
    return root


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Every test that reads the real benchmarks is marked `data` (select or skip with -m)."""
    for item in items:
        if "data_root" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.data)
