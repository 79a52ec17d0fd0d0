"""runtime.run_ahead: a background stage of whole-video mode."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from mosegpipe.runtime import run_ahead


def test_run_ahead_yields_everything_in_order_from_another_thread() -> None:
    threads: set[str] = set()

    def items() -> Iterator[int]:
        for i in range(50):
            threads.add(threading.current_thread().name)
            yield i

    assert list(run_ahead(items(), depth=3, name="stage")) == list(range(50))
    assert threads == {"stage"}


def test_run_ahead_raises_the_stage_error_in_the_consumer() -> None:
    def items() -> Iterator[int]:
        yield 1
        raise ValueError("bad frame 2")

    out = run_ahead(items(), depth=2)
    assert next(out) == 1
    with pytest.raises(ValueError, match="bad frame 2"):
        next(out)


def test_run_ahead_stops_and_closes_the_stage_when_the_consumer_stops() -> None:
    closed = threading.Event()

    def items() -> Iterator[int]:
        try:
            i = 0
            while True:
                yield i
                i += 1
        finally:
            closed.set()

    out = run_ahead(items(), depth=2, name="endless")
    assert next(out) == 0
    out.close()  # the consumer gives up: the worker must not run on forever
    assert closed.wait(5.0)
    assert not any(t.name == "endless" and t.is_alive() for t in threading.enumerate())


@pytest.mark.parametrize("strict", [False, True])
def test_run_ahead_starts_an_item_only_when_its_depth_allows(strict: bool) -> None:
    started: list[int] = []

    def items() -> Iterator[int]:
        for i in range(6):
            started.append(i)  # the stage starts making item i (a window's frames, its flows)
            yield i

    out = run_ahead(items(), depth=1, strict=strict)
    assert next(out) == 0
    time.sleep(0.3)  # the consumer is busy with item 0: the stage runs ahead as far as it may
    # strict: item 1 is made and waits; without: item 1 waits in the queue and item 2 is being made
    assert started == ([0, 1] if strict else [0, 1, 2])
    assert list(out) == [1, 2, 3, 4, 5]


def test_import_ahead_imports_on_its_own_thread_and_skips_what_is_loaded(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import sys

    from mosegpipe.runtime import import_ahead

    (tmp_path / "moseg_ahead_probe.py").write_text(
        "import threading\nTHREAD = threading.current_thread().name\n", encoding="utf-8"
    )
    (tmp_path / "moseg_ahead_broken.py").write_text("raise RuntimeError('broken on purpose')\n", encoding="utf-8")
    monkeypatch.syspath_prepend(str(tmp_path))
    for name in ("moseg_ahead_probe", "moseg_ahead_broken"):
        monkeypatch.delitem(sys.modules, name, raising=False)
    thread = import_ahead("moseg_ahead_broken", "moseg_ahead_probe")
    assert thread is not None
    thread.join(timeout=30)
    # a failing import is left for the main thread to meet; the next one still loads, on the helper thread
    assert "moseg_ahead_broken" not in sys.modules
    assert sys.modules["moseg_ahead_probe"].THREAD == "moseg-import"
    assert import_ahead("moseg_ahead_probe") is None  # nothing left to import
