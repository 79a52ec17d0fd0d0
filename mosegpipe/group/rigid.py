"""The rigid-motion check after clustering: split off the groups that a cluster's motion does not explain.

Automatic K on the embeddings tends to leave a small object inside the cluster of the background (or of
another object): a car of a few dozen tracks barely moves the silhouette. Geometry sees what the
embedding misses. Every cluster of tracks is meant to be one rigid motion, so between the window's
first frame and a later one its points obey one fundamental matrix (a camera moving through a static
3D scene) or one homography (a camera that only rotates or stands still, a plane). For each cluster
(`split_by_rigid_motion`):

1. Fit both models by RANSAC (OpenCV) from frame 0 to frame t, for t = F // 2 and t = F - 1. The
   homography is used when it keeps nearly as many inliers as the fundamental matrix
   (`homography_ratio`): with a still or rotating camera a fundamental matrix is degenerate and also
   explains an object that translates. A point's residual is the larger of its two frame pairs'
   (Sampson distance, or transfer error for the homography), in pixels.
2. Points with a residual above `residual_px` are candidates. A spatially coherent group of them that
   moves alike is a motion of its own: candidates are linked when they lie within
   `neighbour_frac` of the image diagonal of each other in frame 0 and their displacements agree in
   every frame to `motion_px` plus `motion_frac` of the larger displacement; a connected group of at
   least `min_tracks` points becomes a new cluster when one rigid model of its own explains at
   least `consistency` of it. Scattered outliers (tracker failures) are left where they are.
3. Groups of one host that one rigid model explains together (at least `merge_consistency` of their
   union) are merged: the pieces of one object whose motion varies across it (rotation, depth).
4. Points of the host next to a group that move like their nearest member and fit the group's model
   better than the host's join the group (object points that the host's model happens to explain,
   e.g. near their epipolar lines).
5. A fundamental matrix between two frames is loose enough to explain two objects that move
   differently (two boxes translating in different directions both fit one, to the pixel), so steps
   1-2 leave such a pair in one cluster, and the embedding often puts them there. The clusters other
   than the largest (the background) are therefore cut into pieces, each a connected group of points
   that lie close and move alike (as in step 2); pieces of at least `min_tracks` points stay together
   when their median displacements agree in every frame, when one homography explains
   `merge_consistency` of them (a turning object), or when they touch (within the neighbourhood),
   one rigid model explains them and their displacements point within `max_angle_deg` of each other
   (the near and far ends of a deep object, a car passing close by, move in one direction at
   different speeds). Every other set of pieces that a rigid model of its own explains becomes a
   cluster; the largest keeps the label. Larger track sets (`moseg tracks`) are cut on the sample of
   MAX_CHECKED_POINTS, the other points taking the label of their nearest sampled member.

Measured on data that no protocol scores (docs/RESULTS.md, "The rigid-motion check"; step 5's guards
for touching pieces were added after the in-sample `kt3d-video` protocol showed a near car cut up, see
"Step 5" there). Not applied
when K is given, nor to image pairs (their outliers are their own group).
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from mosegpipe.configs.grouping import RigidCheckConfig
from mosegpipe.group.cluster import relabel_by_size
from mosegpipe.group.twoview import MIN_FUNDAMENTAL, robust_fit, sampson_px, transfer_px

if TYPE_CHECKING:
    from scipy.spatial import cKDTree

Residuals = Callable[[npt.NDArray[np.float64]], npt.NDArray[np.float64]]
"""A fitted rigid motion: (M, F, 2) positions -> (M,) residuals, pixels."""

PairResiduals = Callable[[npt.NDArray[np.float64], npt.NDArray[np.float64]], npt.NDArray[np.float64]]
"""A fitted two-view model: (M, 2) points a, (M, 2) points b -> (M,) residuals of a -> b, pixels."""


def _fit_pair(a: npt.NDArray[np.float64], b: npt.NDArray[np.float64], cfg: RigidCheckConfig) -> PairResiduals | None:
    """The rigid model of most correspondences a -> b as a residual function (None: no model fits)."""
    h_mat, _ = robust_fit("homography", a, b, "ransac", cfg.residual_px, 1000, 0.999)
    # With homography_ratio 0 a fitted homography always wins: no fundamental matrix to fit.
    if len(a) >= MIN_FUNDAMENTAL and (cfg.homography_ratio > 0 or h_mat is None):
        f_mat, _ = robust_fit("fundamental", a, b, "ransac", cfg.residual_px, 1000, 0.999)
        if f_mat is not None:
            f_in = (sampson_px(f_mat, a, b) <= cfg.residual_px).sum()
            if h_mat is None or (transfer_px(h_mat, a, b) <= cfg.residual_px).sum() < cfg.homography_ratio * f_in:
                return lambda a2, b2: sampson_px(f_mat, a2, b2)
    if h_mat is None:
        return None
    return lambda a2, b2: transfer_px(h_mat, a2, b2)


def fit_rigid_motion(xy: npt.NDArray[np.float64], cfg: RigidCheckConfig = RigidCheckConfig()) -> Residuals | None:
    """The rigid motion of most of the points (see the module docstring, step 1).

    Args:
        xy: (N, F, 2) positions of N >= 4 points in F >= 2 frames.
        cfg: the residual threshold (RANSAC's inlier distance) and the model choice.

    Returns:
        A function of (M, F, 2) positions giving each point's residual, pixels: the larger of frame
        pairs (0, F // 2) and (0, F - 1); None when RANSAC found no model (degenerate points).
    """
    frames = xy.shape[1]
    steps = sorted({max(1, frames // 2), frames - 1})
    models = []
    for t in steps:
        model = _fit_pair(np.ascontiguousarray(xy[:, 0]), np.ascontiguousarray(xy[:, t]), cfg)
        if model is None:
            return None
        models.append((t, model))

    def residuals(other: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        res = [m(np.ascontiguousarray(other[:, 0]), np.ascontiguousarray(other[:, t])) for t, m in models]
        return np.asarray(np.max(res, axis=0))

    return residuals


def _alike(
    disp_a: npt.NDArray[np.float64], disp_b: npt.NDArray[np.float64], cfg: RigidCheckConfig
) -> npt.NDArray[np.bool_]:
    """Row-wise: do displacements (M, F, 2) a and b agree in every frame (module docstring, step 2)?"""
    diff = np.linalg.norm(disp_a - disp_b, axis=2).max(axis=1)
    size = np.maximum(np.linalg.norm(disp_a, axis=2).max(axis=1), np.linalg.norm(disp_b, axis=2).max(axis=1))
    return np.asarray(diff <= cfg.motion_px + cfg.motion_frac * size)


def _kdtree(points: npt.NDArray[np.float64]) -> cKDTree:
    """SciPy's k-d tree of (N, 2) points (SciPy imported on first use: see runtime.import_ahead)."""
    from scipy.spatial import cKDTree

    return cKDTree(points)


def _connected(n: int, i: npt.NDArray[np.int64], j: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
    """(n,) int64 connected component of each of n nodes joined by the edges i[e] - j[e]."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    graph = coo_matrix((np.ones(len(i)), (i, j)), shape=(n, n))
    return np.asarray(connected_components(graph, directed=False)[1], dtype=np.int64)


def _coherent_groups(xy: npt.NDArray[np.float64], radius: float, cfg: RigidCheckConfig) -> npt.NDArray[np.int64]:
    """Connected groups of points that lie close in frame 0 and move alike: (N,) group index."""
    disp = xy - xy[:, :1]
    pairs = _kdtree(xy[:, 0]).query_pairs(radius, output_type="ndarray")
    i, j = pairs[:, 0], pairs[:, 1]
    alike = _alike(disp[i], disp[j], cfg)
    n = len(xy)
    return _connected(n, i[alike], j[alike])


def _merge_rigid(
    xy: npt.NDArray[np.float64], groups: list[tuple[npt.NDArray[np.int64], Residuals]], cfg: RigidCheckConfig
) -> list[tuple[npt.NDArray[np.int64], Residuals]]:
    """(members, model) groups merged pairwise while one rigid model explains cfg.merge_consistency of a union."""
    share = cfg.merge_consistency
    groups = list(groups)
    while share is not None and len(groups) > 1:
        for i, j in itertools.combinations(range(len(groups)), 2):
            union = np.r_[groups[i][0], groups[j][0]]
            model = fit_rigid_motion(xy[union], cfg)
            if model is not None and np.mean(model(xy[union]) <= cfg.residual_px) >= share:
                groups[i] = (union, model)
                del groups[j]
                break
        else:
            break
    return groups


# With more points than this the check runs on a seeded random sample of this many and the others
# follow the groups found (see split_by_rigid_motion): linking candidates within a fixed radius is
# quadratic in the density of points (100 000 tracks gave ~10^8 neighbour pairs), and RANSAC gains
# nothing from more than a few thousand points. Clips and video windows (< 1100 tracks) are below it.
MAX_CHECKED_POINTS = 3000

_CHUNK = 65536  # rows per block when the points beyond the sample follow the groups


@dataclass(frozen=True)
class _Split:
    """One group split off a host cluster: its new label, member rows, its model and the host's."""

    host: int
    label: int
    members: npt.NDArray[np.int64]
    own: Residuals
    host_model: Residuals


def _split(
    xy: npt.NDArray[np.float64], lab: npt.NDArray[np.int64], radius: float, cfg: RigidCheckConfig, room: int
) -> tuple[npt.NDArray[np.int64], list[_Split]]:
    """Steps 1-4 of the module docstring on (N, F, 2) positions: (labels, the groups split off, at most `room`)."""
    out = lab.copy()
    next_label = int(lab.max()) + 1
    splits: list[_Split] = []
    min_group = _min_group(len(xy), cfg)
    for c in np.unique(lab):
        host = np.flatnonzero(lab == c)
        if host.size < cfg.min_host + min_group:
            continue
        host_model = fit_rigid_motion(xy[host], cfg)
        if host_model is None:
            continue
        res = host_model(xy[host])
        far = host[res > cfg.residual_px]
        if far.size < min_group:
            continue
        groups = _coherent_groups(xy[far], radius, cfg)
        sizes = np.bincount(groups)
        left = host.size
        found: list[tuple[npt.NDArray[np.int64], Residuals]] = []
        for g in np.flatnonzero(sizes >= min_group):
            members = far[groups == g]
            if left - members.size < cfg.min_host:
                continue
            own = fit_rigid_motion(xy[members], cfg)
            if own is None or np.mean(own(xy[members]) <= cfg.residual_px) < cfg.consistency:
                continue
            found.append((members, own))
            left -= members.size
        for members, own in _merge_rigid(xy, found, cfg)[: max(room - len(splits), 0)]:
            out[members] = next_label
            # Points of the object that happen to fit the host's model too (e.g. near their epipolar
            # lines) follow when they lie next to a member, move like it and fit the group better.
            still = out[host] == c
            rest, rest_res = host[still], res[still]  # the host's residuals, computed above
            dist, near = _kdtree(xy[members, 0]).query(xy[rest, 0], distance_upper_bound=radius)
            ok = np.isfinite(dist)
            rest, rest_res, near = rest[ok], rest_res[ok], members[near[ok]]
            own_res = own(xy[rest])
            joins = (
                _alike(xy[rest] - xy[rest, :1], xy[near] - xy[near, :1], cfg)
                & (own_res <= cfg.residual_px)
                & (own_res < rest_res)
            )
            out[rest[joins]] = next_label
            splits.append(_Split(int(c), next_label, np.flatnonzero(out == next_label), own, host_model))
            next_label += 1
    return out, splits


def _follow(
    xy: npt.NDArray[np.float64],
    lab: npt.NDArray[np.int64],
    sampled: npt.NDArray[np.bool_],
    sample_xy: npt.NDArray[np.float64],
    splits: list[_Split],
    radius: float,
    cfg: RigidCheckConfig,
) -> npt.NDArray[np.int64]:
    """Labels of the points outside the sample (`sampled` False): a point of a host is a candidate for a
    group split off it when the host's model does not explain it (step 2) or the group's model explains
    it better (step 4); candidates join the group by region growing from its sampled members, each
    round taking those within `radius` (frame 0) of a point that joined in the round before and
    moving like it, as step 2 links neighbours."""
    out = lab.copy()
    for split in splits:
        rows = np.flatnonzero((out == split.host) & ~sampled)
        kept = []
        for lo in range(0, rows.size, _CHUNK):
            block = rows[lo : lo + _CHUNK]
            host_res, own_res = split.host_model(xy[block]), split.own(xy[block])
            fits = (host_res > cfg.residual_px) | ((own_res <= cfg.residual_px) & (own_res < host_res))
            kept.append(block[fits])
        candidates = np.concatenate(kept) if kept else rows
        frontier = sample_xy[split.members]
        while candidates.size and frontier.size:
            tree = _kdtree(frontier[:, 0])
            joined = np.zeros(candidates.size, dtype=bool)
            for lo in range(0, candidates.size, _CHUNK):
                block = candidates[lo : lo + _CHUNK]
                dist, near = tree.query(xy[block, 0], distance_upper_bound=radius)
                ok = np.flatnonzero(np.isfinite(dist))
                pts, member = xy[block[ok]], frontier[near[ok]]
                joined[lo + ok[_alike(pts - pts[:, :1], member - member[:, :1], cfg)]] = True
            out[candidates[joined]] = split.label
            frontier = xy[candidates[joined]]
            candidates = candidates[~joined]
    return out


def _min_group(n: int, cfg: RigidCheckConfig) -> int:
    """The smallest group split off n points checked: cfg.min_tracks, or cfg.min_share of them if more."""
    return max(cfg.min_tracks, int(np.ceil(cfg.min_share * n)))


def _together(
    union: npt.NDArray[np.float64],
    disp: npt.NDArray[np.float64],
    tree_a: cKDTree,
    tree_b: cKDTree,
    radius: float,
    cfg: RigidCheckConfig,
) -> bool:
    """Do two pieces of a cluster stay one motion (step 5 of the module docstring)?

    Args:
        union: (N, F, 2) positions of both pieces' points.
        disp: (2, F, 2) each piece's median displacement from frame 0.
        tree_a, tree_b: KD-trees of each piece's frame-0 positions.
        radius: the neighbourhood, pixels.
        cfg: thresholds.
    """
    if _alike(disp[:1], disp[1:], cfg)[0]:
        return True
    share = 0.8 if cfg.merge_consistency is None else cfg.merge_consistency
    plane = fit_rigid_motion(union, replace(cfg, homography_ratio=0.0))
    if plane is not None and float(np.mean(plane(union) <= cfg.residual_px)) >= share:
        return True
    if tree_a.sparse_distance_matrix(tree_b, radius).nnz == 0:
        return False
    a, b = disp[0, -1], disp[1, -1]
    cos = float(a @ b) / max(float(np.linalg.norm(a) * np.linalg.norm(b)), 1e-9)
    if cos < np.cos(np.radians(cfg.max_angle_deg)):
        return False
    rigid = fit_rigid_motion(union, cfg)
    return rigid is not None and float(np.mean(rigid(union) <= cfg.residual_px)) >= share


def _separate(
    xy: npt.NDArray[np.float64], lab: npt.NDArray[np.int64], radius: float, cfg: RigidCheckConfig, room: int
) -> int:
    """Step 5 of the module docstring on (N, F, 2) positions, in place on `lab`: the number of pieces
    split off (at most `room`)."""
    values, counts = np.unique(lab, return_counts=True)
    background = values[np.argmax(counts)]
    next_label = int(lab.max()) + 1
    found = 0
    min_group = _min_group(len(xy), cfg)
    for c in values[values != background]:
        rows = np.flatnonzero(lab == c)
        if rows.size < 2 * min_group:
            continue
        pieces = _coherent_groups(xy[rows], radius, cfg)
        sizes = np.bincount(pieces)
        big = np.flatnonzero(sizes >= min_group)
        if big.size < 2:
            continue
        disp = np.stack([np.median(xy[rows[pieces == g]] - xy[rows[pieces == g], :1], axis=0) for g in big])
        trees = [_kdtree(xy[rows[pieces == g], 0]) for g in big]
        pairs = [
            (i, j)
            for i, j in itertools.combinations(range(big.size), 2)
            if _together(xy[rows[np.isin(pieces, big[[i, j]])]], disp[[i, j]], trees[i], trees[j], radius, cfg)
        ]
        links = np.array(pairs, dtype=np.int64).reshape(-1, 2)
        sets = _connected(big.size, links[:, 0], links[:, 1])
        for k in np.argsort(-np.bincount(sets, weights=sizes[big]), kind="stable")[1:]:  # the largest keeps c
            members = rows[np.isin(pieces, big[sets == k])]
            if found >= room:
                break
            own = fit_rigid_motion(xy[members], cfg)
            if own is None or np.mean(own(xy[members]) <= cfg.residual_px) < cfg.consistency:
                continue
            lab[members] = next_label
            next_label += 1
            found += 1
    return found


def split_by_rigid_motion(
    points: npt.ArrayLike,
    labels: npt.ArrayLike,
    size_hw: tuple[int, int],
    cfg: RigidCheckConfig = RigidCheckConfig(),
    seed: int = 0,
    max_k: int | None = None,
) -> tuple[npt.NDArray[np.int64], int]:
    """Splits off the coherent groups that their cluster's rigid motion does not explain.

    With more than MAX_CHECKED_POINTS points (3000) the check runs on a random sample of that many
    (seeded by `seed`) and every other point of a host joins a group split off it when it fits the
    group's model better than the host's (or the host's not at all) and is linked to a sampled member
    through points that do, each within the neighbourhood of the next and moving like it (region
    growing); memory and time are then linear in N. A group needs max(cfg.min_tracks, cfg.min_share *
    MAX_CHECKED_POINTS) sampled points, so the smallest group split off grows with N.

    Args:
        points: (N, 2F) trajectory matrix in pixels (x_0, y_0, x_1, y_1, ...), F >= 2.
        labels: (N,) cluster labels 0..k-1.
        size_hw: (H, W) of the frames, pixels (the neighbourhood is a fraction of its diagonal).
        cfg: thresholds, see RigidCheckConfig.
        seed: random state of the sample (large N only).
        max_k: no more groups are split off once the labels number this many (None = no limit).

    Returns:
        (labels, number of groups split off): labels ordered by decreasing cluster size as
        `cluster_auto_k` orders them; unchanged (but relabelled by size) when nothing was split.
    """
    data = np.asarray(points, dtype=np.float64)
    lab = np.asarray(labels, dtype=np.int64)
    n = data.shape[0]
    xy = data.reshape(n, data.shape[1] // 2, 2)
    if n == 0:
        return lab.copy(), 0
    radius = cfg.neighbour_frac * float(np.hypot(*size_hw))
    room = n if max_k is None else max(max_k - np.unique(lab).size, 0)
    if n <= MAX_CHECKED_POINTS:
        out, splits = _split(xy, lab, radius, cfg, room)
        separated = _separate(xy, out, radius, cfg, room - len(splits)) if cfg.separate else 0
        return relabel_by_size(out), len(splits) + separated
    idx = np.sort(np.random.default_rng(seed).choice(n, size=MAX_CHECKED_POINTS, replace=False))
    sample_xy = xy[idx]
    sample_out, splits = _split(sample_xy, lab[idx], radius, cfg, room)
    sampled = np.zeros(n, dtype=bool)
    sampled[idx] = True
    out = _follow(xy, lab, sampled, sample_xy, splits, radius, cfg)
    separated = 0
    if cfg.separate:
        # Step 5 on the sample; the other points of a cluster it cut take their nearest sampled member's label.
        before = sample_out.copy()
        separated = _separate(sample_xy, sample_out, radius, cfg, room - len(splits))
        for c in np.unique(before[sample_out != before]):
            members = np.flatnonzero(before == c)
            rows = np.flatnonzero((out == c) & ~sampled)
            if rows.size:
                _, near = _kdtree(sample_xy[members, 0]).query(xy[rows, 0])
                out[rows] = sample_out[members[near]]
    out[idx] = sample_out
    return relabel_by_size(out), len(splits) + separated


def label_by_rigid_motion(
    points: npt.ArrayLike,
    labelled: npt.ArrayLike,
    labels: npt.ArrayLike,
    cfg: RigidCheckConfig = RigidCheckConfig(),
    neighbours: int = 5,
) -> npt.NDArray[np.int64]:
    """Labels for more trajectories from labelled ones, by motion: each takes, among the labels of its
    `neighbours` nearest labelled trajectories (in frame 0), the one whose cluster's rigid model
    (`fit_rigid_motion` on that cluster) fits it best, if within cfg.residual_px; -1 when none does
    (it moves like none of its neighbours: another object, or a tracking error).

    Args:
        points: (M, 2F) trajectories to label, pixels.
        labelled: (N, 2F) labelled trajectories over the same frames.
        labels: (N,) their labels, >= 0. A cluster of fewer than cfg.min_tracks trajectories gets no
            model and labels nothing.
        cfg: residual_px and the model choice.
        neighbours: labelled trajectories consulted per trajectory.

    Returns:
        (M,) int64 labels, -1 = none.
    """
    new = np.asarray(points, dtype=np.float64)
    old = np.asarray(labelled, dtype=np.float64)
    lab = np.asarray(labels, dtype=np.int64)
    out = np.full(len(new), -1, dtype=np.int64)
    if len(new) == 0 or len(old) == 0:
        return out
    new_xy = new.reshape(len(new), -1, 2)
    old_xy = old.reshape(len(old), -1, 2)
    values = np.unique(lab)
    residual = np.full((len(new), values.size), np.inf)
    for j, value in enumerate(values):
        members = old_xy[lab == value]
        if len(members) >= cfg.min_tracks:
            model = fit_rigid_motion(members, cfg)
            if model is not None:
                residual[:, j] = model(new_xy)
    _, near = _kdtree(old_xy[:, 0]).query(new_xy[:, 0], k=min(neighbours, len(old)))
    near = np.asarray(near).reshape(len(new), -1)
    columns = np.searchsorted(values, lab[near])  # (M, neighbours) candidate label columns
    candidate = np.take_along_axis(residual, columns, axis=1)
    best = candidate.argmin(axis=1)
    fits = candidate[np.arange(len(new)), best] <= cfg.residual_px
    out[fits] = values[columns[np.arange(len(new)), best]][fits]
    return out
