"""Folders of clips: find every clip, segment each into its own output folder, summarise.

Three engines run the same work (`run_batch(..., engine=...)`):

- "process" (default): a `concurrent.futures.ProcessPoolExecutor` on this machine, `jobs` worker
  processes, each with one torch/BLAS thread and the model unpickled once (the pool initializer).
- "ray": Ray tasks (`pip install 'mosegpipe[ray]'`), one CPU each, on a local Ray instance or the
  cluster at `address`; the model is put into Ray's object store once and cached per worker.
- "inline": one clip after another in this process (debugging; no clip timeout, a crash stops it).

Fault isolation: a clip that fails (any exception), runs past `clip_timeout` or kills its worker
process is one "failed" row with a one-line reason; the other clips go on (a broken process pool is
rebuilt). Which clip killed a pool is found by re-running the clips that were in flight one at a time.

Resume: each clip's output folder is built under a temporary name and renamed into place when
complete (outputs._OutputDir), and its summary.json records `batch.config_hash`, a hash of every
setting that changes the outputs (PipelineConfig, the model's weights, the recording flag). A re-run
skips the clips whose folder holds summary.json with the same hash and redoes the rest, so a batch
killed at any moment loses nothing and a re-run with other options redoes what they change.
"""

from __future__ import annotations

import collections
import concurrent.futures as cf
import contextlib
import csv
import hashlib
import io as _io
import json
import logging
import os
import queue
import secrets
import shutil
import signal
import threading
import time
import traceback
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from mosegpipe.errors import InputError, MosegError
from mosegpipe.io import IMAGE_SUFFIXES, atomic_write, write_json
from mosegpipe.model import SubspaceNet
from mosegpipe.outputs import write_clip_outputs
from mosegpipe.pipeline import PipelineConfig, segment_clip
from mosegpipe.settings import MAX_CLIP_TIMEOUT_S
from mosegpipe.types import ENGINES

log = logging.getLogger(__name__)

VIDEO_EXTENSIONS = {".mp4", ".avi", ".mov", ".mkv", ".webm", ".m4v", ".mpg", ".mpeg", ".wmv"}
IMAGE_EXTENSIONS = IMAGE_SUFFIXES
SUMMARY_FILES = ("batch_summary.csv", "batch_summary.json")
LOCK_FILE = ".moseg-batch.lock"
FIELDS = ("name", "status", "k", "tracks", "seconds", "output", "error")
#: Output folder names longer than this (bytes) are shortened and get a hash suffix (NAME_MAX is 255).
MAX_NAME_BYTES = 200

SegmentFn = Callable[[Path, PipelineConfig, SubspaceNet], Any]


@dataclass(frozen=True)
class BatchItem:
    """One clip found under the input folder and where its outputs go."""

    source: Path
    name: str
    out_dir: Path


# ---------------------------------------------------------------------------------------------
# Finding clips and naming their output folders
# ---------------------------------------------------------------------------------------------


def find_clips(root: str | Path, exclude: tuple[Path, ...] = ()) -> list[Path]:
    """Video files and frame folders (folders holding at least one image) under `root`, sorted.

    A frame folder's sub-folders are searched too; a video inside a frame folder is listed as well.
    Hidden entries (names starting with ".") and the folders in `exclude` (e.g. the batch output
    folder, when it lies under root) are skipped. Symbolic links are followed, but each folder is
    searched once (by its real path): a link back to a folder above it (a loop) or to one searched
    already is skipped with a warning, as is a link that points nowhere.

    Args:
        root: the folder to search.
        exclude: folders not to descend into.

    Returns:
        Paths of video files and frame folders, in sorted walk order.

    Raises:
        InputError: root is not a folder.
    """
    root = Path(root)
    if not root.is_dir():
        raise InputError(f"{root}: not a folder")
    skip = {p.resolve() for p in exclude}
    searched: dict[Path, Path] = {root.resolve(): root}  # real path -> the path it was searched under

    def walk(folder: Path) -> Iterator[Path]:
        entries = sorted(folder.iterdir())
        if any(e.is_file() and e.suffix.lower() in IMAGE_EXTENSIONS for e in entries):
            yield folder
        for e in entries:
            if e.name.startswith("."):
                continue
            if e.is_symlink() and not e.exists():
                log.warning("%s: a broken symbolic link (to %s); skipped", e, os.readlink(e))
            elif e.is_file() and e.suffix.lower() in VIDEO_EXTENSIONS:
                yield e
            elif e.is_dir():
                real = e.resolve()
                if real in skip:
                    continue
                if real in searched:
                    log.warning("%s: the same folder as %s (a symbolic link); searched once", e, searched[real])
                    continue
                searched[real] = e
                yield from walk(e)

    return list(walk(root))


def _clean_part(part: str) -> bool:
    return bool(part) and "__" not in part and not part.startswith(("_", ".")) and not part.endswith("_")


