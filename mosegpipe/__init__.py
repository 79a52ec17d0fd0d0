"""mosegpipe: motion segmentation of tracked points with SubspaceNet.

The public API, stage by stage (see docs/HOW-IT-WORKS.md):

    frames = read_video("clip.mp4", max_frames=5)        # Frames (T, H, W, 3) uint8
    tracks = track_klt(frames)                           # Tracks xy (N, T, 2), visible (N, T)
    traj = build_trajectories(tracks)                    # Trajectories (N, 2T)
    model = SubspaceNet.default(frames=5)                # shipped weights, offline, eval mode
    result = cluster_auto_k(model.embed(traj))           # Clustering labels (N,), k, scores
    seg = segment_clip("clip.mp4")                       # the whole recipe in one call
    Segmenter()("clip.mp4", out="clip_moseg")            # ... and every output written (docs/OUTPUTS.md)
"""

from __future__ import annotations

__version__ = "0.1.0"

import importlib
from typing import Any

# Public names and the module that defines each. Imported on first use, so that `moseg --help` and
# `import mosegpipe.errors` do not pay for torch, OpenCV and scikit-learn.
_EXPORTS = {
    "mosegpipe.group.cluster": ("ClusterConfig", "cluster_auto_k", "kmeans"),
    "mosegpipe.errors": (
        "CheckpointError",
        "ConfigError",
        "DatasetError",
        "InputError",
        "MosegError",
        "OutputExistsError",
        "TooFewTracksError",
    ),
    "mosegpipe.io.read": ("read_image", "read_video"),
    "mosegpipe.masks": ("MaskConfig", "labels_to_mask", "labels_to_masks"),
    "mosegpipe.points.sift": ("MatchConfig", "match_sift"),
    "mosegpipe.evaluation.metrics": ("misclassification_error", "nmi"),
    "mosegpipe.embed.model": ("ModelConfig", "SubspaceNet"),
    "mosegpipe.apps.outputs": ("write_clip_outputs", "write_pair_outputs", "write_video_outputs"),
    "mosegpipe.group.rigid": ("RigidCheckConfig", "split_by_rigid_motion"),
    "mosegpipe.apps.segmenter": ("Segmenter",),
    "mosegpipe.pipeline": ("PipelineConfig", "segment_clip", "segment_frames", "segment_pair", "segment_video"),
    "mosegpipe.points.klt": ("KLTTracker", "TrackConfig", "track_klt"),
    "mosegpipe.points.trajectories": ("build_trajectories", "resample_frames", "trajectories_from_matches"),
    "mosegpipe.types": (
        "Clustering",
        "Frames",
        "LabeledClip",
        "Matches",
        "Segmentation",
        "Tracks",
        "Trajectories",
    ),
}
_WHERE = {name: module for module, names in _EXPORTS.items() for name in names}


def __getattr__(name: str) -> Any:
    if name in _WHERE:
        value = getattr(importlib.import_module(_WHERE[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'mosegpipe' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_WHERE])


__all__ = sorted(_WHERE) + ["__version__"]
