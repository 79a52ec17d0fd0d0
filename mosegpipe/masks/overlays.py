"""Overlays (mosegpipe.masks): a mask tinted over its frame, with the labelled tracks' dots on it."""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe.colours import UNKNOWN_RGB, WORLD, mask_palette, point_palette
from mosegpipe.errors import InputError


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
