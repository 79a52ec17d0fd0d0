"""`moseg train --preset masknet`: trains the mask network that `mosegpipe/weights/masknet.pt` ships.

The recipe (`MaskTrainConfig`): a fixed number of steps of AdamW (cosine learning rate) on batches of
random crops (flipped left-right at random) drawn from the sources of `learned.data` by weight, loss
binary cross-entropy plus soft Dice against the area share of "not the world" per pixel. Every
`eval_every` steps the held-out development clips (`data.HELD_OUT`) score the network at each threshold
of `thresholds` (mean over clips of the mean J per frame, at the network's size); the weights and
threshold of the best score are kept and written, with the table of scores. That rule (held-out clips,
checkpoint and threshold chosen by their J) was fixed before any training result was seen.

Seeded (numpy and torch) and on one torch thread, the same data give the same weights.
"""

from __future__ import annotations

import contextlib
import copy
import logging
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import torch
import torch.nn.functional as F

from mosegpipe.masks.learned.net import WIDTHS, MaskNet
from mosegpipe.training.masks.data import DataConfig, Frames4Net, load_source

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class MaskTrainConfig:
    """The masknet recipe.

    Attributes:
        steps: optimiser steps.
        batch_size: crops per step.
        lr: peak learning rate (cosine decay to 2 % of it).
        weight_decay: AdamW's.
        crop_hw: crop size at the network's input size (h, w).
        sources: (source, weight) pairs of `data.load_source`.
        eval_every: steps between held-out scores.
        thresholds: thresholds scored on the held-out clips.
        dice_weight: weight of the soft Dice term.
        appearance_jitter: per crop, the Lab channels are scaled by 1 + U(-j, j) and shifted by U(-j, j) (0 = off):
            16 training clips' colours are few, and a network that learns them does not carry over.
        appearance_dropout: share of crops whose Lab channels are set to 0 (the motion evidence alone).
        seed: numpy and torch seed.
        widths: the network's channels per level (`net.WIDTHS` by default).
        data: what the sources hold.
    """

    steps: int = 2000
    batch_size: int = 16
    lr: float = 3e-3
    weight_decay: float = 1e-4
    crop_hw: tuple[int, int] = (56, 96)
    sources: tuple[tuple[str, float], ...] = (("davis", 0.45), ("rendered", 0.35), ("composites", 0.2))
    eval_every: int = 250
    thresholds: tuple[float, ...] = (0.3, 0.4, 0.5, 0.6, 0.7)
    dice_weight: float = 0.5
    appearance_jitter: float = 0.3
    appearance_dropout: float = 0.3
    seed: int = 0
    widths: tuple[int, ...] = WIDTHS
    data: DataConfig = field(default_factory=DataConfig)


