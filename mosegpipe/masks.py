"""From sparse track labels to dense per-frame masks.

Mask values (DAVIS convention, readable by the DAVIS tools): 0 = the world (WORLD: the camera's motion,
the static scene of any depth, told from the other motions by where its tracks lie, `mosegpipe.world`),
1..254 = the moving motions, 255 = unknown (no labelled track near enough: no evidence). The value is the
label itself, in clips, pairs, whole videos, live and batch alike.

Methods (`MaskConfig.method`):

- "watershed": marker-based watershed (OpenCV, Meyer's flooding) on the colour image,
  seeded by the labelled tracks, so that two motions meet on the image edge between their tracks
  rather than half-way between them. On the 10 rendered clips (docs/RESULTS.md) against "nearest":
  J 0.511 -> 0.521 and boundary F 0.252 -> 0.364 with the pipeline's labels, J 0.740 -> 0.805 and
  F 0.553 -> 0.713 with the true track labels. ~13 ms per 640x480 frame.
- "nearest": label of the nearest track (a Voronoi partition, OpenCV's labelled distance
  transform; 4-6 ms per 640x480 frame with 400-1000 tracks).
- "vote": majority label of the `vote_k` nearest tracks.
- "motion" (default): each pixel is moving or not by whether the camera's motion explains its dense optical
  flow (`mosegpipe.motion`: flow residual, flow consistency, a colour model, superpixels); static
  pixels take the world's label (0), moving pixels the label of the
  nearest track of a moving motion, or MOVING_UNCLUSTERED (254) when no track of a moving motion is
  in the frame (the flow found a mover the clustering did not); in a clip also a moving region of a
  rigid motion of its own that no moving motion's tracks explain (`split_unexplained`: an object the
  tracker left without corners, which took the nearest other object's label; rendered clips J 0.671 ->
  0.704). It needs the frames of a clip or
  window (`motion_masks`); without them (a single frame, image pairs, frames too small for dense flow:
  `flow.flow_fits`) it falls back to "watershed".
  On the 20 dev clips of DAVIS-2016 train: mean J 0.58 against 0.26 for "watershed"
  (docs/RESULTS.md, "Real video"). No pixel is left unknown.

Every method but "motion" leaves pixels farther than `max_distance_px` from every labelled track unknown (255).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe.colours import UNKNOWN_RGB, WORLD, mask_palette, point_palette
from mosegpipe.errors import InputError
from mosegpipe.flow import FrameMotion
from mosegpipe.motion import MotionMaskConfig, moving_masks, stack_motion
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


def overlay_mask(
    image: npt.NDArray[np.uint8],
    mask: npt.NDArray[np.uint8],
    palette: npt.NDArray[np.uint8] | None = None,
    alpha: float = 0.5,
) -> npt.NDArray[np.uint8]:
    """Blend mask colours over an image, for people.

    The world (0) keeps the image as it is; every other value, unknown (255) included, is blended
    with its colour in `palette` (by default colours.mask_palette(): the colours of the mask PNGs
    and the recordings, unknown a neutral grey that washes the frame out), so that at alpha 1 each
    pixel is its value's palette colour.

    Args:
        image: (H, W, 3) uint8 RGB.
        mask: (H, W) uint8 mask values.
        palette: (256, 3) uint8 RGB colour per mask value (None: colours.mask_palette()).
        alpha: weight of the mask colour, 0..1.

    Returns:
        (H, W, 3) uint8 RGB.
    """
    if image.shape[:2] != mask.shape:
        raise InputError(f"image {image.shape[:2]} and mask {mask.shape} sizes differ")
    pal = np.ascontiguousarray((mask_palette() if palette is None else palette)[:256], dtype=np.uint8)
    colours = cv2.merge([cv2.LUT(mask, pal[:, c].copy()) for c in range(3)])
    out = cv2.addWeighted(image, 1.0 - alpha, colours, alpha, 0.0)
    cv2.copyTo(image, cv2.compare(mask, WORLD, cv2.CMP_EQ), out)
    return out


_DOT_FILL = [(dy, dx) for dy in range(-3, 4) for dx in range(-3, 4) if dy * dy + dx * dx <= 5]
_DOT_RING = [(dy, dx) for dy in range(-3, 4) for dx in range(-3, 4) if 5 < dy * dy + dx * dx <= 11]


def _stamp(
    out: npt.NDArray[np.uint8],
    xy_int: npt.NDArray[np.int64],
    offsets: list[tuple[int, int]],
    colours: npt.NDArray[np.uint8],
) -> None:
    """Sets the pixels at each point + each offset to that point's colour (inside the image only)."""
    if not len(xy_int):
        return
    off = np.array(offsets, dtype=np.int64)  # (M, 2) dy, dx
    ys = xy_int[:, 1, None] + off[None, :, 0]
    xs = xy_int[:, 0, None] + off[None, :, 1]
    ok = (ys >= 0) & (ys < out.shape[0]) & (xs >= 0) & (xs < out.shape[1])
    out[ys[ok], xs[ok]] = np.broadcast_to(colours[:, None, :], (*ys.shape, 3))[ok]


