"""Masks in the forms other programs take, from an existing output folder (`moseg export`; no re-run).

An output folder's masks/NNNNNN.png hold mask values (docs/OUTPUTS.md): 0 the world, 1..253 moving
motions, 254 moving without a clustered motion, 255 unknown. The objects are the moving values
(1..254) the masks hold; `objects` chooses some of them. The formats (EXPORT_FORMATS):

- binary: masks_by_object/<object>/NNNNNN.png, one 8-bit greyscale PNG per object and frame, 255 on the
  object's pixels and 0 elsewhere (what `cv2.imread(path, 0) > 0` or PIL wants).
- alpha: alpha/NNNNNN.png, RGBA PNGs: the source frame's colours with alpha 255 on the chosen objects
  and 0 elsewhere (an alpha matte for compositing; needs the source frames).
- cutout: cutout.mov, the chosen objects on a transparent background (PNG frames, RGBA, in a QuickTime
  container: lossless with alpha; ffplay, VLC, mpv, DaVinci Resolve and PyAV read it); with a
  `background` colour, cutout.mp4 instead, H.264 with the objects on that colour (any player).
- davis: davis/NNNNN.png, DAVIS-style palette PNGs (5-digit frame names, 0 = background, the chosen
  objects renumbered 1..n in their order, the PASCAL VOC / DAVIS palette) and davis/objects.json
  ({"1": object, ...}).
- npz: masks.npz with `masks` (T, H, W) uint8 mask values (objects not chosen set to 0 when `objects`
  is given), `frames` (T,) int64 source frame indices and `objects` (n,) int64.

Everything is checked before anything is written; a folder is built under a temporary name beside
it and renamed when complete, a file written atomically (io_write.atomic_write), so a failure leaves
nothing half-written.
"""

from __future__ import annotations

import contextlib
import json
import re
import shutil
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from mosegpipe.colours import UNKNOWN, WORLD, voc_palette
from mosegpipe.errors import InputError, OutputExistsError, check_choice
from mosegpipe.types import EXPORT_FORMATS

TARGETS = {"binary": "masks_by_object", "alpha": "alpha", "davis": "davis", "npz": "masks.npz"}
"""The file or folder each format writes into the destination (cutout: cutout.mov or cutout.mp4)."""

_FALLBACK_FPS = 10.0  # frame folders carry no rate (outputs writes overlay.mp4 at the same)
_MASK_NAME = re.compile(r"^(\d{6})\.png$")


@dataclass(frozen=True)
class OutputFolder:
    """An output folder of `moseg run` / `pair` / `tracks --video` / `live --out`, as export reads it.

    Attributes:
        path: the folder.
        summary: its summary.json.
        masks: (source frame index, mask PNG) of every frame, by index.
    """

    path: Path
    summary: dict[str, Any]
    masks: tuple[tuple[int, Path], ...]

    def read_mask(self, position: int) -> npt.NDArray[np.uint8]:
        """The (H, W) uint8 mask values of the frame at `position` in `masks`."""
        from mosegpipe.io.read import read_palette_png

        return read_palette_png(self.masks[position][1])


@dataclass(frozen=True)
class Export:
    """What `export_masks` wrote.

    Attributes:
        path: the file or folder written.
        format: one of EXPORT_FORMATS.
        objects: the objects (mask values) exported, in order.
        frames: frames written.
    """

    path: Path
    format: str
    objects: tuple[int, ...]
    frames: int


