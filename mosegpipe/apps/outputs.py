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
from collections.abc import Callable, Iterable, Iterator
from contextlib import ExitStack
from dataclasses import asdict, replace
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from mosegpipe import __version__
from mosegpipe.apps.window_log import WindowLog
from mosegpipe.colours import mask_palette
from mosegpipe.embed.numpy_net import load_embedder
from mosegpipe.errors import InputError, OutputExistsError
from mosegpipe.io.provenance import source_identity
from mosegpipe.io.read import video_info, write_jpeg, write_json, write_npz, write_palette_png, write_video
from mosegpipe.masks import overlay_with_legend
from mosegpipe.pipeline import (
    ClipResult,
    PairResult,
    PipelineConfig,
    TracksResult,
    VideoFrame,
    WindowResult,
    check_video_settings,
    decode_errors,
    frame_mask,
    model_info,
    segment_video,
)
from mosegpipe.runtime import run_ahead
from mosegpipe.viz import k_statement

if TYPE_CHECKING:
    from mosegpipe.embed.numpy_net import Embedder
    from mosegpipe.viz import VideoRecorder, VizConfig

SUMMARY_SCHEMA = "mosegpipe.summary/2"
"""Version 2: mask value = motion label (0 = the world), 255 = unknown (version 1: label + 1, 0 unknown)."""
_FALLBACK_FPS = 10.0  # frame folders carry no rate; the overlay video needs one


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


class _OutputDir:
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
        write_video(folder / "overlay.mp4", overlays(), fps or _FALLBACK_FPS)


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
    with _OutputDir(Path(out_dir), overwrite) as tmp:
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
    with _OutputDir(Path(out_dir), overwrite) as tmp:
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


def video_summary(
    path: str | Path,
    info: dict[str, Any],
    windows: WindowLog,
    cfg: PipelineConfig,
    model: Embedder,
    seconds: float,
) -> dict[str, Any]:
    """The JSON summary of a whole-video run (schema: docs/OUTPUTS.md)."""
    num_frames = windows.num_frames_read
    records = windows.records()
    return {
        "schema": SUMMARY_SCHEMA,
        "kind": "video",
        "source": str(path),
        "source_identity": source_identity(path),
        "version": __version__,
        "frames": num_frames,
        "size_hw": list(info["size_hw"]),
        "video_fps": float(info.get("fps") or 0.0),
        "window_frames": cfg.frames,
        "num_windows": len(records),
        "num_windows_labelled": sum(r["k"] > 0 for r in records),
        "num_motions": windows.num_motions,
        "num_labels_reused": windows.num_labels_reused,
        "shot_cuts": [r["start"] for r in records if r["shot_start"]],
        "k_method": "fixed" if cfg.k is not None else cfg.cluster.method,
        "windows": records,
        "seconds": round(seconds, 3),
        "processing_fps": round(num_frames / seconds, 3) if seconds > 0 else 0.0,
        "model": model_info(model),
        "config": asdict(cfg),
    }


WINDOWS_AHEAD = 2
"""Windows the tracking thread may run ahead of the writer (memory: that many windows' frames)."""


