"""The grouping of a window's tracks into motions, in one place: `group_window` is the one sequence that clips,
tracks and whole-video windows go through, and the steps it is made of.

The sequence, by method:
- "subspacenet" and "joint": embedding -> K-means with automatic K (`cluster_auto_k`) -> the rigid-motion check
  (`check_rigid`; with "joint" the geometric model selection of `check_joint` / `search_k`) -> the world's motion
  to label 0 (`world_to_zero`) -> the moving tracks clustered again (`split_movers`).
- "geometric": rigid models fitted one after another (`group_geometric`) -> the world to label 0.

A new grouping step is added here, once. The steps read a run's settings through `GroupingSettings` (a
`PipelineConfig` is one), so that this module needs nothing from the pipeline above it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Protocol

import numpy as np
import numpy.typing as npt

from mosegpipe.configs.grouping import ClusterConfig, GeometricConfig, JointConfig, RigidCheckConfig, WorldConfig
from mosegpipe.embed.numpy_net import Embedder
from mosegpipe.group.cluster import cluster_auto_k, kmeans, relabel_by_size
from mosegpipe.group.geometric import group_geometric
from mosegpipe.group.joint import choose_partition, one_rigid_motion, select_models, window_points
from mosegpipe.group.rigid import split_by_rigid_motion
from mosegpipe.group.world import static_share, world_cluster, world_first, world_scores
from mosegpipe.points.flow import FrameMotion
from mosegpipe.types import Clustering, Trajectories


class GroupingSettings(Protocol):
    """The settings the grouping reads (a `mosegpipe.pipeline.PipelineConfig` has them all)."""

    @property
    def method(self) -> str: ...
    @property
    def k(self) -> int | None: ...
    @property
    def cluster(self) -> ClusterConfig: ...
    @property
    def rigid(self) -> RigidCheckConfig: ...
    @property
    def geometric(self) -> GeometricConfig: ...
    @property
    def joint(self) -> JointConfig: ...
    @property
    def world(self) -> WorldConfig: ...


@dataclass(frozen=True)
class Grouping:
    """A window's motions.

    Attributes:
        clustering: labels (N,) with the world's motion 0 (-1: tracks method "joint" leaves out), k, scores, note.
        embeddings: (N, E) float32 SubspaceNet embeddings; None with method "geometric" (no embedding).
        sweep_k: the K automatic K chose on the embedding, before the checks (method "geometric": its K).
    """

    clustering: Clustering
    embeddings: npt.NDArray[np.float32] | None
    sweep_k: int


def group_window(
    traj: Trajectories,
    size_hw: tuple[int, int],
    cfg: GroupingSettings,
    model: Embedder,
    *,
    k: int | None = None,
    sweep: ClusterConfig | None = None,
    prefer_k: int | None = None,
    was_world: npt.NDArray[np.bool_] | None = None,
    known: npt.NDArray[np.bool_] | None = None,
    motion: FrameMotion | None = None,
    timings: dict[str, float] | None = None,
) -> Grouping:
    """The motions of one window's trajectories by cfg.method (the module's sequence).

    Args:
        traj: the trajectories (N, 2F) float32, pixels.
        size_hw: (H, W) of the frames, pixels.
        cfg: method, k, cluster, rigid, geometric, joint and world settings.
        model: the embedding (not used by "geometric").
        k: the number of motions to find (None: automatic K; the steps after K-means read cfg.k).
        sweep: automatic K's settings (None: cfg.cluster); whole videos narrow K around the window before.
        prefer_k: whole videos: the K the window before chose (kept on a tie).
        was_world, known: whole videos: (N,) the tracks that were the world / had a label in the window before.
        motion: the frames' dense flow evidence, if computed (the world's camera evidence).
        timings: gets "embed" and "cluster" seconds, when given.
    """
    t0 = time.perf_counter()
    if cfg.method == "geometric":  # rigid models fitted one after another: no embedding, no check
        clustering = group_geometric(traj.data, size_hw, cfg.geometric, k=k)
        clustering = world_to_zero(clustering, traj.data, size_hw, cfg, was_world, known, motion)
        if timings is not None:
            timings["cluster"] = time.perf_counter() - t0
        return Grouping(clustering, None, clustering.k)
    emb = model.embed(traj)
    t1 = time.perf_counter()
    clustering = cluster_auto_k(emb, sweep or cfg.cluster, k=k, points=traj.data, prefer_k=prefer_k)
    sweep_k = clustering.k
    clustering = check_rigid(clustering, traj.data, size_hw, cfg, emb)
    clustering = world_to_zero(clustering, traj.data, size_hw, cfg, was_world, known, motion)
    clustering = split_movers(clustering, emb, traj.data, cfg)
    if timings is not None:
        timings["embed"], timings["cluster"] = t1 - t0, time.perf_counter() - t1
    return Grouping(clustering, emb, sweep_k)


def check_rigid(
    clustering: Clustering,
    points: npt.NDArray[np.float32],
    size_hw: tuple[int, int],
    cfg: GroupingSettings,
    emb: npt.NDArray[np.floating] | None = None,
) -> Clustering:
    """`clustering` after the rigid-motion check (unchanged when K was given or the check is off); it
    splits off no more groups than cfg.cluster.k_max allows.

    Its note then says how many groups the check split off, after automatic K's own note. With method
    "joint", the model selection of `check_joint` follows the check (cfg.joint.rigid_first) or takes its place;
    with cfg.joint.k_search and the embeddings `emb` (N, E), K-means with the K around automatic K goes through
    the same steps, and the grouping of the lowest summed GRIC is kept (`search_k`).
    """
    if cfg.method == "joint":
        if cfg.k is None and cfg.joint.k_search and emb is not None:
            return search_k(clustering, emb, points, size_hw, cfg)
        if cfg.joint.rigid_first:
            clustering = rigid_split(clustering, points, size_hw, cfg)
        return check_joint(clustering, points, cfg)
    return rigid_split(clustering, points, size_hw, cfg)


def search_k(
    clustering: Clustering,
    emb: npt.NDArray[np.floating],
    points: npt.NDArray[np.float32],
    size_hw: tuple[int, int],
    cfg: GroupingSettings,
) -> Clustering:
    """Method "joint" with K chosen by geometric evidence.

    K-means on the embeddings `emb` (N, E) with automatic K (`clustering`, whose own labels stand for it) and with
    each K up to cfg.joint.k_search more (at most cfg.cluster.k_max and N), each grouping through the rigid-motion
    check (cfg.joint.rigid_first) and the model selection's split and merge; the one of the lowest summed GRIC is
    kept (`joint.choose_partition`: a group must save cfg.joint.group_cost per frame pair). The embedding
    underestimates K where movers look alike to it (docs/results/41-diagnosis.md); the models see them apart.
    K is never lowered: fewer groups than automatic K's gave cars to the world's fundamental matrix on kt3d-video
    (error 3.4 -> 8.3 %, docs/results/41-geometry.md). The note says which K was kept when it is not automatic K's.
    """
    n = clustering.labels.size
    hi = min(max(cfg.cluster.k_max, clustering.k), n, clustering.k + cfg.joint.k_search)
    ks = list(range(clustering.k, hi + 1))
    tried = [clustering]
    for k in ks[1:]:
        labels, _ = kmeans(
            emb, k, seed=cfg.cluster.seed, n_init=cfg.cluster.n_init, num_threads=cfg.cluster.num_threads
        )
        tried.append(Clustering(labels=labels, k=int(labels.max()) + 1, method="fixed"))
    if cfg.joint.rigid_first:
        tried = [rigid_split(c, points, size_hw, cfg) for c in tried]
    k_max = max(cfg.cluster.k_max, clustering.k)
    best, labels, what, _ = choose_partition(points, [c.labels for c in tried], cfg.joint, k_max=k_max)
    k = int(labels.max()) + 1 if (labels >= 0).any() else 0
    if k == 0:  # every track left out: keep the embedding's groups
        return clustering
    if best:
        what = f"{what}; K by GRIC: K-means with K = {ks[best]} (automatic K {clustering.k})"
    # the first candidate grew out of `clustering`, its note included; the others start with none
    note = tried[0].note if best == 0 else "; ".join(x for x in (clustering.note, tried[best].note) if x)
    note = f"{note}; {what}" if note and what else note or what
    return replace(clustering, labels=labels, k=k, note=note)


def rigid_split(
    clustering: Clustering, points: npt.NDArray[np.float32], size_hw: tuple[int, int], cfg: GroupingSettings
) -> Clustering:
    if cfg.k is not None or not cfg.rigid.enabled:
        return clustering
    labels, split = split_by_rigid_motion(points, clustering.labels, size_hw, cfg.rigid, max_k=cfg.cluster.k_max)
    if not split:
        return clustering
    what = f"the rigid-motion check split off {split} group{'s' if split > 1 else ''} (K = {clustering.k} -> {clustering.k + split})"
    note = f"{clustering.note}; {what}" if clustering.note else what
    return replace(clustering, labels=labels, k=clustering.k + split, note=note)


def check_joint(clustering: Clustering, points: npt.NDArray[np.float32], cfg: GroupingSettings) -> Clustering:
    """`clustering` after the model selection of method "joint" (`mosegpipe.group.joint`): groups split
    and merged, tracks moved to the group whose model explains them (or, with cfg.joint.leave_out, labelled
    -1 when none does); unchanged when K was given. Splits stop at cfg.cluster.k_max, and the note says
    what changed after automatic K's own note."""
    if cfg.k is not None:
        return clustering
    labels, what = select_models(points, clustering.labels, cfg.joint, k_max=max(cfg.cluster.k_max, clustering.k))
    k = int(labels.max()) + 1 if (labels >= 0).any() else 0
    if k == 0:  # every track left out: keep the embedding's groups
        return clustering
    note = f"{clustering.note}; {what}" if clustering.note and what else clustering.note or what
    return replace(clustering, labels=labels, k=k, note=note)


