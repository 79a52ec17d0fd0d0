"""runtime.run_ahead: a background stage of whole-video mode."""

from __future__ import annotations

import threading
from collections.abc import Iterator

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
