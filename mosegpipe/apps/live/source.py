"""Live sources (mosegpipe.apps.live.run): what SOURCE names (a camera index, a URL, a file, `-` for raw frames
on stdin), opening it, reading raw frames and telling a wrong --stdin-size."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import IO, TYPE_CHECKING, Literal

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe.errors import InputError

if TYPE_CHECKING:
    pass

SourceKind = Literal["camera", "url", "file", "stdin"]


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
