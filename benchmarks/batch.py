"""Clips per minute of `moseg batch` on this machine: 1 job, N jobs and Ray, on one set of clips, in one run.

    python benchmarks/batch.py [--data-root ../shared/data] [--copies 2] [--jobs N] [--no-ray] [--no-rrd]

The clips are the 22 KT3DMoSeg frame folders (1242x375, the first 5 frames of each are segmented),
each linked --copies times under another name, so every engine gets the same work. Each engine
writes into a fresh output folder with the batch defaults (automatic K, Rerun recording on):

- inline: one clip after another in this process; gives the per-clip cost (CPU seconds from
  time.process_time, the process's peak RSS, output bytes) that docs/SCALING.md extrapolates;
- process, 1 job and N jobs (default: the cores): the process pool, pool start-up included;
- ray, N jobs: a local Ray instance started first (its start-up is reported on its own), then the
  batch on it, the workers' first imports included ("once started"), then Ray is shut down.

The three pool engines run --repeats times each, in rotating order, and the best run of each is
shown. Speed-ups are ratios to `process, 1 job` in the same invocation. The machine may be shared:
the load average is printed after every run.
"""

from __future__ import annotations

import argparse
import logging
import os
import resource
import shutil
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from speed import machine_info  # noqa: E402

from mosegpipe.apps.batch.run import run_batch  # noqa: E402
from mosegpipe.pipeline import PipelineConfig, load_model  # noqa: E402
from mosegpipe.runtime import set_threads  # noqa: E402

_DEFAULT_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def make_clips(data_root: Path, folder: Path, copies: int) -> int:
    """Links each KT3DMoSeg frame folder `copies` times into `folder`; returns the number of clips."""
    frames = data_root / "kt3dmoseg" / "frames"
    seqs = sorted(p for p in frames.iterdir() if p.is_dir())
    if not seqs:
        raise SystemExit(f"{frames}: no frame folders (use --data-root)")
    for c in range(copies):
        for seq in seqs:
            (folder / f"{seq.name}-copy{c}").symlink_to(seq, target_is_directory=True)
    return copies * len(seqs)


def folder_bytes(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())


def run(label: str, clips: Path, out: Path, cfg: PipelineConfig, rrd: bool, **kwargs: Any) -> dict[str, Any]:
    shutil.rmtree(out, ignore_errors=True)
    t0 = time.perf_counter()
    rows = run_batch(clips, out, cfg, rrd=rrd, **kwargs)
    wall = time.perf_counter() - t0
    failed = [r for r in rows if r["status"] != "ok"]
    if failed:
        raise SystemExit(f"{label}: {len(failed)} clips not ok, e.g. {failed[0]}")
    load = os.getloadavg()[0]
    print(f"  {label}: {len(rows)} clips in {wall:.1f} s (load average {load:.2f})", flush=True)
    return {"label": label, "clips": len(rows), "wall": wall, "rows": rows, "load": load}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data-root", type=Path, default=Path(os.environ.get("MOSEG_DATA", _DEFAULT_DATA)))
    ap.add_argument("--copies", type=int, default=2, help="links per KT3DMoSeg clip (22 clips each)")
    ap.add_argument("--jobs", type=int, default=len(os.sched_getaffinity(0)), help="N (default: the cores)")
    ap.add_argument("--no-ray", action="store_true", help="leave Ray out")
    ap.add_argument("--no-rrd", action="store_true", help="no Rerun recordings")
    ap.add_argument("--repeats", type=int, default=2, help="runs per engine, in rotating order; the best is shown")
    args = ap.parse_args()
    set_threads(1)
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")
    cfg = PipelineConfig(frames=5)
    rrd = not args.no_rrd
    print(machine_info(), flush=True)
    work = Path(tempfile.mkdtemp(prefix="moseg-batch-bench-"))
    try:
        clips = work / "clips"
        clips.mkdir()
        n = make_clips(args.data_root, clips, args.copies)
        print(f"{n} clips (KT3DMoSeg x {args.copies}), 5 frames each, recording {'on' if rrd else 'off'}", flush=True)
        model = load_model(5)  # warm the imports and the weights for the inline run

        cpu0 = time.process_time()
        inline = run("inline", clips, work / "out-inline", cfg, rrd, model=model, engine="inline")
        inline["cpu"] = time.process_time() - cpu0
        inline["maxrss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        inline["bytes"] = folder_bytes(work / "out-inline")

        engines: list[tuple[str, dict[str, Any]]] = [
            ("process, 1 job", {"jobs": 1}),
            (f"process, {args.jobs} jobs", {"jobs": args.jobs}),
        ]
        if not args.no_ray:
            engines.append((f"ray, {args.jobs} jobs", {"engine": "ray", "jobs": args.jobs}))
        best: dict[str, dict[str, Any]] = {}
        ray_starts: list[float] = []
        for round_ in range(args.repeats):
            shift = round_ % len(engines)  # rotate the order: slow drifts in the machine's load hit every engine
            for i, (label, kwargs) in enumerate(engines[shift:] + engines[:shift]):
                if kwargs.get("engine") == "ray":
                    import ray

                    t0 = time.perf_counter()
                    ray.init(
                        num_cpus=args.jobs, include_dashboard=False, logging_level=logging.WARNING, log_to_driver=False
                    )
                    ray_starts.append(time.perf_counter() - t0)
                    try:
                        r = run(label, clips, work / f"out-{i}", cfg, rrd, **kwargs)
                    finally:
                        ray.shutdown()
                else:
                    r = run(label, clips, work / f"out-{i}", cfg, rrd, **kwargs)
                if label not in best or r["wall"] < best[label]["wall"]:
                    best[label] = r
        results = [inline] + [best[label] for label, _ in engines]
        ray_start = min(ray_starts) if ray_starts else None
    finally:
        shutil.rmtree(work, ignore_errors=True)

    base = results[1]["clips"] / results[1]["wall"]
    print(f"\nbest of {args.repeats} runs per engine (inline: one run)")
    print("| engine | wall s | clips / min | speed-up vs process, 1 job | load average after (1 min) |")
    print("|---|---:|---:|---:|---:|")
    for r in results:
        rate = r["clips"] / r["wall"]
        print(f"| {r['label']} | {r['wall']:.1f} | {60 * rate:.1f} | {rate / base:.2f}x | {r['load']:.2f} |")
    if ray_start is not None:
        ray_rate = results[-1]["clips"] / results[-1]["wall"]
        pn_rate = results[2]["clips"] / results[2]["wall"]
        print(
            f"\nRay start-up (ray.init, local, {args.jobs} CPUs, best): {ray_start:.1f} s, not in the table; "
            f"ray / process with {args.jobs} jobs: {ray_rate / pn_rate:.2f}"
        )
    secs = sorted(float(r["seconds"]) for r in inline["rows"])
    print(
        f"\nper clip (inline, one thread): {inline['cpu'] / n:.2f} CPU s (process_time, imports excluded), "
        f"wall median {secs[len(secs) // 2]:.2f} s (min {secs[0]:.2f}, max {secs[-1]:.2f}), "
        f"peak RSS of the process {inline['maxrss_mb']:.0f} MB, outputs {inline['bytes'] / n / 1e6:.2f} MB"
    )
    print(machine_info().split(" · ")[-1] + " (after)")


if __name__ == "__main__":
    main()
