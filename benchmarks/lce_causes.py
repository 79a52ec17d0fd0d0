"""Short LCE runs that look for the cause of the gap to the paper, scored on the val split only.

    python benchmarks/lce_causes.py --out causes.json [--val 60] NAME:STEPS:BATCH:BLOCKS:LOSS:NORM[:LR[:SIGMA[:lift]]] ...
    python benchmarks/lce_causes.py --oracle 100     # the floor: every point to its nearest true curve

Each candidate trains a SubspaceNet (width 64, embedding 5) from scratch on the LCE training split, at a
constant learning rate after the warm-up (as `moseg study lce-curve`), and is scored on the first --val
samples of the val split (never test): error with automatic K and with the true K, NMI. SIGMA != 0.05
regenerates every split with that noise (the curves unchanged); "lift" feeds each point as
(x, y, x^2, xy, y^2, x^2 + y^2) of its clip-normalised coordinates, so that every curve is a hyperplane of
the input ("channel" normalisation advised; no mirroring). Prints a Markdown row per candidate; candidates
already in --out are skipped. One thread.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import time
from pathlib import Path
from typing import Any

import numpy as np


def _lifted(clip: Any) -> Any:
    xy = clip.traj.astype(np.float64)
    xy = xy - xy.mean(0)
    xy = xy / np.sqrt((xy**2).sum(1).mean())
    x, y = xy[:, 0], xy[:, 1]
    feats = np.stack([x, y, x * x, x * y, y * y, x * x + y * y], 1).astype(np.float32)
    return dataclasses.replace(clip, traj=feats)


def _curve(curve: dict[str, Any], n: int = 4000) -> np.ndarray:
    """Dense noise-free points of one generated curve (synth/lce.py parameters)."""
    t = np.linspace(0.0, 2 * np.pi, n)
    if curve["type"] == "line":
        s = np.linspace(-1.5, 1.5, n)  # LCEConfig.line_half_length
        return np.asarray(curve["point"]) + s[:, None] * np.asarray(curve["direction"])
    if curve["type"] == "circle":
        return np.asarray(curve["centre"]) + curve["radius"] * np.stack([np.cos(t), np.sin(t)], 1)
    (a, b), ang = curve["axes"], curve["angle"]
    rot = np.array([[np.cos(ang), np.sin(ang)], [-np.sin(ang), np.cos(ang)]])
    return np.asarray(curve["centre"]) + np.stack([a * np.cos(t), b * np.sin(t)], 1) @ rot


def oracle_error(num: int) -> float:
    """Mean error of giving every point of the first `num` val samples to its nearest true curve."""
    from mosegpipe.synth.lce import lce_splits

    val = lce_splits()["val"]
    errors = []
    for i in range(num):
        clip = val[i]
        dist = [np.linalg.norm(clip.traj[:, None, :] - _curve(c)[None], axis=2).min(1) for c in clip.meta["curves"]]
        errors.append(np.mean(np.argmin(np.stack(dist, 1), 1) != clip.labels))
    return float(np.mean(errors))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--val", type=int, default=60)
    parser.add_argument("--out", type=Path)
    parser.add_argument("--oracle", type=int, default=0, help="print the nearest-true-curve error on N val samples")
    parser.add_argument("cands", nargs="*", help="NAME:STEPS:BATCH:BLOCKS:LOSS:NORM[:LR[:SIGMA[:lift]]]")
    args = parser.parse_args()
    if args.oracle:
        print(f"nearest true curve, first {args.oracle} val samples: {100 * oracle_error(args.oracle):.2f} %")
    if not args.cands:
        return
    if args.out is None:
        parser.error("--out is required with candidates")

    from mosegpipe.runtime import set_threads

    set_threads(1)
    logging.getLogger("mosegpipe.group.cluster").setLevel(logging.ERROR)
    from mosegpipe.embed.model import ModelConfig
    from mosegpipe.studies.lce import run_training, score_clips, train_sampler
    from mosegpipe.synth.lce import LCEConfig, lce_splits
    from mosegpipe.training.loop import train_model

    val = [lce_splits()["val"][i] for i in range(args.val)]
    res = json.loads(args.out.read_text()) if args.out.exists() else {}
    for cand in args.cands:
        f = cand.split(":")
        name, steps, batch, blocks, loss, norm = f[0], int(f[1]), int(f[2]), int(f[3]), f[4], f[5]
        lr = float(f[6]) if len(f) > 6 else 1e-3
        sigma = float(f[7]) if len(f) > 7 else 0.05
        lift = len(f) > 8 and f[8] == "lift"
        if name in res:
            continue
        mc = ModelConfig(in_dim=2, width=64, num_blocks=blocks, embed_dim=5, input_norm=norm)
        cfg = run_training(steps=steps, batch_size=batch, loss=loss, lr=lr)
        if sigma != 0.05:
            splits = lce_splits(cfg=LCEConfig(noise_sigma=sigma))
            train = splits["train"]

            def sampler(rng: np.random.Generator, train: Any = train) -> Any:
                return train[int(rng.integers(len(train)))]

            clips = [splits["val"][i] for i in range(args.val)]
        else:
            sampler, clips = train_sampler(), val
        if lift:
            plain = sampler

            def sampler(rng: np.random.Generator, plain: Any = plain) -> Any:
                return _lifted(plain(rng))

            clips = [_lifted(c) for c in clips]
            mc = dataclasses.replace(mc, in_dim=6)
            cfg = dataclasses.replace(cfg, frames=3, flip=False)
        t0, c0 = time.perf_counter(), time.process_time()
        result = train_model(sampler, cfg, mc, log_every=max(1, steps // 10))
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        s = score_clips(result.model, clips)
        res[name] = {
            **s,
            **{"steps": steps, "batch": batch, "blocks": blocks, "loss": loss, "norm": norm, "lr": lr},
            **{"sigma": sigma, "lift": lift, "samples": steps * batch},
            **{"train_wall_s": round(wall, 1), "train_cpu_s": round(cpu, 1)},
            "loss_hist": [round(h["loss"], 4) for h in result.history],
        }
        args.out.write_text(json.dumps(res, indent=1))
        print(
            f"| {name} | {steps} x {batch} | {blocks} | {loss} | {norm} | {lr:g} | {sigma:g} | "
            f"{100 * s['error']:.2f} | {100 * s['error_true_k']:.2f} | {s['nmi']:.3f} | {cpu:.0f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
