"""The "ray" engine of mosegpipe.apps.batch.run: clips as Ray tasks on a local Ray instance or a cluster."""

from __future__ import annotations

import collections
import contextlib
import logging
import secrets
import signal
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

from mosegpipe.apps.batch.plan import BatchItem, Job, one_line, summary_row, usable_cores
from mosegpipe.apps.batch.pool import keep_worker_logs, worker_clip
from mosegpipe.embed.model import SubspaceNet
from mosegpipe.errors import InputError

log = logging.getLogger("mosegpipe.apps.batch.run")


_RAY_CACHE: dict[str, tuple[SubspaceNet, Job]] = {}
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
        from mosegpipe.runtime import LATER_IMPORTS, import_now, quiet_native_logs, set_threads

        keep_worker_logs()
        quiet_native_logs()
        set_threads(1)
        import_now(*LATER_IMPORTS)  # before the first clip: --clip-timeout does not count them
        model, job = ray.get(shared[1])
        _RAY_CACHE.clear()
        _RAY_CACHE[key] = (model.eval(), job)
    model, job = _RAY_CACHE[key]
    yield _STARTED
    yield worker_clip(item, job, model)


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
        return one_line(exc.cause) if getattr(exc, "cause", None) is not None else "Ray task failed"
    return f"Ray: {one_line(exc)}"


def _init_ray(ray: Any, jobs: int | None, address: str | None) -> None:
    """Connects to `address`, or starts a local Ray instance of `jobs` CPUs (None: the usable cores)."""
    kwargs: dict[str, Any] = {"include_dashboard": False, "logging_level": logging.WARNING}
    if address is None:
        # A new instance of `jobs` CPUs ("local"): Ray's default would join a running one, where
        # num_cpus is refused.
        kwargs["num_cpus"] = jobs or usable_cores()
    on_sigterm = _sigterm_handler()
    notice = logging.getLogger(_RAY_AUTH_LOGGER)
    notice.addFilter(_no_auth_notice)
    try:
        ray.init(address="local" if address is None else address, **kwargs)
    except (ConnectionError, ValueError) as exc:  # ValueError: a bad address, Ray Client missing
        raise InputError(f"--address {address}: cannot connect to a Ray cluster ({one_line(exc)})") from None
    finally:
        notice.removeFilter(_no_auth_notice)
        _restore_sigterm(on_sigterm)  # ray.init puts its own there (sys.exit): the caller's clean-up stays


def run_ray(
    todo: list[tuple[int, BatchItem]],
    jobs: int | None,
    model: SubspaceNet,
    job: Job,
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
        _init_ray(ray, jobs, address)
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
            seconds = round(time.monotonic() - t0, 3) if t0 else ""
            emit(index, summary_row(item, status="failed", error=error, seconds=seconds))

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
