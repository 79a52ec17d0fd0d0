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
import logging
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, Literal

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe.errors import InputError, MosegError
from mosegpipe.pipeline import PipelineConfig, VideoFrame, WindowResult, frame_mask, segment_video
from mosegpipe.pipeline.video import MIN_VIDEO_SIDE_PX
from mosegpipe.runtime import run_ahead

if TYPE_CHECKING:
    import rerun as rr

    from mosegpipe.inference import Embedder
    from mosegpipe.viz import VizConfig

log = logging.getLogger(__name__)

SourceKind = Literal["camera", "url", "file", "stdin"]

BUFFER_FRAMES = 4
"""Frames the reader may hold for the pipeline: they bridge the pause of a window's clustering (the
tracker waits for it); once the pipeline falls behind, each held frame adds a frame's time of
latency."""

DEFAULT_FPS = 25.0
"""Frame rate assumed for the outputs of a source that does not state one (stdin, some cameras)."""

_WINDOWS_AHEAD = 1
"""Windows the segmenting thread may run ahead of the view (latency: a window's frames each)."""

_POLL_S = 0.1
"""How often a waiting reader or pipeline looks at the stop signal."""

_JOIN_S = 5.0
"""How long the end of a run waits for the reader of an OpenCV source to finish its read."""

_JOIN_RAW_S = 0.5
"""The same for raw frames on stdin (a read blocked on a silent pipe holds nothing native)."""


# ---------------------------------------------------------------------------------------------
# Sources
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class LiveSource:
    """What to read.

    Attributes:
        name: the source as given (camera index, URL, path or "-").
        kind: "camera" (an index), "url" (anything with "://": rtsp, http, ...), "file" or "stdin".
        realtime: a file is played at its own frame rate (live-like: frames are dropped when the
            pipeline falls behind); False reads it as fast as the pipeline takes it.
        stdin_size: (width, height) of the raw BGR frames on stdin.
        fps: frame rate to assume (None: what the source says, else DEFAULT_FPS).
        drop: drop frames (True) or wait for the pipeline (False) when it falls behind; None: drop
            for a camera, a stream and a file played in real time; wait for stdin (a pipe's writer
            can wait: nothing is lost unless asked) and a file read as fast as possible.
    """

    name: str
    kind: SourceKind
    realtime: bool = False
    stdin_size: tuple[int, int] | None = None
    fps: float | None = None
    drop: bool | None = None

    @property
    def drops(self) -> bool:
        """Whether frames are dropped (not waited for) when the pipeline falls behind."""
        return self.drop if self.drop is not None else self.kind in ("camera", "url") or self.realtime


MAX_STDIN_SIDE_PX = 16_384
"""The widest or tallest raw frame taken on stdin (a size is checked before a frame is allocated)."""

MAX_STDIN_PIXELS = 64 * 2**20
"""The most pixels of a raw frame on stdin (64 Mi: 192 MiB a frame; 8K UHD is 33 M)."""

MAX_CAMERA_INDEX = 2**31 - 1
"""The largest camera index OpenCV takes (a C int)."""


def parse_size(text: str) -> tuple[int, int]:
    """`640x480` -> (640, 480).

    Raises:
        InputError: not WIDTHxHEIGHT with positive integers, or beyond MAX_STDIN_SIDE_PX a side or
            MAX_STDIN_PIXELS in all.
    """
    parts = text.lower().split("x")
    if len(parts) != 2 or not all(p.strip().isascii() and p.strip().isdigit() for p in parts):
        raise InputError(f"--stdin-size {text!r}: expected WIDTHxHEIGHT in pixels, e.g. 640x480")
    size = int(parts[0]), int(parts[1])
    _check_stdin_size(size, text)
    return size


def _check_stdin_size(size: tuple[int, int], text: str) -> None:
    width, height = size
    if min(width, height) < 1:
        raise InputError(f"--stdin-size {text!r}: width and height must be at least 1 pixel")
    if max(width, height) > MAX_STDIN_SIDE_PX or width * height > MAX_STDIN_PIXELS:
        raise InputError(
            f"--stdin-size {text!r}: too large (at most {MAX_STDIN_SIDE_PX} px a side and "
            f"{MAX_STDIN_PIXELS // 2**20} Mi pixels a frame)"
        )


