"""Segmenting large frames at a smaller size (`PipelineConfig.max_side`, `moseg run --max-side N`).

The frames are shrunk (OpenCV's area interpolation) so that their longer side is at most N pixels,
segmented there, and what is written is brought back to the input's size: the masks by
nearest-neighbour upsampling of their labels (a label is never blended into another), the tracks'
positions by the inverse scale (pixel centres at integers on both grids), and the frames themselves
are the input's, so that overlays and recordings show the full-size picture.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, MutableMapping

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe.settings import MIN_MAX_SIDE_PX

__all__ = ["MIN_MAX_SIDE_PX", "shrink_factor", "shrink_image", "shrunk_stream", "upscale_labels", "upscale_xy"]


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
