"""Settings of the stages that group tracks into motions: automatic K, the rigid-motion check, the
geometric and joint model fits, the world's motion, and whole videos' labels across windows.

Light on purpose (standard library and mosegpipe.settings / types only): the CLI takes its defaults from
these classes without importing OpenCV or SciPy. Re-exported by the modules that use them
(mosegpipe.group.cluster, rigid, grouping, geometry_select, world).
"""

from __future__ import annotations

from dataclasses import dataclass

from mosegpipe.settings import MAX_K, MAX_THREADS, Check, SettingError, check_fields
from mosegpipe.types import K_METHODS, KMethodName


@dataclass(frozen=True)
class ClusterConfig:
    """How :func:`cluster_auto_k` chooses K, one line each; how the values were chosen is in docs/HISTORY.md
    ("Where the defaults come from", "ClusterConfig"), how often K is right in docs/RESULTS.md ("The paper's benchmarks"), the movers' settings in docs/results/41-diagnosis.md.

    Attributes:
        method: the automatic-K rule (types.KMethodName): the silhouette, or the elbow of the K-means residual.
        k_min: smallest K considered; 1 allows the answer "a single motion".
        k_max: largest K considered (capped at N - 1 for N points).
        n_init: K-means restarts per K; the best residual of the restarts is kept.
        seed: random seed of K-means (same seed, same labels).
        num_threads: BLAS / OpenMP threads while clustering; 1 is fastest for these sizes.
        min_elbow: "residual" answers K = 1 unless some K >= 2 scores above this (scores lie in [-1, 1]).
        min_silhouette: "silhouette" answers K = 1 unless the best silhouette exceeds this.
        min_spread: below this mean squared distance to the centroid (share of the mean squared norm): K = 1 outright.
        one_motion_spread: K = 1 is a candidate only at most this mean squared distance to the centroid (same share).
        static_residual_px: K = 1 without clustering when one affine motion explains the tracks this well (None: never).
        ambiguity_margin: the K choice is reported as ambiguous when the runner-up scores within this of the winner.
        movers_k_max: the moving tracks clustered again on their own into up to this many groups (1 = off).
        movers_silhouette: ... split only when their best silhouette exceeds this.
        movers_min_group: ... and into groups of at least this many tracks each.
    """

    method: KMethodName = "silhouette"
    k_min: int = 1  # single-motion clips exist (static scene, camera motion only)
    k_max: int = 8  # benchmarks have at most 5 motions; 8 leaves headroom for real videos
    n_init: int = 3  # 10 restarts cost 3x the time; see docs/RESULTS.md for the accuracy check
    seed: int = 0  # fixed so that repeated runs give identical labels
    num_threads: int = 1  # docs/HISTORY.md, ClusterConfig: 2 threads were 10-400x slower
    min_elbow: float = 0.2
    min_silhouette: float = 0.4
    min_spread: float = 1e-4  # RMS distance 0.01 on the unit sphere: identical up to noise
    one_motion_spread: float = 0.1
    static_residual_px: float | None = 2.0
    ambiguity_margin: float = 0.01
    movers_k_max: int = 1
    movers_silhouette: float = 0.4
    movers_min_group: int = 5

    def __post_init__(self) -> None:
        check_fields(self, _CLUSTER_CHECKS)
        if self.k_max < self.k_min:
            raise SettingError("k_max", f"{self.k_max} must be at least k_min ({self.k_min})")


_CLUSTER_CHECKS: tuple[Check, ...] = (
    ("method", lambda v: v in K_METHODS, f"be one of {', '.join(K_METHODS)}"),
    ("k_min", lambda v: v >= 1, "be >= 1"),
    ("k_max", lambda v: v <= MAX_K, f"be at most {MAX_K} (each K is a K-means fit)"),
    ("n_init", lambda v: v >= 1, "be >= 1"),
    ("num_threads", lambda v: 1 <= v <= MAX_THREADS, f"lie in 1..{MAX_THREADS}"),
    ("min_elbow", lambda v: -1 <= v <= 1, "lie in [-1, 1]"),
    ("min_silhouette", lambda v: -1 <= v <= 1, "lie in [-1, 1]"),
    ("min_spread", lambda v: 0 <= v < 1, "lie in [0, 1)"),
    ("one_motion_spread", lambda v: 0 <= v <= 1, "lie in [0, 1]"),
    ("static_residual_px", lambda v: v >= 0, "be >= 0 (or None: never)"),
    ("ambiguity_margin", lambda v: v >= 0, "be >= 0"),
    ("movers_k_max", lambda v: 1 <= v <= MAX_K, f"lie in 1..{MAX_K}"),
    ("movers_silhouette", lambda v: -1 <= v <= 1, "lie in [-1, 1]"),
    ("movers_min_group", lambda v: v >= 1, "be >= 1"),
)
"""ClusterConfig's checks: (field, test, what it must be)."""


