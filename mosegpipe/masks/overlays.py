"""Overlays (mosegpipe.masks): a mask tinted over its frame, with the labelled tracks' dots on it and a
legend of its colours."""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe.colours import (
    MOVING_UNCLUSTERED,
    UNKNOWN,
    UNKNOWN_RGB,
    WORLD,
    legend_rows,
    mask_palette,
    point_palette,
)
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


LEGEND_MAX_SHARE = 1 / 3
"""The largest share of a frame the legend may cover (a tiny frame, or many motions, go without one)."""

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


def draw_legend(
    image: npt.NDArray[np.uint8], rows: list[tuple[int, str, tuple[int, int, int], int]]
) -> npt.NDArray[np.uint8]:
    """The legend drawn into the top-left corner of an overlay: per row a swatch of its colour, its name and
    its track count ("motion 1: 54 tracks"), on a darkened box; sized to the image (text about 1/40 of its
    height, at least 8 px). Left out where it would cover more than LEGEND_MAX_SHARE of the frame.

    Args:
        image: (H, W, 3) uint8 RGB overlay, drawn into in place.
        rows: colours.legend_rows(): (value, name, (R, G, B), tracks).

    Returns:
        `image`.
    """
    if not rows:
        return image
    h = image.shape[0]
    font, scale = cv2.FONT_HERSHEY_SIMPLEX, max(0.35, h / 1000)
    thick = 1 if h < 900 else 2
    texts = [f"{name}: {count} track{'s' if count != 1 else ''}" if count else name for _, name, _, count in rows]
    (_, text_h), _ = cv2.getTextSize("Mg", font, scale, thick)
    line, pad = int(text_h * 1.8), max(2, text_h // 2)
    swatch = text_h
    width = max(cv2.getTextSize(t, font, scale, thick)[0][0] for t in texts) + swatch + 3 * pad
    height = len(rows) * line + pad
    if width * height > image.shape[0] * image.shape[1] * LEGEND_MAX_SHARE:
        return image  # a frame too small to hold it: the picture matters more
    box = image[:height, :width]
    box[:] = (box.astype(np.uint16) * 3 // 10).astype(np.uint8)  # darkened to 30 %: the text reads on any frame
    for i, ((_, _, colour, _), text) in enumerate(zip(rows, texts)):
        y = pad + i * line + text_h
        cv2.rectangle(image, (pad, y - swatch), (pad + swatch, y), colour, thickness=-1)
        cv2.putText(image, text, (2 * pad + swatch, y), font, scale, (255, 255, 255), thick, cv2.LINE_AA)
    return image


def overlay_with_legend(
    image: npt.NDArray[np.uint8],
    mask: npt.NDArray[np.uint8] | None,
    xy: npt.NDArray[np.float32],
    labels: npt.NDArray[np.int64],
    unknown: str = "unknown",
) -> npt.NDArray[np.uint8]:
    """overlay_image with its legend (draw_legend): a row per label of the frame's tracks (their count in
    this frame) and per mask value 254 / 255 the mask shows; what overlay/ and overlay.mp4 hold."""
    out = overlay_image(image, mask, xy, labels)
    shown = [] if mask is None else [v for v in (MOVING_UNCLUSTERED, UNKNOWN) if (mask == v).any()]
    return draw_legend(out, legend_rows(labels, np.array(shown, dtype=np.int64), unknown))