def output_name(name: str) -> str:
    """The output folder name of a clip, from its path under the batch root ("." = the root itself).

    Readable and injective: "a/b.avi" -> "a__b.avi". A path that this flattening could confuse with
    another one (a part holding "__", or starting or ending with "_", or starting with "."), a
    reserved name or a name over MAX_NAME_BYTES is flattened the same way, shortened, and gets
    "___" plus 10 hex digits of the SHA-1 of the path: "a__b.avi" -> "a__b.avi___1f0c...". Plain
    names never hold "___", so the two kinds never meet. The name depends on the path alone, so it
    is stable from run to run whatever other clips the folder holds. Images lying in the root
    itself go to "_root".

    Args:
        name: the clip's path relative to the batch root, "/"-separated.

    Returns:
        A file name (no "/"), unique among the names of distinct paths.
    """
    if name == ".":
        return "_root"
    parts = name.split("/")
    flat = "__".join(parts)
    if all(_clean_part(p) for p in parts) and flat not in SUMMARY_FILES and len(flat.encode()) <= MAX_NAME_BYTES:
        return flat
    digest = hashlib.sha1(name.encode("utf-8", "surrogateescape")).hexdigest()[:10]
    head = flat.encode("utf-8", "surrogateescape")[: MAX_NAME_BYTES - 20].decode("utf-8", "ignore")
    if head.startswith("."):
        head = "_" + head[1:]
    return f"{head}___{digest}"


def plan(root: str | Path, out: str | Path) -> list[BatchItem]:
    """Pairs each clip under root with an output folder named after its path relative to root.

    "a/b.avi" goes to out/"a__b.avi", a frame folder "a/c" to out/"a__c", and images lying in root
    itself to out/"_root"; see output_name for the names that could collide.
    """
    root, out = Path(root), Path(out)
    items = []
    for src in find_clips(root, exclude=(out,)):
        rel = src.relative_to(root)
        name = "." if rel == Path(".") else rel.as_posix()
        items.append(BatchItem(src, name, out / output_name(name)))
    return items


def plan_paths(paths: Iterable[str | Path], out: str | Path, root: str | Path | None = None) -> list[BatchItem]:
    """Pairs each given clip (video file or frame folder) with an output folder under `out`.

    Names are the paths relative to `root` (default: the deepest folder holding them all), so pass
    the same root on every run of a growing list to keep the names stable. A path given twice is
    listed once.

    Raises:
        InputError: no paths, or a path that is not under root.
    """
    sources = list(dict.fromkeys(Path(p).absolute() for p in paths))
    if not sources:
        raise InputError("no clips given")
    base = Path(root).absolute() if root is not None else Path(os.path.commonpath([p.parent for p in sources]))
    items = []
    for src in sources:
        try:
            rel = src.relative_to(base)
        except ValueError:
            raise InputError(f"{src}: not under the batch root {base}") from None
        name = "." if rel == Path(".") else rel.as_posix()
        items.append(BatchItem(src, name, Path(out) / output_name(name)))
    return items


# ---------------------------------------------------------------------------------------------
# What changes the outputs: the config hash that resume compares
# ---------------------------------------------------------------------------------------------


def model_digest(model: SubspaceNet) -> str:
    """SHA-256 of a model's configuration and weights (names, dtypes, shapes and values)."""
    h = hashlib.sha256(json.dumps(model.cfg.to_dict(), sort_keys=True).encode())
    for name, tensor in sorted(model.state_dict().items()):
        t = tensor.detach().cpu().contiguous()
        h.update(f"{name}:{t.dtype}:{tuple(t.shape)}".encode())
        h.update(t.numpy().tobytes())
    return h.hexdigest()


def config_hash(cfg: PipelineConfig, model: SubspaceNet, rrd: bool) -> str:
    """The hash recorded as summary.json `batch.config_hash`: settings, model weights, recording flag."""
    payload = {"config": asdict(cfg), "model": model_digest(model), "rrd": bool(rrd)}
    return hashlib.sha256(json.dumps(payload, sort_keys=True, default=str).encode()).hexdigest()[:16]


