"""A whole video's recording, streamed frame by frame (VideoRecorder), and its layout."""

from __future__ import annotations

import io
import os
import time
from collections.abc import Mapping
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe.errors import InputError
from mosegpipe.io.read import H264Encoder, atomic_write
from mosegpipe.viz.blocks import (
    Sink,
    log_annotation_contexts,
    log_image_layers,
    log_legend,
    log_trails,
    log_written,
    view_panels,
)
from mosegpipe.viz.common import (
    MAX_CLASSES,
    TIMELINE,
    VIDEO_VIZ,
    VizConfig,
    class_ids_of,
    class_names,
    legend_markdown,
    score_lead,
)

if TYPE_CHECKING:
    # rerun is imported where it is used: it takes ~0.6 s, which `import mosegpipe` should not pay.
    import rerun as rr
    import rerun.blueprint as rrb


def video_blueprint(windows: bool, margins: bool) -> rrb.Blueprint:
    """The frame with its mask and tracks above; K per window (and its score margin) and the window's legend under it."""
    import rerun.blueprint as rrb

    frame = rrb.Spatial2DView(origin="video", name="frame, tracks and masks")
    if not windows:
        return rrb.Blueprint(frame, *view_panels(timeline=True))
    series: list[Any] = [rrb.TimeSeriesView(origin="windows/k", name="K per window")]
    if margins:
        series.append(rrb.TimeSeriesView(origin="windows/k_margin", name="how clear K is (score lead)"))
    series.append(rrb.TextDocumentView(origin="legend", name="legend (this window)"))
    return rrb.Blueprint(
        rrb.Vertical(frame, rrb.Horizontal(*series), row_shares=[5.0, 1.0]), *view_panels(timeline=True)
    )


