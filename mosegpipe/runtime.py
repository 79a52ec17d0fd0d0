"""Thread control in one place.

On small problems (hundreds of points, 5-d embeddings) one BLAS/OpenMP thread is much faster than
two on the 2-core machines we target: sklearn K-means was measured 30-50x slower with 2 threads.
Nothing here runs at import; callers (the CLI, benchmarks, tests) opt in.
"""

from __future__ import annotations

import atexit
import contextlib
import gc
import os
import queue
import sys
import threading
from collections.abc import Generator, Iterator
from typing import Any, TypeVar


def set_threads(num_threads: int = 1) -> None:
    """Set torch, OpenCV and BLAS/OpenMP thread counts for this process.

    Torch is not imported for this (a single-clip run may not need it, see inference.py): a torch
    imported later takes the count from `requested_threads` (model.py applies it on import).

    Args:
        num_threads: threads for intra-op parallelism; 1 is fastest for per-clip work here.
    """
    import sys

    import cv2
    from threadpoolctl import threadpool_limits

    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, str(num_threads))
    _requested[0] = num_threads
    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(num_threads)
    cv2.setNumThreads(num_threads)
    threadpool_limits(num_threads)


_requested: list[int | None] = [None]  # the count of the last set_threads call


def requested_threads() -> int | None:
    """The thread count of the last `set_threads` call in this process (None: never called)."""
    return _requested[0]


_active_limit: list[int | None] = [None]  # the limit of the innermost limited_threads block


@contextlib.contextmanager
def limited_threads(num_threads: int = 1) -> Iterator[None]:
    """Context manager limiting the BLAS/OpenMP pools (used around scikit-learn calls).

    Entering threadpoolctl's limit costs ~4-12 ms (it scans the loaded libraries), more than a small
    K-means fit, so a block nested inside one with the same limit enters nothing.

    Args:
        num_threads: threads the pools may use inside the block.
    """
    if _active_limit[0] == num_threads:
        yield
        return
    from threadpoolctl import threadpool_limits

    previous = _active_limit[0]
    with threadpool_limits(num_threads):
        _active_limit[0] = num_threads
        try:
            yield
        finally:
            _active_limit[0] = previous


@contextlib.contextmanager
def collector_paused(marker: str) -> Iterator[None]:
    """Runs heavy imports with Python's cyclic garbage collector paused, then freezes what they built.

    scikit-learn, SciPy and torch build hundreds of thousands of objects (functions, classes, module
    dicts) as they are imported, and they live until the process exits. With the collector running,
    the imports trigger several full collections that walk everything imported so far again, and the
    interpreter's last collection at exit walks it all once more: about 1 s of a `moseg run` on 5
    frames on the 2-core machine (benchmarks/speed.py, table (d)). `gc.freeze()` moves them to the
    permanent generation, which collections skip: later ones walk only what the command builds (a
    whole video is still collected as it goes), and the one at exit walks nothing. The price: the
    few thousand objects of cyclic garbage the imports leave behind are kept until exit.

    Args:
        marker: a module the block imports; when it is imported already (a second start-up in one
            process, as in the tests) the block runs with the collector as it is.
    """
    if not gc.isenabled() or marker in sys.modules:
        yield
        return
    gc.disable()
    try:
        yield
    finally:
        gc.freeze()
        gc.enable()
        atexit.register(gc.freeze)  # at exit: before the interpreter's last collection


_T = TypeVar("_T")
_DONE = object()


def run_ahead(items: Iterator[_T], depth: int, name: str = "moseg-ahead") -> Generator[_T, None, None]:
    """Runs the iterator `items` on a background thread, at most `depth` items ahead of the consumer.

    Whole-video mode spends its time in OpenCV, PyAV and BLAS calls that release the GIL, so its
    stages run as a chain of these: reading + KLT tracking, then embedding + clustering, then masks,
    overlays and encoding (the caller's thread); on two or more cores they overlap.
    An exception in `items` is raised in the consumer. When the consumer stops early (an error,
    Ctrl-C, a closed generator), the thread is told to stop, closes `items` (so that a chain of
    these winds down stage by stage) and exits.
    """
    q: queue.Queue[Any] = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def put(item: Any) -> bool:
        while not stop.is_set():
            try:
                q.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def run() -> None:
        try:
            for item in items:
                if not put(item):
                    return
            put(_DONE)
        except BaseException as exc:  # handed to the consumer, raised there
            put(exc)
        finally:
            close = getattr(items, "close", None)
            if close is not None:
                close()

    worker = threading.Thread(target=run, name=name, daemon=True)
    worker.start()
    try:
        while True:
            item = q.get()
            if item is _DONE:
                return
            if isinstance(item, BaseException):
                raise item
            yield item
    finally:
        stop.set()
        worker.join(timeout=5.0)
