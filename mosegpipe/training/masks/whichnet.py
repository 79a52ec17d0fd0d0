"""`moseg train --preset whichnet`: trains the per-motion network that `mosegpipe/weights/whichnet.pt` ships.

Its data are the mask network's frames with two or more moving objects (`learned.data`: the rendered clips with
their per-object masks, the development composites that use no held-out clip), each with the frame's corners as
the tracker finds them (OpenCV's Shi-Tomasi with the tracker's settings) labelled by the object under them
(`WhichFrames`). A training crop asks about one of the frame's moving motions: the corners' labels are spoiled
first as a clustering spoils them (`WhichTrainConfig.flip_share`: labels moved to another motion or to the world;
`merge_share`: two motions given one label; `keep_share`: some tracks lost), then `which.query_channels` is drawn
from them. The loss is binary cross-entropy on the pixels of moving objects only (which motion; whether the pixel
moves is the other network's question). The rendered clips whose index is a multiple of `held_every` are held out:
every `eval_every` steps the share of their moving pixels that `which.which_motion`'s argmax assigns right (clean
labels) scores the network, and the best step is kept. Seeded, one torch thread: the same data give the same weights.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt
import torch
import torch.nn.functional as F

from mosegpipe.configs.tracking import TrackConfig
from mosegpipe.masks.learned.features import NUM_CHANNELS, net_size
from mosegpipe.masks.learned.net import WIDTHS, MaskNet
from mosegpipe.masks.learned.which import QUERY_CHANNELS, asked_inputs, query_channels
from mosegpipe.training.masks.data import DataConfig, load_source, render_config, rendered_images, training_composites
from mosegpipe.training.masks.masknet import fit, one_thread
from mosegpipe.types import WHICHNET_PRESET

log = logging.getLogger(__name__)

SPLIT_LABEL = 200
"""`spoiled`: object o's split-off tracks take label SPLIT_LABEL + o (below the masks' reserved 254, above any id)."""


@dataclass(frozen=True)
class WhichTrainConfig:
    """The whichnet recipe.

    Attributes:
        steps: optimiser steps.
        batch_size: crops per step.
        lr: peak learning rate (cosine decay to 2 % of it).
        weight_decay: AdamW's.
        crop_hw: crop size at the network's input size (h, w).
        on_object_share: share of crops centred on a moving object's pixel (the rest anywhere).
        flip_share: per crop, each corner's label moves with a chance drawn in [0, this) to another motion or the world.
        merge_share: share of crops (frames with 3+ motions) whose two motions carry one label.
        split_share: share of crops where one object's tracks carry two labels (a minority, 10-45 %, a label of
            their own); the object's pixels are the majority label's.
        keep_share: per crop, the share of corners kept is drawn in [this, 1].
        min_pixels: a moving object takes part in a frame from this many pixels at the network's size.
        held_every: rendered clips whose index is a multiple of this are held out (score and step only).
        eval_every: steps between held-out scores.
        appearance_dropout: share of crops whose Lab channels are set to 0.
        seed: numpy and torch seed.
        widths: the network's channels per level.
        data: the sources' settings (`learned.data.DataConfig`, the mask network's).
    """

    steps: int = 3000
    batch_size: int = 16
    lr: float = 3e-3
    weight_decay: float = 1e-4
    crop_hw: tuple[int, int] = (64, 112)
    on_object_share: float = 0.8
    flip_share: float = 0.15
    merge_share: float = 0.2
    split_share: float = 0.3
    keep_share: float = 0.4
    min_pixels: int = 20
    held_every: int = 5
    eval_every: int = 250
    appearance_dropout: float = 0.3
    seed: int = 0
    widths: tuple[int, ...] = WIDTHS
    data: DataConfig = field(default_factory=DataConfig)


@dataclass
class WhichFrames:
    """Frames with 2+ moving objects: network inputs, object ids and labelled corners, all at the network's size.

    Attributes:
        features: per frame, (NUM_CHANNELS, h, w) float16.
        ids: per frame, (h, w) uint8 id of the moving object at each pixel (0 = the world).
        corners: per frame, (N, 2) float32 corner positions.
        corner_ids: per frame, (N,) uint8 the object id under each corner (0 = the world).
        names: per frame, "<source>/<clip>/<t>".
    """

    features: list[npt.NDArray[np.float16]] = field(default_factory=list)
    ids: list[npt.NDArray[np.uint8]] = field(default_factory=list)
    corners: list[npt.NDArray[np.float32]] = field(default_factory=list)
    corner_ids: list[npt.NDArray[np.uint8]] = field(default_factory=list)
    names: list[str] = field(default_factory=list)


def _present(ids: npt.NDArray[np.uint8], min_pixels: int) -> npt.NDArray[np.int64]:
    """The object ids (1..255) of an id image with at least `min_pixels` pixels."""
    return np.flatnonzero(np.bincount(ids.ravel(), minlength=256)[1:] >= min_pixels) + 1


def frame_corners(image: npt.NDArray[np.uint8], track: TrackConfig = TrackConfig()) -> npt.NDArray[np.float32]:
    """(N, 2) float32 Shi-Tomasi corners of an RGB frame with the tracker's settings (full-resolution pixels)."""
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    found = cv2.goodFeaturesToTrack(
        grey, track.max_corners, track.quality_level, track.min_distance_px, blockSize=track.block_size
    )
    return np.zeros((0, 2), np.float32) if found is None else found.reshape(-1, 2).astype(np.float32)


