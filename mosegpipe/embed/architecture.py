"""What a SubspaceNet is, without building one: its configuration, the shipped weights, input checks.

Nothing here imports torch, so that inference without torch (inference.py) and the command line's
start-up can use them; model.py re-exports every name.
"""

from __future__ import annotations

import dataclasses
import importlib.resources
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from mosegpipe.errors import ConfigError, InputError
from mosegpipe.points.trajectories import resample_frames
from mosegpipe.types import Trajectories

CHECKPOINT_FORMAT = "mosegpipe.subspacenet/1"
INPUT_NORMS = ("shared", "channel", "motion")
ARCHITECTURES = ("subspacenet", "pointnet", "corresnet")
"""ModelConfig.arch: the network (SubspaceNet; and the two baselines of the paper's Figure 6, left)."""

# Context normalisation eps, added to the variance (same role and value as BatchNorm's default): it
# keeps a channel that is constant over a clip (a dead ReLU, a clip of coincident points) at 0
# instead of dividing by zero, and caps the gain on near-constant channels at 1/sqrt(eps) ~ 316.
CN_EPS = 1e-5
# Floor of the input scale, in input units (pixels): only reached when all points coincide.
INPUT_EPS = 1e-6
# Largest coordinate `embed` accepts: squares summed over points stay finite in float64 (1e300 would
# overflow to inf, and the normalised input silently become all zeros).
_MAX_COORD = 1e150
_WEIGHTS_RE = re.compile(r"^subspacenet_f(\d+)\.pt$")

# Bounds of a model configuration, checked before anything is built: a checkpoint is user input,
# and an unchecked width of 2**20 asks for terabytes. Generous next to the paper's model (30 blocks
# x 64 wide, 250 k parameters) and anything trained here.
MODEL_LIMITS: dict[str, int] = {
    "in_dim": 2000,  # 1000 frames
    "width": 4096,
    "num_blocks": 1000,
    "embed_dim": 1024,
    "num_parameters": 50_000_000,  # 200 MB of float32 weights
}


@dataclass(frozen=True)
class ModelConfig:
    """Architecture of a SubspaceNet.

    Attributes:
        in_dim: D, input channels per point: 2F for F frames (x_1, y_1, ..., x_F, y_F).
        width: C, channels of the residual stream.
        num_blocks: residual blocks, each two 1x1 layers (30 blocks x 64 wide as in the paper:
            about 250 k parameters).
        embed_dim: E, dimension of the unit-norm output embedding.
        input_norm: fixed per-clip normalisation of the input. "shared": subtract each channel's
            mean, divide all channels by one scalar (the RMS distance of the centred points), which
            keeps the relative geometry between frames and between x and y. "channel": z-score each
            channel separately (context normalisation applied to the input). "motion": frame 1's
            positions (centred, divided by their RMS) followed by each later frame's displacement from
            frame 1 (divided by the RMS displacement), so that motion, often 1 % of the positions'
            spread, reaches the network at unit scale. All three are invariant to translating or
            scaling the whole clip and have no learned parameters.
        arch: "subspacenet" (the layout of the module docstring), or one of the two baselines of the
            paper's network comparison: "pointnet" (a shared per-point MLP of num_blocks ReLU layers,
            then a max-pooled global feature concatenated to every point's feature and a two-layer
            head; no context normalisation) or "corresnet" (num_blocks blocks of two layers, each
            layer linear -> CN -> batch norm -> ReLU, without the residual shortcut).
        l2_normalize: end with the per-point L2 normalisation (the paper's supplementary study
            switches it off; then the embedding is the head's raw output).
    """

    in_dim: int = 10
    width: int = 64
    num_blocks: int = 30
    embed_dim: int = 5
    input_norm: str = "shared"
    arch: str = "subspacenet"
    l2_normalize: bool = True

    def __post_init__(self) -> None:
        for name in ("in_dim", "width", "num_blocks", "embed_dim"):
            value = getattr(self, name)
            lowest = 0 if name == "num_blocks" else 1
            if not isinstance(value, int) or isinstance(value, bool):
                raise ConfigError(f"ModelConfig.{name}={value!r}: must be an int")
            if not lowest <= value <= MODEL_LIMITS[name]:
                raise ConfigError(f"ModelConfig.{name}={value}: must lie in {lowest}..{MODEL_LIMITS[name]}")
        if not isinstance(self.input_norm, str) or self.input_norm not in INPUT_NORMS:
            raise ConfigError(f"ModelConfig.input_norm={self.input_norm!r}: expected one of {INPUT_NORMS}")
        if not isinstance(self.arch, str) or self.arch not in ARCHITECTURES:
            raise ConfigError(f"ModelConfig.arch={self.arch!r}: expected one of {ARCHITECTURES}")
        if not isinstance(self.l2_normalize, bool):
            raise ConfigError(f"ModelConfig.l2_normalize={self.l2_normalize!r}: must be a bool")
        if self.num_parameters > MODEL_LIMITS["num_parameters"]:
            raise ConfigError(
                f"ModelConfig width={self.width}, num_blocks={self.num_blocks}: {self.num_parameters} parameters, "
                f"more than the {MODEL_LIMITS['num_parameters']} allowed"
            )

    @property
    def num_parameters(self) -> int:
        """Scalar parameters of the model this configuration builds (weights and biases)."""
        c = self.width
        ends = (self.in_dim + 1) * c + (c + 1) * self.embed_dim
        if self.arch == "pointnet":
            return ends + self.num_blocks * (c + 1) * c + (2 * c + 1) * c
        per_block = 2 * (c + 1) * c + (4 * c if self.arch == "corresnet" else 0)
        return ends + self.num_blocks * per_block

    def to_dict(self) -> dict[str, Any]:
        """Plain dict of all fields (stored in checkpoints)."""
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ModelConfig:
        """Inverse of `to_dict`; missing fields take their defaults, unknown fields are an error.

        Raises:
            InputError: unknown field names or invalid values.
        """
        if not isinstance(data, dict) or not all(isinstance(key, str) for key in data):
            raise InputError(f"ModelConfig: expected a dict of field names, got {type(data).__name__}")
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise InputError(f"ModelConfig: unknown fields {unknown}; known: {sorted(known)}")
        return cls(**data)


