"""Between a live source and the pipeline (mosegpipe.apps.live.run): the reader thread (SourceReader), the few
frames it may hold (FrameBuffer: a live source drops its oldest, stdin and files wait) and the
frames as the pipeline takes them (LiveFrames: they end when the source ends, stalls or is stopped)."""

from __future__ import annotations

import collections
import threading
import time
from collections.abc import Iterator
from typing import TYPE_CHECKING, Literal

import numpy as np
import numpy.typing as npt

from mosegpipe.apps.live.source import Capture, RawCapture
from mosegpipe.errors import InputError

if TYPE_CHECKING:
    pass

BUFFER_FRAMES = 4
"""Frames the reader may hold for the pipeline: they bridge the pause of a window's clustering (the
tracker waits for it); once the pipeline falls behind, each held frame adds a frame's time of
latency."""

POLL_S = 0.1
"""How often a waiting reader or pipeline looks at the stop signal."""

_JOIN_S = 5.0
"""How long the end of a run waits for the reader of an OpenCV source to finish its read."""

_JOIN_RAW_S = 0.5
"""The same for raw frames on stdin (a read blocked on a silent pipe holds nothing native)."""


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
                self._cond.wait(POLL_S)
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
            item = buffer.get(POLL_S)
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