def _previous_summary(path: Path) -> dict[str, Any] | None:
    """A completed clip's summary.json, or None when absent or unreadable (then the clip is redone)."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def _stored_hash(summary: dict[str, Any]) -> str | None:
    info = summary.get("batch")
    return info.get("config_hash") if isinstance(info, dict) else None


# ---------------------------------------------------------------------------------------------
# One clip (runs in a worker process, a Ray worker or inline)
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Job:
    """What every clip of one batch shares (pickled once per worker)."""

    cfg: PipelineConfig
    rrd: bool
    config_hash: str
    segment_fn: SegmentFn = field(default=segment_clip)


def _row(item: BatchItem, **values: Any) -> dict[str, Any]:
    row: dict[str, Any] = {f: "" for f in FIELDS}
    row.update(name=item.name, output=item.out_dir.name, **values)
    return row


def _one_line(exc: BaseException) -> str:
    message = " ".join(str(exc).split())[:300]
    return f"{type(exc).__name__}: {message}" if message else type(exc).__name__


def process_clip(item: BatchItem, job: _Job, model: SubspaceNet) -> dict[str, Any]:
    """Segments one clip and writes its folder atomically; every failure becomes a "failed" row.

    Args:
        item: the clip and its output folder.
        job: the batch's settings (pipeline config, recording flag, config hash, segment function).
        model: the model, in eval mode.

    Returns:
        The row (FIELDS), plus "_traceback" for an unexpected exception (logged by the caller).
    """
    t0 = time.perf_counter()
    row = _row(item)
    try:
        result = job.segment_fn(item.source, job.cfg, model)
        # The folder is ours: stale (config changed), incomplete or absent; it is built as .NAME.partial
        # and replaces the old one as a whole.
        batch = {"config_hash": job.config_hash, "name": item.name, "output": item.out_dir.name}
        summary = write_clip_outputs(result, item.out_dir, job.cfg, overwrite=True, rrd=job.rrd, extra={"batch": batch})
        row.update(status="ok", k=summary["k"], tracks=summary["num_tracks_segmented"])
    except MosegError as exc:
        row.update(status="failed", error=" ".join(str(exc).split()))
    except OSError as exc:  # reading errors are InputErrors (decode_errors): this is writing (disk full, permissions)
        where = f" ({exc.filename})" if exc.filename else ""
        row.update(status="failed", error=f"cannot write its outputs: {exc.strerror or _one_line(exc)}{where}")
    except Exception as exc:  # fault isolation: one broken clip must not stop the batch
        row.update(status="failed", error=_one_line(exc), _traceback=traceback.format_exc())
    row["seconds"] = round(time.perf_counter() - t0, 3)
    return row


# ---------------------------------------------------------------------------------------------
# Worker processes (ProcessPoolExecutor)
# ---------------------------------------------------------------------------------------------

_WORKER: dict[str, Any] = {}
MAX_WORKER_WARNINGS = 20
"""Warnings a worker sends back per clip; more are counted in one last line."""


class _WorkerLog(logging.Handler):
    """In a worker process: the warnings logged while its clip runs, sent back with the clip's row.

    A worker writes to the batch's stderr but has none of its logging set up: its warnings were
    bare lines there (a Ray worker's behind Ray's own prefix). The batch process logs them again,
    under the clip's name (see run_batch), where the CLI shows them as `moseg: warning:` lines.
    """

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        try:
            self.messages.append(" ".join(record.getMessage().split()))
        except Exception:  # a record whose arguments do not format: logging's own report
            self.handleError(record)

    def take(self) -> list[str]:
        messages, self.messages = self.messages, []
        if len(messages) > MAX_WORKER_WARNINGS:
            extra = len(messages) - MAX_WORKER_WARNINGS + 1
            messages = [*messages[: MAX_WORKER_WARNINGS - 1], f"... and {extra} more warnings"]
        return messages


_WORKER_LOG = _WorkerLog()


def _keep_worker_logs() -> None:
    """Sends this worker's warnings (Python's `warnings` too) to _WORKER_LOG alone, not to stderr."""
    root = logging.getLogger()
    for handler in list(root.handlers):
        root.removeHandler(handler)
    root.addHandler(_WORKER_LOG)
    root.setLevel(logging.WARNING)
    logging.captureWarnings(True)


def _worker_clip(item: BatchItem, job: _Job, model: SubspaceNet) -> dict[str, Any]:
    """process_clip in a worker: the row carries the clip's warnings as "_warnings"."""
    _WORKER_LOG.take()  # what the worker logged before this clip (its set-up) is not the clip's
    row = process_clip(item, job, model)
    warnings = _WORKER_LOG.take()
    if warnings:
        row["_warnings"] = warnings
    return row


def _watch_parent(lifeline: Any) -> None:
    """Ends this worker when the batch process is gone (its end of the lifeline pipe closes).

    Killing a parent does not kill its children, and forkserver workers are not even the batch
    process's children: without this, the workers of a SIGKILLed batch would go on writing.
    """
    with contextlib.suppress(EOFError, OSError):
        lifeline.recv()  # nothing is ever sent: this returns when the other end closes
    os._exit(1)


def _init_worker(model: SubspaceNet, job: _Job, ready: Any, lifeline: Any) -> None:
    """Pool initializer: one thread, quiet decoders, Ctrl-C left to the parent, the model kept."""
    from mosegpipe.runtime import quiet_native_logs, set_threads

    threading.Thread(target=_watch_parent, args=(lifeline,), name="moseg-lifeline", daemon=True).start()
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent stops the pool on Ctrl-C
    _keep_worker_logs()
    quiet_native_logs()
    set_threads(1)
    model.eval()
    _WORKER.update(model=model, job=job)
    ready.put(os.getpid())


