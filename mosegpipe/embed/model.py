"""SubspaceNet: a per-point residual network that embeds trajectories for subspace clustering.

Xu, Cheong, Li, "Learning for Multi-Type Subspace Clustering", ICCV 2019. Every point (one row of the
trajectory matrix) goes through the same stack of 1x1 layers; the only exchange between points is
context normalisation (CN), which z-scores every channel over the points of one clip. The output is a
unit vector per point, trained so that points of one motion land close together (see losses.py).

Layout (B clips, N points, D = 2F input channels, C = width, E = embed_dim)::

    x (B, N, D) pixels --input norm (fixed)--> (B, N, D)
      -> Linear D->C                                    h0 (B, N, C)
      -> num_blocks x  h + W2(ReLU(CN(W1(ReLU(CN(h))))))  (pre-activation residual block)
      -> W_out(ReLU(CN(h)))  C->E                       (B, N, E)
      -> L2 normalise per point                         z (B, N, E)

One layout in and out: points before channels, (B, N, D) -> (B, N, E), as `embed` (N, D) -> (N, E).

The blocks use the pre-activation order of He et al. (ECCV 2016): the residual stream is never
normalised itself, each branch starts with CN -> ReLU, and the head repeats that before its linear map.

The 1x1 layers are `nn.Linear` on channels-last (B, N, C) tensors. Measured on the 2-core CPU with
torch.set_num_threads(1), 30 blocks x 64 wide, N=500 (median of 11 runs, noisy shared machine):
Conv1d(kernel 1) on (B, C, N) vs Linear on (B, N, C): B=1 forward 6.2 vs 5.7 ms; B=8 forward
75 vs 35 ms; B=8 train step 196 vs 136 ms. Conv1d(kernel 1) runs through the generic slow convolution
path on CPU, Linear is one GEMM. CN statistics are batched matrix products with the per-point weights
mask/count: about twice as fast as masked elementwise sums at B=8, and three times as fast as
`torch.var_mean` at B=1 (17 ms forward).
"""

from __future__ import annotations

import logging
import os
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from mosegpipe.embed import architecture
from mosegpipe.embed.architecture import (
    ARCHITECTURES,
    CHECKPOINT_FORMAT,
    CN_EPS,
    INPUT_EPS,
    INPUT_NORMS,
    MODEL_LIMITS,
    ModelConfig,
    available_default_frames,
    check_embedding,
    check_trajectory_matrix,
    weights_dir,
)
from mosegpipe.errors import CheckpointError, InputError
from mosegpipe.io.read import atomic_write
from mosegpipe.runtime import requested_threads
from mosegpipe.types import Trajectories

__all__ = [
    "ARCHITECTURES",
    "CHECKPOINT_FORMAT",
    "INPUT_NORMS",
    "MODEL_LIMITS",
    "ModelConfig",
    "SubspaceNet",
    "available_default_frames",
    "context_norm",
    "normalize_input",
    "num_parameters",
    "pad_batch",
    "weights_dir",
]

logger = logging.getLogger(__name__)

if requested_threads() is not None:  # set_threads ran before torch was imported (see runtime.py)
    torch.set_num_threads(int(requested_threads() or 1))


def _point_weights(
    mask: Tensor | None, batch: int, num_points: int, device: torch.device, dtype: torch.dtype
) -> Tensor:
    """(B, 1, N) weights mask/count, so that `w @ h` is the per-clip mean over real points."""
    if mask is None:
        return torch.full((batch, 1, num_points), 1.0 / max(num_points, 1), device=device, dtype=dtype)
    m = mask.to(dtype)
    return (m / m.sum(-1, keepdim=True).clamp_min(1.0)).unsqueeze(1)


def context_norm(h: Tensor, w: Tensor, eps: float = CN_EPS) -> Tensor:
    """Z-score every channel over the real points of each clip (no learned parameters).

    Args:
        h: (B, N, C) features.
        w: (B, 1, N) point weights, mask/count (0 on padding), from which mean and variance are
            taken; padded points therefore never affect the statistics.
        eps: added to the variance.

    Returns:
        (B, N, C) normalised features (padded points are normalised with the clip's statistics too;
        their values are meaningless but finite).
    """
    mu = torch.bmm(w, h)  # (B, 1, C)
    hc = h - mu
    var = torch.bmm(w, hc * hc)  # (B, 1, C)
    return hc * torch.rsqrt(var + eps)


