"""Fixed-length windows over incomplete point tracks, and label remapping.

Benchmarks with incomplete trajectories (KT3DMoSeg, FBMS) are evaluated the SubspaceNet way: cut an
F-frame window and keep only the trajectories visible in all F frames, so that every kept row is a
complete (2F,) trajectory vector.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from mosegpipe.errors import InputError

WINDOW_MODES = ("first", "all")


def remap_labels(labels: npt.ArrayLike) -> tuple[npt.NDArray[np.int64], list[int]]:
    """Map integer labels to contiguous ids 0..K-1, in increasing order of the original id.

    Args:
        labels: (N,) integer labels as found in a file (e.g. 1..K, or {0, 2, 5}).

    Returns:
        (N,) int64 labels in 0..K-1, and the K original ids: new label j was original_ids[j].
    """
    arr = np.asarray(labels).reshape(-1)
    original_ids, new = np.unique(arr, return_inverse=True)
    return new.astype(np.int64).reshape(-1), [int(v) for v in original_ids]


def xy_to_traj(xy: npt.ArrayLike) -> npt.NDArray[np.float32]:
    """Flatten per-frame coordinates into trajectory rows.

    Args:
        xy: (N, F, 2) coordinates, last axis (x, y).

    Returns:
        (N, 2F) float32 with columns x_1, y_1, x_2, y_2, ..., x_F, y_F.
    """
    arr = np.asarray(xy, dtype=np.float32)
    if arr.ndim != 3 or arr.shape[2] != 2:
        raise InputError(f"xy must have shape (N, F, 2), got {arr.shape}")
    return np.ascontiguousarray(arr.reshape(arr.shape[0], 2 * arr.shape[1]))


def window_starts(num_frames: int, frames: int, mode: str = "first", stride: int = 1) -> list[int]:
    """0-based start frames of the F-frame windows of a T-frame sequence.

    Args:
        num_frames: T, frames in the sequence.
        frames: F, window length.
        mode: "first" (only the window starting at frame 0) or "all" (every start, step `stride`).
        stride: step between window starts in "all" mode.

    Returns:
        Start indices s with s + F <= T; empty when F > T.
    """
    if mode not in WINDOW_MODES:
        raise InputError(f"window mode {mode!r} is not one of {WINDOW_MODES}")
    if frames < 1:
        raise InputError(f"window length frames={frames} must be >= 1")
    if stride < 1:
        raise InputError(f"window stride={stride} must be >= 1")
    if frames > num_frames:
        return []
    if mode == "first":
        return [0]
    return list(range(0, num_frames - frames + 1, stride))


def complete_in_window(visible: npt.NDArray[np.bool_], start: int, frames: int) -> npt.NDArray[np.int64]:
    """Rows of the tracks visible in every frame of the window [start, start + frames).

    Args:
        visible: (N, T) bool visibility.
        start: 0-based first frame of the window.
        frames: F, window length.

    Returns:
        (M,) int64 row indices, increasing.
    """
    vis = np.asarray(visible, dtype=bool)
    if start < 0 or start + frames > vis.shape[1]:
        raise InputError(f"window [{start}, {start + frames}) does not fit in {vis.shape[1]} frames")
    return np.flatnonzero(vis[:, start : start + frames].all(axis=1)).astype(np.int64)


def drop_small_groups(
    labels: npt.NDArray[np.int64], rows: npt.NDArray[np.int64], min_group: int
) -> npt.NDArray[np.int64]:
    """Keep only the rows whose group has at least `min_group` members among `rows`.

    Args:
        labels: (N,) group of every track.
        rows: (M,) candidate row indices into labels.
        min_group: smallest group size kept.

    Returns:
        (M',) int64 subset of rows, order preserved.
    """
    if min_group <= 1 or rows.size == 0:
        return rows
    ids, counts = np.unique(labels[rows], return_counts=True)
    big = ids[counts >= min_group]
    return rows[np.isin(labels[rows], big)]
