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
complete (outputs.OutputDir), and its summary.json records `batch.config_hash`, a hash of every
setting that changes the outputs (PipelineConfig, the model's weights, the recording flag). A re-run
skips the clips whose folder holds summary.json with the same hash and redoes the rest, so a batch
killed at any moment loses nothing and a re-run with other options redoes what they change.
"""

from __future__ import annotations

import contextlib
import csv
import io as _io
import logging
import os
import shutil
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

from mosegpipe.apps.batch.plan import (
    FIELDS,
    IMAGE_EXTENSIONS,
    MAX_NAME_BYTES,
    SUMMARY_FILES,
    VIDEO_EXTENSIONS,
    BatchItem,
    Job,
    SegmentFn,
    config_hash,
    find_clips,
    model_digest,
    output_name,
    plan,
    plan_paths,
    previous_summary,
    process_clip,
    stored_hash,
    summary_row,
    usable_cores,
)
from mosegpipe.apps.batch.pool import MAX_WORKER_WARNINGS, inline_clip, run_process
from mosegpipe.apps.batch.ray_engine import check_ray, run_ray
from mosegpipe.embed.model import SubspaceNet
from mosegpipe.errors import InputError
from mosegpipe.io.locks import exclusive_lock
from mosegpipe.io.read import atomic_write, write_json
from mosegpipe.pipeline import PipelineConfig, segment_clip
from mosegpipe.settings import MAX_CLIP_TIMEOUT_S
from mosegpipe.types import ENGINES

log = logging.getLogger("mosegpipe.apps.batch.run")

__all__ = [
    "FIELDS",
    "IMAGE_EXTENSIONS",
    "LOCK_FILE",
    "MAX_NAME_BYTES",
    "MAX_WORKER_WARNINGS",
    "SUMMARY_FILES",
    "VIDEO_EXTENSIONS",
    "BatchItem",
    "SegmentFn",
    "check_ray",
    "config_hash",
    "find_clips",
    "model_digest",
    "output_name",
    "plan",
    "plan_paths",
    "process_clip",
    "run_batch",
]

LOCK_FILE = ".moseg-batch.lock"


@contextlib.contextmanager
def _locked(out: Path) -> Iterator[None]:
    """Holds out/.moseg-batch.lock: two batches writing into one folder would undo each other's work."""
    with exclusive_lock(
        out / LOCK_FILE, f"{out}: another moseg batch is writing into this folder (it holds {LOCK_FILE})"
    ):
        yield


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
    _check_options(engine, jobs, clip_timeout, address)
    out = Path(out)
    items, where = _plan_batch(paths, out, root)
    if model is None:
        from mosegpipe.embed.numpy_net import load_model

        model = load_model(cfg.frames, checkpoint)
    job = Job(cfg, rrd, config_hash(cfg, model, rrd), segment_fn or segment_clip)
    return _run_items(items, out, where, job, model, overwrite, on_item, engine, jobs, clip_timeout, address)


def _check_options(engine: str, jobs: int | None, clip_timeout: float | None, address: str | None) -> None:
    """InputError for a bad engine, jobs or timeout, or Ray missing (before anything is written)."""
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


def _plan_batch(
    paths: str | Path | Sequence[str | Path], out: Path, root: str | Path | None
) -> tuple[list[BatchItem], str]:
    """The clips and the folder their names are relative to (summary's "root"); creates `out`."""
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
    return items, where


def _to_do(
    items: list[BatchItem], overwrite: bool, job: Job, emit: Callable[[int, dict[str, Any]], None]
) -> list[tuple[int, BatchItem]]:
    """The clips to run: those done earlier with this config hash are emitted as "skipped" rows."""
    todo: list[tuple[int, BatchItem]] = []
    redone = 0
    for index, item in enumerate(items):
        previous = None if overwrite else previous_summary(item.out_dir / "summary.json")
        if previous is not None and stored_hash(previous) == job.config_hash:
            emit(
                index,
                summary_row(
                    item, status="skipped", k=previous.get("k", ""), tracks=previous.get("num_tracks_segmented", "")
                ),
            )
        else:
            redone += previous is not None
            todo.append((index, item))
    if redone:
        log.warning("%d clips done earlier with other settings or weights are redone", redone)
    return todo


def _run_items(
    items: list[BatchItem],
    out: Path,
    where: str,
    job: Job,
    model: SubspaceNet,
    overwrite: bool,
    on_item: Callable[[BatchItem, dict[str, Any]], None] | None,
    engine: str,
    jobs: int | None,
    clip_timeout: float | None,
    address: str | None,
) -> list[dict[str, Any]]:
    """run_batch once the clips are planned and the model loaded: under out's lock, the clips not
    done yet on `engine`, then the summary files; the rows in the clips' order."""
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
        todo = _to_do(items, overwrite, job, emit)
        workers = min(jobs or usable_cores(), len(todo)) if todo else 0
        try:
            if todo and engine == "inline":
                for index, item in todo:
                    emit(index, inline_clip(item, job, model))
            elif todo and engine == "process":
                run_process(todo, workers, model, job, clip_timeout, emit)
            elif todo:
                run_ray(todo, min(jobs, len(todo)) if jobs else None, model, job, clip_timeout, address, emit)
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
