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

Modules: labels (the mask values, MaskConfig, the track-only methods), moving (the "motion" masks) and
overlays (overlay_mask, overlay_image, overlay_with_legend). Every public name is re-exported here.
"""

from __future__ import annotations

from mosegpipe.colours import WORLD
from mosegpipe.masks.labels import (
    MAX_LABEL,
    MOVING_UNCLUSTERED,
    UNKNOWN,
    MaskConfig,
    labels_to_mask,
    labels_to_masks,
)
from mosegpipe.masks.moving import (
    carry_unclustered,
    label_moving_pixels,
    motion_masks,
    moving_to_labels,
    reassign_along,
    reassign_by_flow,
    split_unexplained,
)
from mosegpipe.masks.overlays import (
    draw_legend,
    overlay_image,
    overlay_mask,
    overlay_with_legend,
)

__all__ = [
    "MAX_LABEL",
    "MOVING_UNCLUSTERED",
    "UNKNOWN",
    "WORLD",
    "MaskConfig",
    "carry_unclustered",
    "label_moving_pixels",
    "labels_to_mask",
    "labels_to_masks",
    "motion_masks",
    "moving_to_labels",
    "draw_legend",
    "overlay_image",
    "overlay_mask",
    "overlay_with_legend",
    "reassign_along",
    "reassign_by_flow",
    "split_unexplained",
]