def parse_source(
    text: str,
    realtime: bool = False,
    stdin_size: tuple[int, int] | None = None,
    fps: float | None = None,
    drop: bool | None = None,
) -> LiveSource:
    """Tells a camera index, a URL, stdin ("-") and a file apart, and checks the options that go with each.

    Raises:
        InputError: a missing file or a folder, a camera index beyond MAX_CAMERA_INDEX, stdin
            without a frame size, a frame size or --realtime that does not apply, a frame rate that
            is not positive.
    """
    if fps is not None and not (np.isfinite(fps) and fps > 0):
        raise InputError(f"--fps {fps}: must be a positive number")
    kind: SourceKind
    if text == "-":
        kind = "stdin"
        if stdin_size is None:
            raise InputError("SOURCE '-' (raw frames on stdin) needs --stdin-size WIDTHxHEIGHT")
    elif text.isascii() and text.isdigit():
        kind = "camera"
        if int(text) > MAX_CAMERA_INDEX:
            raise InputError(f"camera index {text}: too large (OpenCV takes 0..{MAX_CAMERA_INDEX})")
    elif "://" in text:
        kind = "url"
    else:
        if Path(text).is_dir():
            raise InputError(
                f"{text}: is a folder; SOURCE is a camera index, a URL, a video file or '-' "
                "(a folder of frames: `moseg run FOLDER --whole`)"
            )
        if not Path(text).is_file():
            raise InputError(f"{text}: no such file (SOURCE is a camera index, a URL, a video file or '-')")
        kind = "file"
    if stdin_size is not None and kind != "stdin":
        raise InputError("--stdin-size only applies to SOURCE '-' (raw frames on stdin)")
    if stdin_size is not None:
        _check_stdin_size(stdin_size, "x".join(str(n) for n in stdin_size))
    if realtime and kind != "file":
        raise InputError(f"--realtime only applies to a video file (a {kind} delivers frames in real time itself)")
    return LiveSource(text, kind, realtime, stdin_size, fps, drop)


class Capture:
    """A source opened for reading: `read` gives the next (H, W, 3) uint8 RGB frame, None at the end."""

    fps: float = 0.0  # frame rate the source states (0.0 when it does not)

    def read(self) -> npt.NDArray[np.uint8] | None:
        raise NotImplementedError

    def close(self) -> None:
        """Releases the source (called once, by the thread that reads it)."""


class _CvCapture(Capture):
    """A camera, a URL or a file through OpenCV (FFmpeg for files and streams)."""

    def __init__(self, source: LiveSource, timeout_s: float) -> None:
        ms = int(min(timeout_s, 600.0) * 1000)
        timeouts = [cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, ms, cv2.CAP_PROP_READ_TIMEOUT_MSEC, ms]
        if source.kind == "camera":
            self._cap = cv2.VideoCapture(int(source.name))
        elif source.kind == "url":
            self._cap = cv2.VideoCapture(source.name, cv2.CAP_FFMPEG, timeouts)
        else:
            self._cap = cv2.VideoCapture(source.name)
        if not self._cap.isOpened():
            self._cap.release()
            what = {"camera": "camera", "url": "stream", "file": "video"}[source.kind]
            raise InputError(f"{source.name}: cannot open the {what} (OpenCV could not open it)")
        fps = float(self._cap.get(cv2.CAP_PROP_FPS))
        self.fps = fps if np.isfinite(fps) and 0 < fps < 1000 else 0.0

    def read(self) -> npt.NDArray[np.uint8] | None:
        ok, bgr = self._cap.read()
        if not ok or bgr is None:
            return None
        code = cv2.COLOR_GRAY2RGB if bgr.ndim == 2 else cv2.COLOR_BGR2RGB
        return np.asarray(cv2.cvtColor(bgr, code), dtype=np.uint8)

    def close(self) -> None:
        self._cap.release()


class RawCapture(Capture):
    """Raw 8-bit BGR frames of a known size from a byte stream (ffmpeg's `-f rawvideo -pix_fmt bgr24`).

    A stream that ends inside a frame ends there; the partial frame is dropped (`partial_bytes`).
    """

    def __init__(self, stream: IO[bytes], size_wh: tuple[int, int], owned: bool = False) -> None:
        self._stream = stream
        self._owned = owned  # close() closes it
        self._width, self._height = size_wh
        self._frame_bytes = self._width * self._height * 3
        self.partial_bytes = 0

    def read(self) -> npt.NDArray[np.uint8] | None:
        buf = bytearray(self._frame_bytes)
        view = memoryview(buf)
        got = 0
        while got < self._frame_bytes:
            n = self._stream.readinto(view[got:])  # type: ignore[attr-defined]
            if not n:
                self.partial_bytes = got
                return None
            got += n
        bgr = np.frombuffer(buf, dtype=np.uint8).reshape(self._height, self._width, 3)
        return np.asarray(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), dtype=np.uint8)

    def close(self) -> None:
        if self._owned:
            self._stream.close()