def _pool_task(item: BatchItem) -> dict[str, Any]:
    return _worker_clip(item, _WORKER["job"], _WORKER["model"])


def _ping() -> int:
    return os.getpid()


def _mp_context() -> Any:
    import multiprocessing as mp

    if "forkserver" in mp.get_all_start_methods():
        ctx = mp.get_context("forkserver")
        # Workers fork from a server that imported torch and the pipeline once.
        ctx.set_forkserver_preload(["mosegpipe.batch"])
        return ctx
    return mp.get_context("spawn")


def _exit_reason(codes: list[int]) -> str:
    """Why a worker died, from the exit codes of the pool's dead processes.

    The executor SIGTERMs the other workers once one has died, so another signal or exit code
    is the one that tells.
    """
    codes = sorted(codes, key=lambda c: c == -signal.SIGTERM)
    for code in codes[:1]:
        if code < 0:
            try:
                name = signal.Signals(-code).name
            except ValueError:
                name = f"signal {-code}"
            hint = "; out of memory?" if -code == signal.SIGKILL else ""
            return f"its worker process died (killed by {name}{hint})"
        return f"its worker process died (exit code {code})"
    return "its worker process died"


@contextlib.contextmanager
def _hangup_blocked() -> Iterator[None]:
    """SIGHUP blocked in this thread while the pool's processes start (the workers, the forkserver
    and multiprocessing's resource tracker): they inherit the mask. A closed terminal sends SIGHUP
    to every process of the job; the tracker died of it (and was relaunched with warnings on
    stderr) while the batch process was still cleaning up, which ends the workers itself. A SIGHUP
    that arrives meanwhile is delivered when the mask is restored."""
    hangup = getattr(signal, "SIGHUP", None)
    if hangup is None or not hasattr(signal, "pthread_sigmask"):  # Windows
        yield
        return
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, {hangup})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


class _Pool:
    """A ProcessPoolExecutor whose workers are all started and ready (so deadlines count clip time)."""

    def __init__(self, workers: int, model: SubspaceNet, job: _Job, startup_timeout: float = 600.0) -> None:
        ctx = _mp_context()
        with _hangup_blocked():  # the queue's lock starts the resource tracker, the pings the workers
            self.ready = ctx.Queue()
            # Only this process holds the sending end: when it dies, however it dies, the workers see EOF and exit.
            lifeline, self.lifeline = ctx.Pipe(duplex=False)
            self.executor = cf.ProcessPoolExecutor(
                workers, mp_context=ctx, initializer=_init_worker, initargs=(model, job, self.ready, lifeline)
            )
            self.pids: set[int] = set()
            pings = [self.executor.submit(_ping) for _ in range(workers)]  # one submit starts one worker
        deadline = time.monotonic() + startup_timeout
        try:
            while len(self.pids) < workers:
                try:
                    self.pids.add(self.ready.get(timeout=0.2))
                except queue.Empty:
                    failed = [e for f in pings if f.done() and (e := f.exception()) is not None]
                    if failed:
                        raise RuntimeError(
                            f"batch worker processes failed to start ({_one_line(failed[0])}); see the "
                            "worker's traceback above. A script that calls run_batch must do so under "
                            "`if __name__ == '__main__':`, since the workers import the main module"
                        ) from failed[0]
                    if time.monotonic() > deadline:
                        raise RuntimeError(
                            f"batch worker processes did not start within {startup_timeout:g} s"
                        ) from None
            cf.wait(pings)
        except BaseException:
            self.kill()
            raise

    def exit_codes(self) -> list[int]:
        procs = getattr(self.executor, "_processes", None) or {}
        return [p.exitcode for p in list(procs.values()) if p.exitcode]

    def kill(self) -> None:
        """Kills every worker (a hung one included) and shuts the executor down without waiting."""
        procs = list((getattr(self.executor, "_processes", None) or {}).values())
        for p in procs:
            with contextlib.suppress(Exception):
                p.kill()
        self.executor.shutdown(wait=False, cancel_futures=True)
        self.lifeline.close()
        for p in procs:
            with contextlib.suppress(Exception):
                p.join(5)
        with contextlib.suppress(Exception):
            self.ready.close()
            self.ready.join_thread()


