"""Pipeline settings compared on the DAVIS-2016 train clips, printed as a Markdown table.

    python benchmarks/davis_settings.py --set mask.motion.fb_weight=0.5 \
        --set "mask.motion.min_component=0.2 mask.motion.noise_factor=2.5" [--part dev] [--mode whole] [--jobs 2]

Each --set is one variant: space-separated `dotted.field=value` changes of the default PipelineConfig
(`PipelineConfig.with_settings`; values are JSON, a bare word is a string). The defaults run too, as the
reference. Per variant: mean J / F over the part's clips (`moseg eval davis` / `davis-clip5` scores, no
oracle), the change of J against the defaults, and the clips whose J moved most. Variants run in
parallel processes (--jobs), one thread each.

Settings are chosen on the development part (`--part dev`, the default) and the validation part is scored
once after a choice (docs/RESULTS.md, "Real video"). The data root is $MOSEG_DATA or ../shared/data.
"""

from __future__ import annotations

import argparse
import os
import shlex
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from mosegpipe.evaluation.davis import run_davis
from mosegpipe.pipeline import PipelineConfig
from mosegpipe.runtime import set_threads


def _run(args: tuple[str, str, str, list[str]]) -> tuple[float, float, dict[str, float], float]:
    root, mode, part, settings = args
    set_threads(1)
    t0 = time.perf_counter()
    report = run_davis(root, mode, "pipeline", part=part, cfg=PipelineConfig().with_settings(settings), threads=None)
    per_clip = {row.clip: row.j_mean for row in report.rows}
    return report.means[part]["j_mean"], report.means[part]["f_mean"], per_clip, time.perf_counter() - t0


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--set", dest="variants", action="append", default=[], help="one variant: 'a.b=1 c.d=x'")
    ap.add_argument("--part", choices=("dev", "val", "all"), default="dev")
    ap.add_argument("--mode", choices=("whole", "clip5"), default="whole")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--data-root", type=Path, default=Path(os.environ.get("MOSEG_DATA", "../shared/data")))
    args = ap.parse_args(argv)
    variants = [shlex.split(v) for v in args.variants]
    for settings in variants:
        PipelineConfig().with_settings(settings)  # a bad setting fails here, before any clip runs
    root = str(args.data_root)
    jobs = [(root, args.mode, args.part, settings) for settings in [[], *variants]]
    with ProcessPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        results = list(pool.map(_run, jobs))
    (ref_j, _, ref_clips, _) = results[0]
    print(f"DAVIS-2016 train, {args.mode}, {args.part} clips ({len(ref_clips)}), J / F without an oracle\n")
    print("| variant | J | F | J - defaults | clips that moved most (J change) | s |")
    print("|---|---|---|---|---|---|")
    for settings, (j, f, clips, seconds) in zip([[], *variants], results):
        moved = sorted(clips, key=lambda c: -abs(clips[c] - ref_clips[c]))[:3]
        change = ", ".join(f"{c} {clips[c] - ref_clips[c]:+.3f}" for c in moved if clips[c] != ref_clips[c])
        name = " ".join(settings) or "defaults"
        print(f"| {name} | {j:.3f} | {f:.3f} | {j - ref_j:+.3f} | {change or '-'} | {seconds:.0f} |")


if __name__ == "__main__":
    main()
