"""From point tracks or matches to the trajectory matrix that SubspaceNet embeds.

SubspaceNet takes complete trajectories: a point enters the (N, 2F) matrix only if it is visible
in every one of the F frames (the paper's KT3DMoSeg protocol keeps the points visible in all
frames of a 5-frame window). The window cutter here (`window_starts`, `complete_in_window`,
`xy_to_traj`) serves the pipeline, whole videos, the benchmark readers and the training sources.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import numpy.typing as npt

from mosegpipe.errors import InputError
from mosegpipe.types import Matches, Tracks, Trajectories


def build_trajectories(tracks: Tracks, frames: int | None = None, start: int = 0) -> Trajectories:
    """Stack the tracks visible in all frames of a window into the trajectory matrix.

    Args:
        tracks: Tracks with xy (N, T, 2) float32 pixels and visible (N, T) bool.
        frames: window length F (None = from `start` to the last tracked frame).
        start: first frame of the window.

    Returns:
        Trajectories with data (M, 2F) float32 pixels ordered x_1, y_1, ..., x_F, y_F, and
        track_ids (M,) int64 = the rows of `tracks` visible (with finite coordinates) in all
        frames of [start, start + F), ascending.

    Raises:
        InputError: the window does not fit in the tracked frames, or F < 1.
        ValueError: xy is not (N, T, 2) or visible not (N, T) of the same N and T (Tracks built wrongly).
    """
    xy_shape, vis_shape = np.shape(tracks.xy), np.shape(tracks.visible)
    if len(xy_shape) != 3 or xy_shape[2] != 2 or vis_shape != xy_shape[:2]:
        raise ValueError(f"tracks: xy {xy_shape} and visible {vis_shape} must be (N, T, 2) and (N, T)")
    num_frames = tracks.num_frames
    if frames is None:
        frames = num_frames - start
    if start < 0 or frames < 1 or start + frames > num_frames:
        raise InputError(f"window start={start}, frames={frames} does not fit in {num_frames} tracked frames")
    ids = complete_in_window(tracks.visible, start, frames, tracks.xy)
    data = xy_to_traj(tracks.xy[ids, start : start + frames])
    return Trajectories(data=data, track_ids=ids)


def iter_windows(tracks: Tracks, frames: int, stride: int | None = None) -> Iterator[tuple[int, Trajectories]]:
    """Slide a window of `frames` frames over the tracks and build each window's trajectories.

    Args:
        tracks: Tracks over T frames.
        frames: window length F (1 <= F <= T).
        stride: step between window starts (default F: windows that do not overlap). A final
            window ending at frame T is added when the stride would leave frames uncovered.

    Yields:
        (start, Trajectories) for each window [start, start + F).

    Raises:
        InputError: F or stride out of range.
    """
    num_frames = tracks.num_frames
    stride = frames if stride is None else stride
    if not 1 <= frames <= num_frames:
        raise InputError(f"frames={frames} must be between 1 and the {num_frames} tracked frames")
    if stride < 1:
        raise InputError(f"stride={stride} must be >= 1")
    starts = window_starts(num_frames, frames, "all", stride)
    if starts[-1] + frames < num_frames:
        starts.append(num_frames - frames)
    for start in starts:
        yield start, build_trajectories(tracks, frames=frames, start=start)


WINDOW_MODES = ("first", "all")


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


def complete_in_window(
    visible: npt.NDArray[np.bool_], start: int, frames: int, xy: npt.NDArray[np.floating] | None = None
) -> npt.NDArray[np.int64]:
    """Rows of the tracks visible in every frame of the window [start, start + frames): the one window cutter.

    Args:
        visible: (N, T) bool visibility.
        start: 0-based first frame of the window.
        frames: F, window length.
        xy: optional (N, T, 2) coordinates; rows with a non-finite coordinate in the window are dropped too.

    Returns:
        (M,) int64 row indices, increasing.

    Raises:
        InputError: the window does not fit in the T frames.
    """
    vis = np.asarray(visible, dtype=bool)
    if start < 0 or start + frames > vis.shape[1]:
        raise InputError(f"window [{start}, {start + frames}) does not fit in {vis.shape[1]} frames")
    keep = vis[:, start : start + frames].all(axis=1)
    if xy is not None:
        keep &= np.isfinite(xy[:, start : start + frames]).all(axis=(1, 2))
    return np.flatnonzero(keep).astype(np.int64)


def trajectories_from_matches(matches: Matches) -> Trajectories:
    """Two-view trajectories: one row (x1, y1, x2, y2) per correspondence.

    Args:
        matches: Matches with xy1, xy2 (N, 2) float32 pixels.

    Returns:
        Trajectories with data (N, 4) float32 and track_ids = arange(N) (rows of `matches`).
    """
    data = np.concatenate([matches.xy1, matches.xy2], axis=1).astype(np.float32)
    return Trajectories(data=np.ascontiguousarray(data), track_ids=np.arange(len(data), dtype=np.int64))


def _interp_weights(source_frames: int, target_frames: int) -> npt.NDArray[np.float64]:
    """(target, source) matrix of linear-interpolation weights on a common time axis [0, 1]."""
    if source_frames == 1:
        return np.ones((target_frames, 1))
    pos = np.linspace(0.0, source_frames - 1, target_frames)
    lo = np.clip(np.floor(pos).astype(int), 0, source_frames - 2)
    frac = pos - lo
    weights = np.zeros((target_frames, source_frames))
    rows = np.arange(target_frames)
    weights[rows, lo] = 1.0 - frac
    weights[rows, lo + 1] += frac
    return weights


def resample_frames(traj: Trajectories, target_frames: int) -> Trajectories:
    """Linearly interpolate every trajectory in time to a different number of frames.

    The first and last frames are kept; target frame j sits at source time
    j * (F - 1) / (target_frames - 1). Used to feed a model trained on a fixed F with clips of
    another length.

    Args:
        traj: Trajectories with data (N, 2F) float32.
        target_frames: F' >= 1 (F' = 1 keeps the first frame).

    Returns:
        Trajectories with data (N, 2F') float32 and the same track_ids.

    Raises:
        InputError: target_frames < 1 or traj has no frames.
    """
    if target_frames < 1:
        raise InputError(f"target_frames={target_frames} must be >= 1")
    source_frames = traj.num_frames
    if source_frames < 1:
        raise InputError(f"trajectories have no frames (data shape {traj.data.shape})")
    if target_frames == source_frames:
        return traj
    weights = _interp_weights(source_frames, target_frames)
    xy = traj.data.reshape(traj.num_points, source_frames, 2).astype(np.float64)
    out = np.einsum("ts,nsc->ntc", weights, xy).reshape(traj.num_points, 2 * target_frames)
    return Trajectories(data=out.astype(np.float32), track_ids=traj.track_ids.copy())
