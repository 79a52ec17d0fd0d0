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
from mosegpipe.io import atomic_write, write_json
from mosegpipe.model import SubspaceNet
from mosegpipe.pipeline import PipelineConfig, segment_clip, write_clip_outputs

log = logging.getLogger(__name__)

VIDEO_EXTENSIONS = {".mp4", ".avi", ".mov", ".mkv", ".webm", ".m4v", ".mpg", ".mpeg", ".wmv"}
IMAGE_EXTENSIONS = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff"}


@dataclass(frozen=True)
class BatchItem:
    """One clip found under the input folder and where its outputs go."""

    source: Path
    name: str
    out_dir: Path


def find_clips(root: str | Path) -> list[Path]:
    """Video files and frame folders (folders holding at least one image) under `root`, sorted.

    A frame folder's sub-folders are searched too; a video inside a frame folder is listed as well.
    """
    root = Path(root)
    if not root.is_dir():
        raise InputError(f"{root}: not a folder")
    found: list[Path] = []

    def walk(folder: Path) -> Iterator[Path]:
        entries = sorted(folder.iterdir())
        if any(e.is_file() and e.suffix.lower() in IMAGE_EXTENSIONS for e in entries):
            yield folder
        for e in entries:
            if e.name.startswith("."):
                continue
            if e.is_file() and e.suffix.lower() in VIDEO_EXTENSIONS:
                yield e
            elif e.is_dir():
                yield from walk(e)

    found.extend(walk(root))
    return found


def plan(root: str | Path, out: str | Path) -> list[BatchItem]:
    """Pairs each clip under root with an output folder named after its relative path."""
    root, out = Path(root), Path(out)
    items = []
    for src in find_clips(root):
        rel = src.relative_to(root)
        name = "." if rel == Path(".") else str(rel)
        safe = "_root" if name == "." else name.replace("/", "__")
        items.append(BatchItem(src, name, out / safe))
    return items


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

    Args:
        root: folder searched for clips (see find_clips).
        out: output folder (created).
        cfg: pipeline settings for every clip.
        model: the model (loaded once); None = the shipped default for cfg.frames.
        rrd: also write a Rerun recording per clip.
        overwrite: redo clips whose outputs already exist (default: skip them, i.e. resume).
        on_item: called after each clip with its item and row (for progress display).

    Returns:
        One row per clip: name, status ("ok", "skipped", "failed"), k, tracks, seconds, error.
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
        row: dict[str, Any] = {"name": item.name, "status": "", "k": "", "tracks": "", "seconds": "", "error": ""}
        done = item.out_dir / "summary.json"
        if done.exists() and not overwrite:
            previous = json.loads(done.read_text())
            row.update(status="skipped", k=previous.get("k", ""), tracks=previous.get("num_tracks_segmented", ""))
        else:
            t0 = time.perf_counter()
            try:
                result = segment_clip(item.source, cfg, model)
                summary = write_clip_outputs(result, item.out_dir, cfg, overwrite=True, rrd=rrd)
                row.update(status="ok", k=summary["k"], tracks=summary["num_tracks_segmented"])
            except MosegError as exc:
                row.update(status="failed", error=str(exc))
                log.warning("%s: %s", item.name, exc)
            row["seconds"] = round(time.perf_counter() - t0, 3)
        rows.append(row)
        if on_item is not None:
            on_item(item, row)
    buf = _io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(rows[0].keys()))
    writer.writeheader()
    writer.writerows(rows)
    with atomic_write(Path(out) / "batch_summary.csv") as tmp:
        Path(tmp).write_text(buf.getvalue())
    write_json(Path(out) / "batch_summary.json", {"root": str(root), "rows": rows})
    return rows
