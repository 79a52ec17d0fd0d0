"""The cheap probe that chose the configurations of `moseg study lce-curve`, printed as a Markdown table.

    python benchmarks/lce_probe.py [--steps 500] [--val 60] [--out probe.json]

Every candidate trains --steps steps of 16 LCE training samples from scratch at a constant learning
rate after the warm-up (as in the study) and is scored on the first --val samples of the LCE *val*
split (never the test split): error with automatic K and with the true K, NMI. The study compares
the current `lce` recipe with the two alternatives of lowest val error with the true K.
One thread (mosegpipe.runtime.set_threads(1)); candidates run one after another.
"""

from __future__ import annotations

import argparse
import json
import logging
import time
from pathlib import Path
from typing import Any


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=500)
    parser.add_argument("--val", type=int, default=60, help="first this many val samples are scored")
    parser.add_argument("--out", type=Path, default=None, help="also write the scores as JSON")
    args = parser.parse_args()

    from mosegpipe.runtime import set_threads

    set_threads(1)
    logging.getLogger("mosegpipe.group.cluster").setLevel(logging.ERROR)  # K-ambiguity warnings per clip

    from mosegpipe.embed.model import ModelConfig
    from mosegpipe.studies.lce import run_training, score_clips, train_sampler
    from mosegpipe.synth.lce import lce_splits
    from mosegpipe.training.loop import train_model

    candidates: dict[str, tuple[dict[str, Any], dict[str, Any]]] = {
        "recipe (30 x 64, shared, l2, lr 1e-3)": ({}, {}),
        "8 x 128": ({"width": 128, "num_blocks": 8}, {}),
        "8 x 128, lr 3e-3": ({"width": 128, "num_blocks": 8}, {"lr": 3e-3}),
        "channel input norm": ({"input_norm": "channel"}, {}),
        "lr 3e-3": ({}, {"lr": 3e-3}),
        "ce loss": ({}, {"loss": "ce"}),
    }
    val = [lce_splits()["val"][i] for i in range(args.val)]
    scores: dict[str, dict[str, Any]] = {}
    print(f"| candidate ({args.steps} steps x 16) | val error auto K (%) | val error true K (%) | val NMI | train s |")
    print("|---|---|---|---|---|")
    for name, (model_kw, train_kw) in candidates.items():
        model_cfg = ModelConfig(**{"in_dim": 2, "width": 64, "num_blocks": 30, "embed_dim": 5, **model_kw})
        cfg = run_training(steps=args.steps, **train_kw)
        t0 = time.perf_counter()
        result = train_model(train_sampler(), cfg, model_cfg, log_every=100)
        seconds = time.perf_counter() - t0
        s = score_clips(result.model, val)
        scores[name] = {**s, "train_seconds": round(seconds, 1), "loss": [round(h["loss"], 4) for h in result.history]}
        print(
            f"| {name} | {100 * s['error']:.2f} | {100 * s['error_true_k']:.2f} | {s['nmi']:.3f} | {seconds:.0f} |",
            flush=True,
        )
    if args.out is not None:
        args.out.write_text(json.dumps(scores, indent=1))


if __name__ == "__main__":
    main()
