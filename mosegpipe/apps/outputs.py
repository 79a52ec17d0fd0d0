"""Writing results: any pipeline result into an output folder, built atomically.

Each folder is built under a temporary name and renamed when complete, so a failure never leaves half
an output behind; `check_output_dir` lets a caller refuse an occupied folder before spending time on
segmentation. One summary builder per kind of result (clip, pair, video); the folder layout and the
summary.json schema are in docs/OUTPUTS.md; each summary records its source's identity (absolute
path and a fingerprint, mosegpipe.io.provenance) so that `moseg replay` reads the same input.
"""

from __future__ import annotations

import shutil
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from mosegpipe import __version__
from mosegpipe.colours import mask_palette
from mosegpipe.errors import InputError, OutputExistsError
from mosegpipe.io.provenance import source_identity
from mosegpipe.io.read import write_jpeg, write_json, write_npz, write_palette_png, write_video
from mosegpipe.masks import overlay_with_legend
from mosegpipe.pipeline import (
    ClipResult,
    PairResult,
    PipelineConfig,
    TracksResult,
)
from mosegpipe.viz import k_statement

if TYPE_CHECKING:
    pass

SUMMARY_SCHEMA = "mosegpipe.summary/2"
"""Version 2: mask value = motion label (0 = the world), 255 = unknown (version 1: label + 1, 0 unknown)."""
FALLBACK_FPS = 10.0
"""The overlay video's rate when the source has none (frame folders)."""


def check_output_dir(out_dir: str | Path, overwrite: bool) -> None:
    """Fails early when `out_dir` cannot receive a run's outputs.

    An absent or empty folder is fine. A folder holding files is refused unless `overwrite`, and
    even then only when it is a moseg output folder (holds summary.json): --overwrite never deletes
    a folder of other files (an input folder given as --out by mistake, a home directory).

    Raises:
        OutputExistsError: it holds results and overwrite is False.
        InputError: it is a file, or it holds files that are not a moseg output.
    """
    out = Path(out_dir)
    if not out.exists():
        return
    if not out.is_dir():
        raise InputError(f"{out}: exists and is not a folder; choose another --out")
    if not any(out.iterdir()):
        return
    if not (out / "summary.json").is_file():  # first: --overwrite would not replace it either
        raise InputError(f"{out}: holds files but no summary.json, so it is not a moseg output; refusing to replace it")
    if not overwrite:
        raise OutputExistsError(f"{out}: already holds results; pass --overwrite to replace them")


class OutputDir:
    """Builds an output folder under a temporary name; renames it into place only when complete.

    The temporary folder `.NAME.partial` sits beside the final one (same file system, so the rename
    is atomic). On an exception (KeyboardInterrupt included) it is removed and the final folder is
    left as it was; on success an existing final folder is replaced (see check_output_dir).
    """

    def __init__(self, out_dir: Path, overwrite: bool) -> None:
        check_output_dir(out_dir, overwrite)
        # absolute(): "." or "" has no name to build the temporary sibling from.
        self.final = Path(out_dir).absolute()
        self.tmp = self.final.with_name(f".{self.final.name}.partial")

    def __enter__(self) -> Path:
        if self.tmp.exists():
            shutil.rmtree(self.tmp)
        self.tmp.mkdir(parents=True)
        return self.tmp

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc_type is not None:
            shutil.rmtree(self.tmp, ignore_errors=True)
            return
        if self.final.exists():
            old = self.final.with_name(f".{self.final.name}.old")
            shutil.rmtree(old, ignore_errors=True)
            self.final.rename(old)
            self.tmp.rename(self.final)
            shutil.rmtree(old, ignore_errors=True)
        else:
            self.tmp.rename(self.final)


def write_mask_png(path: Path, mask: npt.NDArray[np.uint8]) -> None:
    """One mask PNG of an output folder (every kind): the values as palette indices, coloured as the
    overlays and the recordings colour them (colours.mask_palette())."""
    write_palette_png(path, mask, mask_palette())