def overlay_image(
    image: npt.NDArray[np.uint8],
    mask: npt.NDArray[np.uint8] | None,
    xy: npt.NDArray[np.float32],
    labels: npt.NDArray[np.int64],
    alpha: float = 0.45,
) -> npt.NDArray[np.uint8]:
    """An RGB picture for people: the mask blended over the image and each track as a dot in its label's colour.

    Args:
        image: (H, W, 3) uint8 RGB.
        mask: (H, W) uint8 mask values (see overlay_mask) or None.
        xy: (N, 2) float32 pixel positions of the tracks in this image.
        labels: (N,) int64 labels (-1 = unlabelled / outlier, drawn as a small cross in the unknown
            grey); colour = colours.point_palette()[label]: the colour of mask value `label`, the
            world's tracks white (as the viewer draws them).
        alpha: weight of the mask colour, 0..1.

    Returns:
        (H, W, 3) uint8 RGB.
    """
    out = overlay_mask(image, mask, mask_palette(), alpha) if mask is not None else image.copy()
    points = point_palette()
    labels = np.asarray(labels, dtype=np.int64).reshape(-1)
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)  # type: ignore[assignment]
    finite = np.isfinite(xy).all(axis=1)
    xy_int = np.round(xy[finite]).astype(np.int64)
    labels = labels[finite]
    for x, y in xy_int[labels < 0]:
        cv2.drawMarker(out, (int(x), int(y)), UNKNOWN_RGB, cv2.MARKER_TILTED_CROSS, 5, 1)
    # Each track a dot of radius ~2.5 px in its colour with a black rim, stamped with NumPy
    # (one cv2.circle call per dot cost ~3 ms per frame for 1000 tracks).
    inl = labels >= 0
    colours = points[np.clip(labels[inl], 0, 255)]
    _stamp(out, xy_int[inl], _DOT_RING, np.zeros_like(colours))
    _stamp(out, xy_int[inl], _DOT_FILL, colours)
    return out