@dataclass(frozen=True)
class RigidCheckConfig:
    """Settings of `split_by_rigid_motion`, one line each (the steps: the module docstring); how they were chosen
    is in docs/HISTORY.md ("The rigid-motion check: small objects split off after automatic K", "Step 5"), what the
    check gives in docs/RESULTS.md ("The rigid-motion check").

    Attributes:
        enabled: run the check (clips, whole videos and tracks with automatic K).
        residual_px: a point further than this from its cluster's rigid model (either frame pair) is a candidate.
        min_tracks: the smallest group split off ...
        min_share: ... and at least this share of the points checked (a dense grid's sliver along a border is not one).
        min_host: a split must leave at least this many points in the cluster.
        neighbour_frac: candidates within this fraction of the image diagonal of each other may form one group.
        motion_px: two candidates move alike when their displacements differ by at most motion_px + motion_frac * ...
        motion_frac: ... the larger displacement, in every frame.
        consistency: a group is split off only when one rigid model of its own explains this share of it.
        homography_ratio: the homography is the model when it keeps this share of the fundamental matrix's inliers.
        merge_consistency: two groups split off one cluster merge when one rigid model explains this share (None: never).
        separate: step 5: pieces of an object's cluster that move apart become motions of their own.
        max_angle_deg: step 5: touching pieces whose displacements differ in direction by more are not one object.
    """

    enabled: bool = True
    residual_px: float = 1.5
    min_tracks: int = 10
    min_share: float = 0.01
    min_host: int = 30
    neighbour_frac: float = 0.05
    motion_px: float = 2.0
    motion_frac: float = 0.15
    consistency: float = 0.5
    homography_ratio: float = 0.95
    merge_consistency: float | None = 0.8
    separate: bool = True
    max_angle_deg: float = 30.0

    def __post_init__(self) -> None:
        check_fields(self, _RIGID_CHECK_CHECKS)


_RIGID_CHECK_CHECKS: tuple[Check, ...] = (
    *((name, lambda v: v > 0, "be > 0") for name in ("residual_px", "neighbour_frac", "motion_px")),
    ("merge_consistency", lambda v: 0 <= v <= 1, "lie in [0, 1] (or None: never merged)"),
    *(
        (name, lambda v: 0 <= v <= 1, "lie in [0, 1]")
        for name in ("motion_frac", "consistency", "homography_ratio", "min_share")
    ),
    ("max_angle_deg", lambda v: 0 <= v <= 180, "lie in [0, 180]"),
    *((name, lambda v: v >= 1, "be >= 1") for name in ("min_tracks", "min_host")),
)
"""RigidCheckConfig's checks: (field, test, what it must be)."""


@dataclass(frozen=True)
class GeometricConfig:
    """Settings of `group_geometric` (`--method geometric`), one line each; measured in docs/RESULTS.md
    ("Geometric grouping alone"), chosen as docs/HISTORY.md ("Geometric grouping alone") tells.

    Attributes:
        residual_px: a track within this many pixels of a model in every frame pair is its inlier (RANSAC's too).
        min_group: with automatic K, the smallest group, in tracks ...
        min_share: ... and as a share of all tracks, in [0, 1); the larger applies.
        k_max: with automatic K, the most groups fitted.
        homography_ratio: the homography is the model when it keeps this share of the fundamental matrix's inliers.
        planar_share: tracks only the fundamental matrix explains are a planar motion when one homography explains this share.
        ransac_iters: RANSAC iterations per model.
        confidence: RANSAC's confidence, in (0, 1).
        seed: OpenCV's random seed, set before each grouping (same seed, same labels).
    """

    residual_px: float = 1.5  # KLT tracks of textured points: about 0.5 px noise; rigid.py's threshold
    min_group: int = 10  # fewer tracks barely constrain a model (8 for a fundamental matrix)
    min_share: float = 0.02  # on 1000 tracks, a group of 20: a small object, not a patch of tracker errors
    k_max: int = 8  # as ClusterConfig.k_max: benchmarks have at most 5 motions
    homography_ratio: float = 0.9  # parallax must add a tenth more inliers before the fundamental matrix is used
    planar_share: float = 0.8  # one plane explaining 4/5 of the extra inliers is an object, not depth
    ransac_iters: int = 2000  # USAC_MAGSAC converges in far fewer on these inlier shares
    confidence: float = 0.999  # OpenCV's default for findFundamentalMat
    seed: int = 0  # fixed so that repeated runs give identical labels

    def __post_init__(self) -> None:
        check_fields(self, _GEOMETRIC_CHECKS)


