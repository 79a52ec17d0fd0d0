"""Folders of clips: find every clip, segment each into its own output folder, summarise.

Fault isolation: a clip that fails is recorded with its one-line reason and the rest go on.
Resume: each clip's output folder appears atomically (pipeline._OutputDir), so a folder holding
summary.json is complete and is skipped on a re-run.
"""

from __future__ import annotations

import csv
import io as _io
import json
import logging
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mosegpipe.errors import InputError, MosegError
from mosegpipe.io import IMAGE_SUFFIXES, atomic_write, write_json
from mosegpipe.model import SubspaceNet
from mosegpipe.outputs import write_clip_outputs
from mosegpipe.pipeline import PipelineConfig, segment_clip

log = logging.getLogger(__name__)

VIDEO_EXTENSIONS = {".mp4", ".avi", ".mov", ".mkv", ".webm", ".m4v", ".mpg", ".mpeg", ".wmv"}
IMAGE_EXTENSIONS = IMAGE_SUFFIXES


@dataclass(frozen=True)
class BatchItem:
    """One clip found under the input folder and where its outputs go."""

    source: Path
    name: str
    out_dir: Path


def find_clips(root: str | Path, exclude: tuple[Path, ...] = ()) -> list[Path]:
    """Video files and frame folders (folders holding at least one image) under `root`, sorted.

    A frame folder's sub-folders are searched too; a video inside a frame folder is listed as well.
    Hidden entries (names starting with ".") and the folders in `exclude` (e.g. the batch output
    folder, when it lies under root) are skipped.

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

    def walk(folder: Path) -> Iterator[Path]:
        entries = sorted(folder.iterdir())
        if any(e.is_file() and e.suffix.lower() in IMAGE_EXTENSIONS for e in entries):
            yield folder
        for e in entries:
            if e.name.startswith("."):
                continue
            if e.is_file() and e.suffix.lower() in VIDEO_EXTENSIONS:
                yield e
            elif e.is_dir() and e.resolve() not in skip:
                yield from walk(e)

    return list(walk(root))


def plan(root: str | Path, out: str | Path) -> list[BatchItem]:
    """Pairs each clip under root with an output folder named after its path relative to root.

    "a/b.avi" goes to out/"a__b.avi", a frame folder "a/c" to out/"a__c", and images lying in root
    itself to out/"_root".
    """
    root, out = Path(root), Path(out)
    items = []
    for src in find_clips(root, exclude=(out,)):
        rel = src.relative_to(root)
        name = "." if rel == Path(".") else rel.as_posix()
        safe = "_root" if name == "." else name.replace("/", "__")
        items.append(BatchItem(src, name, out / safe))
    return items


def _previous_summary(path: Path) -> dict[str, Any] | None:
    """A completed clip's summary.json, or None when absent or unreadable (then the clip is redone)."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def run_batch(
    root: str | Path,
    out: str | Path,
    cfg: PipelineConfig = PipelineConfig(),
    model: SubspaceNet | None = None,
    rrd: bool = True,
    overwrite: bool = False,
    on_item: Callable[[BatchItem, dict[str, Any]], None] | None = None,
) -> list[dict[str, Any]]:
    """Segments every clip under `root` into `out/<clip>/`, then writes out/batch_summary.{csv,json}.

    Fault isolation: any error in one clip (a MosegError, or anything else OpenCV, the OS or a bug
    raises) is recorded as a "failed" row with a one-line reason, and the next clip goes on.
    KeyboardInterrupt stops the batch; finished clips stay finished and a re-run resumes.

    Args:
        root: folder searched for clips (see find_clips).
        out: output folder (created).
        cfg: pipeline settings for every clip.
        model: the model (loaded once); None = the shipped default for cfg.frames.
        rrd: also write a Rerun recording per clip.
        overwrite: redo clips whose outputs already exist (default: skip them, i.e. resume).
        on_item: called after each clip with its item and row (for progress display).

    Returns:
        One row per clip: name, status ("ok", "skipped", "failed"), k, tracks, seconds, output, error.

    Raises:
        InputError: root is not a folder or holds no clips.
        CheckpointError: no model given and no shipped weights.
    """
    items = plan(root, out)
    if not items:
        raise InputError(f"{root}: no video files or frame folders found")
    Path(out).mkdir(parents=True, exist_ok=True)
    if model is None:
        from mosegpipe.pipeline import load_model

        model = load_model(cfg.frames)
    rows: list[dict[str, Any]] = []
    for item in items:
        row: dict[str, Any] = {
            "name": item.name, "status": "", "k": "", "tracks": "", "seconds": "", "output": item.out_dir.name, "error": "",
        }
        previous = None if overwrite else _previous_summary(item.out_dir / "summary.json")
        if previous is not None:
            row.update(status="skipped", k=previous.get("k", ""), tracks=previous.get("num_tracks_segmented", ""))
        else:
            t0 = time.perf_counter()
            try:
                result = segment_clip(item.source, cfg, model)
                # The folder is ours: complete (skipped above) or left by an older run; replace it.
                summary = write_clip_outputs(result, item.out_dir, cfg, overwrite=True, rrd=rrd)
                row.update(status="ok", k=summary["k"], tracks=summary["num_tracks_segmented"])
            except MosegError as exc:
                row.update(status="failed", error=str(exc))
                log.info("%s: failed: %s", item.name, exc)  # the row carries it; callers show it
            except Exception as exc:  # fault isolation: one broken clip must not stop the batch
                message = " ".join(str(exc).split())[:300]
                row.update(status="failed", error=f"{type(exc).__name__}: {message}")
                log.warning("%s: unexpected %s: %s", item.name, type(exc).__name__, message)
                log.debug("%s: traceback", item.name, exc_info=True)
            row["seconds"] = round(time.perf_counter() - t0, 3)
        rows.append(row)
        if on_item is not None:
            on_item(item, row)
    buf = _io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(rows[0].keys()))
    writer.writeheader()
    writer.writerows(rows)
    with atomic_write(Path(out) / "batch_summary.csv") as tmp:
        Path(tmp).write_text(buf.getvalue(), encoding="utf-8")
    counts = {s: sum(r["status"] == s for r in rows) for s in ("ok", "skipped", "failed")}
    write_json(Path(out) / "batch_summary.json", {"root": str(root), "counts": counts, "rows": rows})
    return rows