class VideoRecorder:
    """Streams a segmented video into one .rrd file, frame by frame, with flat memory.

    Labels are global motion ids that may grow as the video goes on; the annotation contexts name
    every class 0..254 from the start (logged once, before any data). The layout is sent first:
    the frame with its mask and tracks above, K per window (and its score margin) under it. Track
    trails are kept for
    the last `cfg.trail_frames` frames per track id. With cfg.video_frames "h264" the frames are
    encoded into one H.264 MP4 in memory as they come (about 8 kB a frame at 768x576) and logged
    at close() as an AssetVideo with a VideoFrameReference per frame; the masks, points and trails
    are logged frame by frame either way. The file appears under its final name only after
    close(); abort() (or leaving a `with` block by an exception) removes it.

    Args:
        path: output .rrd file.
        app_id: Rerun application id.
        cfg: display settings.
        fps: frame rate stored in the video asset (the frames are shown on the "frame" timeline
            whatever it is).
        windows: the layout has a chart of K per window (log_window).
        margins: the layout has a chart of the K score margin per window (False when K is forced:
            no window has a margin).

    Example:
        >>> with VideoRecorder("out/recording.rrd", fps=25.0) as rec:  # doctest: +SKIP
        ...     for t, frame in iter_video(path):
        ...         rec.log_frame(t, frame, xy, ids, labels, mask)
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        app_id: str = "mosegpipe",
        cfg: VizConfig = VIDEO_VIZ,
        fps: float = 10.0,
        windows: bool = True,
        margins: bool = True,
    ) -> None:
        if not fps > 0:
            raise InputError(f"{path}: fps={fps} must be > 0")
        self.path = Path(path)
        self.cfg = cfg
        self._started = time.perf_counter()
        self._trail_len = cfg.trail_frames or 10**9
        self._trails: dict[int, list[npt.NDArray[np.float32]]] = {}
        self._num_frames = 0
        self._num_windows = 0
        self._frame_times: list[int] = []
        self._encoder: H264Encoder | None = None
        self._video = io.BytesIO()
        if cfg.video_frames == "h264":
            self._encoder = H264Encoder(self._video, fps, self.path, b_frames=False)
        # atomic_write's context is held open across calls; close()/abort() finish it.
        self._target = atomic_write(self.path)
        tmp = self._target.__enter__()
        try:
            self._sink: Sink | None = Sink(tmp, app_id, self.path, video_blueprint(windows, margins))
            log_annotation_contexts(self._sink.rec, ["video"], class_names(MAX_CLASSES))
        except BaseException as exc:
            self._close_encoder(flush=False)
            self._target.__exit__(type(exc), exc, exc.__traceback__)
            raise

    def log_window(
        self,
        start: int,
        k: int,
        k_scores: Mapping[int, float] | None = None,
        labels: npt.NDArray[np.int64] | None = None,
    ) -> None:
        """Log the K chosen in a window (and how clearly its scores chose it, `score_lead`), at the window's
        first frame; with `labels`, the window's legend (`legend`: value, colour, name, tracks).

        Args:
            start: frame index of the window's first frame (the "frame" timeline).
            k: motions found in the window, 0 = left unlabelled (too few tracks).
            k_scores: the window's score per candidate K (None or empty: no margin is logged).
            labels: (N,) int64 global labels of the window's clustered tracks.

        Raises:
            InputError: the recorder is closed.
        """
        if self._sink is None:
            raise InputError(f"{self.path}: recorder already closed")
        log_window_k(self._sink.rec, start, k, k_scores, first=self._num_windows == 0)
        if labels is not None:
            log_legend(self._sink.rec, legend_markdown(labels), static=False)
        self._num_windows += 1

    def log_frame(
        self,
        t: int,
        image: npt.NDArray[np.uint8],
        xy: npt.NDArray[np.float32],
        ids: npt.NDArray[np.int64],
        labels: npt.NDArray[np.int64],
        mask: npt.NDArray[np.uint8] | None = None,
    ) -> None:
        """Log one frame.

        Args:
            t: frame index in the source (the "frame" timeline); increasing from call to call.
            image: (H, W, 3) uint8 RGB; with H.264 frames, the same size in every call.
            xy: (M, 2) float32 pixel positions of the labelled points in this frame.
            ids: (M,) int64 their track ids (stable across frames: trails follow them).
            labels: (M,) int64 their motion ids, 0..254 (-1 = unlabelled, shown as class 255).
            mask: (H, W) uint8 mask (label, 255 unknown), or None.

        Raises:
            InputError: the recorder is closed, or shapes/labels are invalid.
        """
        if self._sink is None:
            raise InputError(f"{self.path}: recorder already closed")
        xy = np.asarray(xy, dtype=np.float32).reshape(-1, 2)
        ids = np.asarray(ids, dtype=np.int64).reshape(-1)
        labels = np.asarray(labels, dtype=np.int64).reshape(-1)
        if not len(xy) == len(ids) == len(labels):
            raise InputError(f"frame {t}: {len(xy)} points, {len(ids)} ids, {len(labels)} labels: must match")
        if len(labels) and (labels.min() < -1 or labels.max() >= MAX_CLASSES):
            raise InputError(f"frame {t}: labels must be in -1..{MAX_CLASSES - 1}, got {labels.min()}..{labels.max()}")
        if mask is not None and mask.shape != image.shape[:2]:
            raise InputError(f"frame {t}: mask {mask.shape} and image {image.shape[:2]} sizes differ")
        image, mask, xy = self._downscale(image, mask, xy)
        rec = self._sink.rec
        rec.set_time(TIMELINE, sequence=int(t))
        class_ids = class_ids_of(labels)
        if self._encoder is not None:
            self._encoder.add(image)
            self._frame_times.append(int(t))
        log_image_layers(rec, "video", None if self._encoder is not None else image, mask, xy, class_ids, self.cfg)
        live = set(ids.tolist())
        for stale in [i for i in self._trails if i not in live]:
            del self._trails[stale]  # a lost track never comes back (KLTTracker ids are not reused)
        lengths = np.zeros(len(ids), dtype=np.int64)
        for n, (i, p) in enumerate(zip(ids.tolist(), xy)):
            trail = self._trails.setdefault(i, [])
            trail.append(p)
            del trail[: -self._trail_len]
            lengths[n] = len(trail)
        points = [p for i in ids.tolist() for p in self._trails[i]]
        flat = np.array(points, dtype=np.float32).reshape(-1, 2)
        log_trails(rec, flat, lengths, class_ids, self.cfg)
        self._num_frames += 1

    def _downscale(
        self, image: npt.NDArray[np.uint8], mask: npt.NDArray[np.uint8] | None, xy: npt.NDArray[np.float32]
    ) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.uint8] | None, npt.NDArray[np.float32]]:
        side = max(image.shape[:2])
        if self.cfg.max_side_px is None or side <= self.cfg.max_side_px:
            return image, mask, xy
        scale = self.cfg.max_side_px / side
        size_wh = (max(1, round(image.shape[1] * scale)), max(1, round(image.shape[0] * scale)))
        image = cv2.resize(image, size_wh, interpolation=cv2.INTER_AREA)
        if mask is not None:
            mask = cv2.resize(mask, size_wh, interpolation=cv2.INTER_NEAREST)
        # Pixel centres map as (x + 0.5) * s - 0.5.
        return image, mask, ((xy + 0.5) * scale - 0.5).astype(np.float32)

    def _close_encoder(self, flush: bool) -> None:
        if self._encoder is not None:
            encoder, self._encoder = self._encoder, None
            encoder.close(flush=flush)

    def _log_video_asset(self, rec: rr.RecordingStream) -> None:
        """The encoded frames as one AssetVideo, and a VideoFrameReference per logged frame."""
        import rerun as rr

        if self._encoder is None:
            return
        self._close_encoder(flush=True)
        if not self._frame_times:
            return
        asset = rr.AssetVideo(contents=self._video.getvalue(), media_type="video/mp4")
        self._video = io.BytesIO()
        rec.log("video/asset", asset, static=True)
        stamps = asset.read_frame_timestamps_nanos()
        if len(stamps) != len(self._frame_times):
            raise RuntimeError(f"{self.path}: {len(self._frame_times)} frames encoded, the video holds {len(stamps)}")
        num = len(stamps)
        rec.send_columns(
            "video/frame",
            indexes=[rr.TimeColumn(TIMELINE, sequence=self._frame_times)],
            columns=rr.VideoFrameReference.columns(
                timestamp=stamps,
                video_reference=["video/asset"] * num,
                draw_order=np.zeros(num, np.float32),
            ),
        )

    def close(self) -> Path:
        """Finish the file and move it to its final name. Safe to call twice.

        Returns:
            The path written.
        """
        if self._sink is not None:
            sink, self._sink = self._sink, None
            try:
                try:
                    self._log_video_asset(sink.rec)
                except BaseException:
                    self._close_encoder(flush=False)
                    sink.finish(write=False)
                    raise
                sink.finish()
            except BaseException as exc:
                self._target.__exit__(type(exc), exc, exc.__traceback__)
                raise
            self._target.__exit__(None, None, None)
            log_written(self.path, f"{self._num_frames} frames", self._started)
        return self.path

    def abort(self) -> None:
        """Stop recording and remove the temporary file; nothing is written under the final name."""
        if self._sink is not None:
            sink, self._sink = self._sink, None
            try:
                self._close_encoder(flush=False)
                sink.finish(write=False)
            finally:
                err = RuntimeError(f"{self.path}: recording aborted")
                self._target.__exit__(RuntimeError, err, None)

    def __enter__(self) -> VideoRecorder:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


def log_window_k(
    rec: Any, start: int, k: int, k_scores: Mapping[int, float] | None = None, first: bool = False
) -> None:
    """Logs a window's K and how clearly its scores chose it (`score_lead`) at the window's first frame.

    Args:
        rec: the rr.RecordingStream.
        start: frame index of the window's first frame (the "frame" timeline).
        k: motions found in the window, 0 = left unlabelled.
        k_scores: the window's score per candidate K (None or empty: no score lead is logged).
        first: the first window of the recording: the two series' styles are logged first.
    """
    import rerun as rr

    if first:
        rec.log("windows/k", rr.SeriesLines(names="K", interpolation_mode="StepAfter"), static=True)
        rec.log("windows/k", rr.SeriesPoints(names="K", markers="circle", marker_sizes=3.0), static=True)
        style = rr.SeriesLines(names="best K's score minus the next K's (0 = a tie)", interpolation_mode="StepAfter")
        rec.log("windows/k_margin", style, static=True)
    rec.set_time(TIMELINE, sequence=int(start))
    rec.log("windows/k", rr.Scalars(float(k)))
    lead = score_lead(k_scores or {}) if k > 0 else None
    if lead is not None:
        rec.log("windows/k_margin", rr.Scalars(lead))
