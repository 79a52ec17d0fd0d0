"""Motion-segmentation metrics as documented pure NumPy functions (plus SciPy's Hungarian solver and
OpenCV's morphology and distance transform for the boundaries).

Point labels: ``pred`` (N,) cluster ids from a method and ``gt`` (N,) ground-truth group ids; label
values are arbitrary integers, only the partition matters (misclassification error, NMI, FBMS P/R/F,
correct-K rate). Dense masks: the DAVIS region similarity J and boundary F-measure of binary masks,
and the one-to-one matching of predicted mask labels to ground-truth groups that `mask_scores` scores
after. Results are fractions in [0, 1], never percentages.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt
from scipy.optimize import linear_sum_assignment

BOUNDARY_TOLERANCE = 0.008
"""DAVIS boundary tolerance as a fraction of the image diagonal (6.4 -> 7 px at 640x480)."""


def _as_labels(name: str, labels: npt.ArrayLike) -> npt.NDArray[np.int64]:
    arr = np.asarray(labels)
    if arr.ndim != 1:
        raise ValueError(f"{name} must be a 1-D label array, got shape {arr.shape}")
    if arr.size and not np.issubdtype(arr.dtype, np.integer):
        if not np.issubdtype(arr.dtype, np.floating) or not np.all(arr == np.round(arr)):
            raise ValueError(f"{name} must hold integer labels, got dtype {arr.dtype}")
    return arr.astype(np.int64)


def _check_pair(pred: npt.ArrayLike, gt: npt.ArrayLike) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    p = _as_labels("pred", pred)
    g = _as_labels("gt", gt)
    if p.shape != g.shape:
        raise ValueError(f"pred has shape {p.shape} but gt has shape {g.shape}")
    if p.size == 0:
        raise ValueError(f"pred and gt are empty (shape {p.shape})")
    return p, g


def contingency(pred: npt.ArrayLike, gt: npt.ArrayLike) -> npt.NDArray[np.int64]:
    """Count table of predicted clusters against ground-truth groups.

    Args:
        pred: (N,) int predicted cluster ids.
        gt: (N,) int ground-truth group ids.

    Returns:
        (C, G) int64 table; entry [c, g] counts the points in the c-th smallest pred id and the
        g-th smallest gt id.
    """
    p, g = _check_pair(pred, gt)
    _, p_idx = np.unique(p, return_inverse=True)
    _, g_idx = np.unique(g, return_inverse=True)
    table = np.zeros((int(p_idx.max()) + 1, int(g_idx.max()) + 1), dtype=np.int64)
    np.add.at(table, (p_idx.ravel(), g_idx.ravel()), 1)
    return table


def misclassification_error(pred: npt.ArrayLike, gt: npt.ArrayLike) -> float:
    """Fraction of points misassigned under the best one-to-one map of clusters to groups.

    The standard motion-segmentation error (Hopkins155, KT3DMoSeg, AdelaideRMF): clusters are
    matched to groups one-to-one by the Hungarian method on the contingency table, maximising
    the number of points that agree; all other points are errors. With more clusters than
    groups, the unmatched clusters' points are all errors (and vice versa).

    Args:
        pred: (N,) int predicted cluster ids.
        gt: (N,) int ground-truth group ids.

    Returns:
        Error in [0, 1]; 0 when the two partitions are identical up to renaming.

    Raises:
        ValueError: shapes differ, are not 1-D, are empty, or labels are not integers.
    """
    table = contingency(pred, gt)
    rows, cols = linear_sum_assignment(table, maximize=True)
    return float(1.0 - table[rows, cols].sum() / table.sum())


def nmi(pred: npt.ArrayLike, gt: npt.ArrayLike) -> float:
    """Normalised mutual information (arithmetic-mean normalisation, scikit-learn's default).

    Args:
        pred: (N,) int predicted cluster ids.
        gt: (N,) int ground-truth group ids.

    Returns:
        NMI in [0, 1]; 1 for identical partitions (including both being a single cluster).

    Raises:
        ValueError: shapes differ, are not 1-D, are empty, or labels are not integers.
    """
    from sklearn.metrics import normalized_mutual_info_score

    p, g = _check_pair(pred, gt)
    return float(normalized_mutual_info_score(g, p))


def fbms_prf(
    pred: npt.ArrayLike,
    gt: npt.ArrayLike,
    background: int | None = 0,
    object_threshold: float = 0.75,
) -> tuple[float, float, float, int]:
    """Precision, recall, F-measure and extracted objects in the FBMS59 protocol, on points.

    Follows the Freiburg-Berkeley Motion Segmentation evaluation (Ochs, Malik, Brox, PAMI 2014,
    and its MoSegEval tool), with labelled trajectory points standing in for the tracked pixels
    of annotated frames:

    1. Points with gt < 0 are not labelled and are dropped entirely (from clusters too).
    2. For every ground-truth region g (background included) and cluster c:
       P(g, c) = |c ∩ g| / |c| and R(g, c) = |c ∩ g| / |g|, F(g, c) = 2PR / (P + R).
    3. Regions and clusters are matched one-to-one by the Hungarian method maximising the sum of
       F (the tool truncates F to 1e-4 steps first; this function does not).
    4. P and R are averaged over the regions: a region left without a cluster (fewer clusters
       than regions) counts P = 1, R = 0; clusters left without a region are ignored, as in the
       tool. A matched pair without overlap counts P = R = 0.
    5. F = 2 P R / (P + R) of the averaged P and R (not the mean of per-region F).
    6. An object counts as extracted when its matched F exceeds ``object_threshold`` (strictly,
       as in the tool; the PAMI paper reports the count at 0.75). The background region is not
       counted. The tool instead subtracts one from the count over all regions, which differs
       only when the background itself is not extracted.

    Args:
        pred: (N,) int predicted cluster ids.
        gt: (N,) int ground-truth region ids; negative = unlabelled, not scored.
        background: gt id of the background region (excluded from the object count), or None
            when every region is an object.
        object_threshold: F-measure above which a region counts as extracted.

    Returns:
        precision, recall, fmeasure (fractions in [0, 1]) and the number of extracted objects.

    Raises:
        ValueError: shapes differ, are not 1-D, are empty, or no point is labelled.
    """
    p, g = _check_pair(pred, gt)
    labelled = g >= 0
    if not np.any(labelled):
        raise ValueError(f"gt of shape {g.shape} has no labelled point (all labels < 0)")
    p, g = p[labelled], g[labelled]
    regions = np.unique(g)
    table = contingency(p, g).astype(np.float64)  # (C, G) overlap counts
    cluster_size = table.sum(axis=1, keepdims=True)
    region_size = table.sum(axis=0, keepdims=True)
    precision = table / cluster_size
    recall = table / region_size
    with np.errstate(invalid="ignore", divide="ignore"):
        fmeasure = np.where(table > 0, 2 * precision * recall / (precision + recall), 0.0)
    rows, cols = linear_sum_assignment(fmeasure, maximize=True)

    num_regions = regions.size
    sum_p = float(precision[rows, cols].sum()) + (num_regions - cols.size)  # unmatched: P = 1
    sum_r = float(recall[rows, cols].sum())  # unmatched regions: R = 0
    avg_p, avg_r = sum_p / num_regions, sum_r / num_regions
    avg_f = 2 * avg_p * avg_r / (avg_p + avg_r) if avg_p + avg_r > 0 else 0.0
    is_object = regions[cols] != background if background is not None else np.ones_like(cols, bool)
    num_objects = int(np.sum((fmeasure[rows, cols] > object_threshold) & is_object))
    return avg_p, avg_r, float(avg_f), num_objects


def correct_k_rate(pred_k: Sequence[int], true_k: Sequence[int]) -> float:
    """Fraction of clips whose number of clusters was estimated exactly.

    Args:
        pred_k: estimated K per clip.
        true_k: ground-truth K per clip, same length.

    Returns:
        Fraction in [0, 1].

    Raises:
        ValueError: lengths differ or are zero.
    """
    p = np.asarray(pred_k)
    t = np.asarray(true_k)
    if p.ndim != 1 or p.shape != t.shape:
        raise ValueError(f"pred_k has shape {p.shape} but true_k has shape {t.shape}")
    if p.size == 0:
        raise ValueError("pred_k and true_k are empty (shape (0,))")
    return float(np.mean(p == t))


def error_summary(errors: Sequence[float]) -> dict[str, float]:
    """Mean and median of per-clip errors, as benchmark tables report them.

    Args:
        errors: per-clip errors as fractions in [0, 1] (not percentages).

    Returns:
        {"mean", "median", "max"} as fractions, and "count" (number of clips, as a float).

    Raises:
        ValueError: empty, not 1-D, or containing NaN/inf.
    """
    e = np.asarray(errors, dtype=np.float64)
    if e.ndim != 1 or e.size == 0:
        raise ValueError(f"errors must be a non-empty 1-D sequence, got shape {e.shape}")
    if not np.all(np.isfinite(e)):
        raise ValueError(f"errors of shape {e.shape} contain NaN or inf")
    return {
        "mean": float(e.mean()),
        "median": float(np.median(e)),
        "max": float(e.max()),
        "count": float(e.size),
    }


# ---------------------------------------------------------------------------------------------
# Mask metrics (DAVIS region similarity J and boundary F)


def jaccard(pred: npt.ArrayLike, gt: npt.ArrayLike) -> float:
    """Region similarity J = |P ∩ G| / |P ∪ G| of two binary masks.

    Args:
        pred: (H, W) bool (or 0/1) predicted mask.
        gt: (H, W) bool (or 0/1) ground-truth mask.

    Returns:
        J in [0, 1]; 1.0 when both masks are empty (DAVIS convention).

    Raises:
        ValueError: shapes differ.
    """
    p = np.asarray(pred, dtype=bool)
    g = np.asarray(gt, dtype=bool)
    if p.shape != g.shape:
        raise ValueError(f"pred has shape {p.shape} but gt has shape {g.shape}")
    union = np.count_nonzero(p | g)
    if union == 0:
        return 1.0
    return float(np.count_nonzero(p & g) / union)


def union_shares(pred: npt.ArrayLike, gt: npt.ArrayLike) -> tuple[float, float]:
    """The false-positive and miss shares of the union of two binary masks.

    With U = pred | gt: false positives |pred & ~gt| / |U| (background written as moving) and misses
    |gt & ~pred| / |U| (the object written as background), so that J + both = 1; both 0 when U is empty
    (J is then 1).

    Args:
        pred: (H, W) bool predicted foreground.
        gt: (H, W) bool ground truth.

    Returns:
        (false-positive share, miss share), each in [0, 1].
    """
    p, g = np.asarray(pred, dtype=bool), np.asarray(gt, dtype=bool)
    union = int(np.count_nonzero(p | g))
    if union == 0:
        return 0.0, 0.0
    return np.count_nonzero(p & ~g) / union, np.count_nonzero(g & ~p) / union


def background_points_moving(
    points: Sequence[tuple[npt.ArrayLike, npt.ArrayLike]], gt: npt.ArrayLike, world: int = 0
) -> float:
    """The share of labelled points on the true background whose label is a mover's (not `world`).

    Args:
        points: per frame t, (xy (N, 2) float pixels, labels (N,) int; -1 = unlabelled, not counted).
        gt: (T, H, W) bool ground-truth foreground; a point outside the frame is not counted.
        world: the world's label.

    Returns:
        In [0, 1]; NaN when no labelled point lies on the true background.
    """
    truth = np.asarray(gt, dtype=bool)
    on_background = moving = 0
    for t, (xy, labels) in enumerate(points):
        ij = np.round(np.asarray(xy, np.float64).reshape(-1, 2)).astype(np.int64)
        lab = np.asarray(labels, np.int64).reshape(-1)
        h, w = truth.shape[1:]
        ok = (lab >= 0) & (ij[:, 0] >= 0) & (ij[:, 0] < w) & (ij[:, 1] >= 0) & (ij[:, 1] < h)
        bg = ok.copy()
        bg[ok] = ~truth[t][ij[ok, 1], ij[ok, 0]]
        on_background += int(bg.sum())
        moving += int(np.count_nonzero(bg & (lab != world)))
    return moving / on_background if on_background else math.nan


def boundary_map(mask: npt.ArrayLike) -> npt.NDArray[np.bool_]:
    """One-pixel inner boundary of a binary mask.

    A pixel is on the boundary when it is in the mask and one of its 4-neighbours is not. The
    image border is not a boundary (a mask running off the image has no contour there), as in
    the DAVIS evaluation.

    Args:
        mask: (H, W) bool (or 0/1).

    Returns:
        (H, W) bool.
    """
    m = np.ascontiguousarray(np.asarray(mask, dtype=bool), dtype=np.uint8)
    cross = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))
    # erode pads with +inf by default, so pixels on the image border keep their value.
    eroded = cv2.erode(m, cross)
    return (m > 0) & (eroded == 0)


def _tolerance_px(tolerance: float, size_hw: tuple[int, int]) -> float:
    """DAVIS: a tolerance >= 1 is in pixels, below 1 a fraction of the diagonal, rounded up."""
    if tolerance >= 1:
        return float(tolerance)
    return float(math.ceil(tolerance * math.hypot(*size_hw)))


def boundary_f(
    pred: npt.ArrayLike, gt: npt.ArrayLike, tolerance: float = BOUNDARY_TOLERANCE
) -> tuple[float, float, float]:
    """DAVIS boundary precision, recall and F-measure of two binary masks.

    Follows Perazzi et al. (CVPR 2016): boundary pixels of the prediction count as correct when a
    ground-truth boundary pixel lies within the tolerance, and vice versa; F = 2PR / (P + R).
    Distances come from a Euclidean distance transform (OpenCV, exact mask) instead of DAVIS's
    dilation with a disk of the same radius, which selects the same pixels.

    Args:
        pred: (H, W) bool predicted mask.
        gt: (H, W) bool ground-truth mask.
        tolerance: below 1: fraction of the image diagonal, rounded up to whole pixels (DAVIS uses
            0.008); from 1 up: pixels.

    Returns:
        (precision, recall, F) in [0, 1]. Both boundaries empty: (1, 1, 1). Only the prediction's
        empty: (1, 0, 0); only the ground truth's empty: (0, 1, 0).

    Raises:
        ValueError: shapes differ.
    """
    p = np.asarray(pred, dtype=bool)
    g = np.asarray(gt, dtype=bool)
    if p.shape != g.shape or p.ndim != 2:
        raise ValueError(f"pred has shape {p.shape} but gt has shape {g.shape} (need equal (H, W))")
    bp, bg = boundary_map(p), boundary_map(g)
    n_p, n_g = int(bp.sum()), int(bg.sum())
    if n_p == 0 and n_g == 0:
        return 1.0, 1.0, 1.0
    if n_p == 0:
        return 1.0, 0.0, 0.0
    if n_g == 0:
        return 0.0, 1.0, 0.0
    tol = _tolerance_px(tolerance, p.shape)
    # distanceTransform measures the distance to the nearest zero pixel: zeros on the boundary.
    dist_to_g = cv2.distanceTransform((~bg).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    dist_to_p = cv2.distanceTransform((~bp).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    precision = float(np.mean(dist_to_g[bp] <= tol))
    recall = float(np.mean(dist_to_p[bg] <= tol))
    f = 2 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0
    return precision, recall, float(f)


@dataclass(frozen=True)
class MaskScores:
    """DAVIS-style scores of predicted label masks against ground-truth masks.

    Attributes:
        j: region similarity, mean over the scored ground-truth groups of the mean over frames.
        f: boundary F-measure, averaged the same way.
        j_per_group: ground-truth id -> mean J over frames.
        f_per_group: ground-truth id -> mean F over frames.
        assignment: ground-truth id -> the predicted mask value matched to it (None: unmatched,
            scored as an empty prediction).
    """

    j: float
    f: float
    j_per_group: dict[int, float]
    f_per_group: dict[int, float]
    assignment: dict[int, int | None]


def match_masks(pred_masks: npt.ArrayLike, gt_masks: npt.ArrayLike, unknown: int | None = 255) -> dict[int, int | None]:
    """One-to-one map of ground-truth groups to predicted labels maximising the overlap.

    Overlaps are pixel counts summed over all frames (one assignment per clip, as labels are
    consistent across frames); the Hungarian method maximises the total. Ground-truth groups left
    over when there are fewer predicted labels, or matched with zero overlap, map to None.

    Args:
        pred_masks: (T, H, W) or (H, W) non-negative int predicted labels.
        gt_masks: same shape, non-negative int ground-truth group ids (background included).
        unknown: predicted value meaning "no label" (never matched), or None.

    Returns:
        {gt id: predicted value or None} for every id present in gt_masks.

    Raises:
        ValueError: shapes differ or values are negative.
    """
    p = np.asarray(pred_masks)
    g = np.asarray(gt_masks)
    if p.shape != g.shape:
        raise ValueError(f"pred_masks has shape {p.shape} but gt_masks has shape {g.shape}")
    p = p.reshape(-1).astype(np.int64)
    g = g.reshape(-1).astype(np.int64)
    if p.size and (p.min() < 0 or g.min() < 0):
        raise ValueError("mask values must be non-negative")
    gt_ids = np.unique(g)
    pred_ids = np.unique(p)
    if unknown is not None:
        pred_ids = pred_ids[pred_ids != unknown]
    out: dict[int, int | None] = {int(i): None for i in gt_ids}
    if pred_ids.size == 0 or gt_ids.size == 0:
        return out
    # Pixel-pair histogram via one bincount over a combined index: fast for uint8-sized label sets.
    pi = np.searchsorted(pred_ids, p)
    valid = (pi < pred_ids.size) & (pred_ids[np.minimum(pi, pred_ids.size - 1)] == p)
    gi = np.searchsorted(gt_ids, g)
    table = np.bincount(pi[valid] * gt_ids.size + gi[valid], minlength=pred_ids.size * gt_ids.size).reshape(
        pred_ids.size, gt_ids.size
    )
    rows, cols = linear_sum_assignment(table, maximize=True)
    for r, c in zip(rows, cols):
        if table[r, c] > 0:
            out[int(gt_ids[c])] = int(pred_ids[r])
    return out


def mask_scores(
    pred_masks: npt.ArrayLike,
    gt_masks: npt.ArrayLike,
    background: int | None = 0,
    unknown: int | None = 255,
    tolerance: float = BOUNDARY_TOLERANCE,
) -> MaskScores:
    """Region similarity J and boundary F of label masks, after the best one-to-one label matching.

    Ground-truth groups (the background included) are matched to predicted labels by
    `match_masks`, so that the background cannot be claimed by a cluster that an object needs.
    J and F are then computed per group and frame with `jaccard` / `boundary_f`, averaged over
    frames, and averaged over the scored groups: every ground-truth id except `background`, as
    DAVIS scores objects only (all ids when background is None, or when the background is the only
    group). A group absent from a frame, whose matched label is absent there too, scores 1 there.

    Args:
        pred_masks: (T, H, W) non-negative int predicted labels (pipeline masks: 255 = unknown).
        gt_masks: (T, H, W) non-negative int ground-truth group ids.
        background: ground-truth id left out of the averages (still matched), or None.
        unknown: predicted value meaning "no label", or None.
        tolerance: boundary tolerance, see `boundary_f`.

    Returns:
        MaskScores.

    Raises:
        ValueError: shapes differ or values are negative.
    """
    p = np.asarray(pred_masks)
    g = np.asarray(gt_masks)
    if p.ndim == 2:
        p, g = p[None], np.asarray(g)[None]
    if p.shape != g.shape or p.ndim != 3:
        raise ValueError(f"pred_masks has shape {p.shape} but gt_masks has shape {g.shape} (need (T, H, W))")
    assignment = match_masks(p, g, unknown=unknown)
    scored = [i for i in assignment if i != background] or list(assignment)
    j_per: dict[int, float] = {}
    f_per: dict[int, float] = {}
    for gid in scored:
        pid = assignment[gid]
        js, fs = [], []
        for t in range(g.shape[0]):
            gm = g[t] == gid
            pm = p[t] == pid if pid is not None else np.zeros_like(gm)
            js.append(jaccard(pm, gm))
            fs.append(boundary_f(pm, gm, tolerance)[2])
        j_per[gid] = float(np.mean(js))
        f_per[gid] = float(np.mean(fs))
    return MaskScores(
        j=float(np.mean(list(j_per.values()))),
        f=float(np.mean(list(f_per.values()))),
        j_per_group=j_per,
        f_per_group=f_per,
        assignment=assignment,
    )
