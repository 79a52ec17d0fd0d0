"""One colour per mask value, for every output: the mask PNGs, the overlays and the Rerun recordings.

Mask values (mosegpipe.masks documents them): 0 the world (the camera's motion), 1..253 moving
motions, 254 moving with no clustered motion (masks.MOVING_UNCLUSTERED), 255 unknown
(masks.UNKNOWN). Every output colours a value from :func:`mask_palette`:

- 0, the world: black in the mask PNGs (the DAVIS background); the overlays leave the frame
  untinted and the viewer draws it transparent (:func:`mask_rgba`), so the world is never coloured.
  Tracks of the world are drawn white (their palette colour would vanish on dark frames).
- 1..254: the PASCAL VOC / DAVIS palette colour of the value (motion 1 red, 2 green, ...; 254 teal),
  blended over the frame in the overlays and the viewer.
- 255, unknown: neutral grey (UNKNOWN_RGB), not the palette's cream: "no evidence" reads as no
  colour. The overlays blend it like any other value (the frame looks washed out), the viewer
  draws it at the mask opacity, and unlabelled tracks and outlier matches (class 255) are dots or
  crosses of the same grey.

The overlays blend at 45 % and the viewer at the same mask opacity, so a pixel looks alike in both;
at full weight an overlay pixel is exactly its value's palette colour. No project imports: io,
masks and viz all take their colours from here.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

WORLD = 0
"""Mask value of the world (the camera's motion): never tinted."""

MOVING_UNCLUSTERED = 254
"""Mask value of moving pixels with no clustered motion (masks.MOVING_UNCLUSTERED)."""

UNKNOWN = 255
"""Mask value of pixels without evidence (masks.UNKNOWN); also the class of unlabelled tracks."""

UNKNOWN_RGB = (160, 160, 160)
"""Colour of unknown pixels, unlabelled tracks and outlier matches in every output."""

WORLD_POINT_RGB = (255, 255, 255)
"""Colour of the world's tracks (dots in the overlays, points and trails in the viewer)."""


def voc_palette() -> npt.NDArray[np.uint8]:
    """The 256-colour palette of PASCAL VOC / DAVIS masks: index 0 black, then distinct colours.

    Colour i spreads the bits of i over the high bits of R, G and B (bit 0 -> R, 1 -> G, 2 -> B,
    3 -> R one level lower, ...), so small indices get saturated, well separated colours.

    Returns:
        (256, 3) uint8 RGB.
    """
    index = np.arange(256)
    palette = np.zeros((256, 3), dtype=np.int64)
    for level in range(8):
        for channel in range(3):
            bit = (index >> (3 * level + channel)) & 1
            palette[:, channel] |= bit << (7 - level)
    return palette.astype(np.uint8)


def mask_palette() -> npt.NDArray[np.uint8]:
    """The colour of each mask value: the palette of the mask PNGs, the overlays' tint and the viewer's.

    Returns:
        (256, 3) uint8 RGB: :func:`voc_palette` with UNKNOWN in UNKNOWN_RGB (no other entry is that grey).
    """
    palette = voc_palette()
    palette[UNKNOWN] = UNKNOWN_RGB
    return palette


def mask_rgba() -> npt.NDArray[np.uint8]:
    """RGBA per mask value as the viewer draws masks: :func:`mask_palette`, opaque, the world transparent.

    Returns:
        (256, 4) uint8.
    """
    rgba = np.concatenate([mask_palette(), np.full((256, 1), 255, np.uint8)], axis=1)
    rgba[WORLD] = 0
    return rgba


def point_palette() -> npt.NDArray[np.uint8]:
    """RGB per track label (class id; 255 = unlabelled / outlier) as overlays and viewer draw tracks.

    Returns:
        (256, 3) uint8: :func:`mask_palette` with the world WORLD_POINT_RGB.
    """
    palette = mask_palette()
    palette[WORLD] = WORLD_POINT_RGB
    return palette


def value_names(num_motions: int, unknown: str = "unknown") -> dict[int, str]:
    """Display name per mask value / class id: the world, motions 1..num_motions-1, 254 and 255.

    Args:
        num_motions: motions 0..num_motions-1 are named (at most 254: 254 and 255 are not motions).
        unknown: the name of 255 (a pair: "unknown / outlier").

    Returns:
        {0: "the world (motion 0)", i: "motion i", 254: "moving, no clustered motion", 255: unknown}.
    """
    names = {i: f"motion {i}" for i in range(min(num_motions, MOVING_UNCLUSTERED))}
    if num_motions:
        names[WORLD] = "the world (motion 0)"
    return {**names, MOVING_UNCLUSTERED: "moving, no clustered motion", UNKNOWN: unknown}


def legend_rows(
    labels: npt.NDArray[np.int64], mask_values: npt.NDArray[np.int64] | None = None, unknown: str = "unknown"
) -> list[tuple[int, str, tuple[int, int, int], int]]:
    """The rows of a legend: what each colour of an overlay or a recording is, and how many tracks it has.

    A value's colour never depends on the frame or the window: it is its entry in :func:`point_palette`
    (the colour of its tracks' dots; the world's white, its pixels untinted), the same mask value always
    the same colour.

    Args:
        labels: (N,) int64 track labels (-1 = unlabelled, not counted).
        mask_values: values the mask shows, added without tracks when no track has them (254, 255).
        unknown: the name of 255.

    Returns:
        (value, name, (R, G, B), tracks) per value, by value: "the world (motion 0)", "motion m", ...
    """
    labels = np.asarray(labels, dtype=np.int64).reshape(-1)
    counts = np.bincount(labels[(labels >= 0) & (labels <= UNKNOWN)], minlength=256)
    shown = set(np.flatnonzero(counts).tolist())
    if mask_values is not None:
        shown |= {int(v) for v in np.asarray(mask_values).reshape(-1) if v in (MOVING_UNCLUSTERED, UNKNOWN)}
    highest = max((v for v in shown if v < MOVING_UNCLUSTERED), default=-1)
    names = value_names(highest + 1, unknown)
    palette = point_palette()
    rows = []
    for value in sorted(shown):
        r, g, b = (int(c) for c in palette[value])
        rows.append((value, names.get(value, f"motion {value}"), (r, g, b), int(counts[value])))
    return rows