def write_video_outputs(
    path: str | Path,
    out_dir: str | Path,
    cfg: PipelineConfig = PipelineConfig(),
    model: Embedder | None = None,
    overwrite: bool = False,
    rrd: bool = True,
    max_frames: int | None = None,
    on_window: Callable[[WindowResult], None] | None = None,
    viz: VizConfig | None = None,
    frames: Iterable[tuple[int, npt.NDArray[np.uint8]]] | None = None,
    info: dict[str, Any] | None = None,
    on_frame: Callable[[VideoFrame, npt.NDArray[np.uint8]], None] | None = None,
    summary_extra: Callable[[], dict[str, Any]] | None = None,
    overlays: bool = True,
) -> dict[str, Any]:
    """Segments a whole video (pipeline.segment_video) and streams its outputs into a folder.

    Output folder (built atomically; see docs/OUTPUTS.md): masks/NNNNNN.png for every frame (palette
    PNG, value = global motion label, 255 = unknown), overlay.mp4 (H.264), labels.npz, summary.json
    and recording.rrd (frames as one H.264 video asset, K per window). Flat memory: a few windows' frames.

    Args:
        path: video file or frame folder.
        out_dir: output folder.
        cfg: pipeline settings; cfg.frames is the window length F (>= 2).
        model: the model (None = shipped default for cfg.frames).
        overwrite: replace an existing moseg output folder.
        rrd: also write a Rerun recording (frames downscaled to keep it small).
        max_frames: stop after this many frames (None = whole video).
        on_window: called in this thread after each window's frames were written, with the window
            (its `frames` emptied; `num_frames_read` counts the frames done): a progress display.
        viz: settings of the recording (None = viz.VIDEO_VIZ: frames of at most 960 px as one H.264
            video asset).
        frames: the frames themselves, read in place of `path` (a live source; see segment_video).
        info: what video_info says of the source, "fps" (0.0 unknown) and "size_hw" (None: read from
            `path`; given with `frames`).
        on_frame: called in this thread with each frame and its mask once they were written (a live
            view).
        summary_extra: called once the frames ended; its keys are added to summary.json (a live run's
            counts).
        overlays: also write overlay.mp4.

    Returns:
        The summary dict written to summary.json.

    Raises:
        InputError: unreadable input, fewer than F frames, F < 2 or max_frames < 1.
        TooFewTracksError: no window had cfg.min_tracks tracks through all its frames.
        OutputExistsError: out_dir holds results and overwrite is False.
    """
    check_video_settings(cfg, max_frames)
    check_output_dir(out_dir, overwrite)
    model = model or load_embedder(cfg.frames)
    if info is None:
        with decode_errors(path):
            info = video_info(path)
    fps = float(info.get("fps") or 0.0) or _FALLBACK_FPS
    t_start = time.perf_counter()
    with _OutputDir(Path(out_dir), overwrite) as tmp:
        (tmp / "masks").mkdir()
        with ExitStack() as stack:
            windows = stack.enter_context(WindowLog(tmp))
            recorder = None
            if rrd:
                from mosegpipe.viz import VIDEO_VIZ, VideoRecorder

                # A forced K has no runner-up: no margin chart.
                rec = VideoRecorder(tmp / "recording.rrd", cfg=viz or VIDEO_VIZ, fps=fps, margins=cfg.k is None)
                recorder = stack.enter_context(rec)

            segmented = partial(segment_video, path, cfg, model, max_frames, masks=False, frames=frames)
            shown = _written_overlays(segmented, cfg, tmp, windows, recorder, on_frame, on_window, overlays)
            _drain(shown, tmp / "overlay.mp4" if overlays else None, fps)
        windows.write_labels(tmp / "labels.npz")
        summary = video_summary(path, info, windows, cfg, model, time.perf_counter() - t_start)
        if summary_extra is not None:
            summary.update(summary_extra())
        write_json(tmp / "summary.json", summary)
    return summary


def _drain(shown: Iterator[npt.NDArray[np.uint8] | None], video: Path | None, fps: float) -> None:
    """Runs `shown` to its end (each frame's files are written as it is asked for), its overlays into
    `video` (H.264) when given."""
    if video is not None:
        write_video(video, (o for o in shown if o is not None), fps)
        return
    for _ in shown:
        pass


def _written_overlays(
    segmented: Callable[[], Iterator[WindowResult]],
    cfg: PipelineConfig,
    tmp: Path,
    windows: WindowLog,
    recorder: VideoRecorder | None,
    on_frame: Callable[[VideoFrame, npt.NDArray[np.uint8]], None] | None,
    on_window: Callable[[WindowResult], None] | None,
    overlays: bool = True,
) -> Iterator[npt.NDArray[np.uint8] | None]:
    """Writes each frame's mask (and recording) as the windows arrive; yields its overlay (None without
    `overlays`). The windows come from `segmented()`, called when the first overlay is asked for; each goes
    into `windows`."""
    for window in run_ahead(segmented(), WINDOWS_AHEAD, "moseg-segment"):
        windows.add(window)  # what the summary and labels.npz need, not the images (flat memory)
        if recorder is not None:
            recorder.log_window(window.start, window.k, window.k_scores, window.labels)
        for fr in window.frames:
            keep = fr.labels >= 0
            mask = frame_mask(fr, cfg.mask)
            write_mask_png(tmp / "masks" / f"{fr.index:06d}.png", mask)
            if recorder is not None:
                recorder.log_frame(fr.index, fr.image, fr.xy[keep], fr.track_ids[keep], fr.labels[keep], mask)
            if on_frame is not None:
                on_frame(fr, mask)
            yield overlay_with_legend(fr.image, mask, fr.xy[keep], fr.labels[keep]) if overlays else None
        if on_window is not None:
            on_window(replace(window, frames=()))
        del window, fr  # before the next window is read: hold a few windows' frames at most


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
    with _OutputDir(Path(out_dir), overwrite) as tmp:
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
