"""Masks from labelled tracks alone (mosegpipe.masks): the mask values, MaskConfig, and the
"watershed", "nearest" and "vote" methods (labels_to_mask, labels_to_masks)."""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe.errors import InputError
from mosegpipe.motion import MotionMaskConfig
from mosegpipe.types import MASK_METHODS, Tracks

MAX_LABEL = 254
"""Largest motion label a uint8 mask can hold (the mask value is the label)."""

UNKNOWN = 255
"""Mask value of pixels without evidence (DAVIS' "void")."""


MOVING_UNCLUSTERED = MAX_LABEL
""""motion" masks: moving pixels with no track of a moving motion in their frame."""


@dataclass(frozen=True)
class MaskConfig:
    """Settings for densifying track labels.

    Attributes:
        max_distance_px: pixels farther than this from every labelled track are unknown (255).
            40 px covers the gaps between ~1000 tracks on 640x480 (mean spacing ~18 px) while
            leaving textureless areas without tracks (sky, blank walls) unknown.
        method: "watershed", "nearest", "vote" or "motion" (see the module docstring).
        vote_k: tracks consulted per pixel by "vote".
        vote_downsample: "vote" labels a grid of every n-th pixel and upsamples (nearest), to
            keep the k-nearest-neighbour query fast.
        median_px: odd size of a median filter applied to the label image to smooth jagged
            borders and remove specks (0 or 1 = off). A median of label values can produce a
            label absent from the window only where three or more labels meet.
        min_agree: "watershed": a track seeds the flood only when at least this many of its
            `vote_k` nearest tracks carry its label (itself included); isolated mislabelled
            tracks would otherwise flood a region of their own. 1 = every track seeds (the
            default: on the rendered clips 2 lowered J from 0.521 to 0.515 with the pipeline's
            labels and from 0.805 to 0.764 with the true ones, as it also drops the few tracks of
            small objects).
        blur_px: "watershed": odd Gaussian kernel applied to the image before flooding (0 or 1 =
            off). Off by default: on the rendered clips a 3 px blur lowered boundary F from 0.367
            to 0.331 (it blurs the very edges the flood should stop at).
        scale: "watershed" floods an image resized by this factor (0 < scale <= 1) and resizes the
            labels back (nearest); 0.5 costs a quarter of the time.
        extra_tracks: clips (not whole videos, not pairs): up to this many more corners, spread over
            the image away from the clustered tracks (`track.spread_corners`), are tracked through
            the clip and labelled by motion (`rigid.label_by_rigid_motion`), for the masks only: a
            weakly textured object that got few of the tracker's corners gets more evidence.
            0 = off. Not used by "motion" (it does not need more tracks).
        motion: "motion": the flow and mask settings (mosegpipe.motion).
        unexplained_px: "motion", clips: moving pixels whose flow to the next frame (the previous, for
            the last) misses, by more than this many pixels, the homography of the tracks of the motion
            they were labelled with (or twice that motion's own tracks' 90th-percentile miss, if more),
            and that no other moving motion's homography explains either, take MOVING_UNCLUSTERED
            when they form a region of at least `unexplained_area` of the frame that one homography of
            its own explains (`unexplained_rigid`): an object the tracker left without corners would
            otherwise take the label of the nearest other object (`split_unexplained`). 0 = off.
            Chosen on the rendered dev clips (seeds 100-123, per-object J with the pipeline's labels; no
            protocol scores them) and the DAVIS dev clips' first 5 frames (foreground J cannot change, only
            labels do: best-label J and labels per clip), with unexplained_rigid 0.8: off 0.623, 2 px 0.646,
            4 px 0.649, 6 px 0.632 (with `--points flow`: off 0.650, 2 px 0.658, 4 px 0.667); DAVIS best-label
            J 0.666 / 0.666 / 0.665 (off / 2 / 4 px), labels per clip 2.65 / 2.85 / 2.90. Without the rigid
            test, 2 / 4 / 8 px: rendered 0.662 / 0.659 / 0.638, DAVIS best-label J 0.625 / 0.639 / 0.650.
        unexplained_area: smallest such region, as a share of the frame's pixels.
        unexplained_rigid: ... and the share of its pixels (sampled) that the region's own homography
            (RANSAC, 1 px) must explain: an object's fragment that its label's homography misses (flow
            smoothed over a border, a limb) is rarely rigid on its own. At 2 px, rendered dev 0.6 / 0.7 / 0.8 /
            0.95: J 0.656 / 0.653 / 0.646 / 0.621; DAVIS dev best-label J 0.661 / 0.665 / 0.666 / 0.665,
            labels per clip 3.15 / 2.90 / 2.85 / 2.80 (none: 0.662, 0.625, 3.25). 0 = no such test.
    """

    max_distance_px: float = 40.0
    method: str = "motion"
    vote_k: int = 5
    vote_downsample: int = 4
    median_px: int = 0
    min_agree: int = 1
    blur_px: int = 0
    scale: float = 1.0
    extra_tracks: int = 1000
    unexplained_px: float = 4.0
    unexplained_area: float = 0.002
    unexplained_rigid: float = 0.8
    motion: MotionMaskConfig = field(default_factory=MotionMaskConfig)

    def __post_init__(self) -> None:
        if self.method not in MASK_METHODS:
            raise ValueError(f"method={self.method!r} must be one of {', '.join(MASK_METHODS)}")
        if not self.max_distance_px > 0:
            raise ValueError(f"max_distance_px={self.max_distance_px} must be > 0")
        if self.vote_k < 1 or self.vote_downsample < 1:
            raise ValueError(f"vote_k={self.vote_k} and vote_downsample={self.vote_downsample} must be >= 1")
        for name in ("median_px", "blur_px"):
            v = getattr(self, name)
            if v not in (0, 1) and (v < 3 or v % 2 == 0):
                raise ValueError(f"{name}={v} must be 0, 1 or an odd number >= 3")
        if not 0 < self.scale <= 1:
            raise ValueError(f"scale={self.scale} must be in (0, 1]")
        if self.extra_tracks < 0:
            raise ValueError(f"extra_tracks={self.extra_tracks} must be >= 0 (0 = off)")
        if self.unexplained_px < 0 or not 0 < self.unexplained_area <= 1 or not 0 <= self.unexplained_rigid <= 1:
            raise ValueError(
                f"unexplained_px={self.unexplained_px} must be >= 0, unexplained_area={self.unexplained_area} "
                f"in (0, 1], unexplained_rigid={self.unexplained_rigid} in [0, 1]"
            )
        if not 1 <= self.min_agree <= self.vote_k:
            raise ValueError(f"min_agree={self.min_agree} must be in 1..vote_k ({self.vote_k})")


def _distance_and_cells(
    xy_int: npt.NDArray[np.int64], size_hw: tuple[int, int]
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.int32]]:
    """Distance of each pixel to the nearest seed pixel, and the id of that seed's Voronoi cell."""
    height, width = size_hw
    seeds = np.full((height, width), 255, dtype=np.uint8)
    seeds[xy_int[:, 1], xy_int[:, 0]] = 0
    dist, cells = cv2.distanceTransformWithLabels(seeds, cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL)
    return dist, cells


def _nearest(
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
    if cfg.method in ("watershed", "motion") and image is not None:
        mask = _watershed(image, xy[inside], xy_int[inside], values, cfg)  # type: ignore[arg-type]
    elif cfg.method == "vote":
        mask = _vote(xy[inside], values, (height, width), cfg)  # type: ignore[arg-type]
    else:
        mask = _nearest(xy_int[inside], values, (height, width), cfg.max_distance_px)
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
