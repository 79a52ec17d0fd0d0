"""Size of a whole-video run's outputs, and the first-use cost of the Rerun recording.

    python benchmarks/output_size.py [--data-root ../shared/data] [--frames-limit N] [--keep DIR] [--trails-row]
    python benchmarks/output_size.py --startup [--repeats 5]

(a) Sizes (default): `moseg run VIDEO --whole` (mosegpipe.apps.outputs.write_video_outputs, shipped
    5-frame model, default settings) on videos/vtest.avi (795 frames, 768x576), once with the
    recording's frames as one JPEG per frame (VizConfig(video_frames="jpeg"), the recording
    before) and once as one H.264 video asset with a VideoFrameReference per frame (the default).
    Prints overlay.mp4, recording.rrd, their total and the total per frame, and the ratios
    new/old. --trails-row adds a run without track trails (what the trails cost);
    --frames-limit N stops after N frames (a quick run); --keep DIR keeps the output folders.

(b) --startup: the Rerun part of a 5-frame `moseg run` on the first frames of vtest.avi, in a
    fresh Python process each time: `import rerun`, then the first write_recording (what a
    5-frame run pays once, summary.json timings_s.rrd) and a second one (warm), median of
    --repeats processes. The segmentation is computed before the clock starts. To time another
    version of the package, put it first on the path, e.g. the main branch:

        git archive main | tar -x -C /tmp/moseg-main
        PYTHONPATH=/tmp/moseg-main python benchmarks/output_size.py --startup

    (the child processes report which mosegpipe they imported).

Numbers depend on the machine and its load; run both variants back to back.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

_DEFAULT_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
_MB = 1e6

_STARTUP_CHILD = r"""
import json, sys, time
import mosegpipe.viz as viz
from mosegpipe.pipeline import PipelineConfig, segment_clip
from mosegpipe.runtime import set_threads

set_threads(1)
video, work = sys.argv[1], sys.argv[2]
result = segment_clip(video, PipelineConfig(frames=5))
c = result.clustering
args = (result.frames, result.tracks, result.trajectories.track_ids, c.labels, result.embeddings, result.masks, c.scores, c.k)
t0 = time.perf_counter()
import rerun  # noqa: F401
t1 = time.perf_counter()
viz.write_recording(work + "/first.rrd", *args)
t2 = time.perf_counter()
viz.write_recording(work + "/second.rrd", *args)
t3 = time.perf_counter()
print(json.dumps({"viz": viz.__file__, "tracks": int(len(c.labels)), "import": t1 - t0, "first": t2 - t1,
                  "second": t3 - t2, "compute_imported": "pyarrow.compute" in sys.modules}))
"""


def _size(path: Path) -> float:
    return path.stat().st_size / _MB


def sizes(video: Path, frames_limit: int | None, keep: Path | None, trails_row: bool) -> str:
    from mosegpipe.apps.outputs import write_video_outputs
    from mosegpipe.pipeline import PipelineConfig, load_model
    from mosegpipe.runtime import set_threads
    from mosegpipe.viz import VIDEO_VIZ

    set_threads(1)
    cfg = PipelineConfig()
    model = load_model(cfg.frames)
    variants = {
        "old: a JPEG per frame": replace(VIDEO_VIZ, video_frames="jpeg"),
        "new: one H.264 video asset": VIDEO_VIZ,
    }
    if trails_row:
        variants["new, without trails (trail_frames=1)"] = replace(VIDEO_VIZ, trail_frames=1)
    rows = {}
    with tempfile.TemporaryDirectory(prefix="moseg-size-") as tmp:
        work = keep or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        for i, (name, viz) in enumerate(variants.items()):
            out = work / f"out_{i}"
            t0 = time.perf_counter()
            summary = write_video_outputs(video, out, cfg, model, overwrite=True, max_frames=frames_limit, viz=viz)
            rows[name] = {
                "frames": summary["frames"],
                "overlay": _size(out / "overlay.mp4"),
                "recording": _size(out / "recording.rrd"),
                "seconds": time.perf_counter() - t0,
            }
    old = rows["old: a JPEG per frame"]
    old_total = old["overlay"] + old["recording"]
    frames = old["frames"]
    lines = [
        f"{video.name}: {frames} frames; `moseg run --whole` defaults (shipped model, frames at most 960 px)",
        "",
        "| recording frames | overlay.mp4 MB | recording.rrd MB | total MB | per frame kB | recording new/old "
        "| total new/old | run s |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, r in rows.items():
        total = r["overlay"] + r["recording"]
        lines.append(
            f"| {name} | {r['overlay']:.2f} | {r['recording']:.2f} | {total:.2f} | {1000 * total / frames:.1f} | "
            f"{r['recording'] / old['recording']:.3f} | {total / old_total:.3f} | {r['seconds']:.0f} |"
        )
    return "\n".join(lines)


def startup(video: Path, repeats: int) -> str:
    runs = []
    with tempfile.TemporaryDirectory(prefix="moseg-startup-") as tmp:
        for _ in range(repeats):
            done = subprocess.run(
                [sys.executable, "-c", _STARTUP_CHILD, str(video), tmp],
                capture_output=True,
                text=True,
                check=False,
                cwd=tmp,
            )
            if done.returncode != 0:
                sys.exit(f"output_size.py: the timing process failed:\n{done.stderr}")
            runs.append(json.loads(done.stdout.strip().splitlines()[-1]))
    med = {key: statistics.median(r[key] for r in runs) for key in ("import", "first", "second")}
    load = " / ".join(f"{v:.2f}" for v in os.getloadavg())
    return "\n".join(
        [
            f"mosegpipe.viz from {runs[0]['viz']}; {runs[0]['tracks']} tracks, 5 frames of {video.name}; "
            f"median of {repeats} processes; load average {load}",
            "",
            "| import rerun ms | 1st write_recording ms | first use ms | 2nd write_recording ms | pyarrow.compute imported |",
            "|---|---|---|---|---|",
            f"| {1000 * med['import']:.0f} | {1000 * med['first']:.0f} | {1000 * (med['import'] + med['first']):.0f} | "
            f"{1000 * med['second']:.0f} | {', '.join(sorted({str(r['compute_imported']) for r in runs}))} |",
            "",
            "runs (import / first / second ms): "
            + "; ".join(f"{1000 * r['import']:.0f} / {1000 * r['first']:.0f} / {1000 * r['second']:.0f}" for r in runs),
        ]
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data-root", type=Path, default=Path(os.environ.get("MOSEG_DATA", _DEFAULT_DATA)))
    parser.add_argument("--frames-limit", type=int, default=None, help="stop after this many frames")
    parser.add_argument("--keep", type=Path, default=None, help="keep the output folders here")
    parser.add_argument("--trails-row", action="store_true", help="also a run without track trails")
    parser.add_argument("--startup", action="store_true", help="time the recording's first use instead")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    logging.getLogger("mosegpipe").setLevel(logging.ERROR)  # per-window "ambiguous K" warnings
    video = args.data_root / "videos" / "vtest.avi"
    if not video.is_file():
        sys.exit(f"output_size.py: {video} not found; pass --data-root (the benchmark data folder)")
    if args.frames_limit is not None and args.frames_limit < 5:
        sys.exit("output_size.py: --frames-limit must be at least 5 (one window)")
    print(startup(video, args.repeats) if args.startup else sizes(video, args.frames_limit, args.keep, args.trails_row))


if __name__ == "__main__":
    main()
