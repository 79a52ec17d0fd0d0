"""The "process" engine of mosegpipe.apps.batch.run: clips on a pool of local worker processes, each with one
thread and the model, rebuilt after a worker dies or a clip times out; the warnings a worker logs
go back with its clip's row."""

from __future__ import annotations

import collections
import concurrent.futures as cf
import contextlib
import logging
import os
import queue
import signal
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

from mosegpipe.apps.batch.plan import BatchItem, Job, one_line, process_clip, summary_row
from mosegpipe.embed.model import SubspaceNet
from mosegpipe.runtime import LATER_IMPORTS

log = logging.getLogger("mosegpipe.apps.batch.run")


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


def keep_worker_logs() -> None:
    """Sends this worker's warnings (Python's `warnings` too) to _WORKER_LOG alone, not to stderr."""
    root = logging.getLogger()
    for handler in list(root.handlers):
        root.removeHandler(handler)
    root.addHandler(_WORKER_LOG)
    root.setLevel(logging.WARNING)
    logging.captureWarnings(True)


def worker_clip(item: BatchItem, job: Job, model: SubspaceNet) -> dict[str, Any]:
    """process_clip in a worker: the row carries the clip's warnings as "_warnings"."""
    _WORKER_LOG.take()  # what the worker logged before this clip (its set-up) is not the clip's
    row = process_clip(item, job, model)
    warnings = _WORKER_LOG.take()
    if warnings:
        row["_warnings"] = warnings
    return row


def inline_clip(item: BatchItem, job: Job, model: SubspaceNet) -> dict[str, Any]:
    """process_clip in this process (engine "inline"), its warnings carried in the row as a worker's are, so
    that they are logged under the clip's name too; meanwhile the handlers of this process take the rest."""
    caught = _WorkerLog()
    root = logging.getLogger()
    handlers = list(root.handlers)

    def not_a_warning(record: logging.LogRecord) -> bool:
        return record.levelno < logging.WARNING

    for handler in handlers:
        handler.addFilter(not_a_warning)
    root.addHandler(caught)
    try:
        row = process_clip(item, job, model)
    finally:
        root.removeHandler(caught)
        for handler in handlers:
            handler.removeFilter(not_a_warning)
    warnings = caught.take()
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


def _init_worker(model: SubspaceNet, job: Job, ready: Any, lifeline: Any) -> None:
    """Pool initializer: one thread, quiet decoders, Ctrl-C left to the parent, the model kept."""
    from mosegpipe.runtime import import_now, quiet_native_logs, set_threads

    threading.Thread(target=_watch_parent, args=(lifeline,), name="moseg-lifeline", daemon=True).start()
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent stops the pool on Ctrl-C
    keep_worker_logs()
    quiet_native_logs()
    set_threads(1)
    import_now(*LATER_IMPORTS)  # before the first clip: --clip-timeout does not count them
    model.eval()
    _WORKER.update(model=model, job=job)
    ready.put(os.getpid())


def _pool_task(item: BatchItem) -> dict[str, Any]:
    return worker_clip(item, _WORKER["job"], _WORKER["model"])


def _ping() -> int:
    return os.getpid()


def mp_context() -> Any:
    import multiprocessing as mp

    if "forkserver" in mp.get_all_start_methods():
        ctx = mp.get_context("forkserver")
        # Workers fork from a server that imported torch and the pipeline once.
        ctx.set_forkserver_preload(["mosegpipe.apps.batch.run", *LATER_IMPORTS])
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


def _start_forkserver(ctx: Any) -> None:
    """Starts multiprocessing's forkserver (once per process; nothing for another start method) with Ctrl-C
    ignored, which it passes to every worker it forks from birth. Ctrl-C reaches the terminal's whole process
    group: a worker it reached before `_init_worker` set it aside printed its traceback after the batch's
    error line (a mask of blocked signals would not do: the forkserver unblocks SIGINT for its children).
    A Ctrl-C in the milliseconds of the start is lost."""
    if ctx.get_start_method() != "forkserver":
        return
    from multiprocessing import forkserver

    if threading.current_thread() is not threading.main_thread():  # signal handlers are the main thread's
        forkserver.ensure_running()
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        forkserver.ensure_running()
    finally:
        signal.signal(signal.SIGINT, previous)