def _write_masks_and_overlays(
    folder: Path,
    indices: list[int],
    images: Any,
    masks: Any,
    xys: list[npt.NDArray[np.float32]],
    labels: npt.NDArray[np.int64],
    fps: float | None = None,
    overlays_too: bool = True,
    unknown: str = "unknown",
) -> None:
    """masks/NNNNNN.png (palette) and overlay/NNNNNN.jpg for each image, named by its index in the source;
    with `fps` (0.0 = unknown), the overlays also as overlay.mp4 (H.264, as whole videos write it). Without
    `overlays_too`, the masks only. The legend names 255 `unknown`."""
    (folder / "masks").mkdir()
    if not overlays_too:
        for index, mask in zip(indices, masks):
            write_mask_png(folder / "masks" / f"{index:06d}.png", mask)
        return
    (folder / "overlay").mkdir()

    def overlays() -> Iterator[npt.NDArray[np.uint8]]:
        for index, image, mask, xy in zip(indices, images, masks, xys):
            write_mask_png(folder / "masks" / f"{index:06d}.png", mask)
            overlay = overlay_with_legend(image, mask, xy, labels, unknown)
            write_jpeg(folder / "overlay" / f"{index:06d}.jpg", overlay, quality=90)
            yield overlay

    if fps is None:
        for _ in overlays():
            pass
    else:
        write_video(folder / "overlay.mp4", overlays(), fps or FALLBACK_FPS)


def _write_clip_views(
    folder: Path, result: ClipResult, summary: dict[str, Any], rrd: bool, overlays: bool = True
) -> None:
    """A clip's masks/, (overlays) overlay/ and overlay.mp4, and (rrd) recording.rrd into `folder`; the
    recording's seconds go into summary["timings_s"]."""
    traj = result.trajectories
    _write_masks_and_overlays(
        folder,
        [result.frames.start + t for t in range(result.frames.num_frames)],
        result.frames.images,
        result.masks,
        [result.tracks.xy[traj.track_ids, t] for t in range(result.frames.num_frames)],
        result.clustering.labels,
        fps=result.frames.fps,
        overlays_too=overlays,
    )
    if rrd:
        from mosegpipe.viz import write_recording

        c = result.clustering
        shown = c.labels >= 0  # method "joint" leaves out the tracks no model explains (-1): not drawn
        clip_args = (
            result.frames,
            result.tracks,
            traj.track_ids[shown],
            c.labels[shown],
            result.embeddings[shown],
            result.masks,
        )
        k_why = {"k_note": c.note, "k_method": c.method}
        _timed_recording(summary, write_recording, folder / "recording.rrd", *clip_args, c.scores, c.k, **k_why)


def _timed_recording(summary: dict[str, Any], write: Callable[..., Any], *args: Any, **kwargs: Any) -> None:
    """Calls `write(*args, **kwargs)` (a viz writer) and records its seconds as summary["timings_s"]["rrd"]."""
    t0 = time.perf_counter()
    write(*args, **kwargs)
    summary["timings_s"]["rrd"] = round(time.perf_counter() - t0, 4)


def clip_summary(result: ClipResult, cfg: PipelineConfig) -> dict[str, Any]:
    """The JSON summary of a clip run (schema: docs/OUTPUTS.md)."""
    c = result.clustering
    return {
        "schema": SUMMARY_SCHEMA,
        "kind": "clip",
        "source": result.frames.source,
        "source_identity": source_identity(result.frames.source),
        "version": __version__,
        "start": result.frames.start,
        "frames": result.frames.num_frames,
        "size_hw": list(result.frames.size_hw),
        "k": c.k,
        "k_method": c.method,
        "k_scores": {str(k): float(v) for k, v in c.scores.items()},
        "k_note": c.note,
        "k_reason": k_statement(c.k, c.scores, c.note, c.method),
        "num_tracks_detected": result.tracks.num_tracks,
        "num_tracks_segmented": result.trajectories.num_points,
        "tracks_per_motion": np.bincount(c.labels[c.labels >= 0], minlength=c.k).tolist(),
        "timings_s": {k: round(v, 4) for k, v in result.timings.items()},
        "model": result.model_info,
        "config": asdict(cfg),
    }