def add_clip(
    out: WhichFrames,
    images: npt.NDArray[np.uint8],
    ids: npt.NDArray[np.uint8],
    features: dict[str, npt.NDArray[np.float16]],
    name: str,
    cfg: WhichTrainConfig,
) -> None:
    """Appends a clip's frames with 2+ moving objects (`cfg.min_pixels` each) to `out`; `features` by frame name
    (`learned.data.load_source`'s, "<name>/<t>")."""
    hw = net_size(images.shape[1:3], cfg.data.scale)
    to_net = np.array([hw[1] / images.shape[2], hw[0] / images.shape[1]], np.float32)
    for t in range(len(images)):
        small = cv2.resize(ids[t], (hw[1], hw[0]), interpolation=cv2.INTER_NEAREST)
        if len(_present(small, cfg.min_pixels)) < 2 or f"{name}/{t}" not in features:
            continue
        xy = frame_corners(images[t])
        p = np.clip(np.round(xy).astype(np.int64), 0, [images.shape[2] - 1, images.shape[1] - 1])
        out.features.append(features[f"{name}/{t}"])
        out.ids.append(small)
        out.corners.append((xy + 0.5) * to_net - 0.5)
        out.corner_ids.append(ids[t][p[:, 1], p[:, 0]])
        out.names.append(f"{name}/{t}")


def which_frames(root: str | Path, cfg: WhichTrainConfig) -> tuple[WhichFrames, WhichFrames]:
    """(training, held-out) frames: the rendered clips (held out: every `held_every`-th) and the composites (held
    out: those that use a held-out development clip) of the mask network's sources."""
    from mosegpipe.synth.render import render_clip
    from mosegpipe.training.own_tracks import texture_photos

    train, held = WhichFrames(), WhichFrames()
    rendered = load_source("rendered", root, cfg.data)
    by_name = dict(zip(rendered.names, rendered.features))
    photos = [im for _, im in texture_photos(root)]
    for i in range(cfg.data.rendered_clips):
        clip = render_clip(render_config(cfg.data, i), photos)
        images = rendered_images(cfg.data, i, clip.frames)
        add_clip(held if i % cfg.held_every == 0 else train, images, clip.masks, by_name, f"rendered/{i}", cfg)
    for part, held_out in ((train, False), (held, True)):
        composites = load_source("composites-held-out" if held_out else "composites", root, cfg.data)
        by_name = dict(zip(composites.names, composites.features))
        for comp, moving in training_composites(root, cfg.data, held_out):
            add_clip(part, comp.frames, moving, by_name, f"composite/{comp.name}", cfg)
    log.info("whichnet data: %d training frames, %d held out", len(train.names), len(held.names))
    return train, held