def _crop(
    rng: np.random.Generator,
    feats: npt.NDArray[np.float16],
    truth: npt.NDArray[np.float16],
    hw: tuple[int, int],
    appearance: tuple[float, float] = (0.0, 0.0),
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
    h, w = truth.shape
    ch, cw = min(hw[0], h), min(hw[1], w)
    y, x = int(rng.integers(h - ch + 1)), int(rng.integers(w - cw + 1))
    f = feats[:, y : y + ch, x : x + cw].astype(np.float32)
    t = truth[y : y + ch, x : x + cw].astype(np.float32)
    if ch < hw[0] or cw < hw[1]:  # a frame smaller than the crop: padded by its border
        pad = ((0, hw[0] - ch), (0, hw[1] - cw))
        f = np.pad(f, ((0, 0), *pad), mode="edge")
        t = np.pad(t, pad, mode="edge")
    if rng.random() < 0.5:  # left-right flip: the flow's x component changes sign
        f, t = f[:, :, ::-1].copy(), t[:, ::-1].copy()
        f[4] = -f[4]
    jitter, dropout = appearance
    if jitter > 0:
        f[6:9] = f[6:9] * (1 + rng.uniform(-jitter, jitter, (3, 1, 1))) + rng.uniform(-jitter, jitter, (3, 1, 1))
    if dropout > 0 and rng.random() < dropout:
        f[6:9] = 0.0
    return f, t


def _batch(
    rng: np.random.Generator, data: list[Frames4Net], weights: npt.NDArray[np.float64], cfg: MaskTrainConfig
) -> tuple[torch.Tensor, torch.Tensor]:
    feats, truths = [], []
    for _ in range(cfg.batch_size):
        src = data[int(rng.choice(len(data), p=weights))]
        i = int(rng.integers(len(src.features)))
        f, t = _crop(rng, src.features[i], src.truth[i], cfg.crop_hw, (cfg.appearance_jitter, cfg.appearance_dropout))
        feats.append(f)
        truths.append(t)
    return torch.from_numpy(np.stack(feats)), torch.from_numpy(np.stack(truths))


def mask_loss(logits: torch.Tensor, truth: torch.Tensor, dice_weight: float = 0.5) -> torch.Tensor:
    """Binary cross-entropy plus `dice_weight` x soft Dice; logits (B, 1, h, w), truth (B, h, w) in [0, 1]."""
    z = logits[:, 0]
    bce = F.binary_cross_entropy_with_logits(z, truth)
    p = torch.sigmoid(z)
    dice = 1 - (2 * (p * truth).sum() + 1) / (p.sum() + truth.sum() + 1)
    return bce + dice_weight * dice


def held_out_scores(net: MaskNet, held: Frames4Net, thresholds: tuple[float, ...]) -> npt.NDArray[np.float64]:
    """(len(thresholds),) mean over the held-out clips of their mean J per frame, at the network's size."""
    from mosegpipe.masks.learned.net import predict

    per_clip: dict[str, list[npt.NDArray[np.float64]]] = {}
    for f, t, name in zip(held.features, held.truth, held.names):
        prob = predict(net, f[None].astype(np.float32))[0]
        gt = t.astype(np.float32) > 0.5
        js = []
        for thr in thresholds:
            pred = prob > thr
            union = (pred | gt).sum()
            js.append(1.0 if union == 0 else float((pred & gt).sum() / union))
        per_clip.setdefault(name.rsplit("/", 1)[0], []).append(np.array(js))
    return np.mean([np.mean(v, axis=0) for v in per_clip.values()], axis=0)


def train_masknet(
    out: Path,
    data_root: Path,
    cfg: MaskTrainConfig = MaskTrainConfig(),
    command: str = "",
    on_log: Callable[[dict[str, float]], None] | None = None,
    device: str = "cpu",
) -> dict[str, Any]:
    """Trains the mask network by recipe `cfg` and writes the held-out-best checkpoint to `out`.

    Args:
        device: the torch device the steps run on (checked by the caller: `training.loop.resolve_device`);
            the held-out scores and the checkpoint are the CPU's.

    Returns:
        The recipe record stored in the checkpoint (settings, chosen step and threshold, scores).
    """
    with one_thread():
        return run_training(out, data_root, cfg, command, on_log, device)


@contextlib.contextmanager
def one_thread() -> Iterator[None]:
    """Torch on one thread while a recipe trains (one thread gives the same sums in the same order every time);
    the thread count before comes back after."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


def fit(
    net: MaskNet,
    steps: int,
    lr: float,
    weight_decay: float,
    eval_every: int,
    batch: Callable[[], tuple[torch.Tensor, torch.Tensor]],
    loss_fn: Callable[[torch.Tensor, torch.Tensor], torch.Tensor],
    score: Callable[[MaskNet], npt.NDArray[np.float64]],
    on_log: Callable[[dict[str, float]], None] | None = None,
    device: str = "cpu",
) -> tuple[int, int, float, list[dict[str, Any]], float]:
    """AdamW (5 % warm-up, cosine decay to 2 %) on `batch()`es by `loss_fn`; every `eval_every` steps `score(net)`
    gives a score per choice (thresholds, ...), and the weights of the best (step, choice) are loaded into `net`.
    The steps run on `device`; `score` and the network returned are on the CPU.

    Returns:
        (best step, index of the best choice, its score, the table of scores per evaluation, CPU seconds).
    """
    opt = torch.optim.AdamW(net.parameters(), lr=lr, weight_decay=weight_decay)
    warm = max(1, steps // 20)
    sched = torch.optim.lr_scheduler.LambdaLR(
        opt, lambda s: min(1.0, (s + 1) / warm) * (0.02 + 0.98 * 0.5 * (1 + np.cos(np.pi * min(s, steps) / steps)))
    )
    best: tuple[float, int, int, dict[str, torch.Tensor]] | None = None
    table = []
    start, running = time.process_time(), 0.0
    net.to(device).train()
    for step in range(1, steps + 1):
        x, t = batch()
        loss = loss_fn(net(x.to(device)), t.to(device))
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        running += loss.item()
        if step % eval_every == 0 or step == steps:
            scores = score(net.cpu().eval())
            net.to(device).train()
            k = int(np.argmax(scores))
            table.append({"step": step, "j": [round(float(s), 4) for s in scores]})
            entry = {"step": float(step), "loss": running / eval_every, "held_out_j": float(scores[k])}
            entry.update(choice=float(k), cpu_s=time.process_time() - start)
            log.info("%s step %d: %s", net.output, step, entry)
            if on_log is not None:
                on_log(entry)
            running = 0.0
            if best is None or scores[k] > best[0]:
                best = (float(scores[k]), step, k, copy.deepcopy(net.state_dict()))
    assert best is not None
    net.cpu().load_state_dict(best[3])
    return best[1], best[2], best[0], table, time.process_time() - start


def run_training(
    out: Path,
    data_root: Path,
    cfg: MaskTrainConfig,
    command: str,
    on_log: Callable[[dict[str, float]], None] | None,
    device: str,
) -> dict[str, Any]:
    rng = np.random.default_rng(cfg.seed)
    torch.manual_seed(cfg.seed)
    data = [load_source(name, data_root, cfg.data) for name, _ in cfg.sources]
    held = load_source("held-out", data_root, cfg.data)
    weights = np.array([w for _, w in cfg.sources], np.float64)
    weights /= weights.sum()
    net = MaskNet(widths=cfg.widths)

    def logged(entry: dict[str, float]) -> None:
        if on_log is not None:
            on_log({**entry, "threshold": cfg.thresholds[int(entry["choice"])]})

    step, k, best, table, cpu_s = fit(
        net,
        cfg.steps,
        cfg.lr,
        cfg.weight_decay,
        cfg.eval_every,
        lambda: _batch(rng, data, weights, cfg),
        lambda logits, t: mask_loss(logits, t, cfg.dice_weight),
        lambda n: held_out_scores(n, held, cfg.thresholds),
        logged,
        device,
    )
    record = {
        "name": "masknet",
        "command": command,
        "settings": asdict(cfg),
        "frames": {name: len(d.features) for (name, _), d in zip(cfg.sources, data)},
        "chosen_step": step,
        "threshold": cfg.thresholds[k],
        "held_out_j": round(best, 4),
        "held_out_table": table,
        "cpu_s": round(cpu_s, 1),
    }
    net.eval().save(out, recipe=record)
    return record
