"""Motion-segmentation metrics as documented pure NumPy functions (plus SciPy's Hungarian solver).

Every function takes per-point integer labels: ``pred`` (N,) cluster ids from a method and ``gt``
(N,) ground-truth group ids. Label values are arbitrary integers; only the partition matters.
Results are fractions in [0, 1], never percentages.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt
from scipy.optimize import linear_sum_assignment


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