def label_moving_pixels(
    moving: npt.NDArray[np.bool_],
    xy: npt.NDArray[np.float32],
    labels: npt.NDArray[np.int64],
    background: int,
    new_label: int,
) -> npt.NDArray[np.uint8]:
    """One frame's label image: static pixels get the background label, moving ones a moving motion's.

    A moving pixel takes the label of the nearest track of a motion other than the background (the
    "nearest" partition of those tracks); with no such track in the frame it takes `new_label` (a
    motion the camera fit found that the tracks' clustering did not).

    Args:
        moving: (H, W) bool moving pixels.
        xy: (N, 2) float32 track positions in this frame (pixels).
        labels: (N,) int64 their motion labels (-1 = unlabelled, ignored).
        background: the background motion's label.
        new_label: label for moving pixels when no track of a moving motion is in the frame.

    Returns:
        (H, W) uint8 label image.
    """
    height, width = moving.shape
    out = np.full((height, width), max(background, 0), np.uint8)
    if not moving.any():
        return out
    keep = (labels >= 0) & (labels != background)
    pts = np.round(xy[keep]).astype(np.int64)
    inside = (pts[:, 0] >= 0) & (pts[:, 0] < width) & (pts[:, 1] >= 0) & (pts[:, 1] < height)
    if not inside.any():
        out[moving] = new_label
        return out
    present = np.unique(labels[keep][inside])
    if present.size == 1:  # one moving motion: it is every moving pixel's nearest
        out[moving] = present[0]
        return out
    nearest = _nearest(pts[inside], labels[keep][inside].astype(np.uint8), (height, width), np.inf)
    out[moving] = nearest[moving]
    return out


def carry_unclustered(
    mask: npt.NDArray[np.uint8], previous: npt.NDArray[np.uint8] | None, min_share: float = 0.3
) -> npt.NDArray[np.uint8]:
    """A whole video's frame mask with its MOVING_UNCLUSTERED regions given the moving label they had.

    Each connected region of MOVING_UNCLUSTERED pixels (moving, but no track of a moving motion in
    the frame: the window's clustering merged the object into the background, or its tracks were
    lost) takes the moving label that covers most of it in the frame before, when that label covers at
    least `min_share` of it: an object keeps its identity through the windows where the clustering
    misses it, instead of turning into an anonymous mover. A label counts when it is neither this
    world (WORLD) nor MOVING_UNCLUSTERED or UNKNOWN.

    Args:
        mask: (H, W) uint8 label image of this frame (`moving_to_labels`).
        previous: the frame before's final mask, same shape (None: the first frame of a shot).
        min_share: least share of the region the label must cover in the frame before.

    Returns:
        (H, W) uint8: `mask` itself when nothing changes, else a relabelled copy.
    """
    unclustered = mask == MOVING_UNCLUSTERED
    if previous is None or previous.shape != mask.shape or not unclustered.any():
        return mask
    background = WORLD
    num, regions = cv2.connectedComponents(unclustered.astype(np.uint8), connectivity=8)
    before = previous.astype(np.int64)
    usable = (before != background) & (before != MOVING_UNCLUSTERED) & (before != UNKNOWN) & unclustered
    if not usable.any():
        return mask
    # counts[r, l]: pixels of region r that carried label l in the frame before
    counts = np.zeros((num, 256), np.int64)
    np.add.at(counts, (regions[usable], before[usable]), 1)
    sizes = np.bincount(regions[unclustered], minlength=num)
    best = counts.argmax(axis=1)
    take = counts[np.arange(num), best] >= min_share * np.maximum(sizes, 1)
    take[0] = False  # region 0: the pixels that are not MOVING_UNCLUSTERED
    if not take.any():
        return mask
    out = mask.copy()
    relabel = take[regions] & unclustered
    out[relabel] = best[regions[relabel]].astype(np.uint8)
    return out


