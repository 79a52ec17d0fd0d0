"""Live mode: a camera, a stream, a video file played in real time or frames piped on stdin, segmented as
the frames arrive and shown in a Rerun viewer.

The frames go through the whole-video machinery unchanged (`segment_video` reads them from a
`LiveFrames` iterator in place of a file: windows, stable labels, shot cuts); with an output folder,
`write_video_outputs` writes it as `moseg run --whole` does. What is live is around it:

- `open_source` opens the source (`parse_source` tells a camera index, a URL, a file and `-` apart);
  `SourceReader` reads it, the first frame too, on a thread of its own into a `FrameBuffer` of a
  few frames. When the pipeline falls behind a live source (a camera, a stream, a file played in
  real time), the buffer drops its oldest frame for each new one (whole frames, counted): latency
  stays bounded and memory flat; it never grows a queue. Stdin and a file read as fast as
  possible wait instead (a pipe's writer can wait), so that no frame is lost; and nothing is
  dropped before the pipeline has shown its first mask (model loading, the first window).
- `LiveFrames` hands the frames to the pipeline and ends the stream when the source ends, stalls
  (no frame for `stall_timeout_s`) or is told to stop (Ctrl-C): the pipeline then finishes the
  window in hand, so the outputs are complete.
- `LiveView` streams each frame, its mask, its tracks and each window's K to the viewer's sinks
  (a spawned viewer, a running viewer over gRPC, a web viewer), with the layout and colours of a
  whole-video recording (mosegpipe.viz).
- `LiveStats` measures frames/s, the latency from a frame's arrival to its mask leaving for the
  viewer, and the dropped frames, in constant memory; with an output folder they go into its
  summary.json (`live`), and a run that dropped most of its frames says so in a warning.

Stdin takes raw frames, 8-bit BGR (what `ffmpeg ... -f rawvideo -pix_fmt bgr24 -` writes), of a
size given beside it (`parse_source(stdin_size=...)`).
"""

from __future__ import annotations

import collections
import contextlib
import logging
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from mosegpipe.apps.live.reader import BUFFER_FRAMES, POLL_S, FrameBuffer, LiveFrames, SourceReader
from mosegpipe.apps.live.source import (
    MAX_CAMERA_INDEX,
    MAX_STDIN_PIXELS,
    MAX_STDIN_SIDE_PX,
    Capture,
    LiveSource,
    RawCapture,
    SourceKind,
    open_source,
    parse_size,
    parse_source,
    stdin_size_suspect,
)
from mosegpipe.errors import InputError, MosegError, TooFewTracksError
from mosegpipe.pipeline import PipelineConfig, VideoFrame, WindowResult, segment_video
from mosegpipe.pipeline.video import MIN_VIDEO_SIDE_PX
from mosegpipe.runtime import run_ahead

if TYPE_CHECKING:
    import rerun as rr

    from mosegpipe.embed.numpy_net import Embedder
    from mosegpipe.viz import VizConfig

log = logging.getLogger("mosegpipe.apps.live.run")

__all__ = [
    "BUFFER_FRAMES",
    "DEFAULT_FPS",
    "MAX_CAMERA_INDEX",
    "MAX_STDIN_PIXELS",
    "MAX_STDIN_SIDE_PX",
    "MOST_DROPPED",
    "Capture",
    "FrameBuffer",
    "LiveFrames",
    "LiveResult",
    "LiveSource",
    "LiveStats",
    "LiveView",
    "RawCapture",
    "SourceKind",
    "SourceReader",
    "live_viz",
    "open_source",
    "parse_size",
    "parse_source",
    "run_live",
    "stdin_size_suspect",
]

DEFAULT_FPS = 25.0
"""Frame rate assumed for the outputs of a source that does not state one (stdin, some cameras)."""

WINDOWS_AHEAD = 1
"""Windows the segmenting thread may run ahead of the view (latency: a window's frames each)."""


# ---------------------------------------------------------------------------------------------
# Statistics
# ---------------------------------------------------------------------------------------------

_LATENCY_BIN_S = 0.005
_LATENCY_BINS = 12_000  # 60 s in 5 ms bins; longer latencies fall into the last one


