"""Dense-mask methods compared on the rendered clips, printed as a Markdown table.

    python benchmarks/masks.py [--seeds 10] [--model PATH]

The 10 clips of `moseg eval rendered` (mosegpipe.evaluation.e2e.rendered_config, 640x480, 5 frames)
go through the pipeline once; then every densifier turns the same tracks and the same cluster labels
into masks, and the ground-truth label of each track ("true labels") as well. Scores: J and boundary
F per frame and object (DAVIS; background matched but not averaged), mean over clips; ms per frame
of the densifier alone. One thread.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from mosegpipe.embed.model import SubspaceNet
from mosegpipe.evaluation.e2e import rendered_config
from mosegpipe.evaluation.metrics import mask_scores
from mosegpipe.masks import UNKNOWN, MaskConfig, labels_to_masks
from mosegpipe.pipeline import PipelineConfig, load_model, segment_frames
from mosegpipe.runtime import set_threads
from mosegpipe.synth.render import render_clip

VARIANTS = {
    "nearest": MaskConfig(method="nearest"),
    "vote": MaskConfig(method="vote"),
    "watershed (default)": MaskConfig(method="watershed"),
    "watershed, min_agree=2": MaskConfig(method="watershed", min_agree=2),
    "watershed, blur_px=3": MaskConfig(method="watershed", blur_px=3),
    "watershed, scale=0.5": MaskConfig(method="watershed", scale=0.5),
}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--model", type=Path, default=None, help="5-frame checkpoint (default: shipped weights)")
    args = ap.parse_args(argv)
    set_threads(1)
    model = SubspaceNet.from_checkpoint(args.model) if args.model else load_model(5)
    scores: dict[str, list[tuple[float, float, float, float, float]]] = {name: [] for name in VARIANTS}
    for seed in range(args.seeds):
        clip = render_clip(rendered_config(seed))
        result = segment_frames(clip.to_frames(), PipelineConfig(), model)
        ids = result.trajectories.track_ids
        truth = clip.label_at(0, result.tracks.xy[ids, 0])
        for name, mcfg in VARIANTS.items():
            t0 = time.perf_counter()
            own = labels_to_masks(result.tracks, ids, result.clustering.labels, mcfg, clip.frames)
            ms = 1000 * (time.perf_counter() - t0) / clip.num_frames
            best = labels_to_masks(result.tracks, ids, truth, mcfg, clip.frames)
            s = mask_scores(own, clip.masks, background=0, unknown=UNKNOWN)
            o = mask_scores(best, clip.masks, background=0, unknown=UNKNOWN)
            scores[name].append((s.j, s.f, o.j, o.f, ms))
    print("| method | J | F | J, true labels | F, true labels | ms / frame |\n|---|---|---|---|---|---|")
    for name, rows in scores.items():
        m = np.mean(np.array(rows), axis=0)
        print(f"| {name} | {m[0]:.3f} | {m[1]:.3f} | {m[2]:.3f} | {m[3]:.3f} | {m[4]:.1f} |")


if __name__ == "__main__":
    main()
