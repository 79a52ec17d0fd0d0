"""Writing masks, JSON, CSV, arrays, images and videos (mosegpipe.io.read): every writer goes through
:func:`atomic_write`, so an interrupted run never leaves a half-written file under the final name."""

from __future__ import annotations

import contextlib
import csv
import json
import os
import secrets
from collections.abc import Iterable, Iterator, Mapping, Sequence
from io import StringIO as _StringIO
from pathlib import Path
from typing import Any, BinaryIO

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe.colours import mask_palette
from mosegpipe.errors import InputError

_VIDEO_FOURCC: dict[str, str] = {
    # opencv-python-headless has no H.264 encoder; MJPG writes and reads back frame-exact.
    ".avi": "MJPG",
}

H264_CRF = 23
"""x264 constant-rate factor of .mp4 files (its default; 0 = lossless, 51 = worst)."""

H264_PRESET = "veryfast"
"""x264 speed preset: 'veryfast' encodes a 640x480 frame in a few ms, files ~10 % larger than 'medium'."""


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Write a file under a temporary name and move it into place only if the body succeeds.

    The temporary file lives in the same folder (so os.replace is an atomic rename) and keeps the
    final suffix (OpenCV and numpy choose the format from it). Missing parent folders are created.

    Args:
        path: final file path.

    Yields:
        Temporary path the body must write to (the file does not exist yet).

    Raises:
        FileNotFoundError: the body finished without creating the temporary file.
        OSError: the body's or the rename's, named by the final path when it named no file (a full disk shows
            when a file is closed, and Python's error then names none).
    """
    final = Path(path)
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = final.with_name(f".{final.stem}.{secrets.token_hex(4)}.tmp{final.suffix}")
    try:
        yield tmp
        if not tmp.exists():
            raise FileNotFoundError(f"{final}: nothing was written to the temporary file {tmp.name}")
        os.replace(tmp, final)
    except BaseException as exc:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        if isinstance(exc, OSError) and exc.filename is None and exc.errno is not None:
            raise type(exc)(exc.errno, exc.strerror, str(final)) from exc
        raise


def default_palette() -> npt.NDArray[np.uint8]:
    """The palette of the mask PNGs: colours.mask_palette() (the PASCAL VOC / DAVIS colours, 255 grey).

    Returns:
        (256, 3) uint8 RGB, one colour per mask value, as the overlays and recordings draw them.
    """
    return mask_palette()


def write_palette_png(
    path: str | os.PathLike[str],
    mask: npt.NDArray[np.uint8],
    palette: npt.NDArray[np.uint8] | None = None,
) -> None:
    """Write an indexed-colour (palette) PNG, the DAVIS convention for label masks (Pillow's encoder).

    The pixel values are stored as palette indices (PNG colour type 3, 8 bits), so reading the
    file back gives the labels exactly while image viewers show colours.

    Args:
        path: output .png path (written atomically).
        mask: (H, W) uint8 label image.
        palette: (P, 3) uint8 RGB with P <= 256 (default :func:`default_palette`).

    Raises:
        ValueError: mask is not 2-D uint8 or palette is not (P <= 256, 3) uint8.
    """
    from PIL import Image

    mask = np.asarray(mask)
    if mask.ndim != 2 or mask.dtype != np.uint8 or mask.size == 0:
        raise ValueError(f"mask must be a non-empty (H, W) uint8 array, got {mask.dtype} {mask.shape}")
    palette = default_palette() if palette is None else np.asarray(palette)
    if palette.ndim != 2 or palette.shape[1] != 3 or not 1 <= palette.shape[0] <= 256 or palette.dtype != np.uint8:
        raise ValueError(f"palette must be (P <= 256, 3) uint8, got {palette.dtype} {palette.shape}")
    image = Image.fromarray(np.ascontiguousarray(mask))
    image.putpalette(np.ascontiguousarray(palette).tobytes())
    with atomic_write(path) as tmp:
        # zlib level 6: masks are long runs; the files are byte-identical to those of earlier versions.
        image.save(tmp, format="PNG", compress_level=6)


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    raise TypeError(f"object of type {type(obj).__name__} is not JSON serialisable")


def write_json(path: str | os.PathLike[str], obj: Any) -> None:
    """Write `obj` as indented UTF-8 JSON (numpy scalars/arrays and paths converted), atomically.

    Args:
        path: output file.
        obj: JSON-serialisable object; numpy values and os.PathLike are converted.
    """
    text = json.dumps(obj, indent=2, default=_json_default, ensure_ascii=False)
    with atomic_write(path) as tmp:
        tmp.write_text(text + "\n", encoding="utf-8")


def write_text(path: str | os.PathLike[str], text: str) -> None:
    """Write UTF-8 text as it is (no newline added), atomically.

    Args:
        path: output file.
        text: the whole content.
    """
    with atomic_write(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def write_csv(path: str | os.PathLike[str], rows: Sequence[Mapping[str, Any]]) -> None:
    """Write rows as CSV with a header, atomically; the columns are every key in order of first appearance.

    Args:
        path: output file.
        rows: one mapping per row; a missing key leaves its cell empty. No rows: a header "name" only.
    """
    buf = _StringIO()
    fields = list(dict.fromkeys(k for r in rows for k in r)) or ["name"]
    writer = csv.DictWriter(buf, fieldnames=fields)
    writer.writeheader()
    writer.writerows(rows)
    write_text(path, buf.getvalue())


def write_npz(path: str | os.PathLike[str], **arrays: npt.ArrayLike) -> None:
    """Write arrays to a compressed .npz file atomically.

    Args:
        path: output file (numpy would append ".npz" to a bare name; here the name is kept as given).
        **arrays: name -> array.
    """
    with atomic_write(path) as tmp, open(tmp, "wb") as fh:
        # A file object, not a name: np.savez would append ".npz" to the temporary name.
        np.savez_compressed(fh, **arrays)  # type: ignore[arg-type]


def write_jpeg(path: str | os.PathLike[str], rgb: npt.NDArray[np.uint8], quality: int = 90) -> None:
    """Write an RGB image as JPEG (OpenCV's encoder), atomically.

    Args:
        path: output .jpg path.
        rgb: (H, W, 3) uint8 RGB.
        quality: JPEG quality, 0..100.

    Raises:
        ValueError: OpenCV could not encode the image (not a valid (H, W, 3) uint8 array).
    """
    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise ValueError(f"{path}: OpenCV could not encode a JPEG of shape {rgb.shape}")
    with atomic_write(path) as tmp:
        tmp.write_bytes(buf.tobytes())


class H264Encoder:
    """Push-style H.264 encoder (yuv420p, x264 through PyAV, which bundles its codec) into an MP4.

    Frames are encoded as they are added; nothing but the encoder's look-ahead is held. Odd frame
    sizes are padded by one replicated row / column (yuv420p needs even sizes). The target is a file
    path or a seekable binary buffer (io.BytesIO: the MP4 muxer seeks back to write its index).

    Args:
        target: output .mp4 path or seekable binary file object.
        fps: frames per second to store (> 0).
        name: what error messages call the output (the final path).
        b_frames: let x264 use B-frames (smaller files). Off for a recording's video asset: frames
            then decode in presentation order, which every Rerun decoder plays frame-exact.
    """

    def __init__(
        self, target: str | os.PathLike[str] | BinaryIO, fps: float, name: str | os.PathLike[str], b_frames: bool = True
    ) -> None:
        import av

        if not fps > 0:
            raise InputError(f"{name}: fps={fps} must be > 0")
        self.name = Path(name)
        self.num_frames = 0
        self._fps = fps
        self._b_frames = b_frames
        self._size_wh: tuple[int, int] | None = None
        self._stream: Any = None
        target_arg = str(target) if isinstance(target, (str, os.PathLike)) else target
        self._container: Any = av.open(target_arg, mode="w", format="mp4")

    def add(self, frame: npt.NDArray[np.uint8]) -> None:
        """Encode one (H, W, 3) uint8 RGB frame, the same size as the first.

        Raises:
            InputError: wrong shape or dtype, or a size other than the first frame's.
        """
        import av

        frame = _check_video_frame(self.name, frame, self.num_frames, self._size_wh)
        if self._stream is None:
            from fractions import Fraction

            self._size_wh = (frame.shape[1], frame.shape[0])
            stream = self._container.add_stream("libx264", rate=Fraction(self._fps).limit_denominator(1001))
            width, height = self._size_wh
            stream.width, stream.height = width + width % 2, height + height % 2  # yuv420p: even sizes
            stream.pix_fmt = "yuv420p"
            stream.options = {"crf": str(H264_CRF), "preset": H264_PRESET, **({} if self._b_frames else {"bf": "0"})}
            self._stream = stream
        pad_h, pad_w = frame.shape[0] % 2, frame.shape[1] % 2
        if pad_h or pad_w:
            frame = cv2.copyMakeBorder(frame, 0, pad_h, 0, pad_w, cv2.BORDER_REPLICATE)
        for packet in self._stream.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(frame), format="rgb24")):
            self._container.mux(packet)
        self.num_frames += 1

    def close(self, flush: bool = True) -> int:
        """Flush the encoder (unless `flush` is False: a failed write) and close the container.

        Returns:
            Number of frames encoded.
        """
        if self._container is None:
            return self.num_frames
        container, self._container = self._container, None
        try:
            if flush and self._stream is not None:
                for packet in self._stream.encode(None):
                    container.mux(packet)
        finally:
            container.close()
        return self.num_frames


def _write_h264(final: Path, tmp: Path, frames_iter: Iterable[npt.NDArray[np.uint8]], fps: float) -> int:
    """H.264 into an .mp4 at `tmp` (see H264Encoder); frames counted."""
    encoder = H264Encoder(tmp, fps, final)
    flush = False
    try:
        for frame in frames_iter:
            encoder.add(frame)
        flush = True
    finally:
        encoder.close(flush=flush)
    return encoder.num_frames


def _check_video_frame(
    final: Path, frame: npt.NDArray[np.uint8], count: int, size_wh: tuple[int, int] | None
) -> npt.NDArray[np.uint8]:
    frame = np.asarray(frame)
    if frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype != np.uint8:
        raise InputError(f"{final}: frame {count} must be (H, W, 3) uint8, got {frame.dtype} {frame.shape}")
    if size_wh is not None and (frame.shape[1], frame.shape[0]) != size_wh:
        raise InputError(
            f"{final}: frame {count} is {frame.shape[1]}x{frame.shape[0]}, earlier frames are {size_wh[0]}x{size_wh[1]}"
        )
    return frame


def write_video(
    path: str | os.PathLike[str],
    frames_iter: Iterable[npt.NDArray[np.uint8]],
    fps: float,
) -> int:
    """Encode RGB frames to a video file atomically (H.264 in .mp4 through PyAV, MJPG in .avi through OpenCV).

    H.264 files are ~10-20x smaller than MJPG ones at similar quality (docs/RESULTS.md) and play in
    browsers and in Rerun; MJPG stays for readers without an H.264 decoder.

    Args:
        path: output path ending in .avi or .mp4.
        frames_iter: (H, W, 3) uint8 RGB frames, all the same size (consumed lazily).
        fps: frames per second to store (> 0).

    Returns:
        Number of frames written.

    Raises:
        InputError: unsupported suffix, fps <= 0, no frames, or frames of different sizes/dtypes.
        OSError: OpenCV could not open a writer for the file.
    """
    final = Path(path)
    suffix = final.suffix.lower()
    fourcc = _VIDEO_FOURCC.get(suffix)
    if fourcc is None and suffix != ".mp4":
        raise InputError(f"{final}: unsupported video suffix {final.suffix!r}; use .mp4 (H.264) or .avi (MJPG)")
    if not fps > 0:
        raise InputError(f"{final}: fps={fps} must be > 0")
    count = 0
    with atomic_write(final) as tmp:
        if fourcc is None:
            count = _write_h264(final, tmp, frames_iter, fps)
            if count == 0:
                raise InputError(f"{final}: no frames to write")
            return count
        writer: cv2.VideoWriter | None = None
        size_wh: tuple[int, int] | None = None
        try:
            for frame in frames_iter:
                frame = np.asarray(frame)
                if frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype != np.uint8:
                    raise InputError(f"{final}: frame {count} must be (H, W, 3) uint8, got {frame.dtype} {frame.shape}")
                if writer is None:
                    size_wh = (frame.shape[1], frame.shape[0])
                    writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*fourcc), float(fps), size_wh)  # type: ignore[attr-defined]
                    if not writer.isOpened():
                        raise OSError(f"{final}: OpenCV could not open a {fourcc} video writer")
                elif (frame.shape[1], frame.shape[0]) != size_wh:
                    raise InputError(
                        f"{final}: frame {count} is {frame.shape[1]}x{frame.shape[0]}, "
                        f"earlier frames are {size_wh[0]}x{size_wh[1]}"  # type: ignore[index]
                    )
                writer.write(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
                count += 1
        finally:
            if writer is not None:
                writer.release()
        if count == 0:
            raise InputError(f"{final}: no frames to write")
    return count
