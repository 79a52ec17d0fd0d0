"""Short clips: `segment_frames` (a stack of frames) and `segment_clip` (F frames of a video or frame
folder), their `ClipResult`, and `clip_masks` (the clip's dense masks, extra mask tracks included)."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from mosegpipe.embed.numpy_net import Embedder
from mosegpipe.errors import InputError, TooFewTracksError
from mosegpipe.group.refine import group_window
from mosegpipe.group.rigid import label_by_rigid_motion
from mosegpipe.io.read import check_images, read_video, video_info
from mosegpipe.masks import labels_to_masks, motion_masks
from mosegpipe.masks.learned.probability import check_mask_networks
from mosegpipe.masks.moving_pixels import stack_motion
from mosegpipe.pipeline.common import (
    check_k,
    decode_errors,
    embed_at_model_frames,
    frames_text,
    model_info,
    model_or_default,
)
from mosegpipe.pipeline.config import PipelineConfig
from mosegpipe.pipeline.resize import dense_sized, shrink_factor, shrink_image, shrink_images, upscale_mask, upscale_xy
from mosegpipe.points.flow import FrameMotion, flow_fits
from mosegpipe.points.flow_grid import combine_tracks, track_flow
from mosegpipe.points.klt import spread_corners, track_klt, track_points
from mosegpipe.points.trajectories import build_trajectories
from mosegpipe.types import FLOW_MASK_METHODS, Clustering, Frames, Tracks, Trajectories


@dataclass(frozen=True)
class ClipResult:
    """Everything one clip's segmentation produced.

    Attributes:
        frames: the frames segmented.
        tracks: all KLT tracks (N_all, T).
        trajectories: the tracks visible in all frames (N rows, track_ids into `tracks`).
        embeddings: (N, E) float32 SubspaceNet embeddings (method "geometric": (N, 2F - 2) displacements
            from frame 0, pixels; see group_tracks).
        clustering: labels (N,) and the automatic-K evidence.
        masks: (T, H, W) uint8, k = motion k, 255 = no track nearby (unknown).
        timings: seconds per stage.
        model_info: the model's recipe name, input frames and checkpoint format.
    """

    frames: Frames
    tracks: Tracks
    trajectories: Trajectories
    embeddings: npt.NDArray[np.float32]
    clustering: Clustering
    masks: npt.NDArray[np.uint8]
    timings: dict[str, float]
    model_info: dict[str, Any]


def group_tracks(
    traj: Trajectories,
    size_hw: tuple[int, int],
    cfg: PipelineConfig,
    model: Embedder,
    timings: dict[str, float],
    motion: FrameMotion | None = None,
) -> tuple[npt.NDArray[np.float32], Clustering]:
    """The motions of trajectories by cfg.method: embedding + automatic K + the rigid-motion check
    ("subspacenet"), or rigid models fitted one after another ("geometric"; it has no embedding, so
    each track's displacements from frame 0, (N, 2F - 2) pixels, stand in for the recording and for
    the evaluation's K-means with the true K). Either way the world's motion is 0 (`world_to_zero`).

    Args:
        traj: the trajectories (N, 2F), pixels.
        size_hw: (H, W) of the frames, pixels.
        cfg: method, cluster, rigid, geometric and k.
        model: the embedding model (not used by "geometric").
        timings: gets "embed" (subspacenet) and "cluster" seconds.
        motion: the frames' dense flow evidence, if computed (the world's camera evidence).

    Returns:
        ((N, E) float32 embeddings, the clustering).
    """
    grouped = group_window(traj, size_hw, cfg, model, k=cfg.k, motion=motion, timings=timings)
    if grouped.embeddings is None:
        data = traj.data
        return np.asarray(data[:, 2:] - np.tile(data[:, :2], traj.num_frames - 1), dtype=np.float32), grouped.clustering
    return grouped.embeddings, grouped.clustering


def _uses_flow_points(frames: Frames, cfg: PipelineConfig) -> bool:
    return cfg.tracker != "klt" and frames.num_frames >= 2 and flow_fits(frames.size_hw, cfg.flow)


def _uses_motion_masks(frames: Frames, cfg: PipelineConfig) -> bool:
    return cfg.mask.method in FLOW_MASK_METHODS and frames.num_frames >= 2 and flow_fits(frames.size_hw, cfg.flow)


def clip_tracks(frames: Frames, cfg: PipelineConfig, motion: FrameMotion | None = None) -> Tracks:
    """A clip's point tracks by cfg.tracker: KLT corners, a grid carried along the dense flow (cfg.flow,
    shared with the motion masks; `motion`: those flows, if already computed), or both. One frame, or
    frames too small for the flow: KLT."""
    if not _uses_flow_points(frames, cfg):
        return track_klt(frames, cfg.track)
    dense = track_flow(frames.images, cfg.flow_tracks, cfg.flow, motion)
    if cfg.tracker == "flow":
        return dense
    return combine_tracks(track_klt(frames, cfg.track), dense, cfg.flow_tracks.klt_distance_px)


def segment_frames(frames: Frames, cfg: PipelineConfig = PipelineConfig(), model: Embedder | None = None) -> ClipResult:
    """Segments the motions in a short stack of frames.

    Args:
        frames: Frames with images (T, H, W, 3) uint8 RGB; every frame is segmented.
        cfg: pipeline settings (cfg.frames is not used here: T is what the frames hold).
        model: the model (None = the shipped default for T frames).

    Returns:
        ClipResult; its masks are (T, H, W) uint8 with k = motion k and 255 = unknown.

    Raises:
        TooFewTracksError: fewer than cfg.min_tracks tracks live through all frames.
        InputError: cfg.k larger than the number of tracks.
        CheckpointError: no model given and no shipped weights, or a mask network the settings ask for cannot
            be used (`check_mask_networks`).

    One frame shows no motion: unless cfg.k says otherwise, its tracks are one motion (K = 1, with a
    note saying why).

    With cfg.max_side, frames whose longer side exceeds it are segmented shrunk to it and the result is
    brought back to their size (`full_size`): masks upsampled (edges snapped to the frames'), track positions scaled.
    """
    scale = shrink_factor(frames.images.shape[1:3], cfg.max_side)
    if scale >= 1.0:
        return _segment_frames(frames, cfg, model)
    t0 = time.perf_counter()
    small = replace(
        frames,
        images=shrink_images(frames.images, scale),
        before=None if frames.before is None else shrink_image(frames.before, scale),
        after=None if frames.after is None else shrink_image(frames.after, scale),
    )
    resize_s = time.perf_counter() - t0
    return full_size(_segment_frames(small, cfg, model), frames, scale, resize_s)


def full_size(result: ClipResult, frames: Frames, scale: float, resize_s: float = 0.0) -> ClipResult:
    """A clip's result on frames shrunk by `scale` brought back to `frames` (the input): its frames, its
        tracks' positions on the input's grid, its masks upsampled with their edges snapped to the input's frames
    (resize.upscale_mask); timings gain "resize"
        (the shrinking and the upsampling, seconds)."""
    t0 = time.perf_counter()
    tracks = Tracks(
        xy=upscale_xy(result.tracks.xy, scale),
        visible=result.tracks.visible,
        size_hw=(int(frames.images.shape[1]), int(frames.images.shape[2])),
    )
    traj = replace(
        result.trajectories,
        data=upscale_xy(result.trajectories.data.reshape(-1, 2), scale).reshape(result.trajectories.data.shape),
    )
    masks = np.stack([upscale_mask(m, image) for m, image in zip(result.masks, frames.images)])
    timings = {**result.timings, "resize": resize_s + time.perf_counter() - t0}
    return replace(result, frames=frames, tracks=tracks, trajectories=traj, masks=masks, timings=timings)


def _segment_frames(frames: Frames, cfg: PipelineConfig, model: Embedder | None) -> ClipResult:
    """segment_frames at the frames' own size (the dense stage at most at mask.motion.max_side_px: `dense_sized`)."""
    timings: dict[str, float] = {}
    check_images(frames.images, f"{frames.source or 'frames'}: images", stack=True)
    cfg = dense_sized(cfg, frames.images.shape[1:3])
    check_mask_networks(cfg.mask)
    model = model_or_default(model, frames.num_frames, timings)
    t0 = time.perf_counter()
    # Flow points, the world's camera evidence and the motion masks share the clip's flows: computed once, here.
    shared = (
        stack_motion(frames.images, cfg.mask.motion, frames.before, frames.after)
        if _uses_motion_masks(frames, cfg)
        else None
    )
    if shared is not None:
        timings["flow"] = time.perf_counter() - t0
        t0 = time.perf_counter()
    tracks = clip_tracks(frames, cfg, shared)
    timings["track"] = time.perf_counter() - t0
    traj = build_trajectories(tracks, frames=frames.num_frames)
    if traj.num_points < cfg.min_tracks:
        raise TooFewTracksError(
            f"{frames.source or 'clip'}: only {traj.num_points} tracks survived {frames.num_frames} frames; "
            f"need at least {cfg.min_tracks} (textureless or blank frames?)"
        )
    check_k(cfg.k, traj.num_points, frames.source or "clip")
    if frames.num_frames == 1 and cfg.k is None:
        emb, clustering = _one_frame(traj, cfg, model, timings)
    else:
        emb, clustering = group_tracks(traj, tracks.size_hw, cfg, model, timings, shared)
    t0 = time.perf_counter()
    masks = clip_masks(
        frames.images, tracks, traj.track_ids, clustering.labels, cfg, frames.before, frames.after, shared
    )
    timings["masks"] = time.perf_counter() - t0
    return ClipResult(frames, tracks, traj, emb, clustering, masks, timings, model_info(model))


def _one_frame(
    traj: Trajectories, cfg: PipelineConfig, model: Embedder, timings: dict[str, float]
) -> tuple[npt.NDArray[np.float32], Clustering]:
    """The grouping of one frame's tracks: one motion (the rigid-motion check and "geometric" fit
    motions between two frames or more, and raised on one)."""
    t0 = time.perf_counter()
    emb = (
        np.zeros((traj.num_points, 0), np.float32) if cfg.method == "geometric" else embed_at_model_frames(model, traj)
    )
    timings["embed"] = time.perf_counter() - t0
    labels = np.zeros(traj.num_points, np.int64)
    return emb, Clustering(labels=labels, k=1, note="one frame: no motion to tell apart, so one motion (K = 1)")


def clip_masks(
    images: npt.NDArray[np.uint8],
    tracks: Tracks,
    track_ids: npt.NDArray[np.int64],
    labels: npt.NDArray[np.int64],
    cfg: PipelineConfig = PipelineConfig(),
    before: npt.NDArray[np.uint8] | None = None,
    after: npt.NDArray[np.uint8] | None = None,
    motion: FrameMotion | None = None,
) -> npt.NDArray[np.uint8]:
    """The dense masks of a clip from its labelled tracks (segment_frames' mask stage).

    With cfg.mask.extra_tracks, more corners spread over the first image away from the tracks are
    tracked through the clip and labelled by motion (`label_by_rigid_motion`); those with a label
    join the labelled tracks for the masks only.

    Args:
        images: (T, H, W, 3) uint8 RGB frames.
        tracks: the clip's tracks (N rows over the T frames).
        track_ids: (M,) rows of `tracks` that carry labels (live through the whole clip).
        labels: (M,) their labels.
        cfg: mask settings (and the rigid-motion settings that label the extra tracks).
        before, after: the source's frames next to the clip (Frames.before / after), evidence for the
            motion masks only.
        motion: the motion masks' flow evidence of the clip (`moving_pixels.stack_motion`), if already computed.

    Returns:
        (T, H, W) uint8 masks, 255 = unknown.
    """
    if cfg.mask.method in FLOW_MASK_METHODS and images.shape[0] >= 2 and flow_fits(images.shape[1:3], cfg.flow):
        # the world's 3D structure: its parallax is not motion (MaskSequence.moving)
        return motion_masks(images, tracks, track_ids, labels, cfg.mask, before, after, motion, cfg.world)
    budget = cfg.mask.extra_tracks
    if budget > 0 and len(track_ids) and images.shape[0] >= 2:
        corners = spread_corners(images[0], budget, tracks.xy[tracks.visible[:, 0], 0], cfg.track)
        extra = track_points(images, corners, cfg.track)
        full = np.flatnonzero(extra.visible.all(axis=1))
        data = extra.xy[full].reshape(len(full), 2 * len(images))
        known = tracks.xy[track_ids].reshape(len(track_ids), 2 * len(images))
        found = label_by_rigid_motion(data, known, labels, cfg.rigid)
        keep = found >= 0
        rows = full[keep]
        track_ids = np.concatenate([track_ids, tracks.num_tracks + np.arange(rows.size)])
        labels = np.concatenate([labels, found[keep]])
        tracks = Tracks(
            xy=np.concatenate([tracks.xy, extra.xy[rows]]),
            visible=np.concatenate([tracks.visible, extra.visible[rows]]),
            size_hw=tracks.size_hw,
        )
    return labels_to_masks(tracks, track_ids, labels, cfg.mask, images)


def _with_context(path: str | Path, cfg: PipelineConfig) -> Frames | None:
    """cfg.frames frames from cfg.start with the source's frames just before and after them as
    Frames.before / after (evidence for the motion masks), read in one pass; None when the masks do
    not use them, or the clip with its neighbours cannot be read (the caller then reads the clip alone,
    and reports what is wrong with it)."""
    if cfg.mask.method not in FLOW_MASK_METHODS or not cfg.flow.both_directions:
        return None
    lead = 1 if cfg.start > 0 else 0
    try:
        with decode_errors(path):
            wide = read_video(path, max_frames=cfg.frames + lead + 1, start=cfg.start - lead)
    except InputError:  # e.g. the frame after the clip does not decode
        return None
    end = lead + cfg.frames
    if wide.num_frames < end:
        return None
    images = wide.images
    return Frames(
        images=images[lead:end],
        fps=wide.fps,
        source=wide.source,
        start=cfg.start,
        before=images[0] if lead else None,
        after=images[end] if images.shape[0] > end else None,
    )


def _container_frames(path: str | Path) -> int | None:
    """The frame count a video container claims (None for folders, images or when it does not say)."""
    try:
        with decode_errors(path):
            info = video_info(path)
    except InputError:
        return None
    return info["num_frames"] if info["kind"] == "video" else None


def segment_clip(path: str | Path, cfg: PipelineConfig = PipelineConfig(), model: Embedder | None = None) -> ClipResult:
    """Reads cfg.frames frames from frame cfg.start of a video file or frame folder and segments them.

    Args:
        path: a video file OpenCV can read or a folder of images (sorted by name).
        cfg: pipeline settings; cfg.frames frames are read, from frame cfg.start.
        model: the model (None = the shipped default for cfg.frames).

    Returns:
        ClipResult (timings also hold "read").

    Raises:
        InputError: missing, unreadable, corrupt or truncated input, fewer than cfg.frames frames
            from cfg.start, or cfg.start past the end.
        TooFewTracksError: see segment_frames.
    """
    t0 = time.perf_counter()
    frames = _with_context(path, cfg)
    if frames is None:
        with decode_errors(path):
            frames = read_video(path, max_frames=cfg.frames, start=cfg.start)
    if frames.num_frames < cfg.frames:
        claimed = _container_frames(path)
        hint = ""
        if claimed and claimed - cfg.start > frames.num_frames:
            hint = f" of the {claimed} its header lists (truncated or corrupt video?)"
        after = f" from frame {cfg.start}" if cfg.start else ""
        raise InputError(
            f"{path}: only {frames_text(frames.num_frames)} could be read{after}{hint}; --frames needs {cfg.frames}"
        )
    read_s = time.perf_counter() - t0
    result = segment_frames(frames, cfg, model)
    return replace(result, timings={"read": read_s, **result.timings})
