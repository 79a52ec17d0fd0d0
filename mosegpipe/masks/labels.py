"""Masks from labelled tracks alone (mosegpipe.masks): the mask values, MaskConfig, and the
"watershed", "nearest" and "vote" methods (labels_to_mask, labels_to_masks)."""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe.configs.masks import MaskConfig
from mosegpipe.errors import InputError
from mosegpipe.types import FLOW_MASK_METHODS, Tracks

MAX_LABEL = 254
"""Largest motion label a uint8 mask can hold (the mask value is the label)."""

UNKNOWN = 255
"""Mask value of pixels without evidence (DAVIS' "void")."""


MOVING_UNCLUSTERED = MAX_LABEL
""""motion" masks: moving pixels with no track of a moving motion in their frame."""


def _distance_and_cells(
    xy_int: npt.NDArray[np.int64], size_hw: tuple[int, int]
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.int32]]:
    """Distance of each pixel to the nearest seed pixel, and the id of that seed's Voronoi cell."""
    height, width = size_hw
    seeds = np.full((height, width), 255, dtype=np.uint8)
    seeds[xy_int[:, 1], xy_int[:, 0]] = 0
    dist, cells = cv2.distanceTransformWithLabels(seeds, cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL)
    return dist, cells


def nearest_labels(
    xy_int: npt.NDArray[np.int64], values: npt.NDArray[np.uint8], size_hw: tuple[int, int], max_distance_px: float
) -> npt.NDArray[np.uint8]:
    dist, voronoi = _distance_and_cells(xy_int, size_hw)
    # Voronoi cell ids are assigned to seed pixels in scan order; reading them at the seeds
    # gives the id -> value table without relying on that order. When two tracks round to the
    # same pixel the later one wins.
    lut = np.full(int(voronoi.max()) + 1, UNKNOWN, dtype=np.uint8)
    lut[voronoi[xy_int[:, 1], xy_int[:, 0]]] = values
    mask = lut[voronoi]
    mask[dist > max_distance_px] = UNKNOWN
    return mask


def _agreeing(
    xy: npt.NDArray[np.float64], values: npt.NDArray[np.uint8], k: int, min_agree: int
) -> npt.NDArray[np.bool_]:
    """Which points share their label with at least `min_agree` of their k nearest points (self included)."""
    if min_agree <= 1 or len(xy) <= 1:
        return np.ones(len(xy), dtype=bool)
    from scipy.spatial import cKDTree

    k = min(k, len(xy))
    _, idx = cKDTree(xy).query(xy, k=k)
    idx = np.asarray(idx).reshape(len(xy), k)
    return (values[idx] == values[:, None]).sum(axis=1) >= min_agree


def _watershed(
    image: npt.NDArray[np.uint8],
    xy: npt.NDArray[np.float64],
    xy_int: npt.NDArray[np.int64],
    values: npt.NDArray[np.uint8],
    cfg: MaskConfig,
) -> npt.NDArray[np.uint8]:
    height, width = image.shape[:2]
    seed = _agreeing(xy, values, cfg.vote_k, cfg.min_agree)
    if not seed.any():
        seed[:] = True
    img = image if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2RGB)
    if cfg.scale < 1:
        small_hw = (max(1, round(height * cfg.scale)), max(1, round(width * cfg.scale)))
        img = cv2.resize(img, (small_hw[1], small_hw[0]), interpolation=cv2.INTER_AREA)
        sx, sy = small_hw[1] / width, small_hw[0] / height
        xy_s = np.stack(
            [
                np.clip(np.round((xy[:, 0] + 0.5) * sx - 0.5), 0, small_hw[1] - 1),
                np.clip(np.round((xy[:, 1] + 0.5) * sy - 0.5), 0, small_hw[0] - 1),
            ],
            axis=1,
        ).astype(np.int64)
    else:
        small_hw, xy_s = (height, width), xy_int
    if cfg.blur_px > 1:
        img = cv2.GaussianBlur(img, (cfg.blur_px, cfg.blur_px), 0)
    seed_values = np.unique(values[seed])
    if seed_values.size == 1:
        # One label floods everything: the result of the flood without running it (a single-motion
        # window of a video costs ~20 ms less per 640x480 frame).
        mask = np.full(small_hw, seed_values[0], dtype=np.uint8)
    else:
        markers = np.zeros(small_hw, dtype=np.int32)
        # Marker 0 is "to flood" for cv2.watershed, so seeds carry value + 1.
        markers[xy_s[seed, 1], xy_s[seed, 0]] = values[seed].astype(np.int32) + 1
        cv2.watershed(np.ascontiguousarray(img), markers)
        # The flood marks the one-pixel lines where regions meet with -1: give them a neighbour's label.
        lines = markers < 1
        if lines.any():
            grown = cv2.dilate(np.where(lines, 0, markers).astype(np.float32), np.ones((3, 3), np.uint8))
            markers = np.where(lines, grown.astype(np.int32), markers)
        mask = np.where(markers > 0, markers - 1, UNKNOWN).astype(np.uint8)
    # Evidence comes from every labelled track (seeding or not): no track near = unknown. (The
    # distances alone, without the Voronoi cells, cost a fifth of the time.)
    tracked = np.full(small_hw, 255, dtype=np.uint8)
    tracked[xy_s[:, 1], xy_s[:, 0]] = 0
    dist = cv2.distanceTransform(tracked, cv2.DIST_L2, 5)
    mask[dist > cfg.max_distance_px * small_hw[1] / width] = UNKNOWN
    if small_hw != (height, width):
        mask = cv2.resize(mask, (width, height), interpolation=cv2.INTER_NEAREST)
    return mask