def write_clip_outputs(
    result: ClipResult,
    out_dir: str | Path,
    cfg: PipelineConfig = PipelineConfig(),
    overwrite: bool = False,
    rrd: bool = True,
    extra: dict[str, Any] | None = None,
    overlays: bool = True,
) -> dict[str, Any]:
    """Writes summary.json, labels.npz, masks/*.png (palette), overlay/*.jpg, overlay.mp4 and recording.rrd
    atomically.

    The folder layout and every field are documented in docs/OUTPUTS.md. Mask and overlay files are
    named after the source frame index (000000.png, ...).

    Args:
        result: what segment_clip / segment_frames returned.
        out_dir: output folder; built under a temporary name and renamed when complete.
        cfg: the settings the result was computed with (recorded in summary.json).
        overwrite: replace an existing moseg output folder.
        rrd: also write the Rerun recording.
        extra: more summary.json fields (a batch records its config hash there).
        overlays: also write overlay/ and overlay.mp4 (False: the masks, labels.npz and summary.json only,
            `moseg run --outputs masks`).

    Returns:
        The summary dict that was written.

    Raises:
        OutputExistsError, InputError: see check_output_dir.
    """
    summary = {**clip_summary(result, cfg), **(extra or {})}
    with OutputDir(Path(out_dir), overwrite) as tmp:
        traj = result.trajectories
        write_npz(
            tmp / "labels.npz",
            track_ids=traj.track_ids,
            labels=result.clustering.labels,
            xy=result.tracks.xy[traj.track_ids],
            embeddings=result.embeddings,
        )
        _write_clip_views(tmp, result, summary, rrd, overlays)
        write_json(tmp / "summary.json", summary)
    return summary


def pair_summary(result: PairResult, cfg: PipelineConfig, sources: tuple[str, str]) -> dict[str, Any]:
    """The JSON summary of a pair run (schema: docs/OUTPUTS.md)."""
    c = result.clustering
    motions = result.labels[result.labels >= 0]
    num_motions = int(motions.max()) + 1 if motions.size else 0
    return {
        "schema": SUMMARY_SCHEMA,
        "kind": "pair",
        "source": list(sources),
        "source_identity": [source_identity(s) for s in sources],
        "version": __version__,
        "size_hw": [list(result.images[0].shape[:2]), list(result.images[1].shape[:2])],
        "k": c.k,
        "num_motions": num_motions,
        "outlier_cluster": result.outlier_cluster,
        "num_outliers": int((result.labels < 0).sum()),
        "k_method": c.method,
        "k_scores": {str(k): float(v) for k, v in c.scores.items()},
        "k_note": c.note,
        "k_reason": k_statement(c.k, c.scores, c.note, c.method),
        "num_matches": result.matches.num_matches,
        "matches_per_motion": np.bincount(motions, minlength=num_motions).tolist(),
        "timings_s": {k: round(v, 4) for k, v in result.timings.items()},
        "model": result.model_info,
        "config": asdict(cfg),
    }