def _run_process(
    todo: list[tuple[int, BatchItem]],
    jobs: int,
    model: SubspaceNet,
    job: _Job,
    clip_timeout: float | None,
    emit: Callable[[int, dict[str, Any]], None],
) -> None:
    """Runs clips on a process pool; rebuilds it after a worker death or a timeout.

    After a pool breaks, the clips that were in flight are suspects: each is re-run alone, and the
    one that breaks the pool alone is the one that failed.
    """
    pending = collections.deque(todo)
    suspects: collections.deque[tuple[int, BatchItem]] = collections.deque()
    while pending or suspects:
        pool = _Pool(max(1, min(jobs, len(pending) + len(suspects))), model, job)
        inflight: dict[cf.Future[dict[str, Any]], tuple[int, BatchItem, float, bool]] = {}
        try:
            while True:
                if suspects:
                    if not inflight:
                        index, item = suspects.popleft()
                        inflight[pool.executor.submit(_pool_task, item)] = (index, item, time.monotonic(), True)
                else:
                    while pending and len(inflight) < jobs:
                        index, item = pending.popleft()
                        inflight[pool.executor.submit(_pool_task, item)] = (index, item, time.monotonic(), False)
                if not inflight:
                    break
                wait_s = None
                if clip_timeout is not None:
                    wait_s = max(0.0, min(t0 for _, _, t0, _ in inflight.values()) + clip_timeout - time.monotonic())
                done, _ = cf.wait(inflight, timeout=wait_s, return_when=cf.FIRST_COMPLETED)
                broken = False
                for fut in done:
                    index, item, t0, alone = inflight.pop(fut)
                    try:
                        emit(index, fut.result())
                    except cf.process.BrokenProcessPool:
                        broken = True
                        inflight[fut] = (index, item, t0, alone)  # judged below with the others
                    except Exception as exc:  # e.g. a result that cannot be pickled
                        emit(
                            index,
                            _row(item, status="failed", error=_one_line(exc), seconds=round(time.monotonic() - t0, 3)),
                        )
                if broken:
                    time.sleep(0.05)  # let the executor reap the dead worker, for its exit code
                    reason = _exit_reason(pool.exit_codes())
                    lost = []
                    for fut, (index, item, t0, _alone) in sorted(inflight.items(), key=lambda kv: kv[1][0]):
                        if fut.done() and not fut.cancelled() and fut.exception() is None:
                            emit(index, fut.result())  # finished before the pool broke
                        else:
                            lost.append((index, item, t0))
                    if len(lost) == 1:  # it ran alone: it is the one that killed its worker
                        index, item, t0 = lost[0]
                        log.warning("%s: %s", item.name, reason)
                        emit(index, _row(item, status="failed", error=reason, seconds=round(time.monotonic() - t0, 3)))
                    else:
                        log.info("a worker died with %d clips in flight; re-running them one at a time", len(lost))
                        suspects.extendleft((index, item) for index, item, _ in reversed(lost))
                    inflight.clear()
                    break
                now = time.monotonic()
                late = [v for v in inflight.values() if clip_timeout is not None and now - v[2] >= clip_timeout]
                if late:
                    for index, item, t0, _ in late:
                        log.warning("%s: timed out after %g s", item.name, clip_timeout)
                        emit(
                            index,
                            _row(
                                item,
                                status="failed",
                                error=f"timed out after {clip_timeout:g} s (--clip-timeout)",
                                seconds=round(now - t0, 3),
                            ),
                        )
                    late_ids = {v[0] for v in late}
                    innocent = sorted((v for v in inflight.values() if v[0] not in late_ids), key=lambda v: v[0])
                    pending.extendleft(
                        (index, item) for index, item, _, _ in reversed(innocent)
                    )  # killed with it: redo
                    inflight.clear()
                    break
        finally:
            pool.kill()


# ---------------------------------------------------------------------------------------------
# Ray
# ---------------------------------------------------------------------------------------------

_RAY_CACHE: dict[str, tuple[SubspaceNet, _Job]] = {}
_RAY_CANCEL_WAIT_S = 10.0
_RAY_AUTH_LOGGER = "ray._private.authentication.authentication_token_setup"


def _no_auth_notice(record: logging.LogRecord) -> bool:
    """Drops the WARNING line with which Ray (>= 2.59) tells that it started a local instance with
    token authentication, its secure default, on every run; its warning that authentication is
    off, and any other line, pass."""
    return not str(record.msg).startswith("Token authentication is enabled")


_STARTED = "started"


def _ray_task(shared: list[Any], item: BatchItem) -> Iterator[Any]:
    """A Ray task (a streaming generator): yields _STARTED once the worker is set up, then the row.

    The model and job (an object ref, wrapped in a list so that Ray does not fetch it for every
    task) are fetched and set up once per worker process and batch. The first yield tells the
    driver when the clip really starts, so that --clip-timeout does not count a worker's start-up.
    """
    import ray

    key = shared[0]
    if key not in _RAY_CACHE:
        from mosegpipe.runtime import quiet_native_logs, set_threads

        _keep_worker_logs()
        quiet_native_logs()
        set_threads(1)
        model, job = ray.get(shared[1])
        _RAY_CACHE.clear()
        _RAY_CACHE[key] = (model.eval(), job)
    model, job = _RAY_CACHE[key]
    yield _STARTED
    yield _worker_clip(item, job, model)


def _import_ray() -> Any:
    try:
        import ray
    except ImportError:
        raise InputError("--engine ray needs Ray: pip install 'mosegpipe[ray]'") from None
    return ray