def read_output_folder(path: str | Path) -> OutputFolder:
    """The summary and mask files of an output folder.

    Raises:
        InputError: not a folder, no readable summary.json (not a moseg output), or no masks/ PNGs
            (a `moseg tracks` run without --video, a batch folder).
    """
    folder = Path(path)
    if not folder.is_dir():
        raise InputError(f"{folder}: no such folder (expected an output folder of moseg run)")
    summary_path = folder / "summary.json"
    if not summary_path.is_file():
        hint = " (a batch folder: export one of its clip folders)" if (folder / "batch_summary.json").is_file() else ""
        raise InputError(f"{folder}: holds no summary.json, so it is not a moseg output folder{hint}")
    try:
        summary = json.loads(summary_path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{summary_path}: not readable JSON ({exc})") from exc
    if not isinstance(summary, dict):
        raise InputError(f"{summary_path}: not a moseg summary (a JSON object)")
    masks_dir = folder / "masks"
    found = sorted(
        (int(m.group(1)), p)
        for p in (masks_dir.iterdir() if masks_dir.is_dir() else ())
        if (m := _MASK_NAME.match(p.name))
    )
    if not found:
        why = " (moseg tracks writes masks with --video only)" if summary.get("kind") == "tracks" else ""
        raise InputError(f"{folder}: holds no masks/NNNNNN.png to export{why}")
    return OutputFolder(folder, summary, tuple(found))


def parse_objects(text: str) -> tuple[int, ...]:
    """`--objects 1,3` -> (1, 3).

    Raises:
        InputError: not comma-separated whole numbers, or a number named twice.
    """
    parts = [p.strip() for p in text.split(",") if p.strip()]
    if not parts or not all(p.isdigit() for p in parts):
        raise InputError(f"--objects {text!r}: expected object numbers separated by commas, e.g. 1,3")
    objects = tuple(int(p) for p in parts)
    if len(set(objects)) != len(objects):
        raise InputError(f"--objects {text!r}: an object is named twice")
    return objects


def parse_colour(text: str) -> tuple[int, int, int]:
    """`--background` as `#RRGGBB`, `RRGGBB` or `R,G,B` (0..255 each) -> (R, G, B).

    Raises:
        InputError: neither form.
    """
    t = text.strip()
    hexa = re.fullmatch(r"#?([0-9a-fA-F]{6})", t)
    if hexa:
        value = int(hexa.group(1), 16)
        return (value >> 16) & 255, (value >> 8) & 255, value & 255
    parts = t.split(",")
    if len(parts) == 3 and all(p.strip().isdigit() and int(p) <= 255 for p in parts):
        r, g, b = (int(p) for p in parts)
        return r, g, b
    raise InputError(f"--background {text!r}: expected a colour as #RRGGBB or R,G,B (0..255 each), e.g. #00ff00")


def objects_in(folder: OutputFolder) -> tuple[int, ...]:
    """The moving values (1..254) any of the folder's masks holds, in increasing order."""
    seen = np.zeros(256, dtype=bool)
    for position in range(len(folder.masks)):
        seen |= np.bincount(folder.read_mask(position).ravel(), minlength=256) > 0
    seen[[WORLD, UNKNOWN]] = False
    return tuple(int(v) for v in np.flatnonzero(seen))


def _chosen(folder: OutputFolder, objects: Sequence[int] | None, fmt: str) -> tuple[int, ...]:
    """The objects to export: `objects` checked against the masks, or every one they hold."""
    present = objects_in(folder)
    listed = ", ".join(map(str, present)) or "none"
    if objects is None:
        if not present and fmt != "npz":
            raise InputError(f"{folder.path}: its masks hold no moving object (only the world / unknown)")
        return present
    for obj in objects:
        if obj == WORLD:
            raise InputError(f"object 0 is the world (the camera's motion), not an object; objects there: {listed}")
        if obj not in present:
            raise InputError(f"object {obj}: not in the masks of {folder.path} (objects there: {listed})")
    return tuple(objects)


def _source(summary: dict[str, Any], what: str) -> tuple[Any, Any]:
    """(the source path or paths as run, the identity recorded) of a summary; a tracks run's video."""
    if summary.get("kind") == "tracks":
        return summary.get("video"), summary.get("video_identity")
    identity = summary.get("source_identity")
    source = summary.get("source")
    if isinstance(identity, dict) and identity.get("path"):
        source = identity["path"]
    elif isinstance(identity, list):
        source = [i.get("path") if isinstance(i, dict) else s for i, s in zip(identity, source or [])]
    if not source:
        raise InputError(f"{what} needs the source frames, and the summary names no source (frames from Python?)")
    return source, identity


def _check_source(path: str, identity: Any, what: str) -> None:
    """Fails when the source the masks were made on is gone or changed."""
    from mosegpipe.io.provenance import identity_differences, source_identity

    now = source_identity(path)
    if now is None:
        raise InputError(f"{path}: not found; {what} needs the frames the masks were made on")
    if isinstance(identity, dict):
        differ = identity_differences(identity, now)
        if differ:
            raise InputError(f"{path}: changed since the run ({', '.join(differ)}); {what} needs the frames it had")


def source_frames(folder: OutputFolder, what: str = "export") -> Iterator[npt.NDArray[np.uint8]]:
    """The source frame of each mask of the folder, in its order: (H, W, 3) uint8 RGB each.

    The source is checked first (named by summary.json, unchanged since the run, the masks' size).

    Raises:
        InputError: the source is gone, changed or unreadable, or its frames are not the masks' size.
    """
    from mosegpipe.io.read import iter_video, read_image

    source, identity = _source(folder.summary, what)
    indices = [index for index, _ in folder.masks]
    if isinstance(source, list):  # a pair: masks 0 and 1 are its two images
        for path, ident in zip(source, identity if isinstance(identity, list) else [None] * len(source)):
            _check_source(path, ident, what)
        reads = (read_image(source[index]) for index in indices)
    else:
        _check_source(source, identity, what)
        first, last = indices[0], indices[-1]
        wanted = set(indices)
        stream = iter_video(source, start=first, max_frames=last - first + 1)
        reads = (frame for index, frame in stream if index in wanted)
    count = 0
    for position, frame in enumerate(reads):
        mask_hw = folder.read_mask(position).shape
        if frame.shape[:2] != mask_hw:
            raise InputError(
                f"{folder.masks[position][1]}: {mask_hw[1]}x{mask_hw[0]}, but its source frame is "
                f"{frame.shape[1]}x{frame.shape[0]}; {what} needs the frames the masks were made on"
            )
        count += 1
        yield frame
    if count < len(indices):
        raise InputError(f"{source}: only {count} of the {len(indices)} frames the masks name could be read")


@contextlib.contextmanager
def _built(final: Path, overwrite: bool) -> Iterator[Path]:
    """A folder built under `.NAME.partial` beside `final` and renamed into place when the body succeeds
    (an existing `final` replaced); removed on any failure."""
    tmp = final.with_name(f".{final.name}.partial")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if final.exists() and overwrite:
        old = final.with_name(f".{final.name}.old")
        shutil.rmtree(old, ignore_errors=True)
        final.rename(old)
        tmp.rename(final)
        shutil.rmtree(old, ignore_errors=True)
    else:
        tmp.rename(final)


def _save_png(path: Path, image: npt.NDArray[np.uint8], palette: npt.NDArray[np.uint8] | None = None) -> None:
    """An 8-bit greyscale ((H, W)), RGBA ((H, W, 4)) or, with `palette`, palette PNG, written atomically."""
    from PIL import Image

    from mosegpipe.io.write import atomic_write

    picture = Image.fromarray(np.ascontiguousarray(image))
    if palette is not None:
        picture.putpalette(np.ascontiguousarray(palette).tobytes())
    with atomic_write(path) as tmp:
        picture.save(tmp, format="PNG", compress_level=6)


def _write_binary(folder: OutputFolder, objects: tuple[int, ...], tmp: Path) -> None:
    for obj in objects:
        (tmp / str(obj)).mkdir()
    for position, (index, _) in enumerate(folder.masks):
        mask = folder.read_mask(position)
        for obj in objects:
            _save_png(tmp / str(obj) / f"{index:06d}.png", np.where(mask == obj, 255, 0).astype(np.uint8))


def matte(mask: npt.NDArray[np.uint8], objects: Sequence[int]) -> npt.NDArray[np.uint8]:
    """(H, W) uint8 alpha: 255 on the pixels of `objects`, 0 elsewhere."""
    return np.where(np.isin(mask, np.asarray(objects, dtype=np.uint8)), 255, 0).astype(np.uint8)


def _write_alpha(folder: OutputFolder, objects: tuple[int, ...], tmp: Path) -> None:
    for position, frame in enumerate(source_frames(folder, "--as alpha")):
        alpha = matte(folder.read_mask(position), objects)
        _save_png(tmp / f"{folder.masks[position][0]:06d}.png", np.dstack([frame, alpha]))


def _write_davis(folder: OutputFolder, objects: tuple[int, ...], tmp: Path) -> None:
    lut = np.zeros(256, dtype=np.uint8)
    lut[np.asarray(objects, dtype=np.int64)] = np.arange(1, len(objects) + 1)
    palette = voc_palette()
    for position, (index, _) in enumerate(folder.masks):
        _save_png(tmp / f"{index:05d}.png", lut[folder.read_mask(position)], palette)
    from mosegpipe.io.write import write_json

    write_json(tmp / "objects.json", {str(i + 1): obj for i, obj in enumerate(objects)})


def _stacked_masks(folder: OutputFolder, objects: tuple[int, ...] | None) -> npt.NDArray[np.uint8]:
    masks = [folder.read_mask(p) for p in range(len(folder.masks))]
    if len({m.shape for m in masks}) > 1:
        raise InputError(f"{folder.path}: its masks differ in size (a pair?); --as npz needs one size: use --as binary")
    stack = np.stack(masks)
    if objects is not None:
        stack = np.where(np.isin(stack, np.asarray(objects, dtype=np.uint8)), stack, 0).astype(np.uint8)
    return stack


def _fps(folder: OutputFolder) -> float:
    """The frame rate of the folder's source (summary.json's, or the video's own; 10 when unknown)."""
    fps = folder.summary.get("video_fps")
    if not fps:
        source, _ = _source(folder.summary, "--as cutout")
        if isinstance(source, str):
            from mosegpipe.io.read import video_info

            with contextlib.suppress(InputError):
                fps = video_info(source).get("fps")
    return float(fps) if fps and fps > 0 else _FALLBACK_FPS


def _cutout_frames(
    folder: OutputFolder, objects: tuple[int, ...], background: tuple[int, int, int] | None
) -> Iterator[npt.NDArray[np.uint8]]:
    """RGBA frames (the objects' colours, transparent and black elsewhere), or RGB ones on `background`."""
    for position, frame in enumerate(source_frames(folder, "--as cutout")):
        keep = matte(folder.read_mask(position), objects)
        inside = (keep > 0)[..., None]
        if background is None:
            yield np.dstack([np.where(inside, frame, 0).astype(np.uint8), keep])
        else:
            yield np.where(inside, frame, np.asarray(background, dtype=np.uint8)).astype(np.uint8)


def _write_alpha_mov(path: Path, frames: Iterator[npt.NDArray[np.uint8]], fps: float) -> int:
    """RGBA frames as a QuickTime file of PNG frames (lossless, with alpha; PyAV's FFmpeg), atomically."""
    import av

    from mosegpipe.io.write import atomic_write

    count = 0
    with atomic_write(path) as tmp:
        container: Any = av.open(str(tmp), mode="w", format="mov")
        try:
            stream: Any = None
            for rgba in frames:
                if stream is None:
                    stream = container.add_stream("png", rate=Fraction(fps).limit_denominator(1001))
                    stream.width, stream.height = rgba.shape[1], rgba.shape[0]
                    stream.pix_fmt = "rgba"
                for packet in stream.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(rgba), format="rgba")):
                    container.mux(packet)
                count += 1
            if stream is not None:
                for packet in stream.encode(None):
                    container.mux(packet)
        finally:
            container.close()
    return count