def weights_dir() -> Path:
    """Folder of the shipped checkpoints (`mosegpipe/weights`).

    The package is installed as plain files (editable or wheel), so the resource is a real folder.
    """
    return Path(str(importlib.resources.files("mosegpipe").joinpath("weights")))


def available_default_frames() -> list[int]:
    """Frame counts F with a shipped `subspacenet_f{F}.pt`, ascending (empty if none)."""
    folder = weights_dir()
    if not folder.is_dir():
        return []
    found = (_WEIGHTS_RE.match(p.name) for p in folder.iterdir())
    return sorted(int(m.group(1)) for m in found if m)


def check_trajectory_matrix(traj: Trajectories | npt.NDArray[np.floating], cfg: ModelConfig) -> npt.NDArray[np.generic]:
    """The (N, cfg.in_dim) matrix a model embeds, checked (Trajectories are resampled in time first).

    Raises:
        InputError: the matrix is not 2-D, has D != cfg.in_dim columns, is not real numbers
            (complex, str, object), holds NaN/inf, or holds values too large to normalise.
    """
    if isinstance(traj, Trajectories):
        traj = resample_frames(traj, cfg.in_dim // 2).data
    try:
        arr = np.asarray(traj)
    except (TypeError, ValueError) as exc:  # ragged lists
        raise InputError(f"trajectory matrix: not an array of numbers ({exc})") from exc
    if arr.dtype.kind not in "iuf":
        raise InputError(
            f"trajectory matrix dtype {arr.dtype}: expected real numbers (float or int; complex, str and "
            "object arrays are not coordinates)"
        )
    if arr.ndim != 2 or arr.shape[1] != cfg.in_dim:
        raise InputError(
            f"trajectory matrix shape {arr.shape}: this model expects (N, {cfg.in_dim}) ({cfg.in_dim // 2} frames)"
        )
    if not np.all(np.isfinite(arr)):
        raise InputError("trajectory matrix holds NaN or inf values")
    if arr.size and float(np.abs(arr).max()) > _MAX_COORD:
        raise InputError(
            f"trajectory matrix values up to {float(np.abs(arr).max()):.3g}: too large to normalise "
            f"(more than {_MAX_COORD:.0e}; coordinates are expected in pixels)"
        )
    return arr


def check_embedding(out: npt.NDArray[np.float32], arr: npt.NDArray[np.generic]) -> npt.NDArray[np.float32]:
    """`out`, the embeddings of the checked matrix `arr`, if they are finite.

    Raises:
        InputError: non-finite embeddings: the coordinates were too large to normalise.
    """
    if not np.all(np.isfinite(out)):
        raise InputError(
            f"trajectory matrix values up to {float(np.abs(arr).max()):.3g}: too large to normalise "
            "(coordinates are expected in pixels)"
        )
    return out