def check_ray(address: str | None) -> None:
    """Fails before any work when --engine ray cannot run: Ray missing, or a ray:// address without
    Ray Client (its gRPC transport, the extra 'ray[client]')."""
    ray = _import_ray()
    if address is not None and address.strip().startswith("ray://") and not ray.is_initialized():
        try:
            import grpc  # noqa: F401  (what Ray Client connects with)
        except ImportError:
            raise InputError(
                f"--address {address}: a ray:// address needs Ray Client, which is not installed "
                "(no grpc module): pip install 'ray[client]'"
            ) from None


def _ray_failure(ray: Any, exc: BaseException) -> str:
    exceptions = ray.exceptions
    if isinstance(exc, getattr(exceptions, "OutOfMemoryError", ())):
        return "its Ray worker was killed by Ray's memory monitor (out of memory)"
    if isinstance(exc, (exceptions.WorkerCrashedError, getattr(exceptions, "NodeDiedError", ()))):
        return "its Ray worker process died"
    if isinstance(exc, exceptions.RayTaskError):
        return _one_line(exc.cause) if getattr(exc, "cause", None) is not None else "Ray task failed"
    return f"Ray: {_one_line(exc)}"


def _run_ray(
    todo: list[tuple[int, BatchItem]],
    jobs: int | None,
    model: SubspaceNet,
    job: _Job,
    clip_timeout: float | None,
    address: str | None,
    emit: Callable[[int, dict[str, Any]], None],
) -> None:
    """Runs clips as Ray tasks (num_cpus=1, max_retries=0: a failed clip is reported, not retried).

    Uses the Ray instance this process is already connected to, else connects to `address`, else
    starts a new local one with `jobs` CPUs (shut down at the end). At most `jobs` tasks (default: the
    cluster's CPUs) are in flight; a task past clip_timeout (from the moment it started) is
    cancelled with force, which kills its worker.
    """
    ray = _import_ray()
    started = False
    if not ray.is_initialized():
        kwargs: dict[str, Any] = {"include_dashboard": False, "logging_level": logging.WARNING}
        if address is None:
            # A new instance of `jobs` CPUs ("local"): Ray's default would join a running one, where
            # num_cpus is refused.
            kwargs["num_cpus"] = jobs or _usable_cores()
        on_sigterm = _sigterm_handler()
        notice = logging.getLogger(_RAY_AUTH_LOGGER)
        notice.addFilter(_no_auth_notice)
        try:
            ray.init(address="local" if address is None else address, **kwargs)
        except (ConnectionError, ValueError) as exc:  # ValueError: a bad address, Ray Client missing
            raise InputError(f"--address {address}: cannot connect to a Ray cluster ({_one_line(exc)})") from None
        finally:
            notice.removeFilter(_no_auth_notice)
            _restore_sigterm(on_sigterm)  # ray.init puts its own there (sys.exit): the caller's clean-up stays
        started = True
    try:
        limit = jobs or max(1, int(ray.cluster_resources().get("CPU", 1)))
        shared = [secrets.token_hex(8), ray.put((model, job))]  # a key per batch: workers set up once per batch
        remote = ray.remote(_ray_task).options(num_cpus=1, max_retries=0, num_returns="streaming")
        pending = collections.deque(todo)
        # generator -> [index, item, when it started (None: queued)]
        inflight: dict[Any, list[Any]] = {}
        cancelled: list[Any] = []  # waited for at the end: a killed worker writes nothing after the sweep

        def fail(gen: Any, error: str) -> None:
            index, item, t0 = inflight.pop(gen)
            log.warning("%s: %s", item.name, error)
            emit(index, _row(item, status="failed", error=error, seconds=round(time.monotonic() - t0, 3) if t0 else ""))

        try:
            while pending or inflight:
                while pending and len(inflight) < limit:
                    index, item = pending.popleft()
                    inflight[remote.remote(shared, item)] = [index, item, None]
                wait_s = None
                running = [t0 for _, _, t0 in inflight.values() if t0 is not None]
                if clip_timeout is not None and running:
                    wait_s = max(0.0, min(running) + clip_timeout - time.monotonic())
                ready, _ = ray.wait(list(inflight), num_returns=1, timeout=wait_s)
                for gen in ready:
                    try:
                        value = ray.get(next(gen))
                    except StopIteration:
                        fail(gen, "its Ray task ended without a result (cancelled?)")
                        continue
                    except ray.exceptions.RayError as exc:
                        fail(gen, _ray_failure(ray, exc))
                        continue
                    if isinstance(value, str) and value == _STARTED:
                        inflight[gen][2] = time.monotonic()
                    else:
                        index, item, _ = inflight.pop(gen)
                        emit(index, value)
                now = time.monotonic()
                for gen, (_, _, t0) in list(inflight.items()):
                    if clip_timeout is not None and t0 is not None and now - t0 >= clip_timeout:
                        ray.cancel(gen, force=True)  # kills the worker running it
                        cancelled.append(gen)
                        fail(gen, f"timed out after {clip_timeout:g} s (--clip-timeout)")
        except BaseException:
            for gen in inflight:
                with contextlib.suppress(Exception):
                    ray.cancel(gen, force=True)
                    cancelled.append(gen)
            raise
        finally:
            if cancelled and not started:  # a cluster's workers; shutdown ends a local instance's
                with contextlib.suppress(Exception):
                    ray.wait(cancelled, num_returns=len(cancelled), timeout=_RAY_CANCEL_WAIT_S)
    finally:
        if started:
            ray.shutdown()