_GEOMETRIC_CHECKS: tuple[Check, ...] = (
    ("residual_px", lambda v: v > 0, "be > 0"),
    ("min_group", lambda v: v >= 1, "be >= 1"),
    ("min_share", lambda v: 0 <= v < 1, "lie in [0, 1)"),
    ("k_max", lambda v: v >= 1, "be >= 1"),
    *((name, lambda v: 0 < v <= 1, "lie in (0, 1]") for name in ("homography_ratio", "planar_share")),
    ("ransac_iters", lambda v: v >= 1, "be >= 1"),
    ("confidence", lambda v: 0 < v < 1, "lie in (0, 1)"),
)
"""GeometricConfig's checks: (field, test, what it must be)."""


@dataclass(frozen=True)
class JointConfig:
    """Settings of `select_models` (`--method joint`), one line each (the steps: the module docstring); measured
    in docs/RESULTS.md ("Several movers: composites in real textures") and docs/results/41-geometry.md.

    Attributes:
        sigma_px: the noise of a track's position, pixels (GRIC's sigma).
        residual_px: a track within this many pixels of a model is its inlier (RANSAC's distance too).
        outlier_px: a track further than this from its group's model in most frame pairs is not explained (None: off).
        rigid_share: a group is one rigid motion when its model explains this share of it.
        planar_share: a split's second part must be one motion: a homography explains this share of it.
        merge_share: two groups merge only when the union's model explains this share of each.
        merge_most_pairs: ... a track is explained when within residual_px in most frame pairs, not in every one.
        reassign: a track its group's model does not explain may go to a group whose model does.
        leave_out: a track that no model explains is left out (-1); else it keeps its group.
        merge_3d: two groups that both need a fundamental matrix may merge under one.
        split_largest: the largest group (usually the world) may be split too.
        rigid_first: the rigid-motion check (mosegpipe.group.rigid) splits the groups first.
        min_group: the smallest group a split makes, in tracks ...
        min_share: ... and as a share of all tracks; the larger applies.
        max_pairs: at most this many frame pairs (0, t), spread evenly over the window, are fitted.
        ransac_iters: RANSAC iterations per model.
        seed: OpenCV's random seed, set before each selection (same seed, same labels).
        k_search: K-means also with up to this many more groups than automatic K; the lowest summed GRIC wins (0 = off).
        group_cost: what a group costs in that sum, per frame pair, beyond its model's GRIC.
        new_rigid_tracks: whole videos: a small cluster of this many tracks that geometry supports is labelled (None = off).
    """

    sigma_px: float = 1.0  # KLT tracks: about 0.5 px noise, plus drift over the window; world.parallax_sigma_px
    residual_px: float = 1.5  # as the rigid-motion check and the geometric fit
    outlier_px: float | None = 4.0  # well beyond the noise: a tracker failure or a motion of its own
    rigid_share: float = 0.5
    planar_share: float = 0.8  # as the geometric fit: one plane explaining 4/5 of the rest is an object
    merge_share: float = 0.8  # as the rigid-motion check's merge_consistency
    merge_most_pairs: bool = True  # one slipped frame is a tracking glitch (rendered correct K 50 -> 60 %)
    reassign: bool = True
    leave_out: bool = False  # True: composites J +0.03, kt3d-video +1.5 points of error (left out = wrong)
    merge_3d: bool = False  # KT3D (kt3d-video): cars driving with the camera fit the world's matrix
    split_largest: bool = False
    rigid_first: bool = True
    min_group: int = 10  # as the geometric fit: fewer barely constrain a model
    min_share: float = 0.02
    max_pairs: int = 8  # a 20-frame window: every third frame or so; enough to see a motion change
    ransac_iters: int = 1000
    seed: int = 0
    k_search: int = 1  # composites 0.252 -> 0.29; 2 gave the same (docs/results/41-geometry.md)
    group_cost: float = 50.0  # 0: kt3d-video 3.40 -> 8.97 %; an 18-track object saves about 4 x 18 per frame pair
    new_rigid_tracks: int | None = 8  # the guard (15 tracks / 5 %) drops most pasted objects (about 18 tracks)

    def __post_init__(self) -> None:
        check_fields(self, _JOINT_CHECKS)


