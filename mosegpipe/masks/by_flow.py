"""Mask steps that the flow decides, per frame after the moving pixels: moving pixels given the motion whose step
explains their flow (`reassign_by_flow`, `reassign_along`), a moving region that no moving motion's tracks explain
split off as a motion of its own (`split_unexplained`), static pixels that a moving motion's tracks hold and whose
flow it explains given to it (`missed_movers`)."""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe.colours import WORLD
from mosegpipe.group.twoview import robust_fit
from mosegpipe.masks.labels import MOVING_UNCLUSTERED, UNKNOWN, MaskConfig
from mosegpipe.masks.rigid_tracks import Seen


def common_step(
    seen: Seen, near: Seen
) -> tuple[npt.NDArray[np.intp], tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]]:
    """The tracks of one frame also seen in a neighbour frame, matched by id: (their rows in `seen`, ((K, 2) float32
    positions here, (K, 2) there))."""
    _, here, there = np.intersect1d(seen[0], near[0], assume_unique=True, return_indices=True)
    return here, (np.asarray(seen[1], np.float32)[here], np.asarray(near[1], np.float32)[there])


def flow_at_full_size(flow: npt.NDArray[np.float32], scale: float, hw: tuple[int, int]) -> npt.NDArray[np.float32]:
    """A flow at `scale` of the frame resized (linear) to the frame's (h, w), in full-resolution pixels."""
    if scale == 1:
        return flow
    out: npt.NDArray[np.float32] = cv2.resize(flow, (hw[1], hw[0]), interpolation=cv2.INTER_LINEAR) / np.float32(scale)
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
    flow = flow_at_full_size(flow, scale, (height, width))
    xy, xy_next = step
    ys, xs = np.nonzero(moving)  # only moving pixels are judged: a tenth of the frame or less
    points = np.stack([xs, ys], axis=1).astype(np.float32)
    ends = points + flow[ys, xs]
    explained = np.zeros(ys.size, bool)
    judged = np.zeros((height, width), bool)
    for m in present:
        of = labels == m
        hom = robust_fit("homography", xy[of], xy_next[of], "ransac", 2.0)[0] if of.sum() >= 8 else None
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
        own, inliers = robust_fit("homography", p, p + flow[ry[pick], rx[pick]], "ransac", 1.0)
        split[r] = own is not None and inliers is not None and float(inliers.mean()) >= cfg.unexplained_rigid
    if not split.any():
        return mask
    out = mask.copy()
    out[split[regions]] = MOVING_UNCLUSTERED
    return out


REASSIGN_MIN_TRACKS = 6
"""A moving motion needs this many tracks in the frame and its neighbour for `reassign_by_flow` to fit its step."""


def reassign_by_flow(
    mask: npt.NDArray[np.uint8],
    step: tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]],
    labels: npt.NDArray[np.int64],
    flow: npt.NDArray[np.float32],
    scale: float,
    ratio: float,
) -> npt.NDArray[np.uint8]:
    """One frame's mask with each moving pixel given the moving motion whose step best explains its flow.

    Each moving motion of the mask with at least REASSIGN_MIN_TRACKS tracks gets the affine map of its tracks'
    step to the neighbour frame (RANSAC, 2 px). A pixel of such a motion whose flow another one's map predicts
    with less than `ratio` times its own's miss takes that motion (the nearest track's label, which the mask
    gives it, bleeds across touching objects); a 5 x 5 median over those pixels then removes single flips.
    World, unknown and unclustered pixels are left as they are, and so is every pixel's moving or not.

    Args:
        mask: (H, W) uint8 labels of the frame (`moving_to_labels`).
        step: (N, 2) float32 positions of the labelled tracks in this frame and (N, 2) in the neighbour frame.
        labels: (N,) int64 their labels.
        flow: (h, w, 2) float32 flow from this frame to the neighbour frame at the flow's scale.
        scale: the flow's scale (h / H).
        ratio: `MaskConfig.reassign_ratio`.

    Returns:
        (H, W) uint8 labels (`mask` itself when fewer than two motions can be fitted).
    """
    height, width = mask.shape
    models = {}
    for m in np.unique(mask):
        of = labels == m
        if m in (WORLD, UNKNOWN, MOVING_UNCLUSTERED) or of.sum() < REASSIGN_MIN_TRACKS:
            continue
        affine = _step_affine(step, of)
        if affine is not None:
            models[int(m)] = affine
    if len(models) < 2:
        return mask
    flow = flow_at_full_size(flow, scale, (height, width))
    names = np.array(sorted(models), np.uint8)
    judged = np.isin(mask, names)
    ys, xs = np.nonzero(judged)
    points = np.stack([xs, ys], axis=1).astype(np.float32)
    miss = _affine_misses(points, points + flow[ys, xs], models, names)
    own = miss[np.searchsorted(names, mask[ys, xs]), np.arange(ys.size)]
    best = miss.argmin(axis=0)
    change = miss[best, np.arange(ys.size)] < ratio * own
    if not change.any():
        return mask
    out = mask.copy()
    out[ys[change], xs[change]] = names[best[change]]
    smooth = cv2.medianBlur(out, 5)
    take = judged & np.isin(smooth, names)
    out[take] = smooth[take]
    return out


