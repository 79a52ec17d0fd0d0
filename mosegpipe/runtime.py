"""Thread control in one place, and the native libraries' own messages.

On small problems (hundreds of points, 5-d embeddings) one BLAS/OpenMP thread is much faster than
two on the 2-core machines we target: sklearn K-means was measured 30-50x slower with 2 threads.
OpenCV, FFmpeg and libpng print their complaints about a bad input straight to stderr;
`quiet_native_logs` keeps them off it (the failure they lead to is reported once, in our words).
`warnings_held` keeps one thread's warnings of a logger back while a block runs.
Nothing here runs at import; callers (the CLI, benchmarks, tests) opt in.
"""

from __future__ import annotations

import atexit
import contextlib
import gc
import importlib
import logging
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


LATER_IMPORTS = ("scipy.spatial", "scipy.sparse.csgraph", "skimage.filters.thresholding", "scipy.optimize")
"""What the pipeline imports on first use, in the order a run asks for them (the rigid-motion check, the world, the
motion masks' thresholds, a video's label matching): batch workers import them before their first clip
(`import_now`); `moseg run` imports what it needs of them ahead (`import_ahead`)."""


def import_now(*names: str) -> None:
    """Imports the modules `names` here, with the collector paused (`collector_paused`): a batch worker's
    set-up, so that a clip's time limit does not count them."""
    with collector_paused(names[0] if names else "sys"):
        for name in names:
            importlib.import_module(name)


def import_ahead(*names: str) -> threading.Thread | None:
    """Imports the modules `names` (in order) on a background thread, with the collector paused as
    `collector_paused` pauses it; returns the thread (None when all are imported already).

    `moseg run` needs scikit-learn only to cluster, Rerun and PyAV only to write: imported on this
    thread, they load while the main thread reads, tracks and computes the flow, whose OpenCV calls
    release the GIL, so on two cores the imports and the first stages overlap instead of adding up
    (benchmarks/speed.py, table (d)). A module the main thread asks for before this thread is done with
    it waits for it (Python's per-module import locks). An import that fails here is ignored: the
    main thread's own import of it then raises, where it is reported as ever.
    """
    missing = [name for name in names if name not in sys.modules]
    if not missing:
        return None

    def run() -> None:
        with collector_paused(missing[0]):
            for name in missing:
                with contextlib.suppress(Exception):
                    importlib.import_module(name)

    thread = threading.Thread(target=run, name="moseg-import", daemon=True)
    thread.start()
    return thread


QUIET_OPENCV_LOG_LEVEL = "SILENT"
"""OpenCV's log level in quiet mode: its [ERROR] lines too say what our own error line says (a corrupt
PNG's "IHDR chunk shall be first", a camera index that does not open)."""

_quiet_native: list[bool] = [False]
_muted_lock = threading.Lock()
_muted: list[int] = [0, -1]  # blocks inside native_stderr_muted, the saved descriptor of stderr


def quiet_native_logs() -> None:
    """Keeps FFmpeg's, OpenCV's and libpng's own messages off stderr in this process (the CLI's default;
    `-v` keeps them). A level the user set in the environment wins.

    FFmpeg reads OPENCV_FFMPEG_LOGLEVEL when it first opens a video; OpenCV reads OPENCV_LOG_LEVEL once,
    so an OpenCV imported before this call is told again through its API. libpng has no level: its
    errors go straight to file descriptor 2 (see native_stderr_muted).
    """
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")  # AV_LOG_QUIET
    os.environ.setdefault("OPENCV_LOG_LEVEL", QUIET_OPENCV_LOG_LEVEL)
    level_name = os.environ["OPENCV_LOG_LEVEL"].strip().upper()
    _quiet_native[0] = level_name == QUIET_OPENCV_LOG_LEVEL
    cv2 = sys.modules.get("cv2")
    logging_api = getattr(getattr(cv2, "utils", None), "logging", None)
    level = getattr(logging_api, f"LOG_LEVEL_{level_name}", None)
    if logging_api is not None and isinstance(level, int):
        logging_api.setLogLevel(level)


@contextlib.contextmanager
def native_stderr_muted() -> Iterator[None]:
    """File descriptor 2 points at /dev/null inside the block, after quiet_native_logs (else nothing
    changes): for a native call that prints to it with no level to turn it off (libpng's "libpng
    error: Not enough image data" from OpenCV's PNG decoder). Blocks may overlap across threads; the
    last one out restores stderr. Python's own writes to stderr inside the block are lost too, so
    keep the block to the one call.
    """
    if not _quiet_native[0]:
        yield
        return
    with _muted_lock:
        if _muted[0] == 0:
            with contextlib.suppress(OSError, ValueError):
                sys.stderr.flush()
            try:
                saved = os.dup(2)
                devnull = os.open(os.devnull, os.O_WRONLY)
            except OSError:  # no descriptor 2 (a daemon): nothing to mute
                saved = -1
            else:
                os.dup2(devnull, 2)
                os.close(devnull)
            _muted[1] = saved
        _muted[0] += 1
    try:
        yield
    finally:
        with _muted_lock:
            _muted[0] -= 1
            if _muted[0] == 0 and _muted[1] >= 0:
                os.dup2(_muted[1], 2)
                os.close(_muted[1])
                _muted[1] = -1


_T = TypeVar("_T")
_DONE = object()


def run_ahead(
    items: Iterator[_T], depth: int, name: str = "moseg-ahead", strict: bool = False
) -> Generator[_T, None, None]:
    """Runs the iterator `items` on a background thread, at most `depth` items ahead of the consumer.

    With `strict`, the item being made counts too: the thread starts the next item only once the consumer
    has taken one (memory: `depth` items ahead, not `depth` + 1); else it makes the next while the queue is full.

    Whole-video mode spends its time in OpenCV, PyAV and BLAS calls that release the GIL, so its
    stages run as a chain of these: reading + KLT tracking, then embedding + clustering, then masks,
    overlays and encoding (the caller's thread); on two or more cores they overlap.
    An exception in `items` is raised in the consumer. When the consumer stops early (an error,
    Ctrl-C, a closed generator), the thread is told to stop, closes `items` (so that a chain of
    these winds down stage by stage) and exits.
    """
    q: queue.Queue[Any] = queue.Queue(maxsize=depth)
    stop = threading.Event()
    slots = threading.Semaphore(depth) if strict else None  # strict: one per item made and not yet taken

    def start() -> bool:
        while slots is not None and not slots.acquire(timeout=0.1):
            if stop.is_set():
                return False
        return not stop.is_set()

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
            while start():
                item = next(items, _DONE)
                if not put(item) or item is _DONE:
                    return
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
            if slots is not None:
                slots.release()
            if item is _DONE:
                return
            if isinstance(item, BaseException):
                raise item
            yield item
    finally:
        stop.set()
        worker.join(timeout=5.0)


@contextlib.contextmanager
def warnings_held(logger: logging.Logger) -> Iterator[None]:
    """Keeps `logger`'s WARNING records of this thread from its handlers while the block runs.

    Whole-video mode reports automatic K's ambiguity warnings once for all windows, not once per
    window (hundreds of lines on a long video); the notes themselves are kept (WindowResult.k_note).
    Other threads' records pass: a clip segmented beside this video keeps its warning.
    """
    thread = threading.get_ident()

    def keep(record: logging.LogRecord) -> bool:
        return record.thread != thread or record.levelno != logging.WARNING

    logger.addFilter(keep)
    try:
        yield
    finally:
        logger.removeFilter(keep)
