"""SubspaceNet inference in NumPy, so that a single `moseg run` need not import torch.

Importing torch costs about 2 s of a 5-frame `moseg run` (more than half of its start-up on the 2-core
development machine, docs/RESULTS.md). Inference of the shipped architecture is a dozen small matrix
products with context normalisation in between, which NumPy does as fast at these sizes. Checkpoints
stay torch files (`torch.load(weights_only=True)`); the first use of a checkpoint loads it with torch
and keeps a plain-array copy (`.npz`, read with `allow_pickle=False`) in the cache folder, named by the
SHA-256 of the checkpoint file, so every later run of the same weights reads the copy instead. A
changed checkpoint has another digest; a cache copy that does not load, does not fit or holds weights
that are not all finite (a damaged file) is ignored and rewritten.

`load_embedder` is what the single-clip commands use; training, evaluation and batch processing keep
the torch model of `load_model` (they import torch anyway and need its weights; mosegpipe.pipeline
re-exports it).
"""

from __future__ import annotations

import hashlib
import json
import logging
import zipfile
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import numpy.typing as npt

from mosegpipe.embed.architecture import (
    CHECKPOINT_FORMAT,
    CN_EPS,
    INPUT_EPS,
    ModelConfig,
    available_default_frames,
    check_embedding,
    check_trajectory_matrix,
    weights_dir,
)
from mosegpipe.errors import CheckpointError, InputError
from mosegpipe.io.read import atomic_write, default_cache_dir
from mosegpipe.types import Trajectories

if TYPE_CHECKING:
    from mosegpipe.embed.model import SubspaceNet

log = logging.getLogger(__name__)

# Bumped when the cache copy's layout changes, so that old copies are not read.
_CACHE_VERSION = 1


class Embedder(Protocol):
    """What the pipeline needs of a model: SubspaceNet (torch) and NumpySubspaceNet both are one."""

    cfg: ModelConfig
    recipe: dict[str, Any]

    @property
    def num_frames(self) -> int: ...

    def embed(self, traj: Trajectories | npt.NDArray[np.floating]) -> npt.NDArray[np.float32]: ...


def expected_shapes(cfg: ModelConfig) -> dict[str, tuple[int, ...]]:
    """Weight name -> shape of a "subspacenet" model with `cfg` (the names of its torch state dict)."""
    c, shapes = cfg.width, {"input.weight": (cfg.width, cfg.in_dim), "input.bias": (cfg.width,)}
    for i in range(cfg.num_blocks):
        for lin in ("lin1", "lin2"):
            shapes[f"blocks.{i}.{lin}.weight"] = (c, c)
            shapes[f"blocks.{i}.{lin}.bias"] = (c,)
    shapes["head.weight"] = (cfg.embed_dim, c)
    shapes["head.bias"] = (cfg.embed_dim,)
    return shapes


