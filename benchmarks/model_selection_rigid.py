"""Model selection with geometry: the K rules of the paper's Table 5, then the rigid-motion check.

    python benchmarks/model_selection_rigid.py runs/eval/kt3d-loo-vanilla [--protocol kt3d-loo] [--frames 5]

Re-scores the fold models a leave-one-out run stored (OUT/folds/<held-out>.pt, `moseg eval kt3d-loo
--out OUT`): each held-out clip is embedded by the model that never saw it, K is chosen by the
silhouette or the residual rule (second-order difference), and then, in the "+ rigid" rows,
`mosegpipe.group.rigid.split_by_rigid_motion` (the pipeline's check, its default settings) splits off the
coherent groups of tracks that their cluster's rigid motion (a fundamental matrix or a homography)
does not explain. Prints a Markdown table: auto-K error mean / median, correct K, K too small / too
large, NMI. Nothing is trained; one thread.
"""

from __future__ import annotations

import argparse
import logging
import os
from pathlib import Path
from typing import Any

import numpy as np


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="a leave-one-out run's --out folder (with folds/*.pt)")
    parser.add_argument("--protocol", default="kt3d-loo")
    parser.add_argument("--frames", type=int, default=5)
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING, format="%(message)s")

    from mosegpipe.embed.model import SubspaceNet
    from mosegpipe.evaluation.benchmark import embed_clip
    from mosegpipe.evaluation.metrics import misclassification_error, nmi
    from mosegpipe.evaluation.protocols import get_protocol
    from mosegpipe.group.cluster import ClusterConfig, cluster_auto_k
    from mosegpipe.group.rigid import split_by_rigid_motion
    from mosegpipe.runtime import set_threads

    set_threads(1)
    protocol = get_protocol(args.protocol)
    if protocol.load_clips is None or protocol.fold_key is None:
        raise SystemExit(f"{args.protocol} is not a leave-one-out protocol on a dataset's trajectories")
    root = Path(os.environ.get("MOSEG_DATA", "../shared/data"))
    rules: dict[str, list[dict[str, Any]]] = {}
    for clip in protocol.load_clips(root, args.frames):
        path = args.out / "folds" / f"{protocol.fold_key(clip).replace('/', '_')}.pt"
        if not path.exists():
            print(f"{clip.name}: no fold model at {path}; left out")
            continue
        emb = embed_clip(SubspaceNet.from_checkpoint(path), clip)
        size_hw = tuple(clip.meta["image_size_hw"])
        for method in ("silhouette", "residual"):
            auto = cluster_auto_k(emb, ClusterConfig(method=method))
            split, _ = split_by_rigid_motion(clip.traj, auto.labels, size_hw)
            for name, labels in ((method, auto.labels), (f"{method} + rigid", split)):
                k = int(np.unique(labels).size)
                rules.setdefault(name, []).append(
                    {
                        "error": misclassification_error(labels, clip.labels),
                        "k": k,
                        "k_true": clip.k,
                        "nmi": nmi(labels, clip.labels),
                    }
                )
    print(f"\n{args.protocol}, fold models of {args.out} ({len(next(iter(rules.values())))} clips)\n")
    print("| K rule | auto-K error mean / median | correct K | K too small / too large | NMI |")
    print("|---|---|---|---|---|")
    for name, rows in rules.items():
        err = np.array([r["error"] for r in rows]) * 100
        k = np.array([r["k"] for r in rows])
        kt = np.array([r["k_true"] for r in rows])
        print(
            f"| {name} | {err.mean():.2f} / {np.median(err):.2f} % | {100 * np.mean(k == kt):.1f} % "
            f"| {int(np.sum(k < kt))} / {int(np.sum(k > kt))} | {np.mean([r['nmi'] for r in rows]):.3f} |"
        )


if __name__ == "__main__":
    main()