def world_to_zero(
    clustering: Clustering,
    points: npt.NDArray[np.float32],
    size_hw: tuple[int, int],
    cfg: GroupingSettings,
    was_world: npt.NDArray[np.bool_] | None = None,
    known: npt.NDArray[np.bool_] | None = None,
    motion: FrameMotion | None = None,
) -> Clustering:
    """`clustering` renumbered so that the world's motion is 0 (`mosegpipe.group.world`); the others keep their order.

    Args:
        clustering: labels (N,) in 0..k-1.
        points: (N, 2F) float32 trajectories, pixels (x0, y0, x1, y1, ...).
        size_hw: (H, W) of the frames.
        cfg: cfg.world.
        was_world, known: whole videos: (N,) the tracks that were the world / had a label in the window before.
        motion: the dense flow's evidence of the window's frames (its camera residual), if computed.
    """
    xy = np.asarray(points, np.float32).reshape(len(clustering.labels), -1, 2)
    if clustering.k <= 1 or not cfg.world.enabled:
        return clustering
    static = None if motion is None else static_share(xy, motion.residual, motion.scale, cfg.world.static_px)
    scores = world_scores(xy, clustering.labels, clustering.k, size_hw, was_world, known, cfg.world, static)
    world = world_cluster(scores, cfg.world)
    if world == 0:
        return clustering
    return replace(clustering, labels=world_first(clustering.labels, world))