@dataclass
class LiveStats:
    """Frames/s, latency and dropped frames of a live run, in constant memory.

    Attributes:
        frames_read: frames read from the source (dropped ones included).
        frames_dropped: frames dropped because the pipeline fell behind.
        frames_shown: frames whose mask went to the viewer (and the output folder).
        last_latency_s: latency of the last frame shown.
        started: time.monotonic() at the first frame.
    """

    frames_read: int = 0
    frames_dropped: int = 0
    frames_shown: int = 0
    last_latency_s: float = 0.0
    started: float = field(default_factory=time.monotonic)
    _hist: npt.NDArray[np.int64] = field(default_factory=lambda: np.zeros(_LATENCY_BINS, np.int64), repr=False)
    _recent: collections.deque[float] = field(default_factory=lambda: collections.deque(maxlen=50), repr=False)

    def shown(self, latency_s: float | None, now: float | None = None) -> None:
        """Counts one frame shown, `latency_s` after it arrived (None: unknown)."""
        now = time.monotonic() if now is None else now
        self.frames_shown += 1
        self._recent.append(now)
        if latency_s is not None:
            self.last_latency_s = latency_s
            self._hist[min(int(latency_s / _LATENCY_BIN_S), _LATENCY_BINS - 1)] += 1

    def latency_quantile(self, q: float) -> float:
        """The q-quantile of the latencies so far, seconds (to the 5 ms bin; 0.0 before any)."""
        total = int(self._hist.sum())
        if total == 0:
            return 0.0
        index = int(np.searchsorted(np.cumsum(self._hist), q * total, side="left"))
        return (index + 0.5) * _LATENCY_BIN_S

    @property
    def fps(self) -> float:
        """Frames shown per second over the last 50 frames."""
        if len(self._recent) < 2:
            return 0.0
        span = self._recent[-1] - self._recent[0]
        return (len(self._recent) - 1) / span if span > 0 else 0.0

    @property
    def elapsed_s(self) -> float:
        return time.monotonic() - self.started

    @property
    def dropped_share(self) -> float:
        return self.frames_dropped / self.frames_read if self.frames_read else 0.0

    def record(self) -> dict[str, float | int]:
        """The numbers as a dict (for a summary or a benchmark)."""
        return {
            "frames_read": self.frames_read,
            "frames_dropped": self.frames_dropped,
            "frames_shown": self.frames_shown,
            "dropped_share": round(self.dropped_share, 4),
            "latency_median_s": round(self.latency_quantile(0.5), 3),
            "latency_p95_s": round(self.latency_quantile(0.95), 3),
            "seconds": round(self.elapsed_s, 3),
            "fps": round(self.frames_shown / self.elapsed_s, 3) if self.elapsed_s > 0 else 0.0,
        }


# ---------------------------------------------------------------------------------------------
# The viewer
# ---------------------------------------------------------------------------------------------


def live_viz() -> VizConfig:
    """Settings of the live view: a JPEG image per frame (a video asset only exists once the video
    is complete), trails of 10 frames."""
    from mosegpipe.viz import VIDEO_VIZ

    return replace(VIDEO_VIZ, video_frames="jpeg", jpeg_quality=80)


