"""Joint grouping: the embedding proposes the groups, geometric model selection corrects them.

`select_models` takes the groups that K-means (automatic K) found on the embedding and lets a
penalised criterion over the frames of the window (at most `max_pairs` frame pairs) decide what they are:

1. Model selection per group. Four models of how a group's points move from frame 0 to frame t
   (translation, affine, homography, fundamental matrix) are fitted for every frame pair (0, t):
   RANSAC on the pair (0, F - 1) finds the inliers (`residual_px`), a least-squares fit on each pair
   from those inliers gives the model of the window, and the inliers are refitted once. The model
   kept is the one with the smallest GRIC (Torr's geometric robust information criterion,
   `gric`) summed over the frame pairs: residuals against a noise of `sigma_px`, robustly capped,
   plus a cost per point for the model's dimension (a fundamental matrix explains any point's
   motion along a line, so it pays more per point) and a cost for its parameters. A group whose
   model explains less than `rigid_share` of its tracks is not one rigid motion (a person, an
   animal): geometry has no say on it, and the embedding's group stands as it is.
2. Split. A group other than the largest (the world, which the rigid-motion check already splits;
   `split_largest`) is cut into the tracks of its dominant planar motion (the homography or affine
   map that explains most of it, by RANSAC) and the rest when the rest is one motion of its own (one
   homography explains `planar_share` of it, it is at least the smallest group, `min_group` /
   `min_share`) and the two groups' GRIC is lower than that of the best planar model of the whole;
   not when both parts need a fundamental matrix (the depth of one scene). Repeated until no group
   splits or K reaches `k_max`.
3. Merge. Two rigid groups are merged when one planar model of their union explains `merge_share`
   of each (a track within `residual_px` in most frame pairs, `merge_most_pairs`, as step 4 counts it: a
   track that slips in one frame is a tracking glitch, not a motion of its own; else in every frame pair)
   and has a lower GRIC than their two models: K-means cut one motion in two (a turning
   object, a plane of the world). A fundamental matrix is the union's model only with `merge_3d` and
   when both groups need one: beside a part that one homography explains (a still or rotating camera,
   a plane) it is degenerate and explains an object that translates too, and even between two 3D
   groups a car driving along the camera's direction fits the world's matrix (measured on
   kt3d-video, hence off). GRIC alone would merge a small group into a large one, its points costing
   no more than the capped outliers they become; hence the share. The pair with the largest gain
   first, repeated.
4. Outliers. A track of a rigid group that its own model does not explain in most frame pairs
   (residual above `outlier_px`) goes to the rigid group whose planar model explains it (residual
   within `residual_px` in most frame pairs), the best such (a fundamental matrix, loose, takes
   none). When none does, with `leave_out` it is left out of every object (label -1); by default it
   keeps its group, since the protocols that score every track count a track left out as wrong
   (kt3d-video: 3.68 % -> 5.22 %). Tracks of the groups that are not rigid keep their label.

The pipeline (`PipelineConfig.method` "joint") runs the rigid-motion check first (`rigid_first`), then
this. With `k_search`, K-means with automatic K and with up to that many more groups each go through both, and
`choose_partition` keeps the partition of the lowest summed GRIC (plus `group_cost` per group and frame pair).
In whole videos, `geometry_supported` tells the small new clusters that are rigid motions of their own, which the
label matching then labels below its size guard (`new_rigid_tracks`). Measured in docs/results/41-geometry.md.

Memory is O(N K) residuals per frame pair. Nothing is applied when K is given (the caller's rule).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe.configs.grouping import JointConfig
from mosegpipe.group.twoview import gric, least_squares, robust_fit, sampson_px, transfer_px

logger = logging.getLogger(__name__)

ModelKind = Literal["translation", "affine", "homography", "fundamental"]
MODEL_KINDS: tuple[ModelKind, ...] = ("translation", "affine", "homography", "fundamental")

# (dimension of the model's manifold d, number of parameters k) per model, for GRIC (r = 4: two image points)
_DIM_PARAMS: dict[str, tuple[int, int]] = {
    "translation": (2, 2),
    "affine": (2, 6),
    "homography": (2, 8),
    "fundamental": (3, 7),
}
# the fewest points each model is fitted to (a fundamental matrix needs 8; 15 to constrain it at all)
_LEAST: dict[str, int] = {"translation": 2, "affine": 4, "homography": 6, "fundamental": 15}


@dataclass(frozen=True)
class GroupModel:
    """One group's model over the window: a 3x3 matrix per frame pair (0, t) and its evidence.

    Attributes:
        kind: translation, affine, homography or fundamental.
        mats: one (3, 3) float64 matrix per frame pair (translation and affine as homographies).
        score: the model's GRIC on the group, summed over the frame pairs (lower is better).
        share: the share of the group's tracks it explains (residual within residual_px in every pair).
    """

    kind: str
    mats: tuple[npt.NDArray[np.float64], ...]
    score: float
    share: float

    def residuals(self, xy: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """(M, P + 1, 2) positions in the fitted frames -> (M, P) residual per frame pair, pixels."""
        pair = sampson_px if self.kind == "fundamental" else transfer_px
        a = np.ascontiguousarray(xy[:, 0])
        return np.stack([pair(m, a, np.ascontiguousarray(xy[:, t + 1])) for t, m in enumerate(self.mats)], axis=1)


def _pair_fit(kind: str, a: npt.NDArray[np.float64], b: npt.NDArray[np.float64]) -> npt.NDArray[np.float64] | None:
    """The model of all correspondences a -> b by least squares, None when degenerate."""
    if kind == "translation":
        mat = np.eye(3)
        mat[:2, 2] = np.mean(b - a, axis=0)
        return mat
    if kind == "affine":
        design = np.c_[a, np.ones(len(a))]
        sol, _, rank, _ = np.linalg.lstsq(design, b, rcond=None)
        if rank < 3:
            return None
        return np.vstack([sol.T, [0.0, 0.0, 1.0]])
    return least_squares("homography" if kind == "homography" else "fundamental", a, b)


def _ransac_inliers(
    kind: str, a: npt.NDArray[np.float64], b: npt.NDArray[np.float64], cfg: JointConfig
) -> npt.NDArray[np.bool_] | None:
    """The inliers of the model of most correspondences a -> b (RANSAC), None when none is found."""
    thr = cfg.residual_px
    if kind == "translation":
        d = b - a
        return np.asarray(np.linalg.norm(d - np.median(d, axis=0), axis=1) <= thr)
    if kind == "affine":
        _, mask = cv2.estimateAffine2D(a, b, method=cv2.RANSAC, ransacReprojThreshold=thr, maxIters=cfg.ransac_iters)
    else:
        return robust_fit(
            "homography" if kind == "homography" else "fundamental", a, b, "ransac", thr, cfg.ransac_iters, 0.999
        )[1]
    if mask is None or len(mask) != len(a):
        return None
    return np.asarray(mask.ravel().astype(bool))


def fit_model(kind: str, xy: npt.NDArray[np.float64], cfg: JointConfig = JointConfig()) -> GroupModel | None:
    """One kind of model of the tracks xy (M, P + 1, 2) over the frame pairs (0, t) (step 1), or None.

    The inliers of RANSAC on the pair (0, P) give a least-squares model per frame pair; the tracks it
    explains in every pair are refitted once. Its score is GRIC summed over the pairs.
    """
    if len(xy) < _LEAST[kind]:
        return None
    a = np.ascontiguousarray(xy[:, 0])
    inliers = _ransac_inliers(kind, a, np.ascontiguousarray(xy[:, -1]), cfg)
    best: tuple[tuple[npt.NDArray[np.float64], ...], npt.NDArray[np.float64]] | None = None
    for _ in range(2):
        if inliers is None or inliers.sum() < _LEAST[kind]:
            break
        pair_mats = [_pair_fit(kind, a[inliers], np.ascontiguousarray(xy[inliers, t])) for t in range(1, xy.shape[1])]
        if any(m is None for m in pair_mats):
            break
        found = tuple(m for m in pair_mats if m is not None)
        res = GroupModel(kind, found, 0.0, 0.0).residuals(xy)
        if (
            best is not None
            and (res.max(axis=1) <= cfg.residual_px).sum() < (best[1].max(axis=1) <= cfg.residual_px).sum()
        ):
            break
        best = (found, res)
        inliers = res.max(axis=1) <= cfg.residual_px
    if best is None:
        return None
    mats, res = best
    d, k = _DIM_PARAMS[kind]
    score = sum(gric(res[:, t] ** 2, cfg.sigma_px, d, k) for t in range(res.shape[1]))
    return GroupModel(kind, mats, score, float((res.max(axis=1) <= cfg.residual_px).mean()))


def best_model(xy: npt.NDArray[np.float64], cfg: JointConfig = JointConfig()) -> GroupModel | None:
    """The model of the tracks xy (M, P + 1, 2) with the lowest GRIC (step 1), None when none fits."""
    fitted = [m for m in (fit_model(kind, xy, cfg) for kind in MODEL_KINDS) if m is not None]
    return min(fitted, key=lambda m: m.score) if fitted else None


def _pairs(num_frames: int, most: int) -> npt.NDArray[np.int64]:
    """Frames 0 and up to `most` later frames spread evenly to the last."""
    later = np.unique(np.round(np.linspace(1, num_frames - 1, min(most, num_frames - 1))).astype(np.int64))
    return np.concatenate([[0], later])


@dataclass
class _Group:
    rows: npt.NDArray[np.int64]
    model: GroupModel | None

    def is_rigid(self, cfg: JointConfig) -> bool:
        return self.model is not None and self.model.share >= cfg.rigid_share


def _planar(model: GroupModel | None) -> bool:
    return model is not None and model.kind != "fundamental"


def best_planar(xy: npt.NDArray[np.float64], cfg: JointConfig = JointConfig()) -> GroupModel | None:
    """The translation, affine map or homography of the tracks xy with the lowest GRIC, None when none fits."""
    fitted = [m for m in (fit_model(kind, xy, cfg) for kind in MODEL_KINDS[:3]) if m is not None]
    return min(fitted, key=lambda m: m.score) if fitted else None


def _try_split(
    xy: npt.NDArray[np.float64], group: _Group, min_size: int, cfg: JointConfig
) -> tuple[_Group, _Group] | None:
    """The group cut into its dominant planar motion and the rest when two models beat one (step 2)."""
    if group.model is None or group.rows.size < 2 * min_size:
        return None
    own = xy[group.rows]
    fits = [m for m in (fit_model(kind, own, cfg) for kind in ("homography", "affine")) if m is not None]
    if not fits:
        return None
    dominant = max(fits, key=lambda m: m.share)
    first = dominant.residuals(own).max(axis=1) <= cfg.residual_px
    if first.sum() < min_size or (~first).sum() < min_size:
        return None
    a, b = (
        _Group(group.rows[first], best_model(own[first], cfg)),
        _Group(group.rows[~first], best_model(own[~first], cfg)),
    )
    if a.model is None or b.model is None or not b.is_rigid(cfg):
        return None
    if not (_planar(a.model) or _planar(b.model)):
        return None  # both parts need a fundamental matrix: one scene's depth, the whole's matrix stands
    rest = fit_model("homography", own[~first], cfg)
    if rest is None or rest.share < cfg.planar_share:
        return None  # the rest is no one motion of its own (depth around the dominant plane)
    one = best_planar(own, cfg)
    if one is not None and a.model.score + b.model.score >= one.score:
        return None
    return a, b


def _merge_gain(xy: npt.NDArray[np.float64], one: _Group, two: _Group, cfg: JointConfig) -> tuple[float, _Group] | None:
    """(GRIC saved, the merged group) when one model of the union beats the two (step 3), else None.

    A fundamental matrix is the union's model only when both groups need one: with a part that one
    homography explains (a still or rotating camera, a plane), it is degenerate and explains an object
    that translates as well.
    """
    assert one.model is not None and two.model is not None
    both_3d = cfg.merge_3d and not _planar(one.model) and not _planar(two.model)
    # GRIC caps an outlier's cost: a small group's motion must be explained (merge_share of it), not outvoted.
    model = _union_model(xy, one.rows, two.rows, cfg, both_3d, cfg.merge_share)
    if model is None:
        return None
    gain = one.model.score + two.model.score - model.score
    return (gain, _Group(np.concatenate([one.rows, two.rows]), model)) if gain > 0 else None


def _union_model(
    xy: npt.NDArray[np.float64],
    a: npt.NDArray[np.int64],
    b: npt.NDArray[np.int64],
    cfg: JointConfig,
    three_d: bool,
    share: float,
) -> GroupModel | None:
    """The best model of the rows a and b of xy together (a fundamental matrix allowed only with `three_d`), when
    it explains at least `share` of each within cfg.residual_px in most frame pairs (cfg.merge_most_pairs; else in
    every frame pair); else None."""
    rows = np.concatenate([a, b])
    model = best_model(xy[rows], cfg) if three_d else best_planar(xy[rows], cfg)
    if model is None:
        return None
    res = model.residuals(xy[rows])
    if cfg.merge_most_pairs:
        fits = (res <= cfg.residual_px).sum(axis=1) * 2 > res.shape[1]
    else:
        fits = res.max(axis=1) <= cfg.residual_px
    return model if min(fits[: a.size].mean(), fits[a.size :].mean()) >= share else None


def window_points(points: npt.ArrayLike, cfg: JointConfig = JointConfig()) -> npt.NDArray[np.float64]:
    """(N, 2F) trajectories -> (N, P + 1, 2) their positions in the frames the models are fitted on."""
    data = np.asarray(points, dtype=np.float64)
    return data.reshape(data.shape[0], -1, 2)[:, _pairs(data.shape[1] // 2, cfg.max_pairs)]


def one_rigid_motion(
    xy: npt.NDArray[np.float64],
    a: npt.NDArray[np.int64],
    b: npt.NDArray[np.int64],
    cfg: JointConfig = JointConfig(),
    planar: bool = False,
    share: float | None = None,
) -> bool:
    """Whether one model (translation, affine map, homography, or unless `planar` a fundamental matrix) explains
    `share` (None: cfg.merge_share) of each of the rows a and b of xy (`window_points`): the two move as one rigid
    body (step 3's test, without GRIC)."""
    cv2.setRNGSeed(cfg.seed)
    return _union_model(xy, a, b, cfg, not planar, cfg.merge_share if share is None else share) is not None


def select_models(
    points: npt.ArrayLike,
    labels: npt.ArrayLike,
    cfg: JointConfig = JointConfig(),
    k_max: int = 8,
) -> tuple[npt.NDArray[np.int64], str]:
    """The embedding's groups split, merged and cleaned by model selection (module docstring).

    Args:
        points: (N, 2F) float trajectories in pixels (x_0, y_0, x_1, y_1, ...), F >= 2.
        labels: (N,) int groups in 0..K-1 (automatic K on the embedding).
        cfg: thresholds, see JointConfig.
        k_max: splits stop at this many groups.

    Returns:
        ((N,) int64 labels in 0..K'-1 by decreasing group size, -1 for the tracks no model explains;
        a note saying what changed, "" when nothing did).
    """
    labels_out, note, _, _ = _select(np.asarray(points, dtype=np.float64), labels, cfg, k_max)
    return labels_out, note


def choose_partition(
    points: npt.ArrayLike,
    candidates: list[npt.NDArray[np.int64]],
    cfg: JointConfig = JointConfig(),
    k_max: int = 8,
) -> tuple[int, npt.NDArray[np.int64], str, list[float]]:
    """Of several groupings of the same tracks (K-means with different K), the one geometry supports best.

    Each candidate goes through `select_models`' split and merge; the partition it ends in is scored by the
    summed GRIC of its groups' models (a group no model fits: every track an outlier of a translation) plus
    `cfg.group_cost` per group and frame pair, so that a further group must save more than that to pay for
    itself (`partition_score`). A candidate that ends in more groups no planar model explains (not rigid, or a
    fundamental matrix) than the first is not taken (score inf): GRIC favours cutting a person into pieces, and a
    world of depth into a plane and the rest (its per-point cost is lower for the plane), and either piece costs
    the masks (DAVIS dev, stroller: J 0.73 -> 0.58). The groups a search adds are planar motions: objects.
    Ties go to the earlier candidate.

    Args:
        points: (N, 2F) float trajectories in pixels, F >= 2.
        candidates: (N,) int label arrays in 0..K-1, one per grouping (the first: automatic K).
        cfg: thresholds, see JointConfig.
        k_max: splits stop at this many groups.

    Returns:
        (index of the candidate kept, its labels after select_models, their note, every candidate's score, inf
        for one not allowed).
    """
    if not candidates:
        raise ValueError("choose_partition needs at least one candidate")
    data = np.asarray(points, dtype=np.float64)
    found = [_select(data, labs, cfg, k_max) for labs in candidates]
    scores = [f[2] if f[3] <= found[0][3] else math.inf for f in found]
    best = int(np.argmin(scores)) if np.isfinite(scores).any() else 0  # first of equal scores
    return best, found[best][0], found[best][1], scores


def partition_score(groups_models: list[tuple[int, GroupModel | None]], pairs: int, cfg: JointConfig) -> float:
    """The GRIC of a partition: per group (its size, its model) the model's GRIC summed over the `pairs`
    frame pairs, or, without a model, every track a capped outlier of a translation; plus cfg.group_cost
    per group and frame pair."""
    d, r = _DIM_PARAMS["translation"][0], 4
    total = 0.0
    for size, model in groups_models:
        total += model.score if model is not None else size * pairs * (2.0 * (r - d) + math.log(r) * d)
    return total + cfg.group_cost * pairs * len(groups_models)


def _select(
    data: npt.NDArray[np.float64], labels: npt.ArrayLike, cfg: JointConfig, k_max: int
) -> tuple[npt.NDArray[np.int64], str, float, int]:
    """select_models, the partition_score of its groups after the splits and merges (before tracks move: the
    score of the groups the models were fitted to; inf when there is nothing to score), and how many of those
    groups no planar model explains (not rigid, or a fundamental matrix)."""
    labs = np.asarray(labels, dtype=np.int64).reshape(-1)
    n = labs.size
    if n == 0 or data.shape[1] < 4:
        return labs.copy(), "", math.inf, 0
    xy = window_points(data, cfg)
    cv2.setRNGSeed(cfg.seed)
    min_size = max(cfg.min_group, math.ceil(cfg.min_share * n))
    groups = [
        _Group(rows, best_model(xy[rows], cfg))
        for rows in (np.flatnonzero(labs == g) for g in np.unique(labs[labs >= 0]))
    ]
    splits = 0
    largest = max(range(len(groups)), key=lambda g: groups[g].rows.size) if groups else -1
    queue = [g for g in range(len(groups)) if cfg.split_largest or g != largest]
    while queue and len(groups) < k_max:
        i = queue.pop(0)
        cut = _try_split(xy, groups[i], min_size, cfg)
        if cut is None:
            continue
        groups[i] = cut[0]
        groups.append(cut[1])
        queue += [i, len(groups) - 1]
        splits += 1
    merges = _merge_rigid(xy, groups, cfg)
    score = partition_score([(g.rows.size, g.model) for g in groups], xy.shape[1] - 1, cfg)
    out = np.full(n, -1, dtype=np.int64)
    for g, group in enumerate(groups):
        out[group.rows] = g
    moved = left = 0
    rigid = [i for i, g in enumerate(groups) if g.is_rigid(cfg)]
    if cfg.outlier_px is not None and rigid:
        pairs = xy.shape[1] - 1
        models = [m for m in (groups[i].model for i in rigid) if m is not None]
        res = np.stack([m.residuals(xy) for m in models], axis=0)  # (R, N, P)
        unexplained = (res > cfg.outlier_px).sum(axis=2) * 2 > pairs  # (R, N): off the model in most pairs
        explained = (res <= cfg.residual_px).sum(axis=2) * 2 > pairs
        planar = np.array([_planar(m) for m in models])[:, None]  # a loose fundamental matrix takes no tracks
        cost = np.where(explained & planar & cfg.reassign, res.mean(axis=2), np.inf)
        for r, i in enumerate(rigid):
            rows = groups[i].rows[unexplained[r, groups[i].rows]]
            if rows.size == 0:
                continue
            best = np.argmin(cost[:, rows], axis=0)
            ok = np.isfinite(cost[best, rows])
            out[rows] = np.where(ok, np.array(rigid)[best], -1 if cfg.leave_out else i)
            moved += int(ok.sum())
            left += int((~ok).sum()) if cfg.leave_out else 0
    final = _by_size(out)
    notes = [
        f"{what} {num}"
        for what, num in (("split", splits), ("merged", merges), ("moved", moved), ("left out", left))
        if num
    ]
    kinds = ", ".join(g.model.kind if g.is_rigid(cfg) and g.model else "not rigid" for g in groups)
    note = f"joint: models {kinds}" + (f"; {', '.join(notes)}" if notes else "")
    logger.debug("%s", note)
    return final, note, score, sum(not (g.is_rigid(cfg) and _planar(g.model)) for g in groups)


def geometry_supported(
    points: npt.ArrayLike, labels: npt.ArrayLike, clusters: list[int], cfg: JointConfig = JointConfig()
) -> list[int]:
    """Of `clusters`, those that geometry shows to be a motion of their own: one planar model (translation,
    affine map or homography) of the cluster explains `cfg.planar_share` of its tracks, and no other group's
    model (`best_model`, the fundamental matrix included) explains half of them (within `cfg.residual_px` in
    most frame pairs). A handful of tracks that move as one rigid body the rest of the window does not explain
    is an object, however small (the label matching's guard against small new clusters may let it through).

    Args:
        points: (N, 2F) float trajectories in pixels, F >= 2.
        labels: (N,) int groups in 0..K-1 (-1: no group).
        clusters: the groups to check.
        cfg: thresholds, see JointConfig.

    Returns:
        The groups of `clusters` that are supported, in their order.
    """
    data = np.asarray(points, dtype=np.float64)
    labs = np.asarray(labels, dtype=np.int64).reshape(-1)
    if data.shape[1] < 4 or not clusters:
        return []
    xy = window_points(data, cfg)
    pairs = xy.shape[1] - 1
    cv2.setRNGSeed(cfg.seed)
    others: dict[int, GroupModel | None] = {}
    out = []
    for c in clusters:
        own = xy[labs == c]
        model = best_planar(own, cfg) if own.shape[0] else None
        if model is None or model.share < cfg.planar_share:
            continue
        explained = False
        for g in np.unique(labs[(labs >= 0) & (labs != c)]).tolist():
            if g not in others:
                others[g] = best_model(xy[labs == g], cfg)
            other = others[g]
            if other is not None and ((other.residuals(own) <= cfg.residual_px).sum(axis=1) * 2 > pairs).mean() >= 0.5:
                explained = True
                break
        if not explained:
            out.append(c)
    return out


def _merge_rigid(xy: npt.NDArray[np.float64], groups: list[_Group], cfg: JointConfig) -> int:
    """Merges, best gain first, pairs of rigid groups that one model explains better (in place); returns
    the number of merges."""
    merges = 0
    while len(groups) > 1:
        rigid = [i for i, g in enumerate(groups) if g.is_rigid(cfg)]
        found = [
            (m, i, j)
            for ii, i in enumerate(rigid)
            for j in rigid[ii + 1 :]
            if (m := _merge_gain(xy, groups[i], groups[j], cfg))
        ]
        if not found:
            break
        (gain, merged), i, j = max(found, key=lambda f: f[0][0])
        groups[i] = merged
        del groups[j]
        merges += 1
    return merges


def _by_size(labels: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
    """Labels renumbered 0..K-1 by decreasing group size (ties: first appearance), -1 kept."""
    out = np.full(labels.size, -1, dtype=np.int64)
    keep = labels >= 0
    if keep.any():
        values, first, inverse, counts = np.unique(
            labels[keep], return_index=True, return_inverse=True, return_counts=True
        )
        order = np.lexsort((first, -counts))
        new_id = np.empty(values.size, dtype=np.int64)
        new_id[order] = np.arange(values.size, dtype=np.int64)
        out[keep] = new_id[inverse.ravel()]
    return out
