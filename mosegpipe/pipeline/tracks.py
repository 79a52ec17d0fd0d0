"""Point tracks made elsewhere (CoTracker, TAPIR, ...): `segment_tracks` and its `TracksResult`; `tracks_clip`
for their masks over the video they were made on."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from mosegpipe.embed.numpy_net import Embedder
from mosegpipe.errors import InputError, TooFewTracksError
from mosegpipe.io.read import read_video
from mosegpipe.pipeline.clip import ClipResult, clip_masks, group_tracks
from mosegpipe.pipeline.common import check_k, decode_errors, model_info, model_or_default
from mosegpipe.pipeline.config import PipelineConfig
from mosegpipe.points.trajectories import build_trajectories
from mosegpipe.types import Clustering, Frames, Tracks, Trajectories

# Pixel coordinates beyond this are not pixels (a 1e300 became inf in float32 and then crashed the
# image size); the largest video frames are a few 10^4 px wide.
MAX_COORD_PX = 1e6


@dataclass(frozen=True)
class TracksResult:
    """The segmentation of point tracks made elsewhere (CoTracker, TAPIR, a tracker of one's own).

    Attributes:
        tracks: the tracks as given (N tracks over T frames).
        trajectories: the tracks visible in every frame of the window (M rows, track_ids into `tracks`).
        start: first frame of the window segmented.
        embeddings: (M, E) float32 SubspaceNet embeddings (method "geometric": displacements, see group_tracks).
        clustering: labels (M,) and the automatic-K evidence.
        labels: (N,) int64 motion of every given track, -1 for a track not visible throughout the window.
        timings: seconds per stage.
        model_info: as in ClipResult.
    """

    tracks: Tracks
    trajectories: Trajectories
    start: int
    embeddings: npt.NDArray[np.float32]
    clustering: Clustering
    labels: npt.NDArray[np.int64]
    timings: dict[str, float]
    model_info: dict[str, Any]


def segment_tracks(
    xy: npt.ArrayLike,
    visible: npt.ArrayLike | None = None,
    cfg: PipelineConfig = PipelineConfig(),
    model: Embedder | None = None,
    start: int = 0,
    frames: int | None = None,
) -> TracksResult:
    """Segments the motions of point tracks from another tracker with our embedding and clustering.

    Tracks visible in every frame of the window [start, start + frames) are embedded (resampled in
    time to the model's frame count when the window is longer or shorter) and clustered with
    cfg.cluster (or, with cfg.method "geometric", grouped by rigid models fitted to them, with no
    embedding); the others get label -1.

    Args:
        xy: (N, T, 2) pixel coordinates, x right and y down (CoTracker's (T, N, 2) output transposed).
        visible: (N, T) bool, True where a track is visible (None = everywhere; TAPIR gives
            `occluded`, i.e. its negation).
        cfg: pipeline settings (cfg.frames is not used: the window is `frames`).
        model: the model (None = the shipped default for the window's length).
        start: first frame of the window.
        frames: window length F >= 2 (None = from `start` to the last frame).

    Returns:
        TracksResult.

    Raises:
        InputError: arrays of the wrong shape or type, NaN/inf or coordinates beyond +-MAX_COORD_PX
            where visible, a window outside the frames, or cfg.k larger than the number of tracks.
        TooFewTracksError: fewer than cfg.min_tracks tracks are visible through the whole window.
    """
    arr = np.asarray(xy)
    if arr.ndim != 3 or arr.shape[2] != 2 or arr.dtype.kind not in "iuf" or arr.shape[0] == 0:
        raise InputError(f"xy must be an (N, T, 2) array of pixel coordinates, got {arr.dtype} {arr.shape}")
    num, num_frames = arr.shape[:2]
    vis = np.ones((num, num_frames), dtype=bool) if visible is None else np.asarray(visible)
    if vis.shape != (num, num_frames) or vis.dtype.kind not in "bui":
        raise InputError(f"visible must be an ({num}, {num_frames}) bool array, got {vis.dtype} {vis.shape}")
    vis = vis.astype(bool)
    if not np.all(np.isfinite(arr[vis])):
        raise InputError("xy holds NaN or inf where the tracks are visible")
    if vis.any():
        largest = float(np.abs(arr[vis]).max())
        if largest > MAX_COORD_PX:
            raise InputError(
                f"xy holds coordinates up to {largest:.3g}; pixel coordinates must lie within +-{MAX_COORD_PX:g}"
            )
    for name, value in (("start", start), ("frames", frames)):
        if value is not None and (isinstance(value, bool) or not isinstance(value, (int, np.integer))):
            raise InputError(f"{name}={value!r} must be an integer")
    window = num_frames - start if frames is None else frames
    if num_frames < 2:
        raise InputError(f"the tracks span {num_frames} frame; segmenting needs tracks over 2 or more frames")
    if start < 0 or start > num_frames - 2:
        raise InputError(f"start={start}: must lie in 0..{num_frames - 2} (the tracks span {num_frames} frames)")
    if window < 2 or start + window > num_frames:
        raise InputError(f"start={start}, frames={window}: the window must hold 2 or more of the {num_frames} frames")
    finite = np.where(vis[..., None], arr, 0.0).astype(np.float32)
    span = finite[vis].max(axis=0) if vis.any() else np.zeros(2)
    tracks = Tracks(xy=finite, visible=vis, size_hw=(int(span[1]) + 1, int(span[0]) + 1))
    timings: dict[str, float] = {}
    model = model_or_default(model, window, timings)
    traj = build_trajectories(tracks, frames=window, start=start)
    if traj.num_points < cfg.min_tracks:
        raise TooFewTracksError(
            f"only {traj.num_points} of {num} tracks are visible in all frames {start}..{start + window - 1}; "
            f"need at least {cfg.min_tracks} (choose a shorter window with frames/start)"
        )
    check_k(cfg.k, traj.num_points, "tracks")
    emb, clustering = group_tracks(traj, tracks.size_hw, cfg, model, timings)
    labels = np.full(num, -1, dtype=np.int64)
    labels[traj.track_ids] = clustering.labels
    return TracksResult(tracks, traj, start, emb, clustering, labels, timings, model_info(model))


def tracks_clip(result: TracksResult, video: str | Path | Frames, cfg: PipelineConfig = PipelineConfig()) -> ClipResult:
    """The segmentation of tracks as a clip over the frames they were made on: dense masks from the
    labelled tracks (`clip_masks`), for the same outputs as a clip (masks, overlays, recording).

    Args:
        result: what segment_tracks returned.
        video: the video file or frame folder the tracks were made on (frame t of the tracks = its
            frame t; the window's frames are read), or the window's frames themselves.
        cfg: mask settings.

    Returns:
        ClipResult over the window: the tracks cut to it (same rows), the trajectories, embeddings
        and clustering of `result`, and the masks; timings gain "masks".

    Raises:
        InputError: the frames are not the window's (another count), or the tracks reach far beyond
            them (made on another video or at another resolution).
    """
    window = result.trajectories.num_frames
    if isinstance(video, Frames):
        frames = video
    else:
        with decode_errors(video):
            frames = read_video(video, max_frames=window, start=result.start)
    if frames.num_frames != window:
        raise InputError(
            f"{frames.source or 'frames'}: {frames.num_frames} frames from frame {frames.start}; the tracks' window "
            f"is {window} frames from frame {result.start}"
        )
    span = slice(result.start, result.start + window)
    xy, visible = result.tracks.xy[:, span], result.tracks.visible[:, span]
    height, width = frames.size_hw
    seen = xy[visible]
    if seen.size and (
        seen.min() < -0.1 * max(height, width) or np.any(seen.max(axis=0) > 1.1 * np.array([width, height]))
    ):
        raise InputError(
            f"{frames.source or 'frames'}: the tracks reach x = {seen[:, 0].min():.0f}..{seen[:, 0].max():.0f}, "
            f"y = {seen[:, 1].min():.0f}..{seen[:, 1].max():.0f}, far beyond the {width}x{height} frames (tracks "
            "of another video, or of another resolution?)"
        )
    tracks = Tracks(xy=np.ascontiguousarray(xy), visible=np.ascontiguousarray(visible), size_hw=frames.size_hw)
    timings = dict(result.timings)
    t0 = time.perf_counter()
    masks = clip_masks(frames.images, tracks, result.trajectories.track_ids, result.clustering.labels, cfg)
    timings["masks"] = time.perf_counter() - t0
    return ClipResult(
        frames, tracks, result.trajectories, result.embeddings, result.clustering, masks, timings, result.model_info
    )