class LiveView:
    """Streams a live run to Rerun sinks (a viewer's gRPC server, one of our own), frame by frame.

    Entity paths, layout and colours are a whole-video recording's (mosegpipe.viz, VideoRecorder):
    `video/frame` (JPEG), `video/mask`, `video/points`, `video/tracks` and `windows/k`,
    `windows/k_margin` (viz.log_window_k) on the "frame" timeline. The layout goes first, then the class colours, then
    the data.

    Args:
        sinks: Rerun sinks (rr.GrpcSink, rr.GrpcServerSink, rr.FileSink), all fed the same stream.
        margins: the layout has the K score margin chart (False when K is forced).
        cfg: display settings (None: live_viz()).
    """

    def __init__(self, sinks: Sequence[Any], margins: bool = True, cfg: VizConfig | None = None) -> None:
        import rerun as rr

        from mosegpipe.viz import MAX_CLASSES, class_names, log_annotation_contexts, video_blueprint

        self.cfg = cfg or live_viz()
        self.rec: rr.RecordingStream | None = rr.RecordingStream("mosegpipe")
        self.rec.set_sinks(*sinks)
        self.rec.send_blueprint(video_blueprint(True, margins), make_active=True, make_default=True)
        log_annotation_contexts(self.rec, ["video"], class_names(MAX_CLASSES))
        self._trails: dict[int, collections.deque[npt.NDArray[np.float32]]] = {}
        self._trail_len = self.cfg.trail_frames or 10
        self._windows = 0

    def log_window(self, start: int, k: int, k_scores: Mapping[int, float]) -> None:
        """The K of a window (0 = left unlabelled) and how clearly its scores chose it, at its first frame."""
        from mosegpipe.viz import log_window_k

        log_window_k(self._stream(), start, k, k_scores, first=self._windows == 0)
        self._windows += 1

    def log_frame(self, frame: VideoFrame, mask: npt.NDArray[np.uint8]) -> None:
        """One frame: the image, its mask, its labelled tracks and their recent trails."""
        from mosegpipe.viz import TIMELINE, class_ids_of, log_image_layers, log_trails

        rec = self._stream()
        keep = frame.labels >= 0
        ids, xy = frame.track_ids[keep], frame.xy[keep]
        class_ids = class_ids_of(frame.labels[keep])
        rec.set_time(TIMELINE, sequence=int(frame.index))
        log_image_layers(rec, "video", frame.image, mask, xy, class_ids, self.cfg)
        live = set(ids.tolist())
        for lost in [i for i in self._trails if i not in live]:
            del self._trails[lost]
        lengths = np.zeros(len(ids), dtype=np.int64)
        for n, (i, p) in enumerate(zip(ids.tolist(), xy)):
            trail = self._trails.setdefault(i, collections.deque(maxlen=self._trail_len))
            trail.append(p)
            lengths[n] = len(trail)
        points = np.array([p for i in ids.tolist() for p in self._trails[i]], dtype=np.float32).reshape(-1, 2)
        log_trails(rec, points, lengths, class_ids, self.cfg)

    def _stream(self) -> rr.RecordingStream:
        if self.rec is None:
            raise InputError("live view already closed")
        return self.rec

    def close(self, timeout_s: float = 10.0) -> None:
        """Sends what is still buffered (at most `timeout_s`) and disconnects. Safe to call twice."""
        if self.rec is None:
            return
        rec, self.rec = self.rec, None
        try:
            rec.flush(timeout_sec=timeout_s)
        except Exception as exc:  # a viewer gone away: what was sent is shown; nothing to report beyond a line
            log.warning("the viewer did not take the last frames: %s", exc)
        finally:
            rec.disconnect()


# ---------------------------------------------------------------------------------------------
# A live run
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class LiveResult:
    """How a live run ended.

    Attributes:
        end: "ended" (the source ended), "stalled" (no frame for the stall timeout), "stopped"
            (told to stop: Ctrl-C) or "max-frames".
        stats: the run's numbers.
        summary: the output folder's summary.json (None without an output folder).
        num_windows: windows segmented.
        partial_bytes: bytes of a last, incomplete raw frame on stdin (dropped).
    """

    end: str
    stats: LiveStats
    summary: dict[str, Any] | None
    num_windows: int
    partial_bytes: int = 0


