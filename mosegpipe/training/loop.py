"""Training SubspaceNet: samplers of labelled clips, augmentation, the training loop and named presets.

A sampler is any callable `rng -> LabeledClip`; samplers mix (synthetic data generated on the fly, real
benchmark clips) so one loop serves every recipe. Clips of different sizes train together in padded
batches with exact per-clip statistics (see model.pad_batch).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Collection, Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np
import torch

from mosegpipe.embed.model import ModelConfig, SubspaceNet, pad_batch
from mosegpipe.errors import ConfigError
from mosegpipe.training.losses import LOSSES
from mosegpipe.types import DEVICE_CHOICES, LabeledClip, is_device_name

log = logging.getLogger(__name__)

Sampler = Callable[[np.random.Generator], LabeledClip]


@dataclass(frozen=True)
class TrainConfig:
    """Hyper-parameters of one training run, one line each; the loss and the schedule were chosen as
    docs/HISTORY.md tells ("Losses (the paper's Table 2)", "What made the difference, and how it was chosen").

    Attributes:
        frames: trajectory length F the model is trained for (input dimension 2F).
        loss: a name in types.LossName; "l2" scored best in the losses study.
        alpha: MaxInterMinIntra weight of the inter-cluster term.
        steps: optimiser steps.
        batch_size: clips per step (padded batch).
        lr: peak Adam learning rate; cosine decay to lr * lr_min_ratio after `warmup` linear steps.
        lr_min_ratio: final learning rate as a fraction of lr.
        warmup: linear warm-up steps.
        max_points: clips with more points are randomly subsampled to this many per step (speed).
        flip: random horizontal mirroring of whole clips (a mirrored scene is a valid scene).
        reverse: random time reversal of whole clips (motion played backwards is still rigid motion).
        grad_clip: gradient-norm clip.
        seed: seed of the data stream and the initialisation.
        time_budget_s: stop early after this many seconds (None = run all steps).
    """

    frames: int = 5
    loss: str = "l2"
    alpha: float = 0.5
    steps: int = 2000
    batch_size: int = 8
    lr: float = 1e-3
    lr_min_ratio: float = 0.05
    warmup: int = 50
    max_points: int = 600
    flip: bool = True
    reverse: bool = True
    grad_clip: float = 1.0
    seed: int = 0
    time_budget_s: float | None = None


@dataclass
class TrainResult:
    """The trained model (eval mode) with its loss history (one entry per logged step)."""

    model: SubspaceNet
    history: list[dict[str, float]] = field(default_factory=list)
    seconds: float = 0.0
    steps_done: int = 0


@dataclass
class TrainState:
    """Everything needed to continue a run exactly where it stopped (see `train_model`'s `resume`).

    Attributes:
        step: optimiser steps done.
        model_state: the model's state_dict (tensors on the training device).
        optim_state: the Adam optimizer's state_dict.
        rng_state: the numpy data stream's bit-generator state (plain data).
        history: the loss history up to `step`.
        seconds: training time up to `step` (checkpoint callbacks not counted).
    """

    step: int
    model_state: dict[str, Any]
    optim_state: dict[str, Any]
    rng_state: dict[str, Any]
    history: list[dict[str, float]] = field(default_factory=list)
    seconds: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        """Plain dict for torch.save (tensors moved to the CPU; loadable with weights_only=True)."""
        return {
            "step": self.step,
            "model_state": {k: v.detach().cpu() for k, v in self.model_state.items()},
            "optim_state": _to_cpu(self.optim_state),
            "rng_state": self.rng_state,
            "history": self.history,
            "seconds": self.seconds,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TrainState:
        """Inverse of `to_dict`."""
        return cls(
            step=int(data["step"]),
            model_state=data["model_state"],
            optim_state=data["optim_state"],
            rng_state=data["rng_state"],
            history=list(data.get("history", [])),
            seconds=float(data.get("seconds", 0.0)),
        )


def _to_cpu(obj: Any) -> Any:
    if isinstance(obj, torch.Tensor):
        return obj.detach().cpu()
    if isinstance(obj, dict):
        return {k: _to_cpu(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_to_cpu(v) for v in obj]
    return obj


def resolve_device(name: str) -> str:
    """The torch device a `--device` value names, checked: "cpu", "cuda", "cuda:N" or "auto".

    "auto" is cuda when torch sees a GPU and cpu otherwise; nothing picks a GPU unless asked.

    Raises:
        ConfigError: not one of the values above, or a GPU asked for where torch sees none (or not that one).
    """
    value = name.strip().lower()
    if value == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if value == "cpu":
        return "cpu"
    index = value.removeprefix("cuda:") if value.startswith("cuda:") else None
    if not is_device_name(value):
        raise ConfigError(f"--device {name!r}: choose {', '.join(DEVICE_CHOICES)}")
    if not torch.cuda.is_available():
        raise ConfigError(f"--device {name!r}: torch sees no CUDA device here (use cpu or auto)")
    if index is not None and int(index) >= torch.cuda.device_count():
        raise ConfigError(f"--device {name!r}: torch sees {torch.cuda.device_count()} CUDA device(s)")
    return value


def clip_sampler(clips: Sequence[LabeledClip]) -> Sampler:
    """Uniformly draws one of `clips`."""
    if not clips:
        raise ValueError("clip_sampler needs at least one clip")
    items = list(clips)

    def draw(rng: np.random.Generator) -> LabeledClip:
        return items[int(rng.integers(len(items)))]

    return draw


def mixture_sampler(parts: Sequence[tuple[float, Sampler]]) -> Sampler:
    """Draws from one of several samplers with the given (unnormalised) weights."""
    weights = np.array([w for w, _ in parts], dtype=np.float64)
    if weights.size == 0 or not np.all(np.isfinite(weights)) or np.any(weights < 0) or weights.sum() <= 0:
        raise ValueError(f"mixture weights must be non-negative with a positive sum, got {weights.tolist()}")
    probs = weights / weights.sum()
    samplers = [s for _, s in parts]

    def draw(rng: np.random.Generator) -> LabeledClip:
        return samplers[int(rng.choice(len(samplers), p=probs))](rng)

    return draw


def augment(clip: LabeledClip, rng: np.random.Generator, cfg: TrainConfig) -> tuple[np.ndarray, np.ndarray]:
    """Returns an augmented copy of a clip's (traj (N, 2F) float32, labels (N,) int64).

    Subsamples to cfg.max_points (every group keeps at least one point), mirrors x and reverses time at
    random. Scale and translation need no augmentation: the model's input normalisation removes them.
    """
    traj, labels = clip.traj, clip.labels
    n = traj.shape[0]
    if n > cfg.max_points:
        keep = rng.choice(n, size=cfg.max_points, replace=False)
        missing = np.setdiff1d(np.unique(labels), np.unique(labels[keep]))
        if missing.size:
            extra = np.array([int(rng.choice(np.flatnonzero(labels == g))) for g in missing])
            # Make room only at points whose group keeps another member, so no kept group vanishes.
            _, first = np.unique(labels[keep], return_index=True)
            spare = np.setdiff1d(np.arange(keep.size), first)
            drop = rng.choice(spare, size=min(extra.size, spare.size), replace=False)
            keep = np.concatenate([np.delete(keep, drop), extra])
        traj, labels = traj[keep], labels[keep]
    f = traj.shape[1] // 2
    xy = traj.reshape(-1, f, 2).copy()
    if cfg.flip and rng.random() < 0.5:
        xy[:, :, 0] *= -1.0
    if cfg.reverse and rng.random() < 0.5:
        xy = xy[:, ::-1]
    return np.ascontiguousarray(xy.reshape(-1, 2 * f), dtype=np.float32), labels.astype(np.int64)


def _lr_at(step: int, cfg: TrainConfig) -> float:
    if step < cfg.warmup:
        return cfg.lr * (step + 1) / cfg.warmup
    progress = (step - cfg.warmup) / max(1, cfg.steps - cfg.warmup)
    floor = cfg.lr * cfg.lr_min_ratio
    return floor + 0.5 * (cfg.lr - floor) * (1.0 + math.cos(math.pi * min(1.0, progress)))


def train_model(
    sampler: Sampler,
    cfg: TrainConfig = TrainConfig(),
    model_cfg: ModelConfig | None = None,
    init: SubspaceNet | None = None,
    log_every: int = 50,
    on_log: Callable[[dict[str, float]], None] | None = None,
    checkpoints: Collection[int] = (),
    on_checkpoint: Callable[[TrainState, SubspaceNet], None] | None = None,
    resume: TrainState | None = None,
    stop_after: int | None = None,
    device: str | torch.device = "cpu",
) -> TrainResult:
    """Trains SubspaceNet on clips drawn from `sampler`.

    Args:
        sampler: draws LabeledClips whose trajectories have 2 * cfg.frames columns.
        cfg: training hyper-parameters.
        model_cfg: architecture for a fresh model (ignored when `init` is given).
        init: a model to fine-tune (copied; the argument is left untouched).
        log_every: steps between history entries.
        on_log: called with each history entry (e.g. to print progress).
        checkpoints: step counts (1..cfg.steps) after which `on_checkpoint` is called.
        on_checkpoint: called with the state after each checkpoint step and the model (in eval mode
            during the call; it may embed with it, and must not change its weights). The state holds
            the live tensors: save or copy it during the call. Its time is not counted in the
            training seconds.
        resume: continue from this state (a `TrainState` from an earlier call with the same sampler,
            cfg and architecture): the result is the same as one uninterrupted run.
        stop_after: stop after this many steps (<= cfg.steps) without changing the learning-rate
            schedule, which is always that of cfg.steps (None = run all steps).
        device: where the model trains (the returned model stays there).

    Returns:
        TrainResult with the model in eval mode.
    """
    if cfg.loss not in LOSSES:
        raise ConfigError(f"unknown loss {cfg.loss!r}; choose from {sorted(LOSSES)}")
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    model = _initial_model(cfg, model_cfg, init, checkpoints)
    loss_fn = LOSSES[cfg.loss]
    kwargs: dict[str, Any] = {"alpha": cfg.alpha} if cfg.loss.startswith("mimi") else {}
    model.to(device)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    history, first, spent = _resumed(resume, model, opt, rng)
    last = cfg.steps if stop_after is None else min(cfg.steps, stop_after)
    wanted = set(checkpoints)
    model.train()
    t0 = time.perf_counter()
    paused = 0.0  # seconds spent in on_checkpoint, left out of the training time

    def elapsed() -> float:
        return spent + time.perf_counter() - t0 - paused

    running = 0.0
    count = 0
    step = first
    for step in range(first, last):
        if cfg.time_budget_s is not None and elapsed() > cfg.time_budget_s:
            log.info("time budget of %.0f s reached after %d steps", cfg.time_budget_s, step)
            break
        for group in opt.param_groups:
            group["lr"] = _lr_at(step, cfg)
        running += _train_step(model, opt, loss_fn, kwargs, sampler, rng, cfg, device)
        count += 1
        if (step + 1) % log_every == 0 or step + 1 == cfg.steps:
            history.append(_log_entry(step + 1, running / count, _lr_at(step, cfg), elapsed(), on_log))
            running, count = 0.0, 0
        if step + 1 in wanted and on_checkpoint is not None:
            state = TrainState(
                step + 1, model.state_dict(), opt.state_dict(), dict(rng.bit_generator.state), list(history), elapsed()
            )
            paused += _checkpoint(state, model, on_checkpoint)
    else:
        step = last
    if count:  # stopped by the time budget between two log points: keep the last losses
        history.append(_log_entry(step, running / count, _lr_at(step - 1, cfg), elapsed(), on_log))
    model.eval()
    return TrainResult(model=model, history=history, seconds=elapsed(), steps_done=step)


def _initial_model(
    cfg: TrainConfig, model_cfg: ModelConfig | None, init: SubspaceNet | None, checkpoints: Collection[int]
) -> SubspaceNet:
    """The model training starts from (a copy of `init`, else a fresh one); ConfigError when it does
    not fit cfg.frames or a checkpoint step lies outside 1..cfg.steps."""
    if init is not None:
        model = SubspaceNet(init.cfg)
        model.load_state_dict(init.state_dict())
    else:
        model = SubspaceNet(model_cfg or ModelConfig(in_dim=2 * cfg.frames))
    if model.cfg.in_dim != 2 * cfg.frames:
        raise ConfigError(f"model input dimension {model.cfg.in_dim} does not fit {cfg.frames} frames")
    bad = sorted(c for c in checkpoints if not 1 <= c <= cfg.steps)
    if bad:
        raise ConfigError(f"checkpoint steps {bad} outside 1..{cfg.steps}")
    return model


def _resumed(
    resume: TrainState | None, model: SubspaceNet, opt: torch.optim.Optimizer, rng: np.random.Generator
) -> tuple[list[dict[str, float]], int, float]:
    """(history, first step, seconds spent) of the run `resume` continues, its model, optimiser and rng
    state loaded; ([], 0, 0.0) for a fresh run."""
    history: list[dict[str, float]] = []
    first = 0
    spent = 0.0  # training seconds before this call (resumed runs)
    if resume is not None:
        model.load_state_dict(resume.model_state)
        opt.load_state_dict(resume.optim_state)
        rng.bit_generator.state = resume.rng_state
        history, first, spent = list(resume.history), resume.step, resume.seconds
    return history, first, spent


def _train_step(
    model: SubspaceNet,
    opt: torch.optim.Optimizer,
    loss_fn: Callable[..., torch.Tensor],
    kwargs: dict[str, Any],
    sampler: Sampler,
    rng: np.random.Generator,
    cfg: TrainConfig,
    device: str | torch.device,
) -> float:
    """One optimiser step on a batch of augmented clips drawn from `sampler`; returns its loss."""
    batch = [augment(sampler(rng), rng, cfg) for _ in range(cfg.batch_size)]
    x, labels, mask = pad_batch([b[0] for b in batch], [b[1] for b in batch])
    assert labels is not None  # pad_batch returns labels when given labels
    x, labels, mask = x.to(device), labels.to(device), mask.to(device)
    z = model(x, mask)
    loss = loss_fn(z, labels, mask, **kwargs)
    opt.zero_grad(set_to_none=True)
    loss.backward()
    torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.grad_clip)
    opt.step()
    return float(loss.detach())


def _checkpoint(
    state: TrainState, model: SubspaceNet, on_checkpoint: Callable[[TrainState, SubspaceNet], None]
) -> float:
    """on_checkpoint with the model in eval mode; returns the seconds it took (not training time)."""
    t_pause = time.perf_counter()
    model.eval()
    on_checkpoint(state, model)
    model.train()
    return time.perf_counter() - t_pause


def _log_entry(
    step: int, loss: float, lr: float, seconds: float, on_log: Callable[[dict[str, float]], None] | None
) -> dict[str, float]:
    entry = {"step": float(step), "loss": loss, "lr": lr, "seconds": seconds}
    if on_log is not None:
        on_log(entry)
    return entry


def recipe_of(cfg: TrainConfig, sources: dict[str, Any], result: TrainResult | None = None) -> dict[str, Any]:
    """A plain-data description of a training run, stored in checkpoints."""
    recipe: dict[str, Any] = {"train_config": asdict(cfg), "sources": sources}
    if result is not None:
        recipe["seconds"] = round(result.seconds, 1)
        recipe["steps_done"] = result.steps_done
        recipe["final_loss"] = result.history[-1]["loss"] if result.history else None
    return recipe


def with_overrides(cfg: TrainConfig, **overrides: Any) -> TrainConfig:
    """`cfg` with the given fields replaced, ignoring None values (CLI options left unset)."""
    return replace(cfg, **{k: v for k, v in overrides.items() if v is not None})
