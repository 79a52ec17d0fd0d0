"""The settings of the pipeline's stages, in modules that import no OpenCV, PyTorch or scikit-learn (the CLI
reads its options' defaults from them for --help): tracking (TrackConfig, FlowConfig, FlowTrackConfig,
MatchConfig), grouping (ClusterConfig, RigidCheckConfig, GeometricConfig, JointConfig, WorldConfig,
LabelConfig) and masks (MotionMaskConfig, MaskConfig, LearnedMaskConfig). Each stage's module re-exports its own (`mosegpipe.points.klt.TrackConfig`).
"""

from __future__ import annotations

from mosegpipe.configs.grouping import (
    ClusterConfig,
    GeometricConfig,
    JointConfig,
    LabelConfig,
    RigidCheckConfig,
    WorldConfig,
)
from mosegpipe.configs.masks import LearnedMaskConfig, MaskConfig, MotionMaskConfig
from mosegpipe.configs.tracking import FlowConfig, FlowTrackConfig, MatchConfig, TrackConfig

__all__ = [
    "ClusterConfig",
    "FlowConfig",
    "FlowTrackConfig",
    "GeometricConfig",
    "JointConfig",
    "LabelConfig",
    "LearnedMaskConfig",
    "MaskConfig",
    "MatchConfig",
    "MotionMaskConfig",
    "RigidCheckConfig",
    "TrackConfig",
    "WorldConfig",
]