def spoiled(
    rng: np.random.Generator, ids: npt.NDArray[np.uint8], present: npt.NDArray[np.int64], cfg: WhichTrainConfig
) -> npt.NDArray[np.int64]:
    """The corners' object ids as a clustering might label them: two motions merged, an object's tracks split
    between its label and a label of its own (a window's new label beside the one the tracks carried over),
    some flipped to another motion or to the world (0), some lost (-1)."""
    out = ids.astype(np.int64)
    if len(present) >= 3 and rng.random() < cfg.merge_share:
        a, b = rng.choice(present, 2, replace=False)
        out[out == b] = a
        present = present[present != b]
    if len(present) and rng.random() < cfg.split_share:
        o = int(rng.choice(present))
        own = np.flatnonzero(out == o)
        out[own[rng.random(len(own)) < rng.uniform(0.1, 0.45)]] = SPLIT_LABEL + o
    flip = rng.random(len(out)) < rng.uniform(0.0, cfg.flip_share)
    out[flip] = rng.choice(np.append(present, 0), int(flip.sum()))
    out[rng.random(len(out)) > rng.uniform(cfg.keep_share, 1.0)] = -1
    return out


def _members(
    truth: npt.NDArray[np.uint8], labels: npt.NDArray[np.int64], present: npt.NDArray[np.int64], query: int
) -> npt.NDArray[np.int64]:
    """The objects whose corners carry label `query` most often (the pixels the question is about; none for a
    label that is no object's first)."""
    members = []
    for o in present:
        own = labels[(truth == o) & (labels >= 0)]
        if len(own) and np.bincount(own).argmax() == query:
            members.append(int(o))
    return np.array(members, np.int64)


