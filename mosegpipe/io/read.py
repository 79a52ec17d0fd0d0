"""Reading videos, frame folders and images; writing masks, JSON, arrays and videos atomically.

Every writer goes through :func:`atomic_write`, so an interrupted run never leaves a half-written
file under the final name (a later run that skips finished outputs can trust what it finds).
"""

from __future__ import annotations

import logging
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe.errors import InputError
from mosegpipe.io.provenance import IMAGE_SUFFIXES  # defined there: the CLI lists frame folders without OpenCV
from mosegpipe.io.write import (
    H264_CRF,
    H264_PRESET,
    H264Encoder,
    atomic_write,
    default_palette,
    write_csv,
    write_jpeg,
    write_json,
    write_npz,
    write_palette_png,
    write_text,
    write_video,
)
from mosegpipe.runtime import native_stderr_muted
from mosegpipe.types import Frames

logger = logging.getLogger("mosegpipe.io.read")

__all__ = [
    "H264_CRF",
    "H264_PRESET",
    "IMAGE_SUFFIXES",
    "H264Encoder",
    "as_path",
    "atomic_write",
    "check_images",
    "default_cache_dir",
    "default_palette",
    "iter_video",
    "read_image",
    "read_palette_png",
    "read_video",
    "video_info",
    "write_csv",
    "write_jpeg",
    "write_json",
    "write_npz",
    "write_palette_png",
    "write_text",
    "write_video",
]

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def default_cache_dir() -> Path:
    """`$MOSEG_CACHE`, else `~/.cache/mosegpipe`: tracked training windows, inference copies of weights."""
    env = os.environ.get("MOSEG_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "mosegpipe"


def as_path(path: object, what: str = "path") -> Path:
    """`path` as a Path, or an InputError naming what was given instead (None, a number, an array).

    Args:
        path: a str or os.PathLike.
        what: how the argument is named in the message.

    Raises:
        InputError: `path` is not a str or os.PathLike, or is empty.
    """
    if not isinstance(path, (str, os.PathLike)) or isinstance(path, bytes):
        raise InputError(f"{what}: expected a file path (str or os.PathLike), got {type(path).__name__}")
    p = Path(path)
    if not str(path):
        raise InputError(f"{what}: the path is empty")
    return p


def check_images(images: object, what: str = "image", stack: bool = False) -> npt.NDArray[np.uint8]:
    """An RGB image (or a stack of them) handed in as an array, checked before OpenCV sees it.

    Args:
        images: (H, W, 3) uint8 RGB, or (T, H, W, 3) with `stack`.
        what: how the argument is named in the message.
        stack: expect a stack of T >= 1 frames.

    Returns:
        The array, unchanged.

    Raises:
        InputError: not a uint8 array of that shape, or an empty image (H or W of 0).
    """
    shape = "(T, H, W, 3)" if stack else "(H, W, 3)"
    if not isinstance(images, np.ndarray):
        raise InputError(f"{what}: expected a {shape} uint8 array, got {type(images).__name__}")
    ndim = 4 if stack else 3
    if images.ndim != ndim or images.shape[-1] != 3 or images.dtype != np.uint8:
        raise InputError(f"{what}: expected a {shape} uint8 RGB array, got {images.dtype} {images.shape}")
    if images.size == 0:
        raise InputError(f"{what}: empty image (shape {images.shape})")
    return images


class _NativeStderr:
    """Keeps what OpenCV's own container parsers print to file descriptor 2 off the terminal.

    OpenCV's AVI parser writes lines such as "Unexpected element. Expected: LIST. Got: ..." (often
    with raw, non-UTF-8 bytes from the file) straight to fd 2, before the failure they lead to is
    raised as one InputError. While a capture is entered, fd 2 points at a temporary file; what
    landed there is logged at DEBUG level (`moseg -v` shows it). Entered only around the OpenCV
    calls themselves (open, grab, read), so other output is redirected for microseconds at most.
    """

    def __init__(self) -> None:
        self._file: Any = None
        self._saved: int | None = None

    def __enter__(self) -> _NativeStderr:
        try:
            if self._file is None:
                self._file = tempfile.TemporaryFile()
            self._saved = os.dup(2)
            os.dup2(self._file.fileno(), 2)
        except (OSError, ValueError):  # no fd 2 (a service, a closed stderr): nothing to keep quiet
            self._saved = None
        return self

    def __exit__(self, *exc: object) -> None:
        if self._saved is None:
            return
        os.dup2(self._saved, 2)
        os.close(self._saved)
        self._saved = None
        if self._file.tell():
            self._file.seek(0)
            text = self._file.read(2000).decode("utf-8", "replace")
            logger.debug("OpenCV printed: %s", " ".join(text.split()))
            self._file.seek(0)
            self._file.truncate()

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None


def read_image(path: str | os.PathLike[str]) -> npt.NDArray[np.uint8]:
    """Read one image file as RGB.

    Grayscale images are replicated to 3 channels, alpha is dropped and 16-bit images are scaled
    to 8 bits (OpenCV's IMREAD_COLOR conversion).

    Args:
        path: an image file OpenCV can decode (png, jpg, bmp, tif, ...).

    Returns:
        (H, W, 3) uint8 RGB image.

    Raises:
        InputError: the file is missing or cannot be decoded as an image, or `path` is not a path.
    """
    p = as_path(path, "image")
    if not p.is_file():
        raise InputError(f"{p}: no such image file")
    # np.fromfile + imdecode instead of imread: imread silently fails on some non-ASCII paths.
    try:
        buf = np.fromfile(p, dtype=np.uint8)
    except OSError as exc:
        raise InputError(f"{p}: cannot read file ({exc})") from exc
    with native_stderr_muted():  # libpng prints its errors itself ("libpng error: Not enough image data")
        bgr = cv2.imdecode(buf, cv2.IMREAD_COLOR) if buf.size else None
    if bgr is None:
        raise InputError(f"{p}: not a readable image (corrupt or unsupported format)")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def _list_images(folder: Path) -> list[Path]:
    return sorted(
        (f for f in folder.iterdir() if f.is_file() and f.suffix.lower() in IMAGE_SUFFIXES),
        key=lambda f: f.name,
    )


def _check_start_chunk(path: Path, start: int, chunk: int | None, max_frames: int | None) -> None:
    for name, value in (("start", start), ("chunk", chunk), ("max_frames", max_frames)):
        if value is not None and (isinstance(value, bool) or not isinstance(value, (int, np.integer))):
            raise InputError(f"{path}: {name}={value!r} must be an integer")
    if start < 0:
        raise InputError(f"{path}: start={start} must be >= 0")
    if chunk is not None and chunk < 1:
        raise InputError(f"{path}: chunk={chunk} must be >= 1")
    if max_frames is not None and max_frames < 1:
        raise InputError(f"{path}: max_frames={max_frames} must be >= 1")


def _iter_single_frames(path: Path, start: int, max_frames: int | None) -> Iterator[tuple[int, npt.NDArray[np.uint8]]]:
    """Yield (index, (H, W, 3) RGB frame) from a folder, an image file or a video file."""
    if not path.exists():
        raise InputError(f"{path}: no such file or folder")
    if not (path.is_dir() or path.is_file()):  # before any open(): a FIFO's blocks until a writer comes
        raise InputError(f"{path}: not a regular file or folder (a FIFO, socket or device is not read as a video)")
    stop = None if max_frames is None else start + max_frames
    if path.is_dir():
        files = _list_images(path)
        if not files:
            raise InputError(f"{path}: folder holds no images ({', '.join(sorted(IMAGE_SUFFIXES))})")
        if start >= len(files):
            raise InputError(f"{path}: start={start} but the folder has only {len(files)} images")
        size_hw: tuple[int, int] | None = None
        for index in range(start, len(files) if stop is None else min(stop, len(files))):
            image = read_image(files[index])
            if size_hw is None:
                size_hw = image.shape[:2]
            elif image.shape[:2] != size_hw:
                raise InputError(
                    f"{files[index]}: image is {image.shape[1]}x{image.shape[0]} but earlier images in "
                    f"{path} are {size_hw[1]}x{size_hw[0]}"
                )
            yield index, image
        return
    if path.suffix.lower() in IMAGE_SUFFIXES:
        if start > 0:
            raise InputError(f"{path}: start={start} but a single image has only 1 frame")
        yield 0, read_image(path)
        return
    quiet = _NativeStderr()
    with quiet:
        cap = cv2.VideoCapture(str(path))
    try:
        if not cap.isOpened():
            raise InputError(f"{path}: not a readable video (OpenCV could not open it)")
        # grab() through the skipped frames: seeking with CAP_PROP_POS_FRAMES is keyframe-inexact
        # for some codecs, and frame indices must match the source exactly.
        for skipped in range(start):
            with quiet:
                grabbed = cap.grab()
            if not grabbed:
                if skipped == 0:
                    raise InputError(f"{path}: no frames could be decoded (corrupt or truncated video?)")
                raise InputError(f"{path}: start={start} but the video has only {skipped} frames")
        index = start
        while stop is None or index < stop:
            with quiet:
                ok, bgr = cap.read()
            if not ok or bgr is None:
                break
            if bgr.ndim == 2:
                bgr = cv2.cvtColor(bgr, cv2.COLOR_GRAY2BGR)
            yield index, cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
            index += 1
        if index == start:
            if start == 0:
                raise InputError(f"{path}: no frames could be decoded (corrupt or truncated video?)")
            raise InputError(f"{path}: start={start} is at or past the last decodable frame")
    finally:
        cap.release()
        quiet.close()


def iter_video(
    path: str | os.PathLike[str],
    start: int = 0,
    chunk: int | None = None,
    *,
    max_frames: int | None = None,
) -> Iterator[tuple[int, npt.NDArray[np.uint8]]]:
    """Stream frames of a video file, a folder of images or a single image, keeping memory flat.

    Args:
        path: a video file OpenCV can read, a folder of images (sorted by file name) or one image.
        start: index of the first frame to yield.
        chunk: None to yield single frames; else yield stacks of up to `chunk` consecutive frames
            (the last stack may be shorter), for processing long videos in windows.
        max_frames: stop after this many frames in total (None = to the end).

    Yields:
        (index, frame): index of the (first) frame in the source, and a (H, W, 3) uint8 RGB frame,
        or a (n, H, W, 3) uint8 stack with n <= chunk when `chunk` is given.

    Raises:
        InputError: missing path, unreadable or corrupt video, empty folder, images of different
            sizes, or `start` past the end. Raised lazily, on iteration.
    """
    p = as_path(path, "video")
    _check_start_chunk(p, start, chunk, max_frames)
    frames = _iter_single_frames(p, start, max_frames)
    if chunk is None:
        yield from frames
        return
    batch: list[npt.NDArray[np.uint8]] = []
    first = start
    for index, frame in frames:
        if not batch:
            first = index
        batch.append(frame)
        if len(batch) == chunk:
            yield first, np.stack(batch)
            batch = []
    if batch:
        yield first, np.stack(batch)


def _video_fps(path: Path) -> float:
    if path.is_dir() or path.suffix.lower() in IMAGE_SUFFIXES:
        return 0.0
    with _NativeStderr() as quiet:
        cap = cv2.VideoCapture(str(path))
    quiet.close()
    try:
        fps = float(cap.get(cv2.CAP_PROP_FPS)) if cap.isOpened() else 0.0
    finally:
        cap.release()
    return fps if np.isfinite(fps) and fps > 0 else 0.0


def read_video(path: str | os.PathLike[str], max_frames: int | None = None, start: int = 0) -> Frames:
    """Read frames of a video file, a folder of images or a single image into memory.

    Args:
        path: a video file OpenCV can read, a folder of png/jpg/jpeg/bmp/tif images (sorted by
            name; grayscale images become 3-channel) or one image file.
        max_frames: read at most this many frames (None = all; mind the memory on long videos and
            prefer :func:`iter_video`). A shorter source gives fewer frames, not an error: the
            caller knows how many it needs.
        start: index of the first frame to read.

    Returns:
        Frames with images (T, H, W, 3) uint8 RGB, fps of the source (0.0 for folders/images),
        source = str(path) and start.

    Raises:
        InputError: missing path, unreadable or corrupt video, folder without images, images of
            different sizes, or `start` past the end.
    """
    p = as_path(path, "video")
    images = [frame for _, frame in iter_video(p, start=start, max_frames=max_frames)]
    return Frames(images=np.stack(images), fps=_video_fps(p), source=str(p), start=start)


def video_info(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Describe a video file, frame folder or image without decoding it all.

    Args:
        path: as for :func:`read_video`.

    Returns:
        dict with "kind" ("video", "folder" or "image"), "num_frames" (int, or None when the
        container does not say), "fps" (float, 0.0 when unknown), "size_hw" ((H, W) pixels,
        from the first frame).

    Raises:
        InputError: as for :func:`read_video`.
    """
    p = as_path(path, "video")
    # Decoding the first frame validates the input and gives the true size (container headers
    # can be missing or wrong).
    _, first = next(iter_video(p, max_frames=1))
    size_hw = (int(first.shape[0]), int(first.shape[1]))
    if p.is_dir():
        return {"kind": "folder", "num_frames": len(_list_images(p)), "fps": 0.0, "size_hw": size_hw}
    if p.suffix.lower() in IMAGE_SUFFIXES:
        return {"kind": "image", "num_frames": 1, "fps": 0.0, "size_hw": size_hw}
    with _NativeStderr() as quiet:
        cap = cv2.VideoCapture(str(p))
    quiet.close()
    try:
        count = float(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        fps = float(cap.get(cv2.CAP_PROP_FPS))
    finally:
        cap.release()
    return {
        "kind": "video",
        "num_frames": int(count) if np.isfinite(count) and count > 0 else None,
        "fps": fps if np.isfinite(fps) and fps > 0 else 0.0,
        "size_hw": size_hw,
    }


def read_palette_png(path: str | os.PathLike[str]) -> npt.NDArray[np.uint8]:
    """Read the palette indices of an indexed-colour PNG (the inverse of :func:`write_palette_png`).

    Decodes 8-bit PNGs of colour type 3 (palette) or 0 (grayscale, whose values are returned as
    they are). OpenCV expands palettes to colours, so it cannot be used for this.

    Args:
        path: a .png file.

    Returns:
        (H, W) uint8 palette indices.

    Raises:
        InputError: missing file, not a PNG, corrupt data (CRC/zlib) or an unsupported variant.
    """
    from PIL import Image, UnidentifiedImageError

    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: no such file")
    with p.open("rb") as fh:
        if fh.read(len(_PNG_SIGNATURE)) != _PNG_SIGNATURE:
            raise InputError(f"{p}: not a PNG file")
    try:
        with Image.open(p, formats=["PNG"]) as image:
            if image.mode not in ("P", "L"):
                raise InputError(
                    f"{p}: unsupported PNG variant (mode {image.mode}); expected an 8-bit palette or grayscale PNG"
                )
            image.load()
            return np.array(image, dtype=np.uint8)
    except (UnidentifiedImageError, SyntaxError, OSError, ValueError) as exc:
        raise InputError(f"{p}: corrupt PNG (CRC mismatch or bad image data: {exc})") from exc