_JOINT_CHECKS: tuple[Check, ...] = (
    *((name, lambda v: v > 0, "be > 0") for name in ("sigma_px", "residual_px")),
    ("outlier_px", lambda v: v > 0, "be > 0 (or None: no track moved or left out)"),
    *((name, lambda v: 0 < v <= 1, "lie in (0, 1]") for name in ("rigid_share", "planar_share", "merge_share")),
    ("min_share", lambda v: 0 <= v < 1, "lie in [0, 1)"),
    *((name, lambda v: v >= 1, "be >= 1") for name in ("min_group", "max_pairs", "ransac_iters")),
    ("k_search", lambda v: 0 <= v <= MAX_K, f"lie in 0..{MAX_K}"),
    ("group_cost", lambda v: v >= 0, "be >= 0"),
    ("new_rigid_tracks", lambda v: v >= 4, "be >= 4 (or None: the size guard alone)"),
)
"""JointConfig's checks: (field, test, what it must be)."""


@dataclass(frozen=True)
class WorldConfig:
    """How the world's motion is told from the others (`world_cluster`), one line each; how it was chosen and
    measured is in docs/HISTORY.md ("The world is label 0 in every frame, and the masks are scored as written");
    the rigid_scene settings (`mosegpipe.masks.scene3d`) in docs/RESULTS.md ("Which pixels move").

    Attributes:
        enabled: tell the world by this evidence (False: the motion with the most tracks, as older summaries did).
        grid: cells per side of the area vote.
        border_weight: extra weight of a border cell (it counts 1 + border_weight).
        continuity: whole videos: weight of the window before's world (0 = each window alone).
        static_px: a track lies where the camera explains the flow when the camera residual there is at most this, pixels.
        static_floor: a motion's area is weighted by this plus its tracks' share on such pixels.
        parallax: a pixel nearest a world track is static when its flow lies on the world's epipolar line.
        parallax_sigma_px: the noise of a track's position, pixels (GRIC and RANSAC thresholds).
        parallax_min_points: fewest world tracks to fit a fundamental matrix from.
        rigid_scene: pixels judged against the camera's 3D motion (F by GRIC; one depth along the epipolar lines is static).
        rigid_scene_px: that fit's inlier distance to the epipolar line (twice for the homography), full-resolution px.
        rigid_scene_world: least share of the world's tracks among the fit's inliers for the frame to be judged.
        rigid_scene_scale: the pixels are judged at this share of the flow's resolution.
        rigid_scene_gate: F over H by "gric" (`twoview.gric`) or "parallax" (rigid_scene_parallax of the tracks F's only).
        rigid_scene_parallax: that share, for the "parallax" gate.
        rigid_scene_region: pixels it may explain: "all", "world" (nearest track the world's), "faster" (flow >= the world's).
        rigid_scene_fit: the tracks F and H are fitted to and gated on: "all" or "world" (those labelled the world).
        rigid_scene_world_depth: least share of the world's own tracks off its homography and on its F (0 = no test).
    """

    enabled: bool = True
    grid: int = 16
    border_weight: float = 1.0
    continuity: float = 2.0
    static_px: float = 1.0
    static_floor: float = 0.1
    parallax: bool = True
    parallax_sigma_px: float = 1.0
    parallax_min_points: int = 30
    rigid_scene: bool = False
    rigid_scene_px: float = 1.0
    rigid_scene_world: float = 0.7
    rigid_scene_scale: float = 0.5
    rigid_scene_gate: str = "gric"
    rigid_scene_parallax: float = 0.05
    rigid_scene_region: str = "world"
    rigid_scene_fit: str = "all"
    rigid_scene_world_depth: float = 0.0

    def __post_init__(self) -> None:
        check_fields(self, _WORLD_CHECKS)