@contextlib.contextmanager
def stops_deferred() -> Iterator[None]:
    """Ctrl-C and SIGTERM held back while the pool's processes start, then delivered (to the command's own
    handlers). Interrupted half way through a worker's start, the batch went away with that worker unrecorded
    (not killed), and the worker printed a traceback when it could not find the queue the batch had removed.
    Only in the main thread, where Python runs signal handlers; elsewhere nothing is held back."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    received: list[int] = []

    def hold(signum: int, frame: Any) -> None:
        received.append(signum)

    previous = {signum: signal.signal(signum, hold) for signum in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        if received:
            signal.raise_signal(received[0])


class WorkerPool:
    """A ProcessPoolExecutor whose workers are all started and ready (so deadlines count clip time)."""

    def __init__(self, workers: int, model: SubspaceNet, job: Job, startup_timeout: float = 600.0) -> None:
        ctx = mp_context()
        self.pids: set[int] = set()
        try:
            # The queue's lock starts the resource tracker, the pings the workers.
            with _hangup_blocked(), stops_deferred():
                _start_forkserver(ctx)
                self.ready = ctx.Queue()
                # Only this process holds the sending end: when it dies, however it dies, the workers see EOF.
                lifeline, self.lifeline = ctx.Pipe(duplex=False)
                self.executor = cf.ProcessPoolExecutor(
                    workers, mp_context=ctx, initializer=_init_worker, initargs=(model, job, self.ready, lifeline)
                )
                pings = [self.executor.submit(_ping) for _ in range(workers)]  # one submit starts one worker
            deadline = time.monotonic() + startup_timeout
            while len(self.pids) < workers:
                try:
                    self.pids.add(self.ready.get(timeout=0.2))
                except queue.Empty:
                    failed = [e for f in pings if f.done() and (e := f.exception()) is not None]
                    if failed:
                        raise RuntimeError(
                            f"batch worker processes failed to start ({one_line(failed[0])}); see the "
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
        """Kills every worker (a hung one included) and shuts the executor down without waiting (also a pool
        whose start failed half way)."""
        if not hasattr(self, "executor"):
            with contextlib.suppress(Exception):
                self.lifeline.close()
            return
        procs = list((getattr(self.executor, "_processes", None) or {}).values())
        for p in procs:
            with contextlib.suppress(Exception):
                p.kill()
        # The executor's manager thread closes its wake-up pipe once it sees the workers gone, while the
        # interpreter's exit writes to that pipe: the two raced ("Exception ignored ... Bad file descriptor"
        # after the error line). The thread is let finish first (shutdown forgets it: taken before).
        manager = getattr(self.executor, "_executor_manager_thread", None)
        self.executor.shutdown(wait=False, cancel_futures=True)
        self.lifeline.close()
        for p in procs:
            with contextlib.suppress(Exception):
                p.join(5)
        if manager is not None and manager is not threading.current_thread():
            manager.join(5)
        with contextlib.suppress(Exception):
            self.ready.close()
            self.ready.join_thread()


_InFlight = dict[cf.Future[dict[str, Any]], tuple[int, BatchItem, float, bool]]
"""A pool's clips in flight: future -> (index, item, when it was submitted, whether it runs alone)."""


def run_process(
    todo: list[tuple[int, BatchItem]],
    jobs: int,
    model: SubspaceNet,
    job: Job,
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
        pool = WorkerPool(max(1, min(jobs, len(pending) + len(suspects))), model, job)
        inflight: _InFlight = {}
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
                            summary_row(
                                item, status="failed", error=one_line(exc), seconds=round(time.monotonic() - t0, 3)
                            ),
                        )
                if broken:
                    _judge_broken_pool(pool, inflight, suspects, emit)
                    inflight.clear()
                    break
                now = time.monotonic()
                late = [v for v in inflight.values() if clip_timeout is not None and now - v[2] >= clip_timeout]
                if late:
                    _time_out(late, inflight, pending, clip_timeout, now, emit)
                    inflight.clear()
                    break
        finally:
            pool.kill()


def _judge_broken_pool(
    pool: WorkerPool,
    inflight: _InFlight,
    suspects: collections.deque[tuple[int, BatchItem]],
    emit: Callable[[int, dict[str, Any]], None],
) -> None:
    """After a worker died: the clips that finished are emitted; a clip that ran alone is the one that
    killed its worker (a failed row); more than one are suspects, to be re-run one at a time."""
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
        emit(index, summary_row(item, status="failed", error=reason, seconds=round(time.monotonic() - t0, 3)))
    else:
        log.info("a worker died with %d clips in flight; re-running them one at a time", len(lost))
        suspects.extendleft((index, item) for index, item, _ in reversed(lost))


def _time_out(
    late: list[tuple[int, BatchItem, float, bool]],
    inflight: _InFlight,
    pending: collections.deque[tuple[int, BatchItem]],
    clip_timeout: float | None,
    now: float,
    emit: Callable[[int, dict[str, Any]], None],
) -> None:
    """The clips past --clip-timeout are failed rows; the others in flight, killed with them, are redone."""
    for index, item, t0, _ in late:
        log.warning("%s: timed out after %g s", item.name, clip_timeout)
        emit(
            index,
            summary_row(
                item,
                status="failed",
                error=f"timed out after {clip_timeout:g} s (--clip-timeout)",
                seconds=round(now - t0, 3),
            ),
        )
    late_ids = {v[0] for v in late}
    innocent = sorted((v for v in inflight.values() if v[0] not in late_ids), key=lambda v: v[0])
    pending.extendleft((index, item) for index, item, _, _ in reversed(innocent))  # killed with it: redo