def write_pair_outputs(
    result: PairResult,
    out_dir: str | Path,
    cfg: PipelineConfig = PipelineConfig(frames=2),
    overwrite: bool = False,
    sources: tuple[str, str] = ("", ""),
    rrd: bool = True,
) -> dict[str, Any]:
    """Writes summary.json, labels.npz, masks/00000{0,1}.png, overlay/00000{0,1}.jpg and recording.rrd atomically.

    Args:
        result: what segment_pair returned.
        out_dir: output folder; built under a temporary name and renamed when complete.
        cfg: the settings the result was computed with (recorded in summary.json).
        overwrite: replace an existing moseg output folder.
        sources: the two image paths, for summary.json.
        rrd: also write the Rerun recording.

    Returns:
        The summary dict that was written.

    Raises:
        OutputExistsError, InputError: see check_output_dir.
    """
    summary = pair_summary(result, cfg, sources)
    with OutputDir(Path(out_dir), overwrite) as tmp:
        m = result.matches
        write_npz(
            tmp / "labels.npz",
            xy1=m.xy1,
            xy2=m.xy2,
            labels=result.labels,
            clusters=result.clustering.labels,
            embeddings=result.embeddings,
        )
        xys = [m.xy1, m.xy2]
        _write_masks_and_overlays(
            tmp, [0, 1], result.images, result.masks, xys, result.labels, unknown="unknown / outlier"
        )
        if rrd:
            from mosegpipe.viz import write_pair_recording

            c = result.clustering
            pair_args = (result.images, m, result.labels, result.embeddings, result.masks)
            k_why = {"k_note": c.note, "k_method": c.method}
            _timed_recording(summary, write_pair_recording, tmp / "recording.rrd", *pair_args, c.scores, c.k, **k_why)
        write_json(tmp / "summary.json", summary)
    return summary


def tracks_summary(result: TracksResult, cfg: PipelineConfig, source: str) -> dict[str, Any]:
    """The JSON summary of external tracks segmented by `pipeline.segment_tracks` (schema: docs/OUTPUTS.md)."""
    c = result.clustering
    return {
        "schema": SUMMARY_SCHEMA,
        "kind": "tracks",
        "source": source,
        "source_identity": source_identity(source),
        "version": __version__,
        "start": result.start,
        "frames": result.trajectories.data.shape[1] // 2,
        "num_tracks": result.tracks.num_tracks,
        "num_tracks_segmented": result.trajectories.num_points,
        "k": c.k,
        "k_method": c.method,
        "k_scores": {str(k): float(v) for k, v in c.scores.items()},
        "k_note": c.note,
        "k_reason": k_statement(c.k, c.scores, c.note, c.method),
        "tracks_per_motion": np.bincount(c.labels[c.labels >= 0], minlength=c.k).tolist(),
        "timings_s": {k: round(v, 4) for k, v in result.timings.items()},
        "model": result.model_info,
        "config": asdict(cfg),
    }


def write_tracks_outputs(
    result: TracksResult,
    out_dir: str | Path,
    cfg: PipelineConfig,
    source: str = "",
    overwrite: bool = False,
    clip: ClipResult | None = None,
    rrd: bool = True,
) -> dict[str, Any]:
    """Writes summary.json and labels.npz (labels (N,) of every given track, -1 = not segmented;
    track_ids (M,) and embeddings (M, E) of the segmented ones) atomically.

    With `clip` (pipeline.tracks_clip: the tracks over the frames of the video they were made on),
    also masks/, overlay/, overlay.mp4 and (rrd) recording.rrd as a clip writes them; summary.json
    then records the video ("video", "video_identity").

    Raises:
        OutputExistsError, InputError: see check_output_dir.
    """
    summary = tracks_summary(result, cfg, source)
    if clip is not None:
        summary["video"] = str(Path(clip.frames.source).absolute())
        summary["video_identity"] = source_identity(clip.frames.source)
        summary["timings_s"]["masks"] = round(clip.timings.get("masks", 0.0), 4)
    with OutputDir(Path(out_dir), overwrite) as tmp:
        write_npz(
            tmp / "labels.npz",
            labels=result.labels,
            track_ids=result.trajectories.track_ids,
            embeddings=result.embeddings,
        )
        if clip is not None:
            _write_clip_views(tmp, clip, summary, rrd)
        write_json(tmp / "summary.json", summary)
    return summary
