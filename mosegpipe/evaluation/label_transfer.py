"""Ground-truth labels for our own tracks and matches: nearest point, and agreement of motion.

`nearest_within` / `transfer_labels` give a point the label of the nearest ground-truth point within
a radius; the end-to-end protocols score with them (evaluation/e2e.py).

Nearest-point transfer labels only ~13 % of our KLT tracks on KT3DMoSeg (5 px radius): its ground truth
lies on an 8 px grid on some surfaces only. For training data (training/own_tracks.py) a track takes a
label from farther away when the two points *move alike*: a ground-truth trajectory within
`radius_px` whose displacement from the window's first frame agrees with ours in every frame where it
is visible is, for a rigid scene, on the same body, unless a rival with another label agrees as well.
Measured on every third 5-frame window of six KT3DMoSeg sequences (default settings): 52 % of our
tracks labelled (13 % with the 5 px rule), and 524 of the 525 that also lie within 2 px of a fully
visible ground-truth trajectory take that trajectory's label.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree


def _as_points(name: str, xy: npt.ArrayLike) -> npt.NDArray[np.float64]:
    arr = np.asarray(xy, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(f"{name} must have shape (N, 2), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} of shape {arr.shape} holds NaN or inf")
    return arr


def nearest_within(our_xy: npt.ArrayLike, gt_xy: npt.ArrayLike, max_dist_px: float) -> npt.NDArray[np.int64]:
    """Index of the nearest ground-truth point within a radius, for each of our points.

    Args:
        our_xy: (N, 2) pixel coordinates of our points.
        gt_xy: (M, 2) pixel coordinates of the ground-truth points.
        max_dist_px: largest accepted Euclidean distance, pixels (inclusive).

    Returns:
        (N,) int64 row of gt_xy, or -1 where no ground-truth point lies within max_dist_px.

    Raises:
        ValueError: bad shapes, NaN/inf coordinates or a negative radius.
    """
    ours = _as_points("our_xy", our_xy)
    gt = _as_points("gt_xy", gt_xy)
    if not max_dist_px >= 0:
        raise ValueError(f"max_dist_px={max_dist_px} must be >= 0")
    out = np.full(ours.shape[0], -1, dtype=np.int64)
    if ours.shape[0] == 0 or gt.shape[0] == 0:
        return out
    # cKDTree's bound is strict; nudge it so that a point exactly at max_dist_px is accepted.
    dist, idx = cKDTree(gt).query(ours, k=1, distance_upper_bound=np.nextafter(max_dist_px, np.inf))
    found = np.isfinite(dist)
    out[found] = idx[found]
    return out


def transfer_labels(
    our_xy: npt.ArrayLike,
    gt_xy: npt.ArrayLike,
    gt_labels: npt.ArrayLike,
    max_dist_px: float = 3.0,
) -> npt.NDArray[np.int64]:
    """Ground-truth label of the nearest ground-truth point within a radius.

    Args:
        our_xy: (N, 2) pixel coordinates of our points (tracks in one frame, or matches in one image).
        gt_xy: (M, 2) pixel coordinates of the labelled ground-truth points in the same frame.
        gt_labels: (M,) non-negative integer labels of the ground-truth points.
        max_dist_px: largest accepted distance, pixels (inclusive).

    Returns:
        (N,) int64 label, -1 where no ground-truth point lies within max_dist_px.

    Raises:
        ValueError: bad shapes, NaN/inf coordinates, negative labels or radius.
    """
    labels = np.asarray(gt_labels)
    gt = _as_points("gt_xy", gt_xy)
    if labels.shape != (gt.shape[0],):
        raise ValueError(f"gt_labels has shape {labels.shape}, expected ({gt.shape[0]},)")
    if labels.size and (not np.issubdtype(labels.dtype, np.integer) or labels.min() < 0):
        raise ValueError("gt_labels must be non-negative integers (-1 marks unmatched points)")
    idx = nearest_within(our_xy, gt, max_dist_px)
    out = np.full(idx.shape, -1, dtype=np.int64)
    out[idx >= 0] = labels[idx[idx >= 0]]
    return out


@dataclass(frozen=True)
class TrackTransferConfig:
    """Settings of `transfer_track_labels`.

    Attributes:
        radius_px: candidates lie within this distance in the window's first frame (two cells of
            KT3DMoSeg's 8 px seeding grid).
        tol_px: largest accepted disagreement of the displacements in any frame, pixels.
        rel_tol: ... or this fraction of the candidate's largest displacement, if larger (fast
            points near the camera track with errors proportional to their motion).
        margin_px: a candidate of another label that agrees within this much of the best one makes
            the track ambiguous (label -1).
        offset_weight: the best candidate minimises disagreement + offset_weight * distance.
    """

    radius_px: float = 16.0
    tol_px: float = 1.5
    rel_tol: float = 0.05
    margin_px: float = 0.5
    offset_weight: float = 0.1


@dataclass(frozen=True)
class PairTransferConfig:
    """Settings of `transfer_match_labels`.

    Attributes:
        exact_px: a ground-truth correspondence within this distance in both images gives its label
            (outliers included) directly.
        radius_px: otherwise, inlier correspondences within this distance in image 1 are candidates.
        tol_px: a candidate agrees when the two displacements (image 2 minus image 1) differ by at
            most this much; the candidates that agree must share one label.
        outlier_px: when at least `min_candidates` candidates exist and none comes within this
            distance, the match moves like nothing around it: a gross outlier (file label 0).
        min_candidates: fewer candidates than this and the match stays unlabelled.
    """

    exact_px: float = 3.0
    radius_px: float = 24.0
    tol_px: float = 3.0
    outlier_px: float = 20.0
    min_candidates: int = 3


def transfer_track_labels(
    our_xy: npt.ArrayLike,
    gt_xy: npt.ArrayLike,
    gt_visible: npt.ArrayLike,
    gt_labels: npt.ArrayLike,
    cfg: TrackTransferConfig = TrackTransferConfig(),
) -> npt.NDArray[np.int64]:
    """Label each of our tracks with the ground-truth trajectory that moves like it.

    Args:
        our_xy: (N, F, 2) pixel coordinates of our tracks over the window (visible in all F frames).
        gt_xy: (M, F, 2) ground-truth coordinates over the same window (anything where not visible).
        gt_visible: (M, F) bool.
        gt_labels: (M,) non-negative int labels.
        cfg: settings.

    Returns:
        (N,) int64 label, -1 where no candidate agrees or candidates of two labels do.

    Raises:
        ValueError: inconsistent shapes.
    """
    ours = np.asarray(our_xy, dtype=np.float64)
    gt = np.asarray(gt_xy, dtype=np.float64)
    vis = np.asarray(gt_visible, dtype=bool)
    labels = np.asarray(gt_labels, dtype=np.int64)
    if ours.ndim != 3 or ours.shape[2] != 2 or gt.shape[1:] != ours.shape[1:] or vis.shape != gt.shape[:2]:
        raise ValueError(f"shapes our_xy {ours.shape}, gt_xy {gt.shape}, gt_visible {vis.shape} do not fit")
    if labels.shape != (gt.shape[0],):
        raise ValueError(f"gt_labels has shape {labels.shape}, expected ({gt.shape[0]},)")
    out = np.full(ours.shape[0], -1, dtype=np.int64)
    # A candidate must be seen in the first frame and at least one later one (a displacement).
    cand = np.flatnonzero(vis[:, 0] & vis[:, 1:].any(axis=1))
    if cand.size == 0 or ours.shape[0] == 0:
        return out
    neighbours = cKDTree(gt[cand, 0]).query_ball_point(ours[:, 0], r=cfg.radius_px)
    our_disp = ours - ours[:, :1]
    gt_disp = gt - gt[:, :1]
    for i, near in enumerate(neighbours):
        if not near:
            continue
        j = cand[np.asarray(near)]
        diff = np.linalg.norm(our_disp[i][None] - gt_disp[j], axis=2)  # (c, F)
        mismatch = np.where(vis[j], diff, 0.0).max(axis=1)
        scale = np.where(vis[j], np.linalg.norm(gt_disp[j], axis=2), 0.0).max(axis=1)
        agrees = mismatch <= np.maximum(cfg.tol_px, cfg.rel_tol * scale)
        if not agrees.any():
            continue
        score = mismatch + cfg.offset_weight * np.linalg.norm(ours[i, 0] - gt[j, 0], axis=1)
        score[~agrees] = np.inf
        best = int(np.argmin(score))
        rivals = agrees & (labels[j] != labels[j[best]]) & (score <= score[best] + cfg.margin_px)
        if not rivals.any():
            out[i] = labels[j[best]]
    return out


def transfer_match_labels(
    xy1: npt.ArrayLike,
    xy2: npt.ArrayLike,
    gt_xy1: npt.ArrayLike,
    gt_xy2: npt.ArrayLike,
    gt_labels: npt.ArrayLike,
    cfg: PairTransferConfig = PairTransferConfig(),
) -> npt.NDArray[np.int64]:
    """Label each of our two-view matches from ground-truth correspondences (file labels, 0 = outlier).

    Args:
        xy1, xy2: (N, 2) our matches' pixel coordinates in images 1 and 2.
        gt_xy1, gt_xy2: (M, 2) ground-truth correspondences.
        gt_labels: (M,) file labels: 0 = gross outlier, 1..K = motion.
        cfg: settings.

    Returns:
        (N,) int64 file label (0 = gross outlier, 1..K), -1 where unknown.
    """
    a1, a2 = np.asarray(xy1, np.float64), np.asarray(xy2, np.float64)
    g1, g2 = np.asarray(gt_xy1, np.float64), np.asarray(gt_xy2, np.float64)
    labels = np.asarray(gt_labels, dtype=np.int64)
    if a1.shape != a2.shape or g1.shape != g2.shape or labels.shape != (g1.shape[0],):
        raise ValueError(f"shapes xy1 {a1.shape}, xy2 {a2.shape}, gt {g1.shape}/{g2.shape}, labels {labels.shape}")
    out = np.full(a1.shape[0], -1, dtype=np.int64)
    if a1.shape[0] == 0 or g1.shape[0] == 0:
        return out
    dist, idx = cKDTree(g1).query(a1, k=1)
    exact = (dist <= cfg.exact_px) & (np.linalg.norm(a2 - g2[idx], axis=1) <= cfg.exact_px)
    out[exact] = labels[idx[exact]]
    inliers = np.flatnonzero(labels > 0)
    if inliers.size == 0:
        return out
    tree = cKDTree(g1[inliers])
    our_disp = a2 - a1
    gt_disp = g2[inliers] - g1[inliers]
    for i in np.flatnonzero(~exact):
        near = tree.query_ball_point(a1[i], r=cfg.radius_px)
        if len(near) < cfg.min_candidates:
            continue
        mismatch = np.linalg.norm(our_disp[i] - gt_disp[near], axis=1)
        agree = np.unique(labels[inliers[np.asarray(near)]][mismatch <= cfg.tol_px])
        if agree.size == 1:
            out[i] = agree[0]
        elif agree.size == 0 and mismatch.min() > cfg.outlier_px:
            out[i] = 0
    return out
