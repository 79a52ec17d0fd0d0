"""Settings of the stages that group tracks into motions: automatic K, the rigid-motion check, the
geometric and joint model fits, and the world's motion.

Light on purpose (standard library and mosegpipe.settings / types only): the CLI takes its defaults from
these classes without importing OpenCV or scikit-learn. Re-exported by the modules that use them
(mosegpipe.cluster, rigid, grouping, geometry_select, world).
"""

from __future__ import annotations

from dataclasses import dataclass

from mosegpipe.settings import MAX_K, MAX_THREADS, Check, SettingError, check_fields
from mosegpipe.types import K_METHODS, KMethodName


@dataclass(frozen=True)
class ClusterConfig:
    """How :func:`cluster_auto_k` chooses K.

    Attributes:
        method: "residual" (elbow of the K-means residual) or "silhouette".
        k_min: smallest K considered; 1 allows the answer "a single motion".
        k_max: largest K considered (capped at N - 1 for a clip of N points).
        n_init: K-means restarts per K; the best residual of the restarts is kept.
        seed: random seed of K-means (same seed, same labels).
        num_threads: BLAS/OpenMP threads for scikit-learn; 1 is fastest for these sizes.
        min_elbow: "residual" answers K = 1 unless some K >= 2 scores above this (scores lie in
            [-1, 1]; see cluster_auto_k for measured values).
        min_silhouette: "silhouette" answers K = 1 unless the best silhouette exceeds this.
        one_motion_spread: K = 1 is considered only when the mean squared distance to the centroid
            is at most this fraction of the mean squared norm.
        min_spread: when the mean squared distance to the centroid is below this fraction of the
            mean squared norm, the embeddings are one point up to noise and K = 1 outright.
    """

    # Silhouette chose K better on KT3DMoSeg leave-one-out (correct K 64 % vs 45-59 %, docs/RESULTS.md);
    # "residual" is about twice as fast (no O(N^2) distances).
    method: KMethodName = "silhouette"
    k_min: int = 1  # single-motion clips exist (static scene, camera motion only)
    k_max: int = 8  # benchmarks have at most 5 motions; 8 leaves headroom for real videos
    n_init: int = 3  # 10 restarts cost 3x the time; see docs/RESULTS.md for the accuracy check
    seed: int = 0  # fixed so that repeated runs give identical labels
    num_threads: int = 1  # see the timing note in kmeans(): 2 threads were 10-400x slower
    # Measured on Gaussian blobs on the unit sphere: one blob with N >= 100 scores at most 0.15
    # for E >= 3 (0.19-0.24 for E = 2, up to 0.48 for N = 10; 6 seeds each), while 2-6 groups
    # of 300 points with E = 5 or 16 score 0.4-0.9 at noise 0.05 and 0.2-0.76 at noise 0.15.
    min_elbow: float = 0.2
    # Same blobs: one blob reaches 0.20 (E=5) to 0.38 (E=3) for N >= 100, groups 0.56-0.92 at
    # noise 0.05-0.15 with E = 5; 0.25 (Kaufman & Rousseeuw's "no structure") is too low for E=3.
    min_silhouette: float = 0.4
    min_spread: float = 1e-4  # RMS distance 0.01 on the unit sphere: identical up to noise
    # K = 1 is a candidate only when the mean squared distance to the centroid is at most this
    # fraction of the mean squared norm (RMS distance 0.32 on the unit sphere). Trained embeddings
    # of several motions spread far wider; without this gate the K = 1 threshold score beat the
    # elbow of loosely clustered multi-motion embeddings (zero-shot AdelaideRMF: K = 1 on 14 of 19
    # pairs). Calibrated on synthetic one-body clips: docs/RESULTS.md.
    one_motion_spread: float = 0.1
    # K = 1 without clustering when one affine motion explains the tracks to within this many
    # pixels (99th percentile of the per-track RMS residual, see single_motion_residual_px): the
    # residual flow is tracking noise. Calibrated on rendered synthetic clips (mosegpipe.synth.render,
    # 6 seeds, pixel noise 0/5/10 grey levels, static camera): with nothing moving the percentile
    # was at most 1.62 px, with 1-2 moving objects at least 3.05 px. None = never.
    static_residual_px: float | None = 2.0
    # The K choice is reported as ambiguous (summary.json k_note, a warning) when the runner-up
    # scores within this of the winner (tree.avi, where nothing moves, had 0.003 between K = 3 and 2
    # before the no-motion rule; a clean rendered three-motion clip 0.020). Reporting only: no K changes.
    ambiguity_margin: float = 0.01

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
)
"""ClusterConfig's checks: (field, test, what it must be)."""


