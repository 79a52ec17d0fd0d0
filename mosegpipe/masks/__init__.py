"""From sparse track labels to dense per-frame masks.

Mask values (DAVIS convention, readable by the DAVIS tools): 0 = the world (WORLD: the camera's motion,
the static scene of any depth, told from the other motions by where its tracks lie, `mosegpipe.group.world`),
1..254 = the moving motions, 255 = unknown (no labelled track near enough: no evidence). The value is the
label itself, in clips, pairs, whole videos, live and batch alike.

Methods (`MaskConfig.method`):

- "motion" (default): each pixel is moving or not by whether the camera's motion explains its dense optical
  flow (`moving_pixels`: flow residual, flow consistency, colour models, edge-aware smoothing); static pixels
  take the world's label (0), moving pixels the label of the nearest track of a moving motion, or
  MOVING_UNCLUSTERED (254) when no track of a moving motion is in the frame (the flow found a mover the
  clustering did not). The steps after that are `compose.MaskSequence`'s. It needs the frames of a clip or
  window; without them (a single frame, image pairs, frames too small for dense flow: `flow.flow_fits`) it
  falls back to "watershed".
- "learned": the same sequence with the moving pixels from a small network (`learned`).
- "watershed": marker-based watershed (OpenCV, Meyer's flooding) on the colour image, seeded by the labelled
  tracks, so that two motions meet on the image edge between their tracks rather than half-way between them.
- "nearest": label of the nearest track (a Voronoi partition, OpenCV's labelled distance transform).
- "vote": majority label of the `vote_k` nearest tracks.

Every method but "motion" and "learned" leaves pixels farther than `max_distance_px` from every labelled track
unknown (255). What each method and step measured: docs/RESULTS.md ("Real video", "Rendered clips").

Modules: labels (the mask values, MaskConfig, the track-only methods), moving_pixels (which pixels move),
compose (the mask sequence), by_flow (the steps the flow decides), learned (the mask networks' inference) and overlays (overlay_mask, overlay_image,
overlay_with_legend).
Every public name of labels, compose, by_flow and overlays is re-exported here.
"""

from __future__ import annotations

from mosegpipe.colours import WORLD
from mosegpipe.masks.by_flow import missed_movers, reassign_along, reassign_by_flow, split_unexplained
from mosegpipe.masks.compose import (
    carry_unclustered,
    label_moving_pixels,
    motion_masks,
    moving_to_labels,
    name_unclustered,
)
from mosegpipe.masks.labels import (
    MAX_LABEL,
    MOVING_UNCLUSTERED,
    UNKNOWN,
    MaskConfig,
    labels_to_mask,
    labels_to_masks,
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
    "name_unclustered",
    "label_moving_pixels",
    "labels_to_mask",
    "labels_to_masks",
    "missed_movers",
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