def _step_affine(
    step: tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]], of: npt.NDArray[np.bool_]
) -> npt.NDArray[np.float64] | None:
    """The (2, 3) affine map of the tracks `of` from this frame to the neighbour frame (RANSAC, 2 px), or None."""
    affine: npt.NDArray[np.float64] | None = cv2.estimateAffine2D(
        step[0][of], step[1][of], method=cv2.RANSAC, ransacReprojThreshold=2.0
    )[0]
    return affine


def _affine_misses(
    points: npt.NDArray[np.float32],
    ends: npt.NDArray[np.float32],
    models: dict[int, npt.NDArray[np.float64]],
    names: npt.NDArray[np.uint8],
) -> npt.NDArray[np.float64]:
    """(len(names), P): how far each motion's affine map of `points` lands from where their flow takes them."""
    return np.stack([np.linalg.norm(ends - points @ models[m][:, :2].T - models[m][:, 2], axis=1) for m in names])


def missed_movers(
    mask: npt.NDArray[np.uint8],
    step: tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]],
    labels: npt.NDArray[np.int64],
    flow: npt.NDArray[np.float32],
    residual: npt.NDArray[np.float32],
    scale: float,
    cfg: MaskConfig = MaskConfig(),
) -> npt.NDArray[np.uint8]:
    """One frame's mask with the world's pixels that a moving motion's tracks hold and whose flow that motion
    explains given to that motion: a mover the moving pixels missed (one frame threshold for all movers: a slow
    one beside fast ones falls under it) is not written as the world.

    Each moving motion that the mask misses (`_missed_models`) gets the affine map of its tracks' step to the
    neighbour frame. A world pixel is a candidate of the motion whose
    map predicts its flow best when its camera residual is clear: above the floor of the moving pixels
    (cfg.motion.min_residual_px, cfg.motion.noise_factor x the frame's median residual), twice the 90th
    percentile of the world's tracks' residuals (the camera fit's own error) and cfg.missed_ratio x the pixel's
    flow (the camera's motion explains less than the rest of it: not the world's flow a little off, parallax),
    and when that map misses its flow by under cfg.missed_ratio x the residual (the motion explains it better
    than the camera does). The connected regions of one motion's candidates (after a 3 x 3 opening) that hold
    at least cfg.missed_tracks of its tracks, more than the world's, take the motion when together they hold
    most of its tracks in the frame.

    Args:
        mask: (H, W) uint8 labels of the frame (`moving_to_labels`).
        step: (N, 2) float32 positions of the labelled tracks in this frame and (N, 2) in the neighbour frame.
        labels: (N,) int64 their labels.
        flow: (h, w, 2) float32 flow from this frame to the neighbour frame at the flow's scale.
        residual: (h, w) float32 the frame's camera residual at the flow's scale, in its pixels.
        scale: the flow's scale (h / H).
        cfg: missed_tracks, missed_ratio and the moving pixels' floor (cfg.motion).

    Returns:
        (H, W) uint8 labels (`mask` itself when nothing changes).
    """
    height, width = mask.shape
    xy = step[0]
    ij = np.round(xy).astype(np.int64)
    inside = (ij[:, 0] >= 0) & (ij[:, 0] < width) & (ij[:, 1] >= 0) & (ij[:, 1] < height)
    world = mask == WORLD
    models = _missed_models(world, step, labels, ij, inside, cfg.missed_tracks)
    if not models:
        return mask
    res = flow_at_full_size(residual, scale, (height, width))
    floor = max(cfg.motion.min_residual_px, cfg.motion.noise_factor * float(np.median(res)))
    still = inside & (labels == WORLD)
    if still.any():
        floor = max(floor, 2.0 * float(np.percentile(res[ij[still, 1], ij[still, 0]], 90)))
    flow = flow_at_full_size(flow, scale, (height, width))
    clear = res >= np.maximum(floor, cfg.missed_ratio * np.linalg.norm(flow, axis=2))
    ys, xs = np.nonzero(world & clear)
    if not ys.size:
        return mask
    names = np.array(sorted(models), np.uint8)
    points = np.stack([xs, ys], axis=1).astype(np.float32)
    miss = _affine_misses(points, points + flow[ys, xs], models, names)
    best = miss.argmin(axis=0)
    take = miss[best, np.arange(ys.size)] < cfg.missed_ratio * res[ys, xs]
    out = mask
    opening = np.ones((3, 3), np.uint8)
    for k, m in enumerate(names):
        chosen = np.zeros((height, width), np.uint8)
        pick = take & (best == k)
        chosen[ys[pick], xs[pick]] = 1
        num, regions = cv2.connectedComponents(cv2.morphologyEx(chosen, cv2.MORPH_OPEN, opening), connectivity=8)
        if num <= 1:
            continue
        where = regions[ij[inside, 1], ij[inside, 0]]
        own = np.bincount(where[labels[inside] == m], minlength=num)
        others = np.bincount(where[labels[inside] == WORLD], minlength=num)
        held = (own >= cfg.missed_tracks) & (own > others)
        held[0] = False
        # one object the mask missed holds most of its motion's tracks; a few of a group's tracks scattered over
        # the world's flow (a piece of the background the grouping split off) do not make a mover
        if 2 * own[held].sum() > own.sum():
            out = mask.copy() if out is mask else out
            out[held[regions]] = m
    return out