def _vote(
    xy: npt.NDArray[np.float64], values: npt.NDArray[np.uint8], size_hw: tuple[int, int], cfg: MaskConfig
) -> npt.NDArray[np.uint8]:
    from scipy.spatial import cKDTree

    height, width = size_hw
    step = cfg.vote_downsample
    # One sample at the centre of each step x step cell (clamped inside the image), so that
    # repeating each sample over its cell gives back at least H x W pixels.
    rows = np.minimum(np.arange(0, height, step) + step // 2, height - 1)
    cols = np.minimum(np.arange(0, width, step) + step // 2, width - 1)
    gy, gx = np.meshgrid(rows, cols, indexing="ij")
    grid = np.stack([gx.ravel(), gy.ravel()], axis=1).astype(np.float64)
    k = min(cfg.vote_k, len(xy))
    dist, idx = cKDTree(xy).query(grid, k=k)
    dist, idx = dist.reshape(len(grid), k), idx.reshape(len(grid), k)
    votes = values[idx]
    # Count, for each of the k neighbours, how many neighbours share its label; argmax takes the
    # first (nearest) neighbour among equally frequent labels, which breaks ties by distance.
    agree = (votes[:, :, None] == votes[:, None, :]).sum(axis=2)
    small = votes[np.arange(len(grid)), agree.argmax(axis=1)]
    small[dist[:, 0] > cfg.max_distance_px] = UNKNOWN
    small = small.reshape(gy.shape)
    return np.ascontiguousarray(np.repeat(np.repeat(small, step, axis=0), step, axis=1)[:height, :width])


def labels_to_mask(
    xy: npt.NDArray[np.float32],
    labels: npt.NDArray[np.int64],
    size_hw: tuple[int, int],
    cfg: MaskConfig = MaskConfig(),
    image: npt.NDArray[np.uint8] | None = None,
) -> npt.NDArray[np.uint8]:
    """Dense mask of one frame from labelled points.

    Args:
        xy: (N, 2) pixel coordinates (x right, y down). Points outside the image or not finite
            are ignored.
        labels: (N,) int motion labels in 0..254.
        size_hw: (H, W) of the mask, pixels.
        cfg: densification settings.
        image: (H, W, 3) uint8 RGB (or (H, W) gray) frame the points lie in, the structure
            "watershed" follows; without it "watershed" falls back to "nearest".

    Returns:
        (H, W) uint8 mask: the motion label of each pixel, 255 (UNKNOWN) where no point is within
        cfg.max_distance_px or there are no points.

    Raises:
        InputError: shapes disagree or a label is outside 0..254.
        ValueError: image is not of size size_hw (a caller's bug).
    """
    height, width = int(size_hw[0]), int(size_hw[1])
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)  # type: ignore[assignment]
    labels = np.asarray(labels).reshape(-1)
    if len(xy) != len(labels):
        raise InputError(f"{len(xy)} points but {len(labels)} labels")
    if len(labels) and (labels.min() < 0 or labels.max() > MAX_LABEL):
        raise InputError(f"labels must be in 0..{MAX_LABEL}, got {labels.min()}..{labels.max()}")
    if image is not None and image.shape[:2] != (height, width):
        raise ValueError(f"image is {image.shape[:2]}, the mask ({height}, {width})")
    finite = np.isfinite(xy).all(axis=1)
    xy_int = np.round(np.where(finite[:, None], xy, -1.0)).astype(np.int64)  # type: ignore[index]
    inside = finite & (xy_int[:, 0] >= 0) & (xy_int[:, 0] < width) & (xy_int[:, 1] >= 0) & (xy_int[:, 1] < height)
    if not inside.any():
        return np.full((height, width), UNKNOWN, dtype=np.uint8)
    values = labels[inside].astype(np.uint8)
    if (cfg.method == "watershed" or cfg.method in FLOW_MASK_METHODS) and image is not None:
        mask = _watershed(image, xy[inside], xy_int[inside], values, cfg)  # type: ignore[arg-type]
    elif cfg.method == "vote":
        mask = _vote(xy[inside], values, (height, width), cfg)  # type: ignore[arg-type]
    else:
        mask = nearest_labels(xy_int[inside], values, (height, width), cfg.max_distance_px)
    if cfg.median_px > 1:
        mask = cv2.medianBlur(mask, cfg.median_px)
    return mask


def labels_to_masks(
    tracks: Tracks,
    track_ids: npt.NDArray[np.int64],
    labels: npt.NDArray[np.int64],
    cfg: MaskConfig = MaskConfig(),
    images: npt.NDArray[np.uint8] | None = None,
) -> npt.NDArray[np.uint8]:
    """One dense mask per tracked frame, from the labelled tracks visible in that frame.

    Args:
        tracks: Tracks with xy (N, T, 2) float32 and visible (N, T) bool.
        track_ids: (M,) int64 rows of `tracks` that were labelled (Trajectories.track_ids).
        labels: (M,) int motion labels in 0..254.
        cfg: densification settings.
        images: (T, H, W, 3) uint8 RGB frames, followed by "watershed" (None: "nearest" instead).

    Returns:
        (T, H, W) uint8 masks (the label, 255 = unknown), H, W = tracks.size_hw.

    Raises:
        InputError: track_ids and labels differ in length or an id is out of range.
    """
    track_ids = np.asarray(track_ids, dtype=np.int64).reshape(-1)
    labels = np.asarray(labels).reshape(-1)
    if len(track_ids) != len(labels):
        raise InputError(f"{len(track_ids)} track ids but {len(labels)} labels")
    if len(track_ids) and (track_ids.min() < 0 or track_ids.max() >= tracks.num_tracks):
        raise InputError(f"track ids must be in 0..{tracks.num_tracks - 1}, got {track_ids.min()}..{track_ids.max()}")
    height, width = tracks.size_hw
    masks = np.full((tracks.num_frames, height, width), UNKNOWN, dtype=np.uint8)
    for t in range(tracks.num_frames):
        seen = tracks.visible[track_ids, t]
        image = None if images is None else images[t]
        masks[t] = labels_to_mask(tracks.xy[track_ids[seen], t], labels[seen], (height, width), cfg, image)
    return masks


def without_held_regions(
    moving: npt.NDArray[np.bool_],
    points_ij: npt.NDArray[np.int64],
    held: npt.NDArray[np.bool_],
    share: float,
    min_points: int,
) -> npt.NDArray[np.bool_]:
    """`moving` less its connected regions in which at least `min_points` of the points lie and `share` of those
    are `held` (tracks that say the region is the world's: `compose.world_held`, `rigid_tracks.static_held`).

    Args:
        moving: (H, W) bool moving pixels.
        points_ij: (M, 2) int64 (x, y) pixels of the points that count, each on a moving pixel.
        held: (M,) bool the points that hold their region.
        share: least share of a region's points that are held.
        min_points: least number of points in the region.

    Returns:
        (H, W) bool (`moving` itself when nothing changes).
    """
    num, regions = cv2.connectedComponents(moving.astype(np.uint8), connectivity=8)
    where = regions[points_ij[:, 1], points_ij[:, 0]]
    total = np.bincount(where, minlength=num)
    still = np.bincount(where[held], minlength=num)
    taken = (total >= min_points) & (still >= share * np.maximum(total, 1))
    taken[0] = False
    if not taken.any():
        return moving
    out: npt.NDArray[np.bool_] = moving & ~taken[regions]
    return out