def run_live(
    source: LiveSource,
    cfg: PipelineConfig,
    model: Embedder,
    view: LiveView | None = None,
    out_dir: str | Path | None = None,
    overwrite: bool = False,
    rrd: bool = True,
    stall_timeout_s: float = 10.0,
    buffer_frames: int = BUFFER_FRAMES,
    max_frames: int | None = None,
    stop: threading.Event | None = None,
    on_status: Callable[[LiveStats], None] | None = None,
    status_every_s: float = 0.5,
    stdin: IO[bytes] | None = None,
) -> LiveResult:
    """Segments a live source window by window as its frames arrive, until it ends, stalls or `stop` is set.

    Args:
        source: what to read (parse_source).
        cfg: pipeline settings; cfg.frames is the window length. No window is held back for labels that merge
            back (LabelConfig.merge_back_windows is 0 here): the view would lag by as many.
        model: the embedding model for cfg.frames.
        view: where each frame, mask and K goes as soon as it is ready (None: nowhere).
        out_dir: also write the output folder of a whole-video run there (None: none).
        overwrite: replace an existing moseg output folder.
        rrd: with out_dir, also write recording.rrd there.
        stall_timeout_s: end the run when no frame came for this long.
        buffer_frames: frames held between the reader and the pipeline (FrameBuffer).
        max_frames: stop after this many frames read from the source.
        stop: set it (from a signal handler, another thread) to end the run cleanly: the window in
            hand is finished and the outputs written.
        on_status: called in this thread with the numbers at most every `status_every_s`.
        stdin: the byte stream of SOURCE "-" (None: this process's stdin).

    Raises:
        InputError: the source cannot be opened or gives no frame, its frames are smaller than
            MIN_VIDEO_SIDE_PX, or it ended before a window's worth of frames.
        TooFewTracksError: no window had enough tracks.
        OutputExistsError: out_dir holds results and overwrite is False.
        CheckpointError: a mask network the settings ask for cannot be used (`check_mask_networks`).
    """
    from mosegpipe.apps.outputs import check_output_dir
    from mosegpipe.masks.learned.probability import check_mask_networks

    if out_dir is not None:
        check_output_dir(out_dir, overwrite)
    check_mask_networks(cfg.mask)
    # no window is held back for labels that merge back (pipeline.merge_back): the view would lag by as many
    cfg = replace(cfg, labels=replace(cfg.labels, merge_back_windows=0))
    stop = stop or threading.Event()
    capture = open_source(source, timeout_s=stall_timeout_s, stdin=stdin)
    fps = source.fps or capture.fps or DEFAULT_FPS
    # Held until the first mask is out: what comes before the pipeline started is waited for, not dropped.
    buffer = FrameBuffer(buffer_frames, drop=source.drops, hold=True)
    reader = SourceReader(capture, buffer, stop, fps if source.realtime else None, max_frames, source.name)
    reader.start()
    try:
        return _run_live(
            source, cfg, model, reader, fps, view, out_dir, overwrite, rrd, stall_timeout_s, on_status, status_every_s
        )
    finally:
        reader.finish()


def _first_frame(reader: SourceReader, stall_timeout_s: float) -> npt.NDArray[np.uint8]:
    """Waits for the reader's first frame (left in the buffer), looking at the stop signal as it waits.

    Raises:
        InputError: the source gave no frame, none came for `stall_timeout_s`, or `stop` was set.
    """
    name = reader.source_name
    waited_from = time.monotonic()
    log.info("%s: waiting for the first frame (at most %g s)", name, stall_timeout_s)
    while True:
        if reader.stop.is_set():
            raise InputError(f"{name}: stopped before the first frame came")
        item = reader.buffer.peek(POLL_S)
        if item is False:
            if reader.error is not None:
                raise InputError(f"{name}: reading failed ({reader.error})") from reader.error
            raise InputError(f"{name}: no frame could be read")
        if item is not None:
            return item[1]
        if time.monotonic() - waited_from > stall_timeout_s:
            raise InputError(f"{name}: no frame came in {stall_timeout_s:g} s (--stall-timeout); stopped")


MOST_DROPPED = 0.5
"""A run that dropped more than this share of the frames it read says so in a warning."""


def _check_first_frame(source: LiveSource, first: npt.NDArray[np.uint8]) -> tuple[int, int, str]:
    """(height, width, what looks wrong with raw stdin frames of that size or ""); InputError for
    frames too small to track."""
    height, width = first.shape[:2]
    if min(height, width) < MIN_VIDEO_SIDE_PX:
        raise InputError(
            f"{source.name}: frames of {width}x{height} px are too small to track "
            f"(at least {MIN_VIDEO_SIDE_PX}x{MIN_VIDEO_SIDE_PX})"
        )
    suspect = stdin_size_suspect(first) if source.kind == "stdin" else ""
    if suspect:
        suspect = f"the frames do not look {width}x{height}: {suspect}; is --stdin-size right?"
    return height, width, suspect


def _warn_dropped(name: str, stats: LiveStats) -> None:
    """A warning when the run dropped more than MOST_DROPPED of the frames it read."""
    if stats.dropped_share > MOST_DROPPED:
        log.warning(
            "%s: %d of %d frames dropped (%.0f %%): the segmenter fell far behind the source "
            "(--no-drop waits for it where the source can wait; --preset fast, --max-corners, --mask-method nearest make it faster)",
            name,
            stats.frames_dropped,
            stats.frames_read,
            100 * stats.dropped_share,
        )