def _stdin_bytes() -> tuple[IO[bytes], bool]:
    """This process's stdin as an unbuffered file of its own (a copy of the descriptor; True: to be closed).

    The reader thread may be blocked in a read of it when the process exits (a stalled pipe); a
    read through sys.stdin's buffer would hold the buffer's lock, which Python's shutdown then
    waits for and aborts on.
    """
    import io
    import os
    import sys

    try:
        fd = os.dup(sys.stdin.fileno())
    except (AttributeError, OSError, ValueError, io.UnsupportedOperation):  # not a real file (tests)
        return sys.stdin.buffer, False
    return open(fd, "rb", buffering=0), True  # noqa: SIM115 - closed with the reader's capture


_SHEAR_MAX_PX = 1024
"""The widest shear between rows that `stdin_size_suspect` looks for (a width wrong by up to this)."""


def _row_costs(gray: npt.NDArray[np.float32], lag: int, max_shift: int) -> npt.NDArray[np.float32]:
    """Mean |row r+lag at x+s - row r at x| for s in -max_shift..max_shift, on a sample of rows and columns."""
    h, w = gray.shape
    rows = np.unique(np.linspace(0, h - 1 - lag, min(h - lag, 32)).astype(np.int64))
    above, below = gray[rows], gray[rows + lag]
    costs = np.empty(2 * max_shift + 1, np.float32)
    for i, shift in enumerate(range(-max_shift, max_shift + 1)):
        lo, hi = max(0, -shift), w - max(0, shift)
        cols = np.unique(np.linspace(lo, hi - 1, min(hi - lo, 256)).astype(np.int64))
        costs[i] = np.abs(below[:, cols + shift] - above[:, cols]).mean()
    return costs