@dataclass(frozen=True)
class RigidCheckConfig:
    """Settings of `split_by_rigid_motion` (see the module docstring for what each one does).

    Attributes:
        enabled: run the check (clips, whole videos and tracks with automatic K).
        residual_px: a point further than this from its cluster's rigid model (pixels, in either of
            the two frame pairs) is a candidate for a motion of its own.
        min_tracks: the smallest group split off ...
        min_share: ... and at least this share of the points checked: with a dense grid of points
            (`PipelineConfig.tracker` "flow") a group of 10 is a sliver along an object's border.
        min_host: a split must leave at least this many points in the cluster (so only clusters
            of min_host + min_tracks points or more are checked).
        neighbour_frac: candidates within this fraction of the image diagonal of each other in
            frame 0 may belong to one group.
        motion_px, motion_frac: two candidates move alike when their displacements from frame 0
            differ by at most motion_px + motion_frac * the larger displacement, in every frame.
        consistency: a group is split off only when one rigid model of its own explains at least
            this fraction of it (to residual_px).
        homography_ratio: the homography is the model when it keeps at least this fraction of the
            fundamental matrix's RANSAC inliers.
        merge_consistency: two groups split off one cluster are merged when one rigid model
            explains at least this fraction of their union (None: never merged).
        separate: step 5 of the module docstring (pieces of an object's cluster that move apart).
        max_angle_deg: step 5: touching pieces whose displacements (to the last frame) differ in
            direction by more than this are not one deep object.
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
    """Settings of `group_geometric` (see the module docstring for what each one does).

    Attributes:
        residual_px: a track within this many pixels of a model (in every frame pair) is its inlier;
            also RANSAC's inlier distance.
        min_group: with automatic K, the smallest group, in tracks.
        min_share: with automatic K, the smallest group as a share of all tracks, in [0, 1); the
            larger of the two minimums applies.
        k_max: with automatic K, the most groups fitted.
        homography_ratio: the homography is the group's model when it keeps at least this fraction
            of the fundamental matrix's inliers, in (0, 1].
        planar_share: the tracks that only the fundamental matrix explains are one planar motion of
            their own (and the homography stays the model) when one homography explains at least
            this share of them, in (0, 1].
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
    """Settings of `select_models` (method "joint"; see the module docstring for what each one does).

    Attributes:
        sigma_px: the noise of a track's position, pixels (GRIC's sigma).
        residual_px: a track within this many pixels of a model is its inlier (RANSAC's distance too).
        outlier_px: a track further than this from its group's model in most frame pairs is not
            explained by it (step 4); None: no track is moved or left out.
        rigid_share: a group is one rigid motion when its model explains at least this share of it.
        planar_share: a split's second part must be one motion: a homography explains this share of it.
        merge_share: two groups merge only when the union's model explains this share of each.
        reassign: a track its group's model does not explain may go to a group whose model does (else
            it is left out).
        leave_out: a track that no model explains is left out (-1); else it keeps its group.
        merge_3d: two groups that both need a fundamental matrix may merge under one (off: an object
            moving along the camera's direction fits the world's matrix, the motion degeneracy).
        split_largest: the largest group (usually the world) may be split too.
        rigid_first: the rigid-motion check (mosegpipe.rigid) splits the groups first (the caller's rule).
        min_group: the smallest group a split makes, in tracks ...
        min_share: ... and as a share of all tracks; the larger applies.
        max_pairs: at most this many frame pairs (0, t), spread evenly over the window, are fitted.
        ransac_iters: RANSAC iterations per model.
        seed: OpenCV's random seed, set before each selection (same seed, same labels).
    """

    sigma_px: float = 1.0  # KLT tracks: about 0.5 px noise, plus drift over the window; world.parallax_sigma_px
    residual_px: float = 1.5  # as the rigid-motion check and the geometric fit
    outlier_px: float | None = 4.0  # well beyond the noise: a tracker failure or a motion of its own
    rigid_share: float = 0.5
    planar_share: float = 0.8  # as the geometric fit: one plane explaining 4/5 of the rest is an object
    merge_share: float = 0.8  # as the rigid-motion check's merge_consistency
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

    def __post_init__(self) -> None:
        check_fields(self, _JOINT_CHECKS)


_JOINT_CHECKS: tuple[Check, ...] = (
    *((name, lambda v: v > 0, "be > 0") for name in ("sigma_px", "residual_px")),
    ("outlier_px", lambda v: v > 0, "be > 0 (or None: no track moved or left out)"),
    *((name, lambda v: 0 < v <= 1, "lie in (0, 1]") for name in ("rigid_share", "planar_share", "merge_share")),
    ("min_share", lambda v: 0 <= v < 1, "lie in [0, 1)"),
    *((name, lambda v: v >= 1, "be >= 1") for name in ("min_group", "max_pairs", "ransac_iters")),
)
"""JointConfig's checks: (field, test, what it must be)."""


@dataclass(frozen=True)
class WorldConfig:
    """How the world's motion is told from the others (`world_cluster`).

    Attributes:
        enabled: tell the world by this evidence (False: the motion with the most tracks is the world,
            as summaries written before this step segmented).
        grid: cells per side of the area vote (grid x grid cells over the frame).
        border_weight: extra weight of a border cell (a border cell counts 1 + border_weight).
        continuity: whole videos: weight of the window before's world (0 = each window alone).
        static_px: a track lies where the camera's motion explains the flow when the camera residual
            there is at most this, pixels of the frame.
        static_floor: a motion's area is weighted by this plus its tracks' share on such pixels.
        parallax: where the world's tracks need a fundamental matrix (3D structure near a moving
            camera), a pixel whose nearest labelled track is the world's is static when its flow lies on
            the world's epipolar line (`explain_parallax`).
        parallax_sigma_px: the noise of a track's position, pixels (GRIC and RANSAC thresholds).
        parallax_min_points: fewest world tracks to fit a fundamental matrix from.
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

    def __post_init__(self) -> None:
        check_fields(self, _WORLD_CHECKS)


_WORLD_CHECKS: tuple[Check, ...] = (
    ("grid", lambda v: 2 <= v <= 64, "lie in 2..64"),
    ("parallax_min_points", lambda v: v >= 8, "be >= 8"),
    ("parallax_sigma_px", lambda v: v > 0, "be > 0"),
    *((name, lambda v: v >= 0, "be >= 0") for name in ("border_weight", "continuity", "static_px", "static_floor")),
)
"""WorldConfig's checks: (field, test, what it must be)."""