def _stdin_size_hint(source: LiveSource, exc: MosegError, width: int, height: int) -> str:
    """What to check when raw stdin frames gave no tracks ("" for another source or failure): a width wrong by a
    pixel or two shears the frames too little for `stdin_size_suspect` to tell, and leaves nothing to track."""
    if source.kind == "stdin" and isinstance(exc, TooFewTracksError):
        return f"raw frames read as {width}x{height}: is --stdin-size right?"
    return ""


def _show_only(
    name: str,
    cfg: PipelineConfig,
    model: Embedder,
    frames: LiveFrames,
    on_frame: Callable[[VideoFrame, npt.NDArray[np.uint8]], None],
    on_window: Callable[[WindowResult], None],
) -> None:
    """A run without an output folder: each window's frames and masks, then the window, to the callbacks."""
    from mosegpipe.apps.video_outputs import feed_windows

    # closed here, not when collected: a second Ctrl-C while its threads are joined is then an exception
    with contextlib.closing(
        run_ahead(segment_video(name, cfg, model, masks=False, frames=frames), WINDOWS_AHEAD, "moseg-segment")
    ) as windows:
        feed_windows(windows, cfg, None, on_frame, on_window)


def _run_live(
    source: LiveSource,
    cfg: PipelineConfig,
    model: Embedder,
    reader: SourceReader,
    fps: float,
    view: LiveView | None,
    out_dir: str | Path | None,
    overwrite: bool,
    rrd: bool,
    stall_timeout_s: float,
    on_status: Callable[[LiveStats], None] | None,
    status_every_s: float,
) -> LiveResult:
    from mosegpipe.apps.video_outputs import write_video_outputs

    buffer, capture = reader.buffer, reader.capture
    height, width, suspect = _check_first_frame(source, _first_frame(reader, stall_timeout_s))
    frames = LiveFrames(reader, stall_timeout_s)
    stats = LiveStats()
    last_status = [0.0]
    windows = [0]

    def on_window(window: WindowResult) -> None:
        windows[0] += 1
        if view is not None:
            view.log_window(window.start, window.k, window.k_scores)

    def on_frame(frame: VideoFrame, mask: npt.NDArray[np.uint8]) -> None:
        if buffer.holding:
            buffer.release()  # the pipeline runs: from now on a live source drops what it cannot take
        if view is not None:
            view.log_frame(frame, mask)
        now = time.monotonic()
        arrived = frames.arrival(frame.index)
        stats.shown(None if arrived is None else now - arrived, now)
        stats.frames_read, stats.frames_dropped = reader.frames_read, buffer.dropped
        if on_status is not None and now - last_status[0] >= status_every_s:
            last_status[0] = now
            on_status(stats)

    def counts() -> dict[str, Any]:
        """The run's numbers for summary.json, once the frames ended (the reader stopped first)."""
        reader.finish()
        stats.frames_read, stats.frames_dropped = reader.frames_read, buffer.dropped
        return {"live": {"source_kind": source.kind, "end": frames.end or reader.end, **stats.record()}}

    stats.started = time.monotonic()
    summary = None
    try:
        if out_dir is not None:
            info = {"kind": "stream", "num_frames": None, "fps": fps, "size_hw": (height, width)}
            summary = write_video_outputs(
                source.name, out_dir, cfg, model, overwrite, rrd, None, on_window, None, frames, info, on_frame, counts
            )
        else:
            _show_only(source.name, cfg, model, frames, on_frame, on_window)
    except MosegError as exc:
        hint = suspect or _stdin_size_hint(source, exc, width, height)
        if hint:  # the likely cause of a failure on such frames (no tracks, too few frames)
            raise type(exc)(f"{exc} ({hint})") from exc
        raise
    finally:
        reader.finish()  # the reader stops at its next frame
    if suspect:
        log.warning("%s: %s", source.name, suspect)
    stats.frames_read, stats.frames_dropped = reader.frames_read, buffer.dropped
    _warn_dropped(source.name, stats)
    partial = capture.partial_bytes if isinstance(capture, RawCapture) else 0
    return LiveResult(frames.end or reader.end, stats, summary, windows[0], partial)