def _sigterm_handler() -> Any:
    """This thread's SIGTERM handler (None off the main thread, where it cannot be set)."""
    if threading.current_thread() is not threading.main_thread():
        return None
    return signal.getsignal(signal.SIGTERM)


def _restore_sigterm(handler: Any) -> None:
    if handler is not None:
        signal.signal(signal.SIGTERM, handler)


# ---------------------------------------------------------------------------------------------
# The batch
# ---------------------------------------------------------------------------------------------


def _usable_cores() -> int:
    """Cores this process may run on (affinity mask; os.cpu_count where there is none)."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return os.cpu_count() or 1


@contextlib.contextmanager
def _locked(out: Path) -> Iterator[None]:
    """Holds out/.moseg-batch.lock: two batches writing into one folder would undo each other's work."""
    try:
        import fcntl
    except ImportError:  # not POSIX: no lock
        yield
        return
    with open(out / LOCK_FILE, "a+") as fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            raise InputError(f"{out}: another moseg batch is writing into this folder (it holds {LOCK_FILE})") from None
        try:
            yield
        finally:
            with contextlib.suppress(OSError):
                (out / LOCK_FILE).unlink()
            fcntl.flock(fh, fcntl.LOCK_UN)


def _sweep(out: Path) -> None:
    """Removes what a killed batch left: temporary clip folders (.NAME.partial, .NAME.old) and files."""
    try:
        entries = list(out.iterdir())
    except OSError:  # out itself went: nothing to sweep
        return
    for entry in entries:
        n = entry.name
        if not n.startswith(".") or n == LOCK_FILE:
            continue
        if entry.is_dir() and (n.endswith(".partial") or n.endswith(".old") or ".partial." in n):
            shutil.rmtree(entry, ignore_errors=True)
        elif entry.is_file() and ".tmp" in n:
            with contextlib.suppress(OSError):
                entry.unlink()


def _write_summary(out: Path, rows: list[dict[str, Any]], info: dict[str, Any]) -> None:
    buf = _io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(FIELDS))
    writer.writeheader()
    writer.writerows(rows)
    with atomic_write(out / "batch_summary.csv") as tmp:
        Path(tmp).write_text(buf.getvalue(), encoding="utf-8")
    counts = {s: sum(r["status"] == s for r in rows) for s in ("ok", "skipped", "failed")}
    write_json(out / "batch_summary.json", {**info, "counts": counts, "rows": rows})