def normalize_input(x: Tensor, w: Tensor, mode: str = "shared", eps: float = INPUT_EPS) -> Tensor:
    """Fixed per-clip input normalisation (see `ModelConfig.input_norm`), computed in float64.

    Float64 keeps the translation and scale invariance exact to float32 rounding even for pixel
    coordinates in the thousands; the cost is negligible (B x N x D values).

    Args:
        x: (B, N, D) coordinates (pixels), channels last.
        w: (B, 1, N) point weights mask/count.
        mode: "shared", "channel" or "motion".
        eps: floor of the scale (input units), reached only when all points coincide.

    Returns:
        (B, N, D) float32 normalised coordinates.
    """
    x64 = x.double()
    w64 = w.double()
    xc = x64 - torch.bmm(w64, x64)
    if mode == "shared":
        mean_sq = torch.bmm(w64, (xc * xc).sum(-1, keepdim=True))  # (B, 1, 1)
        scale = mean_sq.sqrt().clamp_min(eps)
    elif mode == "channel":
        scale = torch.bmm(w64, xc * xc).sqrt().clamp_min(eps)  # (B, 1, D)
    elif mode == "motion":
        pos, disp = xc[..., :2], xc[..., 2:] - xc[..., :2].repeat(1, 1, max(0, xc.shape[-1] // 2 - 1))
        pos_scale = torch.bmm(w64, (pos * pos).sum(-1, keepdim=True)).sqrt().clamp_min(eps)
        # Displacements are centred already (differences of centred channels); their scale floor is
        # relative to the positions' so that a motionless clip stays finite without amplifying noise.
        disp_sq = torch.bmm(w64, (disp * disp).sum(-1, keepdim=True)) / max(1, disp.shape[-1] // 2)
        disp_scale = torch.maximum(disp_sq.sqrt(), 1e-4 * pos_scale)
        return torch.cat([pos / pos_scale, disp / disp_scale], dim=-1).to(torch.float32)
    else:
        raise InputError(f"input_norm={mode!r}: expected one of {INPUT_NORMS}")
    return (xc / scale).to(torch.float32)


class _ResidualBlock(nn.Module):
    """h + W2(ReLU(CN(W1(ReLU(CN(h)))))) on (B, N, C)."""

    def __init__(self, width: int) -> None:
        super().__init__()
        self.lin1 = nn.Linear(width, width)
        self.lin2 = nn.Linear(width, width)

    def forward(self, h: Tensor, w: Tensor) -> Tensor:
        u = self.lin1(F.relu(context_norm(h, w)))
        return h + self.lin2(F.relu(context_norm(u, w)))


class _PlainLayer(nn.Module):
    """ReLU(W h) on (B, N, C): one layer of the PointNet-style shared MLP."""

    def __init__(self, width: int) -> None:
        super().__init__()
        self.lin = nn.Linear(width, width)

    def forward(self, h: Tensor, w: Tensor) -> Tensor:
        return F.relu(self.lin(h))


def _masked_batch_norm(bn: nn.BatchNorm1d, h: Tensor, w: Tensor) -> Tensor:
    """Batch norm of (B, N, C) over the real points only (w > 0), padding passed through unchanged."""
    real = (w.squeeze(1) > 0).reshape(-1)
    flat = h.reshape(-1, h.shape[-1])
    out = flat.clone()
    out[real] = bn(flat[real])
    return out.reshape(h.shape)


class _CorresBlock(nn.Module):
    """ReLU(BN(CN(W2 ReLU(BN(CN(W1 h)))))) on (B, N, C), without a residual shortcut."""

    def __init__(self, width: int) -> None:
        super().__init__()
        self.lin1 = nn.Linear(width, width)
        self.bn1 = nn.BatchNorm1d(width)
        self.lin2 = nn.Linear(width, width)
        self.bn2 = nn.BatchNorm1d(width)

    def forward(self, h: Tensor, w: Tensor) -> Tensor:
        u = F.relu(_masked_batch_norm(self.bn1, context_norm(self.lin1(h), w), w))
        return F.relu(_masked_batch_norm(self.bn2, context_norm(self.lin2(u), w), w))


def _block(arch: str, width: int) -> nn.Module:
    if arch == "pointnet":
        return _PlainLayer(width)
    if arch == "corresnet":
        return _CorresBlock(width)
    return _ResidualBlock(width)


class SubspaceNet(nn.Module):
    """Per-point residual network with context normalisation; see the module docstring.

    `cfg.arch` builds the network comparison's baselines in the same class instead (PointNet- and
    CorresNet-style), so that training, checkpoints and inference are shared.

    Attributes:
        cfg: the architecture.
        recipe: training recipe read from a checkpoint ({} for a fresh model).
        metrics: evaluation metrics read from a checkpoint ({} for a fresh model).
    """

    def __init__(self, cfg: ModelConfig = ModelConfig()) -> None:
        super().__init__()
        self.cfg = cfg
        self.recipe: dict[str, Any] = {}
        self.metrics: dict[str, Any] = {}
        self.input = nn.Linear(cfg.in_dim, cfg.width)
        self.blocks = nn.ModuleList(_block(cfg.arch, cfg.width) for _ in range(cfg.num_blocks))
        if cfg.arch == "pointnet":
            # The per-point feature and the max-pooled global feature, concatenated.
            self.pool_head = nn.Linear(2 * cfg.width, cfg.width)
        self.head = nn.Linear(cfg.width, cfg.embed_dim)

    def _embed_points(self, x: Tensor, mask: Tensor | None) -> Tensor:
        """(B, N, D) coordinates -> (B, N, E) unit embeddings (channels last)."""
        batch, num_points, _ = x.shape
        w = _point_weights(mask, batch, num_points, x.device, torch.float32)
        if mask is not None:
            # Padding may hold anything (even NaN); zero it so that 0-weights really remove it.
            x = torch.where(mask.unsqueeze(-1), x, torch.zeros((), dtype=x.dtype, device=x.device))
        w64 = _point_weights(mask, batch, num_points, x.device, torch.float64)
        h = self.input(normalize_input(x, w64, self.cfg.input_norm))
        for block in self.blocks:
            h = block(h, w)
        if self.cfg.arch == "pointnet":
            real = (w > 0).transpose(1, 2)  # (B, N, 1)
            pooled = torch.where(real, h, torch.full((), -torch.inf, dtype=h.dtype)).amax(dim=1, keepdim=True)
            h = F.relu(self.pool_head(torch.cat([h, pooled.expand_as(h)], dim=-1)))
            z = self.head(h)
        elif self.cfg.arch == "corresnet":
            z = self.head(h)
        else:
            z = self.head(F.relu(context_norm(h, w)))
        if self.cfg.l2_normalize:
            z = F.normalize(z, dim=-1)
        if mask is not None:
            z = z * mask.unsqueeze(-1).to(z.dtype)
        return z

    def forward(self, x: Tensor, mask: Tensor | None = None) -> Tensor:
        """Embed a batch of clips.

        Args:
            x: (B, N, D) float32 trajectory coordinates, pixels (any consistent unit: the input is
                normalised per clip), D = cfg.in_dim (pad_batch builds it).
            mask: optional (B, N) bool, True on real points; None means all points are real.
                Padded points never influence the real points' outputs.

        Returns:
            (B, N, E) float32 embeddings, unit L2 norm at every real point (unless cfg.l2_normalize
                is False), 0 at padded points.

        Raises:
            InputError: x or mask has the wrong shape.
        """
        if x.ndim != 3 or x.shape[2] != self.cfg.in_dim:
            raise ValueError(f"x shape {tuple(x.shape)}: expected (B, N, {self.cfg.in_dim})")
        if mask is not None and (mask.shape != (x.shape[0], x.shape[1]) or mask.dtype != torch.bool):
            raise ValueError(
                f"mask shape {tuple(mask.shape)} dtype {mask.dtype}: expected bool ({x.shape[0]}, {x.shape[1]})"
            )
        return self._embed_points(x.to(torch.float32), mask)

    @property
    def num_frames(self) -> int:
        """F, the trajectory length the model takes (its input is (N, 2F))."""
        return self.cfg.in_dim // 2

    def embed(self, traj: Trajectories | npt.NDArray[np.floating]) -> npt.NDArray[np.float32]:
        """Embed one clip's trajectories without gradients.

        Args:
            traj: Trajectories of any length F' (resampled in time to the model's F first, see
                trajectories.resample_frames), or an (N, D) trajectory matrix with columns
                x_1, y_1, ..., x_F, y_F in pixels and D = cfg.in_dim exactly.

        Returns:
            (N, E) float32 embeddings (unit norm unless cfg.l2_normalize is False).

        Raises:
            InputError: the matrix is not 2-D, has D != cfg.in_dim columns, is not real numbers
                (complex, str, object), holds NaN/inf, or holds values too large to normalise.
        """
        arr = check_trajectory_matrix(traj, self.cfg)
        if arr.shape[0] == 0:
            return np.zeros((0, self.cfg.embed_dim), dtype=np.float32)
        device = next(self.parameters()).device
        was_training = self.training
        self.eval()
        try:
            with torch.inference_mode():
                # Float64 into the (float64) input normalisation: float32 coordinates are exact in
                # it, and float64 ones keep their precision and range instead of overflowing to inf.
                x = torch.from_numpy(np.ascontiguousarray(arr, dtype=np.float64)).to(device)
                z = self._embed_points(x.unsqueeze(0), None)[0]
        finally:
            self.train(was_training)
        return check_embedding(z.cpu().numpy().astype(np.float32, copy=False), arr)

    def checkpoint(self, recipe: dict[str, Any] | None = None, metrics: dict[str, Any] | None = None) -> dict[str, Any]:
        """A self-describing, `torch.load(weights_only=True)`-loadable checkpoint dict.

        Args:
            recipe: training settings to record (plain values; numpy scalars/arrays and paths are
                converted). Defaults to the model's current `recipe`.
            metrics: evaluation results to record. Defaults to the model's current `metrics`.

        Returns:
            {"format", "model_config", "state_dict" (CPU tensors), "recipe", "metrics", "version"}.

        Raises:
            CheckpointError: recipe or metrics hold a value that cannot be stored as plain data.
        """
        from mosegpipe import __version__

        return {
            "format": CHECKPOINT_FORMAT,
            "model_config": self.cfg.to_dict(),
            "state_dict": {k: v.detach().cpu().clone() for k, v in self.state_dict().items()},
            "recipe": _plain(self.recipe if recipe is None else recipe, "recipe"),
            "metrics": _plain(self.metrics if metrics is None else metrics, "metrics"),
            "version": __version__,
        }

    def save(
        self, path: str | os.PathLike[str], recipe: dict[str, Any] | None = None, metrics: dict[str, Any] | None = None
    ) -> Path:
        """Write `checkpoint(recipe, metrics)` to `path` atomically (io.atomic_write: temp file + rename).

        Returns:
            The path written. A reader never sees a half-written file, even if saving is interrupted.
        """
        path = Path(path)
        ckpt = self.checkpoint(recipe, metrics)
        with atomic_write(path) as tmp, open(tmp, "wb") as f:
            torch.save(ckpt, f)
            f.flush()
            os.fsync(f.fileno())
        logger.debug("saved SubspaceNet checkpoint %s", path)
        return path

    @classmethod
    def from_checkpoint(cls, path_or_dict: str | os.PathLike[str] | dict[str, Any]) -> SubspaceNet:
        """Rebuild a model from a checkpoint file or dict (see `checkpoint`).

        Args:
            path_or_dict: a file written by `save`, or the dict returned by `checkpoint`.

        Returns:
            The model in eval mode on the CPU, with `.recipe` and `.metrics` from the checkpoint.

        Raises:
            CheckpointError: the file is missing or unreadable, is not a SubspaceNet checkpoint, or its
                weights do not fit its model config. The message names the file.
        """
        if isinstance(path_or_dict, dict):
            src, ckpt = "<checkpoint dict>", path_or_dict
        else:
            path = Path(path_or_dict)
            src = str(path)
            if not path.is_file():
                raise CheckpointError(f"{path}: checkpoint file not found")
            # torch warns about what it is about to refuse (a raw pickle's protocol): recorded here,
            # so that a refused file gives just its error line; a loaded one passes them on.
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                try:
                    ckpt = torch.load(path, weights_only=True, map_location="cpu")
                except Exception as e:  # torch raises many types for corrupt or foreign files
                    failed: Exception | None = e
                else:
                    failed = None
            if failed is not None:
                for w in caught:
                    logger.debug("torch.load(%s) warned: %s", path, w.message)
                logger.debug("torch.load(%s) failed: %s", path, failed)
                raise CheckpointError(
                    f"{path}: cannot read checkpoint: corrupt, truncated, or holding objects "
                    f"other than plain data ({type(failed).__name__})"
                ) from failed
            for w in caught:
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        if not isinstance(ckpt, dict) or ckpt.get("format") != CHECKPOINT_FORMAT:
            found = ckpt.get("format") if isinstance(ckpt, dict) else type(ckpt).__name__
            raise CheckpointError(
                f"{src}: not a SubspaceNet checkpoint (format {found!r}, expected {CHECKPOINT_FORMAT!r})"
            )
        for key in ("model_config", "state_dict"):
            if not isinstance(ckpt.get(key), dict):
                raise CheckpointError(f"{src}: checkpoint lacks a {key!r} dict")
        try:
            cfg = ModelConfig.from_dict(ckpt["model_config"])
        except (InputError, TypeError) as e:
            raise CheckpointError(f"{src}: invalid model_config: {e}") from e
        _check_state_dict(ckpt["state_dict"], cfg, src)
        for key in ("recipe", "metrics"):
            if not isinstance(ckpt.get(key) or {}, dict):
                raise CheckpointError(f"{src}: checkpoint field {key!r} must be a dict, got {type(ckpt[key]).__name__}")
        model = cls(cfg)
        try:
            model.load_state_dict(ckpt["state_dict"], strict=True)
        except (RuntimeError, TypeError) as e:
            detail = " ".join(str(e).split())[:400]
            raise CheckpointError(f"{src}: weights do not fit {cfg}: {detail}") from e
        model.recipe = dict(ckpt.get("recipe") or {})
        model.metrics = dict(ckpt.get("metrics") or {})
        logger.debug("loaded SubspaceNet %s from %s (written by mosegpipe %s)", cfg, src, ckpt.get("version"))
        return model.eval()

    @classmethod
    def default(cls, frames: int = 5) -> SubspaceNet:
        """The shipped model for `frames`-frame trajectories (frames=2: the image-pair model).

        Loads `mosegpipe/weights/subspacenet_f{frames}.pt`; works offline.

        Raises:
            CheckpointError: no shipped weights for that many frames (the message lists the available
                ones), or the file does not fit.
        """
        path = architecture.weights_dir() / f"subspacenet_f{frames}.pt"
        if not path.is_file():
            available = available_default_frames()
            listed = ", ".join(str(f) for f in available) if available else "none"
            raise CheckpointError(f"no shipped weights for {frames} frames; available: {listed} (looked for {path})")
        model = cls.from_checkpoint(path)
        if model.cfg.in_dim != 2 * frames:
            raise CheckpointError(
                f"{path}: model expects in_dim={model.cfg.in_dim}, not {2 * frames} for {frames} frames"
            )
        return model


def _check_state_dict(state: dict[str, Any], cfg: ModelConfig, src: str) -> None:
    """Every weight of `state` has the name, shape and a finite floating value that `cfg` needs.

    The expected names and shapes come from the model built on PyTorch's "meta" device, which
    allocates nothing, so a checkpoint is fully checked before any real memory is spent on it.

    Raises:
        CheckpointError: a missing, unexpected, misshapen, non-float or non-finite weight (named).
    """
    with torch.device("meta"):
        expected = {k: tuple(v.shape) for k, v in SubspaceNet(cfg).state_dict().items()}
    missing = [k for k in expected if k not in state]
    unexpected = [k for k in state if k not in expected]
    if missing or unexpected:
        raise CheckpointError(
            f"{src}: weights do not fit {cfg}: missing {missing[:5]}, unexpected {[str(k) for k in unexpected[:5]]}"
        )
    for name, shape in expected.items():
        value = state[name]
        if name.endswith("num_batches_tracked"):  # batch norm's step counter (corresnet), an integer
            if not isinstance(value, Tensor) or tuple(value.shape) != shape or value.dtype.is_floating_point:
                raise CheckpointError(f"{src}: weight {name!r} must be an integer scalar tensor")
            continue
        if not isinstance(value, Tensor) or not value.dtype.is_floating_point:
            what = value.dtype if isinstance(value, Tensor) else type(value).__name__
            raise CheckpointError(f"{src}: weight {name!r} must be a floating-point tensor, got {what}")
        if tuple(value.shape) != shape:
            raise CheckpointError(
                f"{src}: weights do not fit {cfg}: {name!r} has shape {tuple(value.shape)}, not {shape}"
            )
        if not bool(torch.isfinite(value).all()):
            raise CheckpointError(f"{src}: weight {name!r} holds NaN or inf values")


def pad_batch(
    trajs: list[npt.NDArray[np.floating]],
    labels: list[npt.NDArray[np.integer]] | None = None,
) -> tuple[Tensor, Tensor | None, Tensor]:
    """Stack clips with different numbers of points into one padded batch.

    Args:
        trajs: B trajectory matrices (N_i, D), same D, pixels.
        labels: optional B label vectors (N_i,), integers >= 0.

    Returns:
        x: (B, Nmax, D) float32, 0 on padding (a transposed view of channels-first storage: the
            memory layout the shipped weights were trained with, so that training stays bit-exact).
        labels: (B, Nmax) int64, -1 on padding (None when no labels were given).
        mask: (B, Nmax) bool, True on real points.

    Raises:
        InputError: empty list, mismatched D, or labels that do not match the trajectories.
    """
    if not trajs:
        raise ValueError("pad_batch: no trajectory matrices given")
    arrays = [np.asarray(t) for t in trajs]
    dims = {a.shape[1] if a.ndim == 2 else None for a in arrays}
    if len(dims) != 1 or None in dims:
        raise ValueError(f"pad_batch: trajectory shapes {[a.shape for a in arrays]}: expected (N_i, D), one D")
    dim = dims.pop()
    if labels is not None:
        if len(labels) != len(arrays):
            raise ValueError(f"pad_batch: {len(labels)} label vectors for {len(arrays)} clips")
        for i, (a, lab) in enumerate(zip(arrays, labels)):
            if np.shape(lab) != (a.shape[0],):
                raise ValueError(f"pad_batch: clip {i} labels shape {np.shape(lab)}, expected ({a.shape[0]},)")
    num_max = max(a.shape[0] for a in arrays)
    x_cf = torch.zeros((len(arrays), dim, num_max), dtype=torch.float32)  # type: ignore[arg-type]
    mask = torch.zeros((len(arrays), num_max), dtype=torch.bool)
    lab_t = None if labels is None else torch.full((len(arrays), num_max), -1, dtype=torch.int64)
    for i, a in enumerate(arrays):
        n = a.shape[0]
        x_cf[i, :, :n] = torch.from_numpy(np.ascontiguousarray(a.T, dtype=np.float32))
        mask[i, :n] = True
        if lab_t is not None and labels is not None:
            lab_t[i, :n] = torch.from_numpy(np.asarray(labels[i], dtype=np.int64))
    return x_cf.transpose(1, 2), lab_t, mask


def num_parameters(model: nn.Module) -> int:
    """Number of scalar parameters (trainable or not) of `model`."""
    return sum(p.numel() for p in model.parameters())


def _plain(value: Any, where: str) -> Any:
    """Convert `value` to data that `torch.load(weights_only=True)` accepts, or fail naming it."""
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    if isinstance(value, Tensor):
        return value.detach().cpu().clone()
    if isinstance(value, dict):
        out = {}
        for k, v in value.items():
            if not isinstance(k, str):
                raise CheckpointError(f"cannot store {where} key {k!r} in a checkpoint: keys must be str")
            out[k] = _plain(v, f"{where}.{k}")
        return out
    if isinstance(value, (list, tuple)):
        return [_plain(v, f"{where}[{i}]") for i, v in enumerate(value)]
    raise CheckpointError(f"cannot store {where} of type {type(value).__name__} in a checkpoint")