def moving_to_labels(
    moving: npt.NDArray[np.bool_],
    xy: npt.NDArray[np.float32],
    labels: npt.NDArray[np.int64],
    background: int = WORLD,
    image: npt.NDArray[np.uint8] | None = None,
    cfg: MaskConfig = MaskConfig(),
) -> npt.NDArray[np.uint8]:
    """One frame's "motion" mask from its moving pixels and labelled points.

    Static pixels take the background's label. A moving pixel takes the label the watershed of the
    labelled points gives it (edges between two moving motions follow the image) when that is a
    moving motion's, else the label of the nearest point of a moving motion, else MOVING_UNCLUSTERED.

    Args:
        moving: (H, W) bool moving pixels (`motion.moving_masks`).
        xy: (N, 2) float32 positions of the frame's points, pixels.
        labels: (N,) int64 their labels (-1 = unlabelled, ignored).
        background: the world's label (static pixels take it).
        image: (H, W, 3) uint8 RGB frame for the watershed (None = nearest points only).
        cfg: the watershed's settings (max_distance_px, scale, ...).

    Returns:
        (H, W) uint8: background label where static, a moving motion's label (or MOVING_UNCLUSTERED) where moving.
    """
    labels = np.asarray(labels, dtype=np.int64).reshape(-1)
    xy = np.asarray(xy, np.float32).reshape(-1, 2)
    out = label_moving_pixels(moving, xy, labels, background, MOVING_UNCLUSTERED)
    keep = labels >= 0
    # The flood only decides between two or more moving motions: with one, every moving pixel has its
    # label already (the nearest-track partition above).
    if image is not None and moving.any() and np.unique(labels[keep & (labels != background)]).size >= 2:
        # At the mask stage's scale: it only draws the border between two moving motions.
        flood_cfg = replace(cfg, method="watershed", scale=min(cfg.scale, cfg.motion.work_scale))
        flood = labels_to_mask(xy[keep], labels[keep], moving.shape, flood_cfg, image)
        take = moving & (flood != background) & (flood != UNKNOWN)
        out[take] = flood[take]
    return out


def motion_masks(
    images: npt.NDArray[np.uint8],
    tracks: Tracks,
    track_ids: npt.NDArray[np.int64],
    labels: npt.NDArray[np.int64],
    cfg: MaskConfig = MaskConfig(),
    before: npt.NDArray[np.uint8] | None = None,
    after: npt.NDArray[np.uint8] | None = None,
    motion: FrameMotion | None = None,
) -> npt.NDArray[np.uint8]:
    """The "motion" masks of a clip: moving pixels from the dense flow, labelled by the clip's tracks.

    Args:
        images: (T, H, W, 3) uint8 RGB, T >= 2.
        tracks: the clip's tracks.
        track_ids: (M,) int64 rows of `tracks` that carry labels.
        labels: (M,) int64 their labels; 0 is the world (WORLD, `mosegpipe.world`).
        cfg: mask settings (cfg.motion; the watershed's for the borders between moving motions).
        before, after: the source's frames next to the clip, as evidence (`motion.moving_masks`).
        motion: `motion.stack_motion` of the clip, if already computed (None = computed here).

    Returns:
        (T, H, W) uint8 masks.
    """
    if motion is None and cfg.unexplained_px > 0:
        motion = stack_motion(images, cfg.motion, before, after)  # its flows serve both steps
    moving = moving_masks(images, cfg.motion, before=before, after=after, motion=motion)
    labels = np.asarray(labels, dtype=np.int64).reshape(-1)
    background = WORLD
    out = np.empty(moving.shape, dtype=np.uint8)
    num = len(moving)
    for t in range(num):
        seen = tracks.visible[track_ids, t]
        out[t] = moving_to_labels(moving[t], tracks.xy[track_ids[seen], t], labels[seen], background, images[t], cfg)
        if cfg.unexplained_px > 0 and motion is not None and motion.forward is not None and motion.backward is not None:
            other = t + 1 if t + 1 < num else t - 1
            flow = motion.forward[t] if other > t else motion.backward[t - 1]
            both = seen & tracks.visible[track_ids, other]
            step = (tracks.xy[track_ids[both], t], tracks.xy[track_ids[both], other])
            out[t] = split_unexplained(out[t], moving[t], step, labels[both], background, flow, motion.scale, cfg)
    return out