def _missed_models(
    world: npt.NDArray[np.bool_],
    step: tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]],
    labels: npt.NDArray[np.int64],
    ij: npt.NDArray[np.int64],
    inside: npt.NDArray[np.bool_],
    least: int,
) -> dict[int, npt.NDArray[np.float64]]:
    """`missed_movers`' candidates: label -> the (2, 3) affine map of its tracks' step (RANSAC, 2 px), for each
    moving motion with `least` or more tracks on the world's pixels (`world`), more of its tracks there than on the
    other pixels (a motion the mask shows is not missed) and REASSIGN_MIN_TRACKS in all."""
    on_world = np.zeros(len(step[0]), bool)
    on_world[inside] = world[ij[inside, 1], ij[inside, 0]]
    models = {}
    for m in np.unique(labels[on_world]):
        of = labels == m
        missed = (of & on_world).sum()
        if m < 0 or m in (WORLD, UNKNOWN, MOVING_UNCLUSTERED) or missed < least:
            continue
        if of.sum() < REASSIGN_MIN_TRACKS or 2 * missed <= (of & inside).sum():  # the mask shows it: not missed
            continue
        affine = _step_affine(step, of)
        if affine is not None:
            models[int(m)] = affine
    return models


def reassign_along(
    mask: npt.NDArray[np.uint8],
    tracks: tuple[npt.NDArray[np.int64], npt.NDArray[np.float32], npt.NDArray[np.int64], npt.NDArray[np.float32]],
    labels: npt.NDArray[np.int64],
    flow: npt.NDArray[np.float32],
    scale: float,
    ratio: float,
) -> npt.NDArray[np.uint8]:
    """`reassign_by_flow` with the step of the tracks seen in this frame and in its neighbour frame.

    Args:
        tracks: (ids, xy) of this frame's tracks and (ids, xy) of the neighbour frame's.
        labels: (N,) int64 labels of this frame's tracks.
        flow, scale, ratio: as `reassign_by_flow`'s.
    """
    here, step = common_step(tracks[:2], tracks[2:])
    if not here.size:
        return mask
    return reassign_by_flow(mask, step, labels[here], flow, scale, ratio)