def run_batch(
    paths: str | Path | Sequence[str | Path],
    out: str | Path,
    cfg: PipelineConfig = PipelineConfig(),
    model: SubspaceNet | None = None,
    rrd: bool = True,
    overwrite: bool = False,
    on_item: Callable[[BatchItem, dict[str, Any]], None] | None = None,
    *,
    jobs: int | None = None,
    engine: str = "process",
    clip_timeout: float | None = None,
    address: str | None = None,
    root: str | Path | None = None,
    checkpoint: str | Path | None = None,
    segment_fn: SegmentFn | None = None,
) -> list[dict[str, Any]]:
    """Segments every clip into `out/<clip>/`, then writes out/batch_summary.{csv,json} atomically.

    Fault isolation: an error in one clip (a MosegError, anything OpenCV, the OS or a bug raises, a
    full disk while writing), a clip past `clip_timeout` or one that kills its worker is a "failed"
    row with a one-line reason, and the other clips go on. KeyboardInterrupt stops the batch (the
    workers are killed); finished clips stay finished and a re-run resumes.

    Resume: a clip whose folder holds summary.json with this batch's config hash is "skipped";
    one with another hash (other options or weights) or none is redone, and so is any clip when
    `overwrite`.

    Args:
        paths: a folder searched for clips (see find_clips; names relative to it), or a list of
            video files and frame folders (see plan_paths; names relative to `root`).
        out: output folder (created).
        cfg: pipeline settings for every clip.
        model: the model; None = `checkpoint`, or the shipped default for cfg.frames. Loaded here
            once, then sent to each worker once.
        rrd: also write a Rerun recording per clip.
        overwrite: redo clips whose outputs already exist (default: resume).
        on_item: called in this process after each clip with its item and row (progress display),
            in the order clips finish.
        jobs: worker processes ("process"), or Ray tasks in flight ("ray"; default: the cluster's
            CPUs). Default: the cores this process may use.
        engine: "process" (this machine), "ray" (a Ray instance or cluster) or "inline" (this
            process, one clip after another: no timeout, no crash isolation).
        clip_timeout: seconds a clip may run (from the moment a worker takes it) before its worker
            is killed and it is a failed row; None = no limit.
        address: Ray cluster address ("auto", "ray://host:10001", ...); None = a local instance,
            unless this process is already connected to Ray (then that one is used).
        root: with a list of paths, the folder the names are relative to.
        checkpoint: a checkpoint file to load when model is None.
        segment_fn: what segments one clip (None = pipeline.segment_clip); a module-level function
            (it is pickled to the workers).

    Returns:
        One row per clip, in search (or given) order: name, status ("ok", "skipped", "failed"), k,
        tracks, seconds, output, error.

    Raises:
        InputError: no clips, a bad engine, jobs or timeout, Ray missing or unreachable (checked
            before `out` is created, as far as it can be without connecting), or another batch
            writing into `out`.
        CheckpointError: no model given and no shipped weights.
    """
    if engine not in ENGINES:
        raise InputError(f"--engine {engine!r}: choose {', '.join(map(repr, ENGINES))}")
    if jobs is not None and jobs < 1:
        raise InputError(f"--jobs {jobs} must be >= 1")
    if clip_timeout is not None and not 0 < clip_timeout <= MAX_CLIP_TIMEOUT_S:  # also refuses NaN
        raise InputError(f"--clip-timeout {clip_timeout:g} must be > 0 and at most {MAX_CLIP_TIMEOUT_S:g} seconds")
    if clip_timeout is not None and engine == "inline":
        raise InputError("--clip-timeout needs worker processes; use --engine process or ray")
    if engine == "ray":
        check_ray(address)
    out = Path(out)
    if isinstance(paths, (str, os.PathLike)):
        if Path(paths).is_dir():
            items = plan(paths, out)
            if not items:
                raise InputError(f"{paths}: no video files or frame folders found")
        elif Path(paths).exists():
            items = plan_paths([paths], out, root)
        else:
            raise InputError(f"{paths}: no such file or folder")
        where = str(paths)
    else:
        items = plan_paths(paths, out, root)
        where = str(root) if root is not None else os.path.commonpath([str(i.source.parent) for i in items])
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is not a folder; choose another --out")
    out.mkdir(parents=True, exist_ok=True)
    if model is None:
        from mosegpipe.inference import load_model

        model = load_model(cfg.frames, checkpoint)
    job = _Job(cfg, rrd, config_hash(cfg, model, rrd), segment_fn or segment_clip)
    rows: list[dict[str, Any] | None] = [None] * len(items)

    def emit(index: int, row: dict[str, Any]) -> None:
        tb = row.pop("_traceback", None)
        for message in row.pop("_warnings", ()):  # a worker's, logged here (see _WorkerLog)
            log.warning("%s: %s", items[index].name, message)
        if row["status"] == "failed":
            if tb is not None:
                log.warning("%s: unexpected %s", items[index].name, row["error"])
                log.debug("%s: %s", items[index].name, tb)
            else:
                log.info("%s: failed: %s", items[index].name, row["error"])  # the row carries it; callers show it
        rows[index] = row
        if on_item is not None:
            on_item(items[index], row)

    with _locked(out):
        _sweep(out)
        todo: list[tuple[int, BatchItem]] = []
        redone = 0
        for index, item in enumerate(items):
            previous = None if overwrite else _previous_summary(item.out_dir / "summary.json")
            if previous is not None and _stored_hash(previous) == job.config_hash:
                emit(
                    index,
                    _row(
                        item, status="skipped", k=previous.get("k", ""), tracks=previous.get("num_tracks_segmented", "")
                    ),
                )
            else:
                redone += previous is not None
                todo.append((index, item))
        if redone:
            log.warning("%d clips done earlier with other settings or weights are redone", redone)
        workers = min(jobs or _usable_cores(), len(todo)) if todo else 0
        try:
            if todo and engine == "inline":
                for index, item in todo:
                    emit(index, process_clip(item, job, model))
            elif todo and engine == "process":
                _run_process(todo, workers, model, job, clip_timeout, emit)
            elif todo:
                _run_ray(todo, min(jobs, len(todo)) if jobs else None, model, job, clip_timeout, address, emit)
        finally:
            # A worker killed by --clip-timeout, Ctrl-C or SIGTERM left its clip's .NAME.partial (the
            # workers are gone by now); an interrupted batch leaves nothing half-written either.
            _sweep(out)
        done = [r for r in rows if r is not None]
        if len(done) != len(items):
            raise RuntimeError(f"batch bug: {len(items) - len(done)} clips got no row")
        _write_summary(
            out,
            done,
            {
                "root": where,
                "engine": engine,
                "jobs": workers if engine != "ray" else jobs,
                "config_hash": job.config_hash,
            },
        )
    return done