def split_unexplained(
    mask: npt.NDArray[np.uint8],
    moving: npt.NDArray[np.bool_],
    step: tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]],
    labels: npt.NDArray[np.int64],
    background: int,
    flow: npt.NDArray[np.float32],
    scale: float,
    cfg: MaskConfig = MaskConfig(),
) -> npt.NDArray[np.uint8]:
    """One frame's "motion" mask with the moving regions no clustered motion explains set to MOVING_UNCLUSTERED.

    Each moving motion of the mask with at least 8 tracks gets the homography of its tracks' step to the
    neighbour frame (RANSAC, 2 px); a moving pixel whose flow misses its own motion's prediction by more than
    max(cfg.unexplained_px, 2 x the 90th percentile of that motion's tracks' misses), and every other moving
    motion's by as much, is unexplained. Unexplained regions (after an opening of 5 x 5 px) of at least
    cfg.unexplained_area of the frame whose own flow one homography explains (cfg.unexplained_rigid of
    their pixels within 1 px) take MOVING_UNCLUSTERED. A motion with fewer tracks is not judged.

    Args:
        mask: (H, W) uint8 labels of the frame (`moving_to_labels`).
        moving: (H, W) bool moving pixels.
        step: (N, 2) float32 positions of the labelled tracks in this frame and (N, 2) in the neighbour frame.
        labels: (N,) int64 their labels.
        background: the background's label.
        flow: (h, w, 2) float32 flow from this frame to the neighbour frame at the flow's scale.
        scale: the flow's scale (h / H).
        cfg: the thresholds (unexplained_px, unexplained_area, unexplained_rigid).

    Returns:
        (H, W) uint8 labels (`mask` itself when nothing changes).
    """
    height, width = moving.shape
    present = [int(m) for m in np.unique(mask[moving]) if m not in (background, UNKNOWN, MOVING_UNCLUSTERED)]
    if not present:
        return mask
    if scale != 1:
        flow = cv2.resize(flow, (width, height), interpolation=cv2.INTER_LINEAR) / np.float32(scale)
    xy, xy_next = step
    ys, xs = np.nonzero(moving)  # only moving pixels are judged: a tenth of the frame or less
    points = np.stack([xs, ys], axis=1).astype(np.float32)
    ends = points + flow[ys, xs]
    explained = np.zeros(ys.size, bool)
    judged = np.zeros((height, width), bool)
    for m in present:
        of = labels == m
        hom = cv2.findHomography(xy[of], xy_next[of], cv2.RANSAC, 2.0)[0] if of.sum() >= 8 else None
        if hom is None:
            continue
        track_miss = np.linalg.norm(
            cv2.perspectiveTransform(xy[of].reshape(-1, 1, 2), hom).reshape(-1, 2) - xy_next[of], axis=1
        )
        limit = max(cfg.unexplained_px, 2.0 * float(np.percentile(track_miss, 90)))
        predicted = cv2.perspectiveTransform(points.reshape(-1, 1, 2), hom).reshape(-1, 2)
        explained |= np.linalg.norm(ends - predicted, axis=1) <= limit
        judged |= mask == m
    unexplained = judged.copy()
    unexplained[ys[explained], xs[explained]] = False
    unexplained = cv2.morphologyEx(unexplained.astype(np.uint8), cv2.MORPH_OPEN, np.ones((5, 5), np.uint8))
    n, regions, stats, _ = cv2.connectedComponentsWithStats(unexplained, connectivity=8)
    split = np.zeros(n, bool)
    for r in 1 + np.nonzero(stats[1:, cv2.CC_STAT_AREA] >= cfg.unexplained_area * height * width)[0]:
        ry, rx = np.nonzero(regions == r)
        pick = slice(None, None, max(1, ry.size // 1500))
        p = np.stack([rx[pick], ry[pick]], axis=1).astype(np.float32)
        own, inliers = cv2.findHomography(p, p + flow[ry[pick], rx[pick]], cv2.RANSAC, 1.0)
        split[r] = own is not None and float(inliers.mean()) >= cfg.unexplained_rigid
    if not split.any():
        return mask
    out = mask.copy()
    out[split[regions]] = MOVING_UNCLUSTERED
    return out
