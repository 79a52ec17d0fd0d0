"""FBMS59 readers for the published file formats (Brox & Malik ECCV 2010; Ochs et al. PAMI 2014).

Trajectory files (``<name>Tracks<T>.dat``, written by the Freiburg ``moseg`` tracker) are a stream
of whitespace-separated numbers::

    T                  number of frames
    N                  number of tracks
    label length       per track (on one line or two), then `length` lines of
    x y frame          pixel coordinates and the 0-based frame index

Ground truth is a definition file ``<name>Def.dat`` next to one region image per annotated frame::

    Ground truth definition file; do not change!

    Total number of regions:
    R
    Scale of region 0:
    <colour value of region 0>
    ...
    Confusion penality matrix:
    <R rows>

    Total number of frames in this shot:
    T
    Total number of labeled frames for this shot:
    M
    Frame number:
    <0-based frame index>
    File name:
    <region image, relative to the definition file>
    Input file name:
    <source frame image>
    ...

A region's colour value is the grey level in a PGM image and ``r * 65536 + g * 256 + b`` in a PPM
image.
Region 0 is usually the background.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import numpy.typing as npt

from mosegpipe.data.labels import drop_small_groups, remap_labels
from mosegpipe.errors import DatasetError
from mosegpipe.points.trajectories import complete_in_window, window_starts, xy_to_traj
from mosegpipe.types import LabeledClip

logger = logging.getLogger(__name__)

DATASET = "fbms"
UNLABELLED = -1


def read_fbms_tracks(
    path: str | Path,
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.bool_], npt.NDArray[np.int64]]:
    """Read a moseg tracker trajectory file.

    Args:
        path: a ``*Tracks<T>.dat`` file.

    Returns:
        xy (N, T, 2) float32 pixel coordinates (0 where not visible), visible (N, T) bool, and
        labels (N,) int64: the label column of the file (a tracker's cluster id; not ground truth).

    Raises:
        DatasetError: missing file, truncated or malformed content, frame index outside 0..T-1.
    """
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: FBMS tracks file not found")
    try:
        values = np.array(path.read_text().split(), dtype=np.float64)
    except ValueError as exc:
        raise DatasetError(f"{path}: non-numeric content ({exc})") from exc
    if values.size < 2:
        raise DatasetError(f"{path}: header (frames, tracks) missing")
    num_frames, num_tracks = int(values[0]), int(values[1])
    if num_frames < 0 or num_tracks < 0:
        raise DatasetError(f"{path}: negative header {num_frames} frames, {num_tracks} tracks")
    xy = np.zeros((num_tracks, num_frames, 2), dtype=np.float32)
    visible = np.zeros((num_tracks, num_frames), dtype=bool)
    labels = np.zeros(num_tracks, dtype=np.int64)
    pos = 2
    for i in range(num_tracks):
        if pos + 2 > values.size:
            raise DatasetError(f"{path}: file ends in track {i} of {num_tracks}")
        labels[i] = int(values[pos])
        length = int(values[pos + 1])
        pos += 2
        if length < 0 or pos + 3 * length > values.size:
            raise DatasetError(f"{path}: track {i} has length {length} beyond the end of file")
        points = values[pos : pos + 3 * length].reshape(length, 3)
        pos += 3 * length
        frame = points[:, 2].astype(np.int64)
        if frame.size and (frame.min() < 0 or frame.max() >= num_frames):
            raise DatasetError(f"{path}: track {i} has frame {int(frame.max())} outside 0..{num_frames - 1}")
        xy[i, frame] = points[:, :2]
        visible[i, frame] = True
    if pos != values.size:
        logger.warning("%s: %d trailing values ignored", path, values.size - pos)
    return xy, visible, labels


def _read_region_image(path: Path) -> npt.NDArray[np.int64]:
    """Colour value of every pixel: grey level, or r * 65536 + g * 256 + b for colour images."""
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise DatasetError(f"{path}: unreadable ground-truth image")
    if image.ndim == 2:
        return image.astype(np.int64)
    bgr = image[:, :, :3].astype(np.int64)
    return bgr[:, :, 2] * 65536 + bgr[:, :, 1] * 256 + bgr[:, :, 0]


def _parse_definition(path: Path) -> tuple[list[int], list[tuple[int, str]]]:
    """Region colour values and (frame index, region image name) pairs of a definition file."""
    lines = [line.strip() for line in path.read_text().splitlines()]
    lines = [line for line in lines if line]

    def value_after(i: int) -> str:
        if i + 1 >= len(lines):
            raise DatasetError(f"{path}: value missing after {lines[i]!r}")
        return lines[i + 1]

    def as_int(i: int) -> int:
        text = value_after(i)
        try:
            return int(text)
        except ValueError as exc:
            raise DatasetError(f"{path}: {lines[i]!r} followed by {text!r}") from exc

    num_regions: int | None = None
    colours: dict[int, int] = {}
    frames: list[tuple[int, str]] = []
    pending_frame: int | None = None
    for i, line in enumerate(lines):
        key = line.lower()
        if key.startswith("total number of regions"):
            num_regions = as_int(i)
        elif key.startswith("scale of region"):
            try:
                region = int(key.removeprefix("scale of region").strip(" :"))
            except ValueError as exc:
                raise DatasetError(f"{path}: bad region header {line!r}") from exc
            colours[region] = as_int(i)
        elif key.startswith("frame number"):
            pending_frame = as_int(i)
        elif key.startswith("file name"):
            if pending_frame is None:
                raise DatasetError(f"{path}: 'File name:' before 'Frame number:'")
            frames.append((pending_frame, value_after(i)))
            pending_frame = None
    if num_regions is None:
        raise DatasetError(f"{path}: 'Total number of regions:' missing")
    if sorted(colours) != list(range(num_regions)):
        raise DatasetError(f"{path}: {num_regions} regions declared, colours given for {sorted(colours)}")
    return [colours[r] for r in range(num_regions)], frames


def read_fbms_groundtruth(def_path: str | Path) -> dict[int, npt.NDArray[np.int32]]:
    """Read the annotated frames of an FBMS shot.

    Args:
        def_path: the ``<name>Def.dat`` definition file; region images are found next to it.

    Returns:
        {0-based frame index: (H, W) int32 region map}, regions numbered as in the definition
        file (0..R-1); pixels whose colour is not a defined region are -1.

    Raises:
        DatasetError: missing or malformed definition file, missing region image.
    """
    def_path = Path(def_path)
    if not def_path.is_file():
        raise DatasetError(f"{def_path}: FBMS ground-truth definition file not found")
    colours, frames = _parse_definition(def_path)
    if len(set(colours)) != len(colours):
        raise DatasetError(f"{def_path}: two regions share a colour value ({colours})")
    lookup_keys = np.array(colours, dtype=np.int64)
    order = np.argsort(lookup_keys)
    result: dict[int, npt.NDArray[np.int32]] = {}
    for frame, file_name in frames:
        image_path = def_path.parent / file_name
        if not image_path.is_file():
            raise DatasetError(f"{image_path}: FBMS region image not found")
        values = _read_region_image(image_path)
        idx = np.searchsorted(lookup_keys, values, sorter=order).clip(0, len(colours) - 1)
        region = order[idx]
        known = lookup_keys[region] == values
        region_map = np.where(known, region, UNLABELLED).astype(np.int32)
        if not known.all():
            logger.debug("%s: %d pixels of undefined colour", image_path, int((~known).sum()))
        result[frame] = region_map
    return result


def fbms_track_labels(
    xy: npt.NDArray[np.floating],
    visible: npt.NDArray[np.bool_],
    gt: dict[int, npt.NDArray[np.integer]],
) -> npt.NDArray[np.int64]:
    """Ground-truth region of every track, read at its positions in the annotated frames.

    A track takes the region under its rounded pixel position in every annotated frame where it is
    visible and inside the image. Tracks seen in no annotated frame, only on undefined pixels, or in
    two different regions are left unlabelled.

    Args:
        xy: (N, T, 2) pixel coordinates.
        visible: (N, T) bool.
        gt: {0-based frame index: (H, W) region map, -1 = undefined} from read_fbms_groundtruth.

    Returns:
        (N,) int64 region index, -1 where unlabelled.
    """
    xy = np.asarray(xy)
    visible = np.asarray(visible, dtype=bool)
    num_tracks, num_frames = visible.shape
    labels = np.full(num_tracks, UNLABELLED, dtype=np.int64)
    conflict = np.zeros(num_tracks, dtype=bool)
    for frame, region_map in sorted(gt.items()):
        if not 0 <= frame < num_frames:
            continue
        height, width = region_map.shape
        col = np.rint(xy[:, frame, 0]).astype(np.int64)
        row = np.rint(xy[:, frame, 1]).astype(np.int64)
        inside = visible[:, frame] & (col >= 0) & (col < width) & (row >= 0) & (row < height)
        hit = np.full(num_tracks, UNLABELLED, dtype=np.int64)
        hit[inside] = region_map[row[inside], col[inside]]
        seen = hit != UNLABELLED
        conflict |= seen & (labels != UNLABELLED) & (labels != hit)
        labels[seen & (labels == UNLABELLED)] = hit[seen & (labels == UNLABELLED)]
    labels[conflict] = UNLABELLED
    return labels


def fbms_windows(
    name: str,
    xy: npt.NDArray[np.floating],
    visible: npt.NDArray[np.bool_],
    labels: npt.NDArray[np.integer],
    frames: int = 5,
    mode: str = "first",
    stride: int = 1,
    min_points: int = 10,
    min_group: int = 1,
) -> list[LabeledClip]:
    """F-frame windows of labelled FBMS tracks, keeping tracks visible in all F frames.

    Args:
        name: shot name used in the clip names, e.g. "cars1".
        xy: (N, T, 2) pixel coordinates.
        visible: (N, T) bool.
        labels: (N,) region per track from fbms_track_labels; -1 tracks are left out.
        frames, mode, stride, min_points, min_group: as in mosegpipe.data.kt3dmoseg.kt3d_windows.

    Returns:
        LabeledClips named f"{name}/f{start+1}-{start+F}" with labels remapped to 0..K-1; meta keys
        "sequence", "start", "frames", "frame_range", "track_ids", "original_labels" (region ids),
        "outlier_label" (None).
    """
    labels = np.asarray(labels, dtype=np.int64)
    labelled = labels != UNLABELLED
    clips = []
    for start in window_starts(visible.shape[1], frames, mode, stride):
        rows = complete_in_window(visible, start, frames)
        rows = drop_small_groups(labels, rows[labelled[rows]], min_group)  # type: ignore[arg-type]
        if rows.size < max(min_points, 1):
            continue
        new_labels, original = remap_labels(labels[rows])
        clips.append(
            LabeledClip(
                name=f"{name}/f{start + 1}-{start + frames}",
                traj=xy_to_traj(np.asarray(xy)[rows, start : start + frames]),
                labels=new_labels,
                dataset=DATASET,
                meta={
                    "sequence": name,
                    "start": start,
                    "frames": frames,
                    "frame_range": [start + 1, start + frames],
                    "track_ids": [int(r) for r in rows],
                    "original_labels": original,
                    "outlier_label": None,
                },
            )
        )
    return clips