def _context_norm(h: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
    """Z-score every channel of (N, C) over the points (model.context_norm for one unpadded clip)."""
    hc = h - h.mean(axis=0, keepdims=True)
    return _context_norm_(hc, shifted=True)


def _context_norm_(h: npt.NDArray[np.float32], shifted: bool = False) -> npt.NDArray[np.float32]:
    """_context_norm in place (the same operations, so the same values; one (N, C) array fewer)."""
    if not shifted:
        h -= h.mean(axis=0, keepdims=True)
    # einsum and one multiply: ~40 % faster than (hc * hc).mean and a division at (1000, 64).
    var = np.einsum("ij,ij->j", h, h) / np.float32(h.shape[0])
    h *= np.float32(1.0) / np.sqrt(var + np.float32(CN_EPS))
    return h


# Above this many points the hidden layers are applied in blocks of rows, in place, so that at most
# two (N, width) arrays live (10^6 points, width 64: 512 MB instead of 1.3 GB). Below it the whole
# matrix products run as before (BLAS may round a block of rows differently from the whole).
_ROWS_IN_BLOCKS = 65536


def normalize_input(x: npt.NDArray[np.float64], mode: str) -> npt.NDArray[np.float32]:
    """model.normalize_input for one unpadded (N, D) clip, in float64; returns float32."""
    xc = x - x.mean(axis=0, keepdims=True)
    if mode == "shared":
        scale = max(float(np.sqrt((xc * xc).sum(axis=1).mean())), INPUT_EPS)
        return (xc / scale).astype(np.float32)
    if mode == "channel":
        return (xc / np.maximum(np.sqrt((xc * xc).mean(axis=0, keepdims=True)), INPUT_EPS)).astype(np.float32)
    if mode == "motion":
        pos = xc[:, :2]
        disp = xc[:, 2:] - np.tile(pos, (1, max(0, xc.shape[1] // 2 - 1)))
        pos_scale = max(float(np.sqrt((pos * pos).sum(axis=1).mean())), INPUT_EPS)
        disp_sq = float((disp * disp).sum(axis=1).mean()) / max(1, disp.shape[1] // 2)
        disp_scale = max(float(np.sqrt(disp_sq)), 1e-4 * pos_scale)
        return np.concatenate([pos / pos_scale, disp / disp_scale], axis=1).astype(np.float32)
    raise InputError(f"input_norm={mode!r}: not a known input normalisation")


class NumpySubspaceNet:
    """A "subspacenet" model's inference in NumPy: `embed` gives SubspaceNet.embed's output.

    Attributes:
        cfg: the architecture (arch "subspacenet" only).
        recipe, metrics: as read from the checkpoint.
        weights: name -> float32 array, the torch state dict's names and shapes.
    """

    def __init__(
        self,
        cfg: ModelConfig,
        weights: dict[str, npt.NDArray[np.float32]],
        recipe: dict[str, Any] | None = None,
        metrics: dict[str, Any] | None = None,
    ) -> None:
        if cfg.arch != "subspacenet":
            raise CheckpointError(f"NumPy inference covers arch 'subspacenet', not {cfg.arch!r}")
        shapes = expected_shapes(cfg)
        misfit = sorted(
            k for k in shapes.keys() | weights.keys() if tuple(getattr(weights.get(k), "shape", ())) != shapes.get(k)
        )
        if misfit:
            raise CheckpointError(f"weights do not fit {cfg}: {misfit[:5]}")
        self.cfg = cfg
        self.weights = {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in weights.items()}
        self.recipe: dict[str, Any] = dict(recipe or {})
        self.metrics: dict[str, Any] = dict(metrics or {})
        # Transposed once: x @ W.T is then one contiguous matrix product per layer.
        layers = {k.removesuffix(".weight") for k in self.weights if k.endswith(".weight")}
        self._layers = {n: (self.weights[f"{n}.weight"].T.copy(), self.weights[f"{n}.bias"]) for n in layers}

    @property
    def num_frames(self) -> int:
        """F, the trajectory length the model takes (its input is (N, 2F))."""
        return self.cfg.in_dim // 2

    def _linear(self, name: str, h: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
        wt, b = self._layers[name]
        out: npt.NDArray[np.float32] = h @ wt + b
        return out

    def _linear_rows(self, name: str, h: npt.NDArray[np.float32], out: npt.NDArray[np.float32], add: bool) -> None:
        """out = (out if add else 0) + h @ W.T + b, in blocks of rows (out may be h: square W)."""
        wt, b = self._layers[name]
        for lo in range(0, len(h), _ROWS_IN_BLOCKS):
            block = h[lo : lo + _ROWS_IN_BLOCKS] @ wt + b
            if add:
                out[lo : lo + _ROWS_IN_BLOCKS] += block
            else:
                out[lo : lo + _ROWS_IN_BLOCKS] = block

    def _blocks(self, h: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
        """The residual blocks on (N, width) h; large N in place (see _ROWS_IN_BLOCKS)."""
        if len(h) <= _ROWS_IN_BLOCKS:
            for i in range(self.cfg.num_blocks):
                u = self._linear(f"blocks.{i}.lin1", np.maximum(_context_norm(h), 0))
                h = h + self._linear(f"blocks.{i}.lin2", np.maximum(_context_norm(u), 0))
            return h
        for i in range(self.cfg.num_blocks):
            a = _context_norm(h)
            np.maximum(a, 0, out=a)
            self._linear_rows(f"blocks.{i}.lin1", a, a, add=False)
            _context_norm_(a)
            np.maximum(a, 0, out=a)
            self._linear_rows(f"blocks.{i}.lin2", a, h, add=True)  # h is ours: the input layer's output
            del a
        return h

    def embed(self, traj: Trajectories | npt.NDArray[np.floating]) -> npt.NDArray[np.float32]:
        """(N, E) float32 embeddings; the same checks and errors as SubspaceNet.embed."""
        arr = check_trajectory_matrix(traj, self.cfg)
        if arr.shape[0] == 0:
            return np.zeros((0, self.cfg.embed_dim), dtype=np.float32)
        h = self._linear("input", normalize_input(np.asarray(arr, dtype=np.float64), self.cfg.input_norm))
        h = self._blocks(h)
        a = _context_norm(h)
        del h
        z = self._linear("head", np.maximum(a, 0, out=a))
        if self.cfg.l2_normalize:
            z = z / np.maximum(np.linalg.norm(z, axis=1, keepdims=True), np.float32(1e-12))
        return check_embedding(z.astype(np.float32, copy=False), arr)

    @classmethod
    def from_torch(cls, model: SubspaceNet) -> NumpySubspaceNet:
        """The same weights, copied out of a torch model."""
        weights = {k: v.detach().cpu().numpy().astype(np.float32) for k, v in model.state_dict().items()}
        return cls(model.cfg, weights, model.recipe, model.metrics)

    def save_npz(self, path: Path) -> None:
        """Writes the plain-array copy (weights plus a JSON header; no pickled objects)."""
        header = {
            "format": CHECKPOINT_FORMAT,
            "cache_version": _CACHE_VERSION,
            "model_config": self.cfg.to_dict(),
            "recipe": self.recipe,
            "metrics": self.metrics,
        }
        arrays: dict[str, Any] = {"__header__": np.array(json.dumps(header, default=str)), **self.weights}
        with atomic_write(path) as tmp, open(tmp, "wb") as fh:
            np.savez(fh, **arrays)

    @classmethod
    def load_npz(cls, path: Path) -> NumpySubspaceNet:
        """Reads a copy written by save_npz.

        Raises:
            CheckpointError: unreadable, of another layout, or weights that do not fit.
        """
        try:
            with np.load(path, allow_pickle=False) as data:
                header = json.loads(str(data["__header__"]))
                weights = {k: data[k] for k in data.files if k != "__header__"}
        # BadZipFile: a copy cut short (a full disk, a killed writer of another tool); AttributeError:
        # a .npy where the archive was; TypeError: a header that is not a JSON object.
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, AttributeError) as exc:
            raise CheckpointError(f"{path}: unreadable inference copy ({exc})") from exc
        if not isinstance(header, dict):
            raise CheckpointError(f"{path}: an inference copy without a header")
        bad = sorted(k for k, v in weights.items() if v.dtype.kind != "f" or not np.all(np.isfinite(v)))
        if bad:
            raise CheckpointError(f"{path}: weights {bad[:5]} are not all finite numbers")
        if header.get("format") != CHECKPOINT_FORMAT or header.get("cache_version") != _CACHE_VERSION:
            raise CheckpointError(f"{path}: an inference copy of another layout")
        try:
            cfg = ModelConfig.from_dict(header["model_config"])
        except (InputError, TypeError, KeyError) as exc:
            raise CheckpointError(f"{path}: invalid model_config: {exc}") from exc
        return cls(cfg, weights, header.get("recipe"), header.get("metrics"))


def file_digest(path: Path) -> str:
    """SHA-256 of a file's bytes (hex)."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def _shipped_frames(frames: int) -> int:
    """The frame count of the shipped model that serves `frames` (2 = pairs; a count without its own model: 5)."""
    return 2 if frames == 2 else frames if frames in available_default_frames() else 5


def load_model(frames: int, checkpoint: str | Path | None = None) -> SubspaceNet:
    """The shipped default model for `frames` (or a checkpoint file).

    Clips whose frame count has no shipped model are served by the 5-frame model after temporal
    resampling of each trajectory (see trajectories.resample_frames).

    Args:
        frames: F, the trajectory length the model will see (2 = image pairs).
        checkpoint: a checkpoint file to load instead of the shipped weights.

    Returns:
        The model in eval mode. A model loaded from `checkpoint` carries the file's resolved path as
        `checkpoint_path` (recorded by model_info in summary.json, so that a run can be replayed
        with the same weights; it travels with the model to batch workers).

    Raises:
        CheckpointError: the checkpoint is missing, corrupt or not a SubspaceNet, or no weights are shipped.
    """
    from mosegpipe.embed.model import SubspaceNet

    if checkpoint is not None:
        model = SubspaceNet.from_checkpoint(checkpoint)
        # object.__setattr__: nn.Module's own __setattr__ is typed for tensors and modules only.
        object.__setattr__(model, "checkpoint_path", str(Path(checkpoint).resolve()))
        return model
    try:
        return SubspaceNet.default(frames=_shipped_frames(frames))
    except CheckpointError as exc:
        raise CheckpointError(f"{exc}; pass --model CHECKPOINT to use other weights") from exc


def shipped_path(frames: int) -> Path:
    """The shipped checkpoint that serves `frames` (2 = pairs; a count without its own model: the 5-frame one)."""
    return weights_dir() / f"subspacenet_f{_shipped_frames(frames)}.pt"


def load_embedder(frames: int, checkpoint: str | Path | None = None, cache_dir: Path | None = None) -> Embedder:
    """The model for `frames` (the shipped weights, or `checkpoint`), as load_model gives it,
    but served by NumPy when the checkpoint's inference copy is in the cache.

    On a cache miss the checkpoint is loaded with torch (load_model, same checks and
    errors), and for the "subspacenet" architecture its copy is written for the next run (a cache
    folder that cannot be written is skipped silently: the run itself needs no cache).

    Args:
        frames: F, the trajectory length the model will see (2 = image pairs).
        checkpoint: a checkpoint file instead of the shipped weights.
        cache_dir: where copies live (None = io.default_cache_dir() / "inference").

    Raises:
        CheckpointError: as load_model.
    """
    path = Path(checkpoint) if checkpoint is not None else shipped_path(frames)
    folder = cache_dir if cache_dir is not None else default_cache_dir() / "inference"
    copy: Path | None = None
    if path.is_file():
        copy = folder / f"{path.stem}-{file_digest(path)[:24]}.npz"
        if copy.is_file():
            try:
                model = NumpySubspaceNet.load_npz(copy)
            except CheckpointError as exc:
                # Damaged (cut short, NaN weights) or of another layout: rewritten from the checkpoint below.
                log.warning("ignoring the inference copy %s and rewriting it: %s", copy, exc)
            else:
                # The copy was made from this very file after load_model accepted it.
                if checkpoint is not None:
                    model.checkpoint_path = str(path.resolve())  # type: ignore[attr-defined]
                return model
    from mosegpipe.runtime import collector_paused

    with collector_paused("torch"):
        import mosegpipe.embed.model  # noqa: F401  (torch: imported like the start-up imports, see collector_paused)
    net = load_model(frames, checkpoint)
    if copy is not None and net.cfg.arch == "subspacenet":
        try:
            copy.parent.mkdir(parents=True, exist_ok=True)
            NumpySubspaceNet.from_torch(net).save_npz(copy)
        except OSError as exc:
            log.debug("cannot keep an inference copy in %s: %s", folder, exc)
    return net