def split_movers(
    clustering: Clustering, emb: npt.NDArray[np.floating], points: npt.NDArray[np.float32], cfg: GroupingSettings
) -> Clustering:
    """`clustering` (the world 0) with its moving tracks clustered again on their own embeddings.

    The embedding separates the world from what moves better than one mover from another: automatic K over
    all tracks often puts every mover in one group (docs/results/41-diagnosis.md). The tracks of the groups
    other than 0 are clustered again, K from 1 to cfg.cluster.movers_k_max by the silhouette (K = 1 unless the
    best exceeds cfg.cluster.movers_silhouette); two of the new groups that one rigid motion explains
    (`joint.one_rigid_motion`, cfg.joint's thresholds) are one again. They replace the moving
    groups when there are more of them, each of at least cfg.cluster.movers_min_group tracks. Unchanged when K
    was given, with cfg.cluster.movers_k_max 1, or with fewer than twice movers_min_group moving tracks. The world
    stays 0; the new groups follow it, by decreasing size.
    """
    movers = np.flatnonzero(clustering.labels > 0)
    k_max, least = cfg.cluster.movers_k_max, cfg.cluster.movers_min_group
    if cfg.k is not None or k_max <= 1 or movers.size < 2 * least or k_max <= clustering.k - 1:
        return clustering
    sweep = replace(
        cfg.cluster,
        k_min=1,
        k_max=k_max,
        min_silhouette=cfg.cluster.movers_silhouette,
        one_motion_spread=1.0,  # K = 1 stays a candidate however wide the movers spread
        static_residual_px=None,
    )
    sub = cluster_auto_k(np.asarray(emb)[movers], sweep).labels
    xy = window_points(np.asarray(points)[movers], cfg.joint)
    for a in range(int(sub.max()) + 1):
        for b in range(a + 1, int(sub.max()) + 1):
            rows_a, rows_b = np.flatnonzero(sub == a), np.flatnonzero(sub == b)
            if not (rows_a.size and rows_b.size):
                continue
            if one_rigid_motion(xy, rows_a, rows_b, cfg.joint, planar=True, share=cfg.joint.rigid_share):
                sub[rows_b] = a
    sub = relabel_by_size(sub)
    k = int(sub.max()) + 1
    if k <= clustering.k - 1 or np.bincount(sub).min() < least:
        return clustering
    labels = clustering.labels.copy()
    labels[movers] = sub + 1
    what = f"the moving tracks clustered again: {clustering.k - 1} -> {k} moving groups"
    note = f"{clustering.note}; {what}" if clustering.note else what
    return replace(clustering, labels=labels, k=k + 1, note=note)
