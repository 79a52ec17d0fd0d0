"""Where a whole video's labels lie in its masks, for the window-to-window label matching
(`mosegpipe.group.labels`, LabelConfig.carry_masks): the labels under each track in the last labelled frame's
mask (`labels_under`), and each moving label's last mask (`LabelShape`, `label_shapes`), moved on by its
motion to predict where a label that is missing from some windows is (`shape_holds`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from mosegpipe.masks import MOVING_UNCLUSTERED, WORLD


@dataclass(frozen=True)
class LabelShape:
    """One moving label's pixels in the last frame whose mask showed it.

    Attributes:
        frame: the source index of that frame.
        origin_xy: (2,) int64 (x, y) of the crop's top-left pixel, pixels.
        crop: (h, w) bool the label's pixels inside its bounding box.
    """

    frame: int
    origin_xy: npt.NDArray[np.int64]
    crop: npt.NDArray[np.bool_]


def moving_values(mask: npt.NDArray[np.uint8]) -> npt.NDArray[np.int64]:
    """The moving labels a mask holds: its values but the world (0), the unclustered movers (254) and unknown (255)."""
    vals = np.flatnonzero(np.bincount(mask.ravel(), minlength=256)[:MOVING_UNCLUSTERED])
    return vals[vals != WORLD].astype(np.int64)


def label_shapes(mask: npt.NDArray[np.uint8], frame: int) -> dict[int, LabelShape]:
    """Each moving label's pixels in a frame's mask.

    Args:
        mask: (H, W) uint8 the frame's final labels.
        frame: its source index.

    Returns:
        {moving label: LabelShape}.
    """
    out = {}
    for lab in moving_values(mask).tolist():
        ys, xs = np.nonzero(mask == lab)
        y0, x0 = int(ys.min()), int(xs.min())
        crop = np.zeros((int(ys.max()) - y0 + 1, int(xs.max()) - x0 + 1), dtype=bool)
        crop[ys - y0, xs - x0] = True
        out[lab] = LabelShape(frame, np.array([x0, y0], np.int64), crop)
    return out


def labels_under(mask: npt.NDArray[np.uint8], points_xy: npt.NDArray[np.floating]) -> npt.NDArray[np.int64]:
    """The moving label under each point of a frame's mask.

    Args:
        mask: (H, W) uint8 labels.
        points_xy: (N, 2) positions (x, y) in that frame, pixels.

    Returns:
        (N,) int64 the moving label at each point's nearest pixel; -1 outside the frame, on the world (0),
        on an unclustered mover (254) or on unknown (255).
    """
    h, w = mask.shape
    xy = np.rint(np.asarray(points_xy, dtype=np.float64)).astype(np.int64).reshape(-1, 2)
    inside = (xy[:, 0] >= 0) & (xy[:, 0] < w) & (xy[:, 1] >= 0) & (xy[:, 1] < h)
    out = np.full(xy.shape[0], -1, np.int64)
    vals = mask[xy[inside, 1], xy[inside, 0]].astype(np.int64)
    out[inside] = np.where((vals != WORLD) & (vals < MOVING_UNCLUSTERED), vals, -1)
    return out


def shape_holds(
    shape: LabelShape, points_xy: npt.NDArray[np.floating], shift_xy: npt.NDArray[np.floating]
) -> npt.NDArray[np.bool_]:
    """Which points lie on a label's shape moved by `shift_xy` (its predicted pixels in a later frame).

    Args:
        shape: the label's last pixels.
        points_xy: (N, 2) positions (x, y) in the later frame, pixels.
        shift_xy: (2,) how far the label moved since shape.frame, pixels (its motion per frame times frames).

    Returns:
        (N,) bool.
    """
    h, w = shape.crop.shape
    local = np.rint(np.asarray(points_xy, np.float64).reshape(-1, 2) - np.asarray(shift_xy) - shape.origin_xy)
    local = local.astype(np.int64)
    inside = (local[:, 0] >= 0) & (local[:, 0] < w) & (local[:, 1] >= 0) & (local[:, 1] < h)
    out = np.zeros(local.shape[0], dtype=bool)
    out[inside] = shape.crop[local[inside, 1], local[inside, 0]]
    return out