def _crop_at(rng: np.random.Generator, ids: npt.NDArray[np.uint8], cfg: WhichTrainConfig) -> tuple[int, int]:
    h, w = ids.shape
    ch, cw = min(cfg.crop_hw[0], h), min(cfg.crop_hw[1], w)
    ys, xs = np.nonzero(ids)
    if len(ys) and rng.random() < cfg.on_object_share:
        i = int(rng.integers(len(ys)))
        return int(np.clip(ys[i] - ch // 2, 0, h - ch)), int(np.clip(xs[i] - cw // 2, 0, w - cw))
    return int(rng.integers(h - ch + 1)), int(rng.integers(w - cw + 1))


def sample(
    rng: np.random.Generator, data: WhichFrames, i: int, cfg: WhichTrainConfig
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
    """One crop of frame i: (NUM_CHANNELS + QUERY_CHANNELS, ch, cw) inputs and (2, ch, cw) target and loss weight."""
    ids, hw = data.ids[i], data.ids[i].shape
    present = _present(ids, cfg.min_pixels)
    labels = spoiled(rng, data.corner_ids[i], present, cfg)
    moving = labels > 0
    groups = np.unique(labels[moving])
    query = int(rng.choice(groups)) if len(groups) else int(present[0])
    members = _members(data.corner_ids[i], labels, present, query)
    x = np.concatenate(
        [data.features[i].astype(np.float32), query_channels(data.corners[i][moving], labels[moving], query, hw)]
    )
    target = np.stack([np.isin(ids, members), ids > 0]).astype(np.float32)
    y0, x0 = _crop_at(rng, ids, cfg)
    ch, cw = min(cfg.crop_hw[0], hw[0]), min(cfg.crop_hw[1], hw[1])
    x, target = x[:, y0 : y0 + ch, x0 : x0 + cw], target[:, y0 : y0 + ch, x0 : x0 + cw]
    if (ch, cw) != cfg.crop_hw:
        pad = ((0, 0), (0, cfg.crop_hw[0] - ch), (0, cfg.crop_hw[1] - cw))
        x, target = np.pad(x, pad, mode="edge"), np.pad(target, pad)
    if rng.random() < 0.5:  # left-right flip: the flow's x component changes sign
        x, target = x[:, :, ::-1].copy(), target[:, :, ::-1].copy()
        x[4] = -x[4]
    if rng.random() < cfg.appearance_dropout:
        x[6:9] = 0.0
    return x, target


def which_loss(logits: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Binary cross-entropy of the queried motion's pixels, over the moving objects' pixels only."""
    weight = target[:, 1]
    bce = F.binary_cross_entropy_with_logits(logits[:, 0], target[:, 0], reduction="none")
    return (bce * weight).sum() / weight.sum().clamp(min=1.0)


def held_out_accuracy(net: MaskNet, held: WhichFrames, cfg: WhichTrainConfig) -> npt.NDArray[np.float64]:
    """(2,): the share of the held-out frames' moving pixels assigned their object by the network's argmax over
    the motions, and by the nearest moving corner (the baseline); mean over frames. The corners' labels are
    spoiled as in training but for merges (`spoiled`, seeded by the frame's index: the same in every call)."""
    from mosegpipe.masks.learned.net import predict

    scores = []
    clean = replace(cfg, merge_share=0.0)
    for i, (f, ids, xy, cid) in enumerate(zip(held.features, held.ids, held.corners, held.corner_ids)):
        present = _present(ids, cfg.min_pixels)
        labels = spoiled(np.random.default_rng([cfg.seed, 7, i]), cid, present, clean)
        motions = np.unique(labels[labels > 0])
        on = ids > 0
        if len(motions) < 2 or not on.any():
            continue
        moving = labels > 0
        queries = np.stack([query_channels(xy[moving], labels[moving], int(m), ids.shape) for m in motions])
        prob = predict(net, asked_inputs(f, queries))
        by_net = motions[np.argmax(prob[:, on], axis=0)]
        by_nearest = motions[np.argmax(queries[:, 1][:, on], axis=0)]
        scores.append([np.mean(by_net == ids[on]), np.mean(by_nearest == ids[on])])
    return np.mean(scores, axis=0)


def train_whichnet(
    out: Path,
    data_root: Path,
    cfg: WhichTrainConfig = WhichTrainConfig(),
    command: str = "",
    on_log: Callable[[dict[str, float]], None] | None = None,
    device: str = "cpu",
) -> dict[str, Any]:
    """Trains the per-motion network by recipe `cfg` and writes the held-out-best checkpoint to `out`; the steps
    run on `device` (as `train.fit`)."""
    with one_thread():
        rng = np.random.default_rng(cfg.seed)
        torch.manual_seed(cfg.seed)
        train, held = which_frames(data_root, cfg)
        net = MaskNet(NUM_CHANNELS + QUERY_CHANNELS, cfg.widths, output="which")

        def batch() -> tuple[torch.Tensor, torch.Tensor]:
            crops = [sample(rng, train, int(rng.integers(len(train.names))), cfg) for _ in range(cfg.batch_size)]
            return torch.from_numpy(np.stack([c[0] for c in crops])), torch.from_numpy(np.stack([c[1] for c in crops]))

        baseline = float(held_out_accuracy(net, held, cfg)[1])
        step, _, best, table, cpu_s = fit(
            net,
            cfg.steps,
            cfg.lr,
            cfg.weight_decay,
            cfg.eval_every,
            batch,
            which_loss,
            lambda n: held_out_accuracy(n, held, cfg)[:1],
            on_log,
            device,
        )
    record = {
        "name": WHICHNET_PRESET,
        "command": command,
        "settings": asdict(cfg),
        "frames": {"train": len(train.names), "held_out": len(held.names)},
        "chosen_step": step,
        "held_out_accuracy": round(best, 4),
        "nearest_track_accuracy": round(baseline, 4),
        "held_out_table": table,
        "cpu_s": round(cpu_s, 1),
    }
    net.eval().save(out, recipe=record)
    return record
