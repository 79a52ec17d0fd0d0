"""Stage contracts: the dataclasses that travel between the stages of the pipeline.

Shape letters: T frames, N points, H/W image height/width, D = 2F trajectory dimension,
E embedding dimension, K clusters.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal, get_args

import numpy as np
import numpy.typing as npt

# The vocabularies of the settings, each spelled once: the library checks against them and the CLI builds
# its choices from them (in this order, the default first).

KMethodName = Literal["silhouette", "residual"]
"""Automatic-K rules of cluster.cluster_auto_k: the silhouette, or the elbow of the K-means residual."""
K_METHODS: tuple[KMethodName, ...] = get_args(KMethodName)

SegmentMethod = Literal["joint", "subspacenet", "geometric"]
"""How tracks become motions (PipelineConfig.method): "joint" (the embedding's groups, then per group a model
chosen by GRIC over the window that merges, splits and moves tracks, mosegpipe.group.joint), "subspacenet" (the
learned embedding, automatic K by K-means, the rigid-motion check) or "geometric" (sequential homography /
fundamental-matrix fitting, mosegpipe.group.geometric)."""
SEGMENT_METHODS: tuple[SegmentMethod, ...] = get_args(SegmentMethod)

PointSource = Literal["klt", "flow", "klt+flow"]
"""Where a clip's points come from (PipelineConfig.tracker): KLT corners (`mosegpipe.points.klt`), a grid
carried along the dense flow (`flow_grid.track_flow`), or both (`flow_grid.combine_tracks`)."""
TRACKERS: tuple[PointSource, ...] = get_args(PointSource)

MaskMethod = Literal["motion", "watershed", "nearest", "vote", "learned"]
"""How sparse labels become dense masks (MaskConfig.method, mosegpipe.masks); "learned" is "motion" with the
moving pixels found by a small network (mosegpipe.masks.learned) instead of the hand-made chain."""
FLOW_MASK_METHODS: tuple[MaskMethod, ...] = ("motion", "learned")
"""The mask methods that find moving pixels in the dense flow of a clip or window (the rest use tracks only)."""
MASK_METHODS: tuple[MaskMethod, ...] = get_args(MaskMethod)

PresetName = Literal["best", "balanced", "fast"]
"""Named speed / accuracy trade-offs of the motion masks (`pipeline.config.PRESETS`, `--preset`): "best" is the
library's defaults; "balanced" and "fast" set the dense flow and the mask steps' resolution together for
more frames/s at a measured cost in DAVIS J (docs/RESULTS.md, "Speed")."""
PRESET_NAMES: tuple[PresetName, ...] = get_args(PresetName)

DisPreset = Literal["ultrafast", "fast", "medium"]
"""OpenCV DIS presets of the dense flow (FlowConfig.preset; mosegpipe.points.flow maps them to OpenCV's)."""

DIS_PRESET_NAMES: tuple[DisPreset, ...] = get_args(DisPreset)

EXPORT_FORMATS = ("binary", "alpha", "cutout", "davis", "npz")
"""What `moseg export --as` writes from an output folder (mosegpipe.apps.export)."""

CameraFit = Literal["ransac", "magsac"]
"""Robust fits of the camera's homography to the flow (FlowConfig.camera_fit; mosegpipe.points.flow maps them to
OpenCV's RANSAC and USAC MAGSAC)."""
CAMERA_FIT_NAMES: tuple[CameraFit, ...] = get_args(CameraFit)

Matcher = Literal["bf", "flann"]
"""SIFT descriptor matchers (MatchConfig.matcher): exact brute force or FLANN's approximate KD-trees."""
MATCHERS: tuple[Matcher, ...] = get_args(Matcher)

RecipeName = Literal[
    "clip-f5",
    "clip-f5-rendered",
    "clip-f5-davis",
    "clip-f5-variety",
    "clip-f5-composites",
    "clip-f5-near",
    "base-f5",
    "synthetic-f5",
    "pair-f2",
    "synthetic-f2",
    "lce",
]
"""Named training recipes (`mosegpipe.training.recipes.RECIPES`, `moseg train --preset`); the first is the
shipped 5-frame model's."""
RECIPE_NAMES: tuple[RecipeName, ...] = get_args(RecipeName)

TrainPreset = Literal[RecipeName, "masknet", "whichnet"]
"""`moseg train --preset`: the recipes, then the mask network's (`mosegpipe.training.masks.masknet`, mask method "learned") and
the per-motion network's (`mosegpipe.training.masks.whichnet`, `MaskConfig.which` "learned")."""
TRAIN_PRESETS: tuple[TrainPreset, ...] = get_args(TrainPreset)
MASKNET_PRESET: TrainPreset = "masknet"
"""`moseg train --preset` name of the mask network's recipe (`training.masks.masknet.MaskTrainConfig`)."""
WHICHNET_PRESET: TrainPreset = "whichnet"
"""`moseg train --preset` name of the per-motion network's recipe (`training.masks.whichnet.WhichTrainConfig`)."""

LossName = Literal["mimi", "l2", "l2-balanced", "ce", "triplet", "lifted", "facility", "mimi-point", "mimi-mean"]
"""Training losses (`mosegpipe.training.losses.LOSSES`, `--loss`)."""
LOSS_NAMES: tuple[LossName, ...] = get_args(LossName)

BaselineName = Literal["kmeans-raw", "spectral-raw", "ssc"]
"""Clustering baselines of the benchmark protocols (`mosegpipe.evaluation.baselines.BASELINES`, `--baselines`)."""
BASELINE_NAMES: tuple[BaselineName, ...] = get_args(BaselineName)

BatchEngine = Literal["process", "ray", "inline"]
"""Where `run_batch` runs its clips (mosegpipe.apps.batch.run): a local process pool, Ray tasks, or this process."""
ENGINES: tuple[BatchEngine, ...] = get_args(BatchEngine)

DEVICE_CHOICES = ("cpu", "cuda", "cuda:N", "auto")
"""--device values: "cpu" (the default everywhere), "cuda" / "cuda:N" (a GPU), "auto" (cuda when there is one);
which of them this machine has is `training.loop.resolve_device`'s question."""


def is_device_name(name: str) -> bool:
    """Whether `name` is one of DEVICE_CHOICES (N: a device index), in any case and with spaces around it."""
    value = name.strip().lower()
    index = value.removeprefix("cuda:")
    return value in ("cpu", "cuda", "auto") or (value.startswith("cuda:") and index.isdigit())


@dataclass(frozen=True)
class Frames:
    """A short stack of video frames held in memory.

    Attributes:
        images: (T, H, W, 3) uint8 RGB frames.
        fps: frames per second of the source (0.0 when unknown, e.g. a folder of images).
        source: path or name the frames came from.
        start: index of images[0] in the source video.
        before: (H, W, 3) the source's frame just before images[0], or None: evidence for the motion
            masks only (the first frame's flow back), never segmented.
        after: (H, W, 3) the source's frame just after the last, or None: as `before`, at the other end.
    """

    images: npt.NDArray[np.uint8]
    fps: float = 0.0
    source: str = ""
    start: int = 0
    before: npt.NDArray[np.uint8] | None = None
    after: npt.NDArray[np.uint8] | None = None

    @property
    def num_frames(self) -> int:
        return int(self.images.shape[0])

    @property
    def size_hw(self) -> tuple[int, int]:
        return int(self.images.shape[1]), int(self.images.shape[2])


@dataclass(frozen=True)
class Tracks:
    """Point tracks over T frames.

    Attributes:
        xy: (N, T, 2) float32 pixel coordinates (x right, y down); undefined where not visible.
        visible: (N, T) bool, True where the point was tracked in that frame.
        size_hw: (H, W) of the frames, pixels.
    """

    xy: npt.NDArray[np.float32]
    visible: npt.NDArray[np.bool_]
    size_hw: tuple[int, int]

    @property
    def num_tracks(self) -> int:
        return int(self.xy.shape[0])

    @property
    def num_frames(self) -> int:
        return int(self.xy.shape[1])


@dataclass(frozen=True)
class Matches:
    """Two-view point correspondences.

    Attributes:
        xy1: (N, 2) float32 pixel coordinates in image 1.
        xy2: (N, 2) float32 pixel coordinates in image 2.
        score: (N,) float32 matching score (lower is better for SIFT ratio; see match.py).
        size1_hw: (H, W) of image 1.
        size2_hw: (H, W) of image 2.
    """

    xy1: npt.NDArray[np.float32]
    xy2: npt.NDArray[np.float32]
    score: npt.NDArray[np.float32]
    size1_hw: tuple[int, int]
    size2_hw: tuple[int, int]

    @property
    def num_matches(self) -> int:
        return int(self.xy1.shape[0])


@dataclass(frozen=True)
class Trajectories:
    """The trajectory matrix that SubspaceNet embeds.

    Attributes:
        data: (N, 2F) float32 pixel coordinates, columns ordered x_1, y_1, x_2, y_2, ..., x_F, y_F.
        track_ids: (N,) int64 row index of each trajectory in the Tracks/Matches it came from.
    """

    data: npt.NDArray[np.float32]
    track_ids: npt.NDArray[np.int64]

    @property
    def num_points(self) -> int:
        return int(self.data.shape[0])

    @property
    def num_frames(self) -> int:
        return int(self.data.shape[1] // 2)


@dataclass(frozen=True)
class Clustering:
    """Cluster labels with the evidence for the chosen K.

    Attributes:
        labels: (N,) int64 in 0..k-1.
        k: number of clusters chosen (or forced).
        scores: criterion value per candidate K (method-specific; empty when K was forced).
        method: "residual", "silhouette" or "fixed".
        note: why K is what it is when the scores alone do not say, or a warning that the choice
            is ambiguous ("" when neither); summary.json's `k_note`.
    """

    labels: npt.NDArray[np.int64]
    k: int
    scores: dict[int, float] = field(default_factory=dict)
    method: str = "fixed"
    note: str = ""


@dataclass(frozen=True)
class LabeledClip:
    """One labelled sample of a benchmark or generator: trajectories with ground-truth groups.

    Attributes:
        name: unique name within its dataset, e.g. "Seq005_Clip01/f1-5".
        traj: (N, 2F) float32, same column order as Trajectories.data (pixels or dataset units).
        labels: (N,) int64 in 0..K-1. Datasets with outliers give them their own group.
        dataset: dataset name, e.g. "kt3dmoseg", "hopkins155", "adelaidermf", "lce", "synthetic".
        meta: free-form details (frame range, source file, outlier label, ...).
    """

    name: str
    traj: npt.NDArray[np.float32]
    labels: npt.NDArray[np.int64]
    dataset: str
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def k(self) -> int:
        return int(np.unique(self.labels).size)

    @property
    def num_points(self) -> int:
        return int(self.traj.shape[0])

    @property
    def num_frames(self) -> int:
        return int(self.traj.shape[1] // 2)


@dataclass(frozen=True)
class Segmentation:
    """Dense per-frame masks derived from track labels.

    Attributes:
        masks: (T, H, W) uint8; 0 = no track close enough, k+1 = cluster k.
        labels: (N,) int64 cluster of each track used (see Trajectories.track_ids).
        k: number of clusters.
    """

    masks: npt.NDArray[np.uint8]
    labels: npt.NDArray[np.int64]
    k: int
