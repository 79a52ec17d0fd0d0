"""Which motion a moving pixel belongs to, where a frame's tracks give several: the mask network's per-motion output.

The moving pixels are decided first (the "motion" chain or the "learned" network); a frame whose tracks carry two or
more moving motions then asks, per motion m, a second network (`net.MaskNet` with `QUERY_CHANNELS` more inputs,
checkpoint output "which", mosegpipe/weights/whichnet.pt) for each pixel's probability of being m's, given the frame's
`features.clip_features` and two query channels drawn from the tracks (`query_channels`). Each moving pixel of those
motions takes the motion of the highest probability (`which_motion`), in place of the choice of the nearest track
and the watershed between them; the flow's affine reassignment (`MaskConfig.reassign_ratio`) still runs after it
(`MaskConfig.which` "learned"; the recipe: `moseg train --preset whichnet`, mosegpipe.training.masks.whichnet).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import TYPE_CHECKING

import cv2
import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    from mosegpipe.configs.masks import MaskConfig
    from mosegpipe.points.flow import FrameMotion

QUERY_CHANNELS = 2
"""Inputs the per-motion network takes beside `features.NUM_CHANNELS` (see `query_channels`)."""

MIN_TRACKS = 3
"""A moving motion takes part in a frame's choice from this many of its tracks in the frame."""


def query_channels(
    xy: npt.NDArray[np.float32], groups: npt.NDArray[np.int64], query: int, hw: tuple[int, int]
) -> npt.NDArray[np.float32]:
    """(QUERY_CHANNELS, h, w) float32: the question "which pixels are motion `query`'s" as the network reads it.

    Args:
        xy: (N, 2) the moving motions' track positions at the network's size (pixels; x right, y down).
        groups: (N,) each track's motion (only moving motions' tracks: the world's are not passed).
        query: the motion asked about.
        hw: the network's input size (h, w).

    Returns:
        Channel 0: +1 at the pixels of the query's tracks, -1 at the other moving motions' tracks, 0 elsewhere;
        channel 1: +1 where the nearest moving track is the query's, -1 where it is another's (0 with no track).
    """
    out = np.zeros((QUERY_CHANNELS, *hw), np.float32)
    p = np.round(np.asarray(xy, np.float64).reshape(-1, 2)).astype(np.int64)
    inside = (p[:, 0] >= 0) & (p[:, 0] < hw[1]) & (p[:, 1] >= 0) & (p[:, 1] < hw[0])
    p, sign = p[inside], np.where(np.asarray(groups)[inside] == query, 1.0, -1.0).astype(np.float32)
    if not len(p):
        return out
    out[0, p[:, 1], p[:, 0]] = sign
    seeds = np.full(hw, 255, np.uint8)
    seeds[p[:, 1], p[:, 0]] = 0
    _, cells = cv2.distanceTransformWithLabels(seeds, cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL)
    lut = np.zeros(int(cells.max()) + 1, np.float32)
    lut[cells[p[:, 1], p[:, 0]]] = out[0, p[:, 1], p[:, 0]]
    out[1] = lut[cells]
    return out


def frame_queries(
    xy: npt.NDArray[np.float32], labels: npt.NDArray[np.int64], full_hw: tuple[int, int], hw: tuple[int, int]
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float32]]:
    """The moving motions of a frame that take part (>= MIN_TRACKS tracks; labels 1..253, the world 0 and the
    unlabelled -1 left out) and their queries: ((M,), (M, QUERY_CHANNELS, h, w)); M < 2 = nothing to choose."""
    labels = np.asarray(labels, np.int64).reshape(-1)
    taking = taking_part(labels)
    if len(taking) < 2:
        return taking, np.zeros((0, QUERY_CHANNELS, *hw), np.float32)
    keep = np.isin(labels, taking)
    to_net = np.array([hw[1] / full_hw[1], hw[0] / full_hw[0]], np.float32)
    p = (np.asarray(xy, np.float32).reshape(-1, 2)[keep] + 0.5) * to_net - 0.5
    return taking, np.stack([query_channels(p, labels[keep], int(m), hw) for m in taking])


def which_motion(
    mask: npt.NDArray[np.uint8],
    features: npt.NDArray[np.float32],
    xy: npt.NDArray[np.float32],
    labels: npt.NDArray[np.int64],
    weights: str = "",
) -> npt.NDArray[np.uint8]:
    """One frame's mask with each pixel of a moving motion that takes part (`frame_queries`) given the one the
    per-motion network finds most likely there (its probabilities resized to the frame, linear); other pixels
    (the world, unknown, the unclustered, motions with too few tracks) keep theirs.

    Args:
        mask: (H, W) uint8 label image.
        features: (NUM_CHANNELS, h, w) the frame's `features.clip_features`.
        xy: (N, 2) float32 the frame's track positions (pixels); labels: (N,) their motions (-1 = unlabelled).
        weights: the per-motion checkpoint ("" = the shipped one).

    Returns:
        `mask` itself when there is nothing to choose, else the relabelled copy.
    """
    from mosegpipe.masks.learned.net import load_masknet, predict

    hw = features.shape[1:]
    motions, queries = frame_queries(xy, labels, mask.shape, hw)
    if len(motions) < 2:
        return mask
    asked = np.isin(mask, motions)
    if not asked.any():
        return mask
    prob = predict(load_masknet(weights, output="which"), asked_inputs(features, queries))
    height, width = mask.shape
    full = np.stack([cv2.resize(p, (width, height), interpolation=cv2.INTER_LINEAR) for p in prob])
    out = mask.copy()
    out[asked] = motions[np.argmax(full[:, asked], axis=0)].astype(np.uint8)
    return out


def asked_inputs(features: npt.NDArray[np.floating], queries: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
    """(M, NUM_CHANNELS + QUERY_CHANNELS, h, w) float32: a frame's features beside each of its M queries."""
    shared = np.broadcast_to(features.astype(np.float32, copy=False), (len(queries), *features.shape))
    return np.concatenate([shared, queries], axis=1)


def taking_part(labels: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
    """The moving motions among a frame's track labels with MIN_TRACKS tracks or more (labels 1..253: the world 0,
    the unlabelled -1 and the masks' reserved values left out)."""
    from mosegpipe.colours import WORLD
    from mosegpipe.masks.labels import MOVING_UNCLUSTERED  # here: mosegpipe.masks imports this module

    labels = np.asarray(labels, np.int64).reshape(-1)
    values, counts = np.unique(
        labels[(labels != WORLD) & (labels >= 0) & (labels < MOVING_UNCLUSTERED)], return_counts=True
    )
    return values[counts >= MIN_TRACKS]


def needs_choice(labels: npt.NDArray[np.int64]) -> bool:
    """Whether a frame's tracks carry two or more moving motions of MIN_TRACKS tracks (`which_motion` acts)."""
    return len(taking_part(labels)) >= 2


def window_features(
    images: npt.NDArray[np.uint8],
    motion: FrameMotion,
    cfg: MaskConfig,
    labels: Iterable[npt.NDArray[np.int64]],
    first: int = 0,
) -> npt.NDArray[np.float32] | None:
    """The `clip_features` of frames first..T-1 of a stack when `cfg.which` is "learned" and one of those frames'
    track `labels` `needs_choice`; else None (nothing to choose, nothing computed)."""
    if cfg.which != "learned" or not any(needs_choice(lab) for lab in labels):
        return None
    from mosegpipe.masks.learned.features import clip_features

    return clip_features(images, motion, cfg.learned.scale, first)