_WORLD_CHECKS: tuple[Check, ...] = (
    ("grid", lambda v: 2 <= v <= 64, "lie in 2..64"),
    ("parallax_min_points", lambda v: v >= 8, "be >= 8"),
    ("parallax_sigma_px", lambda v: v > 0, "be > 0"),
    ("rigid_scene_px", lambda v: v > 0, "be > 0"),
    ("rigid_scene_world", lambda v: 0 <= v <= 1, "lie in [0, 1]"),
    ("rigid_scene_scale", lambda v: 0 < v <= 1, "lie in (0, 1]"),
    ("rigid_scene_gate", lambda v: v in ("gric", "parallax"), "be 'gric' or 'parallax'"),
    ("rigid_scene_parallax", lambda v: 0 <= v <= 1, "lie in [0, 1]"),
    ("rigid_scene_region", lambda v: v in ("all", "world", "faster"), "be 'all', 'world' or 'faster'"),
    ("rigid_scene_world_depth", lambda v: 0 <= v <= 1, "lie in [0, 1]"),
    ("rigid_scene_fit", lambda v: v in ("all", "world"), "be 'all' or 'world'"),
    *((name, lambda v: v >= 0, "be >= 0") for name in ("border_weight", "continuity", "static_px", "static_floor")),
)
"""WorldConfig's checks: (field, test, what it must be)."""


@dataclass(frozen=True)
class LabelConfig:
    """How a whole video's motions keep their labels through the windows they are missing from
    (`mosegpipe.group.labels.match_labels`), one line each: a moving label no cluster continues is remembered
    (its tracks, where it was, how it moved) and taken back by the cluster that holds most of its tracks or, for
    new tracks, lies where its motion carried it; never the world (0). How it was chosen and measured is in
    docs/HISTORY.md ("An object keeps its label: a memory of the labels missing from a window"); the mask carry's in
    docs/RESULTS.md ("One label per object").

    Attributes:
        memory_windows: a label missing from more windows than this is forgotten (0 = no memory, a new label).
        revive_share: a cluster takes a label back when at least this share of its tracks held it lately.
        gate: new tracks take a label back within this many radii of its predicted centre (0 = by tracks only).
        min_radius_px: the smallest radius of a remembered label (twice its tracks' RMS spread), pixels.
        new_tracks: a cluster of new tracks with fewer (and under a quarter of the window's) stays unlabelled.
        new_share: ... and one under this share of the window's tracks too (RESULTS.md "Several movers").
        carry_masks: new tracks take the label under them in the last mask; a lost label returns on its moved mask.
        mask_share: ... where at least this share of a cluster's tracks start on that predicted mask.
        name_unclustered: a moving region no clustered motion reaches, of this share of the frame, takes a label (0 = off).
        merge_back_windows: a label born within this many windows that merges back into a motion beside it is that motion's from its start (0 = off; the output lags as many windows).
    """

    memory_windows: int = 4
    revive_share: float = 0.5
    gate: float = 1.0
    min_radius_px: float = 16.0
    new_tracks: int = 15
    new_share: float = 0.05
    carry_masks: bool = True
    mask_share: float = 0.5
    name_unclustered: float = 0.002  # 820 px of 854x480: a far rider, not the flow's speckle
    merge_back_windows: int = 2

    def __post_init__(self) -> None:
        check_fields(self, _LABEL_CHECKS)


_LABEL_CHECKS: tuple[Check, ...] = (
    ("memory_windows", lambda v: 0 <= v <= 10_000, "lie in 0..10000"),
    ("revive_share", lambda v: 0 < v <= 1, "lie in (0, 1]"),
    ("gate", lambda v: 0 <= v <= 100, "lie in 0..100"),
    ("min_radius_px", lambda v: 0 <= v <= 100_000, "lie in 0..100000"),
    ("new_tracks", lambda v: 0 <= v <= 100_000, "lie in 0..100000"),
    ("new_share", lambda v: 0 <= v <= 1, "lie in [0, 1]"),
    ("mask_share", lambda v: 0 < v <= 1, "lie in (0, 1]"),
    ("name_unclustered", lambda v: 0 <= v <= 1, "lie in [0, 1]"),
    ("merge_back_windows", lambda v: 0 <= v <= 100, "lie in 0..100"),
)
"""LabelConfig's checks: (field, test, what it must be)."""
