"""A batch's plan: the clips under a folder (or given), their output folders' names, the hash of
the settings that resume compares, and one clip's run into its folder (process_clip), which every
engine of mosegpipe.apps.batch.run calls."""

from __future__ import annotations

import hashlib
import json
import logging
import os
import time
import traceback
from collections.abc import Callable, Iterable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from mosegpipe.apps.outputs import SUMMARY_SCHEMA, write_clip_outputs
from mosegpipe.embed.model import SubspaceNet
from mosegpipe.errors import InputError, MosegError
from mosegpipe.io.read import IMAGE_SUFFIXES
from mosegpipe.pipeline import PipelineConfig, segment_clip

log = logging.getLogger("mosegpipe.apps.batch.run")

VIDEO_EXTENSIONS = {".mp4", ".avi", ".mov", ".mkv", ".webm", ".m4v", ".mpg", ".mpeg", ".wmv"}
IMAGE_EXTENSIONS = IMAGE_SUFFIXES
SUMMARY_FILES = ("batch_summary.csv", "batch_summary.json")
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
    Hidden entries (names starting with "."), the folders in `exclude` (e.g. the batch output
    folder, when it lies under root) and moseg's own output folders (`moseg_output`: their masks/,
    overlay/ and overlay.mp4 are no clips) are skipped. Symbolic links are followed, but each folder is
    searched once (by its real path): a link back to a folder above it (a loop) or to one searched
    already is skipped with a warning, as is a link that points nowhere.

    Args:
        root: the folder to search.
        exclude: folders not to descend into.

    Returns:
        Paths of video files and frame folders, in sorted walk order.

    Raises:
        InputError: root is not a folder, or is an output folder of moseg.
    """
    root = Path(root)
    if not root.is_dir():
        raise InputError(f"{root}: not a folder")
    if moseg_output(root):
        raise InputError(f"{root}: an output folder of moseg, not a folder of clips")
    skip = {p.resolve() for p in exclude}
    searched: dict[Path, Path] = {root.resolve(): root}  # real path -> the path it was searched under

    def walk(folder: Path) -> Iterator[Path]:
        if moseg_output(folder):
            log.warning("%s: an output folder of moseg, not a clip; skipped", folder)
            return
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


def moseg_output(folder: Path) -> bool:
    """Whether `folder` is an output folder of moseg: a run's (summary.json of our schema) or a batch's
    (batch_summary.json)."""
    if (folder / SUMMARY_FILES[1]).is_file():
        return True
    try:
        with open(folder / "summary.json", encoding="utf-8", errors="replace") as fh:
            head = fh.read(4096)  # "schema" is the first key
    except OSError:  # none there (or unreadable: then not ours to tell)
        return False
    return f'"schema": "{SUMMARY_SCHEMA.split("/")[0]}/' in head


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


def previous_summary(path: Path) -> dict[str, Any] | None:
    """A completed clip's summary.json, or None when absent or unreadable (then the clip is redone)."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def stored_hash(summary: dict[str, Any]) -> str | None:
    info = summary.get("batch")
    return info.get("config_hash") if isinstance(info, dict) else None


# ---------------------------------------------------------------------------------------------
# One clip (runs in a worker process, a Ray worker or inline)
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Job:
    """What every clip of one batch shares (pickled once per worker)."""

    cfg: PipelineConfig
    rrd: bool
    config_hash: str
    segment_fn: SegmentFn = field(default=segment_clip)


def summary_row(item: BatchItem, **values: Any) -> dict[str, Any]:
    row: dict[str, Any] = {f: "" for f in FIELDS}
    row.update(name=item.name, output=item.out_dir.name, **values)
    return row


def one_line(exc: BaseException) -> str:
    message = " ".join(str(exc).split())[:300]
    return f"{type(exc).__name__}: {message}" if message else type(exc).__name__


def process_clip(item: BatchItem, job: Job, model: SubspaceNet) -> dict[str, Any]:
    """Segments one clip and writes its folder atomically; every failure becomes a "failed" row.

    Args:
        item: the clip and its output folder.
        job: the batch's settings (pipeline config, recording flag, config hash, segment function).
        model: the model, in eval mode.

    Returns:
        The row (FIELDS), plus "_traceback" for an unexpected exception (logged by the caller).
    """
    t0 = time.perf_counter()
    row = summary_row(item)
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
        row.update(status="failed", error=f"cannot write its outputs: {exc.strerror or one_line(exc)}{where}")
    except Exception as exc:  # fault isolation: one broken clip must not stop the batch
        row.update(status="failed", error=one_line(exc), _traceback=traceback.format_exc())
    row["seconds"] = round(time.perf_counter() - t0, 3)
    return row


# ---------------------------------------------------------------------------------------------
# The batch
# ---------------------------------------------------------------------------------------------


def usable_cores() -> int:
    """Cores this process may run on (affinity mask; os.cpu_count where there is none)."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return os.cpu_count() or 1
