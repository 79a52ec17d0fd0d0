"""A whole video's outputs: the folder is a sink that the run feeds window by window.

The run drives, the writer writes: `segment_video` yields windows, `feed_windows` hands each to a
`VideoOutputs` (the masks, the recording and the overlay video, written as the windows arrive), and the
caller closes it with the summary. `write_video_outputs` is that loop for a video file or frame folder
(`moseg run --whole`, `Segmenter.video`); a live run feeds the same sink from its source, or feeds none
and only shows the frames. The folder layout is in docs/OUTPUTS.md.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Iterable
from contextlib import ExitStack
from dataclasses import asdict, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from mosegpipe import __version__
from mosegpipe.apps.outputs import FALLBACK_FPS, SUMMARY_SCHEMA, OutputDir, check_output_dir, write_mask_png
from mosegpipe.apps.window_log import WindowLog
from mosegpipe.embed.numpy_net import load_embedder
from mosegpipe.io.provenance import source_identity
from mosegpipe.io.read import video_info, write_json
from mosegpipe.io.write import H264Encoder
from mosegpipe.masks import overlay_with_legend
from mosegpipe.pipeline import (
    PipelineConfig,
    VideoFrame,
    WindowResult,
    check_video_settings,
    decode_errors,
    frame_mask,
    model_info,
    segment_video,
)
from mosegpipe.runtime import run_ahead

if TYPE_CHECKING:
    from mosegpipe.embed.numpy_net import Embedder
    from mosegpipe.viz import VideoRecorder, VizConfig

WINDOWS_AHEAD = 2
"""Windows the tracking thread may run ahead of the writer (memory: that many windows' frames)."""

FrameCallback = Callable[[VideoFrame, npt.NDArray[np.uint8]], None]
"""Called with each frame and its mask once they were written (a live view)."""


class VideoOutputs:
    """The output folder of a whole video, fed one window at a time (flat memory: one window's frames).

    Used as a context manager: entering builds the folder under a temporary name (`OutputDir`) and opens
    the recording and the overlay video; `add` writes each window's masks/NNNNNN.png, recording frames and
    overlays; `finish` closes the video and the recording and writes labels.npz, `write_summary` summary.json; leaving renames the folder into place, or on an
    exception removes it (nothing half-written is left).

    Args:
        out_dir: output folder.
        cfg: the run's settings (the masks' method, forced K).
        fps: frames per second of the overlay video and the recording (0.0: unknown, FALLBACK_FPS).
        overwrite: replace an existing moseg output folder.
        rrd: also write recording.rrd.
        viz: settings of the recording (None = viz.VIDEO_VIZ).
        overlays: also write overlay.mp4.
    """

    def __init__(
        self,
        out_dir: str | Path,
        cfg: PipelineConfig,
        fps: float,
        overwrite: bool = False,
        rrd: bool = True,
        viz: VizConfig | None = None,
        overlays: bool = True,
    ) -> None:
        self.cfg = cfg
        self.fps = fps or FALLBACK_FPS
        self._folder = OutputDir(Path(out_dir), overwrite)
        self._rrd, self._viz, self._overlays = rrd, viz, overlays
        self._stack = ExitStack()
        self.windows: WindowLog
        self._recorder: VideoRecorder | None = None
        self._video: H264Encoder | None = None

    def __enter__(self) -> VideoOutputs:
        self.tmp = self._folder.__enter__()
        try:
            with ExitStack() as stack:
                (self.tmp / "masks").mkdir()
                self.windows = stack.enter_context(WindowLog(self.tmp))
                if self._rrd:
                    from mosegpipe.viz import VIDEO_VIZ, VideoRecorder

                    # A forced K has no runner-up: no margin chart.
                    viz = self._viz or VIDEO_VIZ
                    rec = VideoRecorder(self.tmp / "recording.rrd", cfg=viz, fps=self.fps, margins=self.cfg.k is None)
                    self._recorder = stack.enter_context(rec)
                if self._overlays:
                    self._video = H264Encoder(self.tmp / "overlay.mp4", self.fps, self._folder.final / "overlay.mp4")
                self._stack = stack.pop_all()
        except BaseException as exc:  # the folder goes too
            self._folder.__exit__(type(exc), exc, exc.__traceback__)
            raise
        return self

    def add(self, window: WindowResult) -> list[npt.NDArray[np.uint8]]:
        """Writes a window's frames (mask, recording, overlay) and keeps what the summary and labels.npz need.

        Returns:
            Each frame's (H, W) uint8 mask, in the window's frame order.
        """
        self.windows.add(window)
        if self._recorder is not None:
            self._recorder.log_window(window.start, window.k, window.k_scores, window.labels)
        masks = []
        for fr in window.frames:
            keep = fr.labels >= 0
            mask = frame_mask(fr, self.cfg.mask)
            write_mask_png(self.tmp / "masks" / f"{fr.index:06d}.png", mask)
            if self._recorder is not None:
                self._recorder.log_frame(fr.index, fr.image, fr.xy[keep], fr.track_ids[keep], fr.labels[keep], mask)
            if self._video is not None:
                self._video.add(overlay_with_legend(fr.image, mask, fr.xy[keep], fr.labels[keep]))
            masks.append(mask)
        return masks

    def finish(self) -> None:
        """Finishes the overlay video and the recording, then writes labels.npz (after the last window)."""
        if self._video is not None:
            self._video.close()
            self._video = None
        self._stack.close()  # the recording, then the window log's spool files
        self.windows.write_labels(self.tmp / "labels.npz")

    def write_summary(self, summary: dict[str, Any]) -> None:
        """Writes summary.json (after `finish`, so that its timings count the whole run)."""
        write_json(self.tmp / "summary.json", summary)

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if self._video is not None:  # only after an error: the folder is removed, whatever the encoder says
            with contextlib.suppress(Exception):
                self._video.close(flush=False)
        try:
            self._stack.__exit__(exc_type, exc, tb)
        finally:
            self._folder.__exit__(exc_type, exc, tb)


def feed_windows(
    windows: Iterable[WindowResult],
    cfg: PipelineConfig,
    sink: VideoOutputs | None = None,
    on_frame: FrameCallback | None = None,
    on_window: Callable[[WindowResult], None] | None = None,
) -> None:
    """The run's loop: each window into `sink` (None: no folder, the masks only made), then its frames and
    masks to `on_frame`, then the window (its `frames` emptied) to `on_window` (a progress display)."""
    for window in windows:
        masks = sink.add(window) if sink is not None else [frame_mask(fr, cfg.mask) for fr in window.frames]
        if on_frame is not None:
            for fr, mask in zip(window.frames, masks):
                on_frame(fr, mask)
        if on_window is not None:
            on_window(replace(window, frames=()))
        del window, masks  # before the next window is read: hold a few windows' frames at most


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
    on_frame: FrameCallback | None = None,
    summary_extra: Callable[[], dict[str, Any]] | None = None,
    overlays: bool = True,
) -> dict[str, Any]:
    """Segments a whole video (pipeline.segment_video) and feeds its windows into a `VideoOutputs` folder.

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
    t_start = time.perf_counter()
    fps = float(info.get("fps") or 0.0)
    with VideoOutputs(out_dir, cfg, fps, overwrite, rrd, viz, overlays) as sink:
        segmented = segment_video(path, cfg, model, max_frames, masks=False, frames=frames)
        # closed here, not when collected: a second Ctrl-C while its threads are joined is then an exception
        with contextlib.closing(run_ahead(segmented, WINDOWS_AHEAD, "moseg-segment")) as windows:
            feed_windows(windows, cfg, sink, on_frame, on_window)
        sink.finish()
        summary = video_summary(path, info, sink.windows, cfg, model, time.perf_counter() - t_start)
        if summary_extra is not None:
            summary.update(summary_extra())
        sink.write_summary(summary)
    return summary