def stdin_size_suspect(image: npt.NDArray[np.uint8]) -> str:
    """Why a raw frame read with a declared size looks read with the wrong width ("" when it does not).

    Raw frames of W' px read as W px wide shear: each row continues W' - W px further along in the
    next one, so rows line up best at that shift and not straight below each other (in a camera's
    image they line up straight below: measured 1.0 against 0.13-0.65 for widths wrong by 2..128 px
    on three videos, and no false alarm on 60 benchmark frames); read as half as wide, every other
    row lines up. A slanted grating can look sheared too, so this only warns.

    Args:
        image: (H, W, 3) uint8, one frame as read.
    """
    gray = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY).astype(np.float32)
    h, w = gray.shape
    if h < 4 or w < 8:
        return ""
    max_shift = min(w // 2, _SHEAR_MAX_PX)
    costs = _row_costs(gray, 1, max_shift)
    straight = float(costs[max_shift])
    if straight < 2.0:  # flat: nothing to tell by
        return ""
    best = int(np.argmin(costs))
    shift = best - max_shift
    if abs(shift) >= 2 and costs[best] < 0.7 * straight:
        return f"each row lines up with the next {abs(shift)} px to the {'right' if shift > 0 else 'left'} (frames {w + shift} px wide?)"
    if float(_row_costs(gray, 2, 0)[0]) < 0.5 * straight:
        return f"every other row lines up (frames {2 * w} px wide?)"
    return ""


def open_source(source: LiveSource, timeout_s: float = 10.0, stdin: IO[bytes] | None = None) -> Capture:
    """Opens a source for reading.

    Args:
        source: what to open.
        timeout_s: how long OpenCV may wait to open a stream or for one of its frames.
        stdin: the byte stream of SOURCE "-" (None: this process's stdin).

    Raises:
        InputError: the source cannot be opened.
    """
    if source.kind == "stdin":
        assert source.stdin_size is not None  # parse_source checks it
        if stdin is not None:
            return RawCapture(stdin, source.stdin_size)
        stream, owned = _stdin_bytes()
        return RawCapture(stream, source.stdin_size, owned)
    return _CvCapture(source, timeout_s)


# ---------------------------------------------------------------------------------------------
# The bounded hand-over between the reader and the pipeline
# ---------------------------------------------------------------------------------------------

_Item = tuple[int, npt.NDArray[np.uint8], float]
"""(frame index in the source, RGB image, arrival time on time.monotonic())."""


class FrameBuffer:
    """At most `capacity` frames between a reader thread and the pipeline.

    When it is full, `put` drops the oldest frame held (`drop`, a live source: the newest frames
    are the ones worth showing; `dropped` counts them) or waits for room (a file read as fast as
    possible). A buffer made with `hold` waits instead of dropping until `release` (the pipeline has
    started: its model loaded, its first window segmented): a source read faster than real time
    loses nothing to the start-up. `close` ends it: `get` gives the frames still held, then None
    for good.
    """

    def __init__(self, capacity: int = BUFFER_FRAMES, drop: bool = True, hold: bool = False) -> None:
        if capacity < 1:
            raise InputError(f"buffer of {capacity} frames: must hold at least 1")
        self.capacity = capacity
        self.drop = drop
        self.holding = hold
        self.dropped = 0
        self.last_put = time.monotonic()
        self._items: collections.deque[_Item] = collections.deque()
        self._closed = False
        self._cond = threading.Condition()

    def __len__(self) -> int:
        with self._cond:
            return len(self._items)

    def put(self, item: _Item, stop: threading.Event | None = None) -> bool:
        """Hands over one frame; False when the buffer was closed (or `stop` set) while waiting for room."""
        with self._cond:
            while (not self.drop or self.holding) and len(self._items) >= self.capacity and not self._closed:
                if stop is not None and stop.is_set():
                    return False
                self._cond.wait(_POLL_S)
            if self._closed:
                return False
            if len(self._items) >= self.capacity:
                self._items.popleft()
                self.dropped += 1
            self._items.append(item)
            self.last_put = time.monotonic()
            self._cond.notify_all()
            return True

    def release(self) -> None:
        """From now on a full buffer drops (when made with `drop`) rather than waits."""
        with self._cond:
            self.holding = False
            self._cond.notify_all()

    def peek(self, timeout: float) -> _Item | None | Literal[False]:
        """As `get`, but the frame stays held."""
        with self._cond:
            if not self._items and not self._closed:
                self._cond.wait(timeout)
            if self._items:
                return self._items[0]
            return False if self._closed else None

    def close(self) -> None:
        """No more frames will come (those held are still given out)."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    def get(self, timeout: float) -> _Item | None | Literal[False]:
        """The oldest frame held; None when `timeout` passed without one; False once closed and empty."""
        with self._cond:
            if not self._items and not self._closed:
                self._cond.wait(timeout)
            if self._items:
                item = self._items.popleft()
                self._cond.notify_all()
                return item
            return False if self._closed else None


class SourceReader(threading.Thread):
    """Reads a source into a FrameBuffer until it ends, `max_frames` were read or `stop` is set.

    A realtime source hands frame i over at first + i / fps (a file played at its frame rate; time
    spent waiting for room in the buffer shifts the schedule, so that a held start does not end in
    a burst); otherwise each frame as soon as it is read. Frame indices count every frame read,
    dropped or not. The first frame too is read here, not by the thread that waits for it (a source
    that never delivers must not keep a signal or the stall timeout from ending the wait). The reader
    closes the source itself when it ends (OpenCV captures are not to be released from another
    thread while one reads); `finish` stops it and waits for it, so that no thread is inside OpenCV
    when the process exits (a daemon thread there at exit aborts the process). A read that blocks
    for good (a pipe with no writer data) leaves the thread blocked, which as a daemon does not keep
    the process alive.
    """

    def __init__(
        self,
        capture: Capture,
        buffer: FrameBuffer,
        stop: threading.Event,
        pace_fps: float | None = None,
        max_frames: int | None = None,
        name: str = "source",
    ) -> None:
        super().__init__(name="moseg-source", daemon=True)
        self.source_name = name
        self.capture = capture
        self.buffer = buffer
        self.stop = stop
        self.pace_fps = pace_fps
        self.max_frames = max_frames
        self.frames_read = 0
        self.end = "ended"  # or "max-frames", "stopped"
        self.error: BaseException | None = None

    def run(self) -> None:
        try:
            self._read()
        except BaseException as exc:  # handed to the pipeline's thread by LiveFrames
            self.error = exc
        finally:
            self.buffer.close()
            self.capture.close()

    def finish(self) -> None:
        """Stops the reader and waits for it: at most a read's time (a blocked raw pipe: a moment)."""
        self.stop.set()
        if self.is_alive():
            self.join(_JOIN_RAW_S if isinstance(self.capture, RawCapture) else _JOIN_S)

    def _read(self) -> None:
        started = time.monotonic()
        while not self.stop.is_set():
            frame = self.capture.read()
            if frame is None:
                return
            if self.pace_fps:
                wait = started + self.frames_read / self.pace_fps - time.monotonic()
                if wait > 0 and self.stop.wait(wait):
                    break
            if self.stop.is_set():
                break
            before = time.monotonic()
            if not self.buffer.put((self.frames_read, frame, before), self.stop):
                break
            started += time.monotonic() - before  # a wait for room delays the schedule
            self.frames_read += 1
            if self.max_frames is not None and self.frames_read >= self.max_frames:
                self.end = "max-frames"
                return
        self.end = "stopped"


class LiveFrames:
    """The frames of a live source as segment_video reads them: (index, RGB image), in order.

    The stream ends when the source ends, when no frame came for `stall_timeout_s` (`end` =
    "stalled"), or when `stop` is set ("stopped", e.g. by Ctrl-C). Each frame's arrival time is kept
    until `arrival` takes it (for the latency of its mask).

    Raises (on iteration):
        InputError: the source failed while it was read.
    """

    def __init__(self, reader: SourceReader, stall_timeout_s: float) -> None:
        self.reader = reader
        self.stall_timeout_s = stall_timeout_s
        self.end = ""
        self.frames = 0
        self._arrivals: dict[int, float] = {}

    def arrival(self, index: int) -> float | None:
        """When frame `index` arrived (time.monotonic()), once; None when unknown."""
        return self._arrivals.pop(index, None)

    def __iter__(self) -> Iterator[tuple[int, npt.NDArray[np.uint8]]]:
        buffer, stop = self.reader.buffer, self.reader.stop
        while True:
            if stop.is_set():
                self.end = "stopped"
                return
            item = buffer.get(_POLL_S)
            if item is False:
                if self.reader.error is not None:
                    exc = self.reader.error
                    raise InputError(f"{self.reader.source_name}: reading failed ({exc})") from exc
                self.end = self.reader.end
                return
            if item is None:
                if time.monotonic() - buffer.last_put > self.stall_timeout_s:
                    self.end = "stalled"
                    return
                continue
            index, image, arrived = item
            self._arrivals[index] = arrived
            self.frames += 1
            yield index, image


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
        cfg: pipeline settings; cfg.frames is the window length.
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
    """
    from mosegpipe.outputs import check_output_dir

    if out_dir is not None:
        check_output_dir(out_dir, overwrite)
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
        item = reader.buffer.peek(_POLL_S)
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
    from mosegpipe.outputs import write_video_outputs

    buffer, capture = reader.buffer, reader.capture
    first = _first_frame(reader, stall_timeout_s)
    height, width = first.shape[:2]
    if min(height, width) < MIN_VIDEO_SIDE_PX:
        raise InputError(
            f"{source.name}: frames of {width}x{height} px are too small to track "
            f"(at least {MIN_VIDEO_SIDE_PX}x{MIN_VIDEO_SIDE_PX})"
        )
    suspect = stdin_size_suspect(first) if source.kind == "stdin" else ""
    if suspect:
        suspect = f"the frames do not look {width}x{height}: {suspect}; is --stdin-size right?"
    del first
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
                source.name,
                out_dir,
                cfg,
                model,
                overwrite=overwrite,
                rrd=rrd,
                frames=frames,
                info=info,
                on_window=on_window,
                on_frame=on_frame,
                summary_extra=counts,
            )
        else:
            segmented = segment_video(source.name, cfg, model, masks=False, frames=frames)
            for window in run_ahead(segmented, _WINDOWS_AHEAD, "moseg-segment"):
                for fr in window.frames:
                    on_frame(fr, frame_mask(fr, cfg.mask))
                on_window(window)  # after its frames, as write_video_outputs reports it
                del window
    except MosegError as exc:
        if suspect:  # the likely cause of a failure on such frames (no tracks, too few frames)
            raise type(exc)(f"{exc} ({suspect})") from exc
        raise
    finally:
        reader.finish()  # the reader stops at its next frame
    if suspect:
        log.warning("%s: %s", source.name, suspect)
    stats.frames_read, stats.frames_dropped = reader.frames_read, buffer.dropped
    if stats.dropped_share > MOST_DROPPED:
        log.warning(
            "%s: %d of %d frames dropped (%.0f %%): the segmenter fell far behind the source "
            "(--no-drop waits for it where the source can wait; --preset fast, --max-corners, --mask-method nearest make it faster)",
            source.name,
            stats.frames_dropped,
            stats.frames_read,
            100 * stats.dropped_share,
        )
    partial = capture.partial_bytes if isinstance(capture, RawCapture) else 0
    return LiveResult(frames.end or reader.end, stats, summary, windows[0], partial)
