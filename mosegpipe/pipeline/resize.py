"""Segmenting large frames at a smaller size (`PipelineConfig.max_side`, `moseg run --max-side N`).

The frames are shrunk (OpenCV's area interpolation) so that their longer side is at most N pixels,
segmented there, and what is written is brought back to the input's size: the masks' labels upsampled
with their edges snapped to the full-size frame's (a guided filter per label, `snap_labels`; a label is
never blended into another: each pixel takes one of the small mask's labels), the moving pixels by
nearest neighbour, the tracks' positions by the inverse scale (pixel centres at integers on both grids),
and the frames themselves are the input's, so that overlays and recordings show the full-size picture.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, MutableMapping
from dataclasses import replace
from typing import TYPE_CHECKING

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe.settings import MIN_MAX_SIDE_PX

if TYPE_CHECKING:
    from mosegpipe.pipeline.config import PipelineConfig

__all__ = [
    "MIN_MAX_SIDE_PX",
    "SNAP_RADIUS_PX",
    "dense_sized",
    "shrink_factor",
    "shrink_image",
    "shrunk_stream",
    "snap_labels",
    "upscale_labels",
    "upscale_mask",
    "upscale_xy",
]


def shrink_factor(size_hw: tuple[int, int], max_side: int | None) -> float:
    """The scale (<= 1) that brings the longer side of a (H, W) frame to at most `max_side` pixels.

    Args:
        size_hw: (H, W) of the frame, pixels.
        max_side: the longest side wanted, pixels (None: no limit).

    Returns:
        max_side / max(H, W) when the frame is larger, else 1.0 (frames are never enlarged).
    """
    longer = max(size_hw)
    if max_side is None or longer <= max_side:
        return 1.0
    return max_side / longer


def dense_sized(cfg: PipelineConfig, size_hw: tuple[int, int]) -> PipelineConfig:
    """`cfg` for frames of this (H, W), as segmented: with `mask.motion.max_side_px`, a frame whose longer side
    exceeds it has its flow (`mask.motion.flow.scale`) and its mask steps (`mask.motion.work_scale`) at the scales
    a frame of that longer side would have (both times max_side_px / the longer side): a 1920x1080 frame's dense
    stage costs what a 1280x720 one's does, while its tracks and masks keep the frame's size."""
    motion = cfg.mask.motion
    factor = shrink_factor(size_hw, motion.max_side_px)
    if factor >= 1.0:
        return cfg
    flow = replace(motion.flow, scale=motion.flow.scale * factor)
    motion = replace(motion, flow=flow, work_scale=motion.work_scale * factor)
    return replace(cfg, mask=replace(cfg.mask, motion=motion))


def small_size(size_hw: tuple[int, int], scale: float) -> tuple[int, int]:
    """(H, W) of a frame scaled by `scale`, each side rounded and at least 1 pixel."""
    return max(1, round(size_hw[0] * scale)), max(1, round(size_hw[1] * scale))


def shrink_image(image: npt.NDArray[np.uint8], scale: float) -> npt.NDArray[np.uint8]:
    """One (H, W, 3) uint8 frame scaled by `scale` <= 1 (area interpolation: no aliasing)."""
    if scale >= 1.0:
        return image
    h, w = small_size(image.shape[:2], scale)
    return np.asarray(cv2.resize(image, (w, h), interpolation=cv2.INTER_AREA), dtype=np.uint8)


def shrink_images(images: npt.NDArray[np.uint8], scale: float) -> npt.NDArray[np.uint8]:
    """(T, H, W, 3) uint8 frames scaled by `scale` <= 1 (see shrink_image)."""
    if scale >= 1.0:
        return images
    return np.stack([shrink_image(image, scale) for image in images])


def upscale_labels(mask: npt.NDArray[np.uint8], size_hw: tuple[int, int]) -> npt.NDArray[np.uint8]:
    """A (h, w) or (T, h, w) uint8 label mask brought to (H, W) by nearest-neighbour sampling.

    Returns:
        (H, W) or (T, H, W) uint8: every value is one of the input's values.
    """
    h, w = size_hw
    if mask.shape[-2:] == (h, w):
        return mask
    if mask.ndim == 3:
        return np.stack([upscale_labels(m, size_hw) for m in mask])
    return np.asarray(cv2.resize(mask, (w, h), interpolation=cv2.INTER_NEAREST), dtype=np.uint8)


def snap_labels(
    mask: npt.NDArray[np.uint8], image: npt.NDArray[np.uint8], radius_px: int, eps: float = 1e-3
) -> npt.NDArray[np.uint8]:
    """A (h, w) label mask brought to the (H, W) of `image` with its edges snapped to the image's.

    Each label but the most common one (the world, usually) is scored inside its bounding box (grown by the
    filter's reach): its indicator upsampled bilinearly and smoothed by a guided filter with the full-size
    frame as guide (OpenCV ximgproc); the most common label scores 1 minus the others (the filter is linear
    in its input for a fixed guide, and the indicators sum to 1). Each pixel takes the label that scores
    highest; outside every box, the nearest-neighbour label (`upscale_labels`), which is the common one.

    Args:
        mask: (h, w) uint8 labels on the small grid.
        image: (H, W, 3) uint8 RGB input frame.
        radius_px: the guided filter's radius on the full-size grid, pixels.
        eps: its regularisation (edges in the guide below about sqrt(eps) in [0, 1] grey are smoothed over).

    Returns:
        (H, W) uint8: every value is one of `mask`'s.
    """
    h, w = image.shape[:2]
    out = upscale_labels(mask, (h, w))
    values, counts = np.unique(mask, return_counts=True)
    if values.size == 1:
        return out
    sy, sx = h / mask.shape[0], w / mask.shape[1]
    grow = int(np.ceil(radius_px / min(sx, sy))) + 2  # small pixels: the filter's reach and the bilinear step
    common = values[counts.argmax()]
    best = np.full((h, w), -np.inf, dtype=np.float32)
    others = np.zeros((h, w), dtype=np.float32)
    scored = np.zeros((h, w), dtype=bool)
    for value in values[values != common]:
        ys, xs = np.nonzero(mask == value)
        y0, y1 = max(0, ys.min() - grow), min(mask.shape[0], ys.max() + 1 + grow)
        x0, x1 = max(0, xs.min() - grow), min(mask.shape[1], xs.max() + 1 + grow)
        top, bottom = int(np.floor(y0 * sy)), min(h, int(np.ceil(y1 * sy)))
        left, right = int(np.floor(x0 * sx)), min(w, int(np.ceil(x1 * sx)))
        # The crop's bilinear upsampling on the full frame's grid: pixel centres (x + 0.5) * sx - 0.5.
        to_full = np.array([[sx, 0, (x0 + 0.5) * sx - 0.5 - left], [0, sy, (y0 + 0.5) * sy - 0.5 - top]])
        indicator = (mask[y0:y1, x0:x1] == value).astype(np.float32)
        size = (right - left, bottom - top)
        score = cv2.warpAffine(indicator, to_full, size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        guide = cv2.cvtColor(np.ascontiguousarray(image[top:bottom, left:right]), cv2.COLOR_RGB2GRAY)
        score = cv2.ximgproc.guidedFilter(guide.astype(np.float32) / 255.0, score, radius_px, eps)
        box = (slice(top, bottom), slice(left, right))
        better = score > best[box]
        out[box][better] = value
        best[box] = np.maximum(best[box], score)
        others[box] += score
        scored[box] = True
    out[scored & (1.0 - others >= best)] = common
    return out


SNAP_RADIUS_PX = 2
"""Radius of the guided filter that snaps upsampled masks to the frame's edges, in pixels of the small grid
(`upscale_mask`; 1, 2 and 4 tried on 5 DAVIS dev clips: 2 and 4 alike, 1 below; docs/RESULTS.md)."""


def upscale_mask(mask: npt.NDArray[np.uint8], image: npt.NDArray[np.uint8]) -> npt.NDArray[np.uint8]:
    """A mask segmented on a shrunk frame brought to its input frame `image` ((H, W, 3) uint8): labels
    upsampled with their edges snapped to the frame's (`snap_labels`, radius SNAP_RADIUS_PX small pixels)."""
    if mask.shape == image.shape[:2]:
        return mask
    scale = mask.shape[1] / image.shape[1]
    return snap_labels(mask, image, max(1, round(SNAP_RADIUS_PX / scale)))


def upscale_xy(xy: npt.NDArray[np.float32], scale: float) -> npt.NDArray[np.float32]:
    """Pixel positions (..., 2) on the small grid -> the input's grid (pixel centres at integers on both)."""
    if scale >= 1.0:
        return xy
    return np.asarray((xy + 0.5) / scale - 0.5, dtype=np.float32)


def shrunk_stream(
    frames: Iterable[tuple[int, npt.NDArray[np.uint8]]],
    max_side: int | None,
    originals: MutableMapping[int, npt.NDArray[np.uint8]],
) -> Iterator[tuple[int, npt.NDArray[np.uint8]]]:
    """Frames (index, (H, W, 3) uint8) of a stream shrunk to `max_side`; each input frame is kept in
    `originals` under its index until the consumer pops it (a whole video's writer takes the full-size
    frame back for its overlay, so only the frames in flight are held)."""
    for index, frame in frames:
        scale = shrink_factor(frame.shape[:2], max_side)
        if scale < 1.0:
            originals[index] = frame
        yield index, shrink_image(frame, scale)
