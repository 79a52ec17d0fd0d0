"""Geometric grouping: motions found by sequential multi-model fitting, no learned embedding.

`group_geometric` explains the tracks of a window with as few rigid two-view models as it can, one
after another (sequential RANSAC with automatic K):

1. On the tracks not yet explained, fit a homography and a fundamental matrix from frame 0 to frame
   F - 1 by RANSAC (OpenCV USAC_MAGSAC, inlier distance `residual_px`). Each is then refined on all
   frames: from its RANSAC inliers a model is fitted by least squares for every frame pair (0, t),
   t = 1 .. F - 1, and a track's residual is the largest over those pairs (transfer error for the
   homography, Sampson distance for the fundamental matrix, pixels); the inliers to `residual_px`
   are refitted once more. So a track must follow the motion in every frame, not only the last.
2. The model of the group is the homography unless the fundamental matrix explains clearly more
   tracks (the homography keeps fewer than `homography_ratio` of its inliers) and the tracks that
   only it explains are not one planar motion of their own. A fundamental matrix is degenerate for
   a camera that stands still or only rotates (a planar background): it then also explains an
   object that translates, which the second condition keeps from being swallowed. With parallax (a
   camera moving through a 3D scene) the homography explains only one depth layer and the
   fundamental matrix, explaining all depths, wins: the scene stays one group.
3. The group's inliers are removed and the next group is fitted, until the next one would hold
   fewer than `min_group` tracks or `min_share` of all tracks, or K reaches `k_max`. With K given,
   exactly K models are fitted whatever their size.
4. Every track is labelled with the model that fits it best (smallest residual): leftovers (tracker
   failures, points of motions too small to be a group) join the group whose motion they follow
   most closely. With automatic K, a group left with fewer than the minimum is dissolved the same way.

Memory is O(N K): per track one residual per model, no N x N matrices. On rigid objects moving over
planar backgrounds this is the right model; on articulated or deforming objects (people, animals)
one rigid model per object does not hold, and the learned embedding may do better.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe.configs.grouping import GeometricConfig
from mosegpipe.errors import InputError
from mosegpipe.group.cluster import kmeans, relabel_by_size
from mosegpipe.group.twoview import MIN_FUNDAMENTAL, least_squares, robust_fit, sampson_px, transfer_px
from mosegpipe.types import Clustering

logger = logging.getLogger(__name__)

ModelKind = Literal["homography", "fundamental"]

_MIN_HOMOGRAPHY = 4  # points that determine a homography


@dataclass(frozen=True)
class _Model:
    """One rigid motion over the window: a 3x3 matrix per frame pair (0, t), t = 1 .. F - 1."""

    kind: ModelKind
    mats: tuple[npt.NDArray[np.float64], ...]

    def residuals(self, xy: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """(M, F, 2) positions -> (M,) largest residual over the frame pairs, pixels."""
        pair = transfer_px if self.kind == "homography" else sampson_px
        a = np.ascontiguousarray(xy[:, 0])
        res = [pair(m, a, np.ascontiguousarray(xy[:, t + 1])) for t, m in enumerate(self.mats)]
        return np.asarray(np.max(res, axis=0))


def _fit(
    kind: ModelKind, xy: npt.NDArray[np.float64], cfg: GeometricConfig
) -> tuple[_Model, npt.NDArray[np.bool_]] | None:
    """The model of most of the tracks xy (M, F, 2) and its inliers (M,), or None (too few / degenerate)."""
    least = _MIN_HOMOGRAPHY if kind == "homography" else MIN_FUNDAMENTAL
    if len(xy) < least:
        return None
    a, b = np.ascontiguousarray(xy[:, 0]), np.ascontiguousarray(xy[:, -1])
    mat, found = robust_fit(kind, a, b, "magsac", cfg.residual_px, cfg.ransac_iters, cfg.confidence)
    if mat is None or found is None:
        return None
    inliers = found
    best: tuple[_Model, npt.NDArray[np.bool_]] | None = None
    for _ in range(2):  # least squares on every frame pair from the inliers, then once more from its own
        if inliers.sum() < least:
            break
        mats = [least_squares(kind, a[inliers], np.ascontiguousarray(xy[inliers, t])) for t in range(1, xy.shape[1])]
        if any(m is None for m in mats):
            break
        model = _Model(kind, tuple(m for m in mats if m is not None))
        found = model.residuals(xy) <= cfg.residual_px
        if best is not None and found.sum() < best[1].sum():
            break
        best = (model, found)
        inliers = found
    return best


def _fit_group(xy: npt.NDArray[np.float64], cfg: GeometricConfig) -> tuple[_Model, npt.NDArray[np.bool_]] | None:
    """The rigid motion of most of the tracks xy (M, F, 2): homography or fundamental matrix (step 2)."""
    hom = _fit("homography", xy, cfg)
    fun = _fit("fundamental", xy, cfg)
    if fun is None:
        return hom
    if hom is None:
        return fun
    h_in, f_in = hom[1], fun[1]
    if h_in.sum() >= cfg.homography_ratio * f_in.sum():
        return hom
    extra = f_in & ~h_in
    if extra.sum() >= _MIN_HOMOGRAPHY:
        own = _fit("homography", xy[extra], cfg)
        if own is not None and own[1].mean() >= cfg.planar_share:
            return hom  # the fundamental matrix swallowed a planar motion of its own
    return fun


def _check_points(points: npt.ArrayLike) -> npt.NDArray[np.float64]:
    try:
        data = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"trajectories: not an array of numbers ({exc})") from exc
    if data.ndim != 2 or data.shape[1] < 4 or data.shape[1] % 2:
        raise InputError(f"trajectories must have shape (N, 2F) with F >= 2, got {data.shape}")
    if not np.all(np.isfinite(data)):
        raise InputError(f"trajectories of shape {data.shape} contain NaN or inf")
    return data


def group_geometric(
    points: npt.ArrayLike,
    size_hw: tuple[int, int],
    cfg: GeometricConfig = GeometricConfig(),
    k: int | None = None,
) -> Clustering:
    """Groups trajectories into rigid motions by sequential multi-model fitting (module docstring).

    Args:
        points: (N, 2F) float trajectories in pixels (x_0, y_0, x_1, y_1, ...), F >= 2.
        size_hw: (H, W) of the frames, pixels (checked; the models work in pixels as given).
        cfg: thresholds, see GeometricConfig.
        k: exactly this many groups (None = automatic K, at most cfg.k_max).

    Returns:
        Clustering with labels (N,) in 0..K-1 ordered by decreasing group size (0 = the largest,
        usually the background), method "geometric" and scores {K': share of the tracks that the
        first K' models explain to cfg.residual_px} for each model fitted (K' = 1, 2, ...; the share
        grows with K', and the last entries may exceed K when a small group was dissolved).
        The note names the model of each group in order of fitting ("models: homography, fundamental").

    Raises:
        InputError: points not (N, 2F) finite numbers with N >= 1, F >= 2; a bad size_hw; k < 1 or k > N.
    """
    data = _check_points(points)
    n = data.shape[0]
    if n == 0:
        raise InputError("trajectories: no tracks to group")
    if len(size_hw) != 2 or min(size_hw) < 1:
        raise InputError(f"size_hw={size_hw!r} must be (H, W) with H, W >= 1")
    if k is not None and (isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 1 <= k <= n):
        raise InputError(f"k={k!r} must be an integer in 1..{n} (the number of tracks)")
    xy = data.reshape(n, -1, 2)
    cv2.setRNGSeed(cfg.seed)
    min_size = max(cfg.min_group, math.ceil(cfg.min_share * n))
    target = cfg.k_max if k is None else int(k)
    models: list[_Model] = []
    explained = np.zeros(n, dtype=bool)
    scores: dict[int, float] = {}
    while len(models) < target:
        rest = np.flatnonzero(~explained)
        if rest.size < (_MIN_HOMOGRAPHY if k is not None else max(min_size, _MIN_HOMOGRAPHY)):
            break
        found = _fit_group(xy[rest], cfg)
        if found is None or (k is None and found[1].sum() < min_size) or not found[1].any():
            break
        models.append(found[0])
        explained[rest[found[1]]] = True
        scores[len(models)] = round(float(explained.mean()), 4)
    if not models:
        return Clustering(np.zeros(n, dtype=np.int64), 1, scores, "geometric", "no rigid model fits the tracks")
    res = np.stack([m.residuals(xy) for m in models], axis=1)  # (N, K) pixels
    active = list(range(len(models)))
    labels = np.asarray(np.argmin(res, axis=1), dtype=np.int64)
    while k is None and len(active) > 1:
        sizes = np.bincount(labels, minlength=len(models))[active]
        if sizes.min() >= min_size:
            break
        del active[int(np.argmin(sizes))]  # dissolved: its tracks join the next best model
        labels = np.asarray(np.array(active)[np.argmin(res[:, active], axis=1)], dtype=np.int64)
    if k is not None and len(models) < k:
        labels = _fill_groups(xy, labels, res.min(axis=1), k - len(models), len(models), cfg)
    note = "models: " + ", ".join(models[i].kind for i in active)
    out = relabel_by_size(labels)
    return Clustering(out, int(out.max()) + 1, scores, "geometric", note)


def _fill_groups(
    xy: npt.NDArray[np.float64],
    labels: npt.NDArray[np.int64],
    best: npt.NDArray[np.float64],
    need: int,
    first: int,
    cfg: GeometricConfig,
) -> npt.NDArray[np.int64]:
    """With K given but fewer models fitted: the `need` groups missing, by K-means on the displacements
    of the tracks no model explains (at least `need` of the worst-fitting tracks)."""
    order = np.argsort(-best, kind="stable")
    pool = order[: max(need, int((best > cfg.residual_px).sum()))]
    disp = (xy[pool] - xy[pool, :1]).reshape(len(pool), -1)
    sub, _ = kmeans(disp, need, seed=cfg.seed, n_init=3)
    out = labels.copy()
    out[pool] = first + sub
    return out
