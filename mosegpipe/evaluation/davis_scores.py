"""DAVIS's scores of one clip's labels (Perazzi et al., CVPR 2016): per-frame J and F, their per-clip mean, recall
and decay, the written masks' foreground (0 = the world, 255 = unknown), and the references the protocol
(`mosegpipe.evaluation.davis`) reports beside them: the majority reading, the world painted as a mover, the best
single label."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from mosegpipe.evaluation.metrics import BOUNDARY_TOLERANCE, boundary_f, jaccard
from mosegpipe.masks import UNKNOWN, WORLD


def clip_statistics(per_frame: npt.ArrayLike) -> tuple[float, float, float]:
    """DAVIS's per-clip statistics of a per-frame score: mean, recall and decay.

    Decay follows the DAVIS evaluation code (`db_statistics`): bin edges
    ids = round(linspace(1, T, 5)) - 1 and bin i = frames ids[i] .. ids[i + 1] (inclusive, so
    neighbouring bins share an edge frame); decay = mean(bin 0) - mean(bin 3). For T = 5 that is
    mean(x0, x1) - mean(x3, x4); for T = 25, mean(x0..x6) - mean(x18..x24).

    Args:
        per_frame: (T,) scores in [0, 1], T >= 1.

    Returns:
        (mean, recall = fraction of frames scoring > 0.5, decay).

    Raises:
        ValueError: no scores.
    """
    x = np.asarray(per_frame, dtype=np.float64).ravel()
    if x.size == 0:
        raise ValueError("no per-frame scores")
    ids = (np.round(np.linspace(1, x.size, 5) + 1e-10) - 1).astype(np.int64)
    bins = [x[ids[i] : ids[i + 1] + 1] for i in range(4)]
    return float(x.mean()), float(np.mean(x > 0.5)), float(bins[0].mean() - bins[3].mean())


def background_label(labels: npt.ArrayLike) -> int | None:
    """The label covering the most pixels over all frames (UNKNOWN excluded); None when all are UNKNOWN.

    Args:
        labels: (T, H, W) or (H, W) uint8 labels.
    """
    counts = np.bincount(np.asarray(labels, dtype=np.uint8).ravel(), minlength=256)[:UNKNOWN]
    return int(np.argmax(counts)) if counts.any() else None


def foreground_from_labels(labels: npt.ArrayLike) -> npt.NDArray[np.bool_]:
    """The foreground of label masks as written: every pixel that is neither the world (0) nor unknown (255).

    Args:
        labels: (T, H, W) or (H, W) uint8 labels.

    Returns:
        bool array of the same shape.
    """
    lab = np.asarray(labels, dtype=np.uint8)
    return (lab != WORLD) & (lab != UNKNOWN)


def majority_foreground(labels: npt.ArrayLike) -> npt.NDArray[np.bool_]:
    """The earlier reading, chosen after the fact: every known pixel outside the label covering most pixels
    of the clip (255 pixels are not candidates). For comparison only.

    Args:
        labels: (T, H, W) uint8 labels of one clip, 255 = unknown.

    Returns:
        (T, H, W) bool.
    """
    lab = np.asarray(labels, dtype=np.uint8)
    bg = background_label(lab)
    if bg is None:
        return np.zeros(lab.shape, dtype=bool)
    return (lab != bg) & (lab != UNKNOWN)


def world_off_share(labels: npt.ArrayLike, gt: npt.ArrayLike) -> float:
    """The share of frames in which the label covering most of the true background (255 excluded) is not 0.

    Args:
        labels: (T, H, W) uint8 labels.
        gt: (T, H, W) bool ground-truth foreground.

    Returns:
        In [0, 1]; a frame whose true background is all unknown does not count as off.
    """
    lab = np.asarray(labels, dtype=np.uint8)
    truth = np.asarray(gt, dtype=bool)
    off = 0
    for t in range(lab.shape[0]):
        counts = np.bincount(lab[t][~truth[t]], minlength=256)[:UNKNOWN]
        off += int(counts.any() and counts.argmax() != WORLD)
    return off / max(lab.shape[0], 1)


def per_frame_scores(
    pred: npt.ArrayLike, gt: npt.ArrayLike, tolerance: float = BOUNDARY_TOLERANCE
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """J and boundary F of every frame.

    Args:
        pred: (T, H, W) bool predicted foreground.
        gt: (T, H, W) bool ground truth.
        tolerance: boundary tolerance (see e2e.boundary_f).

    Returns:
        (J, F), each (T,) float64.

    Raises:
        ValueError: shapes differ.
    """
    p, g = np.asarray(pred, dtype=bool), np.asarray(gt, dtype=bool)
    if p.shape != g.shape or p.ndim != 3:
        raise ValueError(f"pred has shape {p.shape} but gt has shape {g.shape} (need equal (T, H, W))")
    j = np.array([jaccard(a, b) for a, b in zip(p, g)])
    f = np.array([boundary_f(a, b, tolerance)[2] for a, b in zip(p, g)])
    return j, f


def best_single_label(labels: npt.ArrayLike, gt: npt.ArrayLike) -> tuple[int | None, float]:
    """Oracle: the one label whose mask has the best mean J against the truth over the clip's frames.

    Args:
        labels: (T, H, W) uint8 labels, 255 = unknown (never chosen).
        gt: (T, H, W) bool ground truth.

    Returns:
        (label, its mean J); (None, mean J of an empty prediction) when every pixel is unknown.
    """
    lab, g = np.asarray(labels, dtype=np.uint8), np.asarray(gt, dtype=bool)
    best: tuple[int | None, float] = (None, float(np.mean([jaccard(np.zeros_like(f), f) for f in g])))
    for k in np.unique(lab):
        if k == UNKNOWN:
            continue
        j = float(np.mean([jaccard(a, b) for a, b in zip(lab == k, g)]))
        if best[0] is None or j > best[1]:
            best = (int(k), j)
    return best


# ---------------------------------------------------------------------------------------------
# Methods (the flow-homography baseline: mosegpipe.evaluation.flow_baseline)