def _destination(folder: OutputFolder, fmt: str, to: str | Path | None, background: Any) -> Path:
    base = Path(to) if to is not None else folder.path
    if base.exists() and not base.is_dir():
        raise InputError(f"--to {base}: exists and is not a folder")
    if fmt == "cutout":
        return base / ("cutout.mov" if background is None else "cutout.mp4")
    return base / TARGETS[fmt]


def export_masks(
    out_dir: str | Path,
    fmt: str,
    objects: Sequence[int] | None = None,
    to: str | Path | None = None,
    background: tuple[int, int, int] | None = None,
    overwrite: bool = False,
) -> Export:
    """Writes an output folder's masks in another form (the formats: this module's docstring).

    Args:
        out_dir: an output folder of moseg run / pair / tracks --video / live --out (summary.json, masks/).
        fmt: one of EXPORT_FORMATS.
        objects: mask values (1..254) to export, in this order (None: every moving value the masks hold).
        to: the folder to write into (default: `out_dir` itself); created when missing.
        background: cutout only: (R, G, B) 0..255 -> an H.264 cutout.mp4 on that colour (None: a transparent
            cutout.mov).
        overwrite: replace an earlier export of the same format there.

    Returns:
        What was written.

    Raises:
        InputError: not an output folder, an unknown format or object, a background without cutout, a source
            that is gone or changed (alpha, cutout), masks of different sizes (npz, cutout).
        OutputExistsError: the export exists and overwrite is False.
    """
    check_choice("--as", fmt, EXPORT_FORMATS)
    if background is not None and fmt != "cutout":
        raise InputError(f"--background applies to --as cutout only, not --as {fmt}")
    folder = read_output_folder(out_dir)
    chosen = _chosen(folder, objects, fmt)
    final = _destination(folder, fmt, to, background)
    if final.exists() and not overwrite:
        raise OutputExistsError(f"{final}: exists; pass --overwrite to replace it")
    if fmt in ("alpha", "cutout"):
        next(iter(source_frames(folder, f"--as {fmt}")), None)  # the source checked before anything is written
    if fmt == "cutout" and len({folder.read_mask(p).shape for p in range(len(folder.masks))}) > 1:
        raise InputError(f"{folder.path}: its masks differ in size (a pair?); a video needs one size: use --as alpha")
    created = not final.parent.exists()
    final.parent.mkdir(parents=True, exist_ok=True)
    try:
        _write(folder, fmt, chosen, objects, final, background, overwrite)
    except BaseException:
        if created and not any(final.parent.iterdir()):
            final.parent.rmdir()
        raise
    return Export(final, fmt, chosen, len(folder.masks))


def _write(
    folder: OutputFolder,
    fmt: str,
    chosen: tuple[int, ...],
    objects: Sequence[int] | None,
    final: Path,
    background: tuple[int, int, int] | None,
    overwrite: bool,
) -> None:
    """The export itself, into `final` (checked by export_masks)."""
    if fmt == "npz":
        from mosegpipe.io.write import write_npz

        indices = np.array([index for index, _ in folder.masks], dtype=np.int64)
        stack = _stacked_masks(folder, None if objects is None else chosen)
        write_npz(final, masks=stack, frames=indices, objects=np.array(chosen, dtype=np.int64))
    elif fmt == "cutout" and background is not None:
        from mosegpipe.io.write import write_video

        write_video(final, _cutout_frames(folder, chosen, background), _fps(folder))
    elif fmt == "cutout":
        _write_alpha_mov(final, _cutout_frames(folder, chosen, None), _fps(folder))
    else:
        writer = {"binary": _write_binary, "alpha": _write_alpha, "davis": _write_davis}[fmt]
        with _built(final, overwrite) as tmp:
            writer(folder, chosen, tmp)


__all__ = [
    "EXPORT_FORMATS",
    "Export",
    "OutputFolder",
    "export_masks",
    "matte",
    "objects_in",
    "parse_colour",
    "parse_objects",
    "read_output_folder",
    "source_frames",
]
