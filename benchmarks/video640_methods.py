"""Whole-video mode at 640x480 (200 frames of vtest.avi resized) with each mask method, against a bare KLT loop
measured just before each run: the table "whole video at 640x480 by mask method" of docs/RESULTS.md.

Usage: python benchmarks/video640_methods.py [DATA_ROOT]   (DATA_ROOT defaults to ../shared/data)
"""

import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from speed import bare_klt_fps, resized_frames, write_video

from mosegpipe.apps.outputs import write_video_outputs
from mosegpipe.embed.numpy_net import load_embedder
from mosegpipe.masks import MaskConfig
from mosegpipe.pipeline import PipelineConfig
from mosegpipe.runtime import set_threads

set_threads(1)
root = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parents[1].parent / "shared" / "data"
work = Path(tempfile.mkdtemp(prefix="moseg-bench-"))
v = write_video(resized_frames(root / "videos" / "vtest.avi", 200, (640, 480)), work / "vt640_200.avi")
m = load_embedder(5)
print("| mask method | frames | frames/s | bare KLT frames/s | x bare KLT | CPU ms / frame |")
print("|---|---|---|---|---|---|")
for method in ("nearest", "watershed", "motion"):
    ref = bare_klt_fps(v)
    cfg = replace(PipelineConfig(frames=5), mask=MaskConfig(method=method))
    t0, c0 = time.perf_counter(), time.process_time()
    s = write_video_outputs(v, work / f"out_{method}", cfg, m, overwrite=True, rrd=False)
    dt = time.perf_counter() - t0
    print(
        f"| {method} | {s['frames']} | {s['frames'] / dt:.1f} | {ref:.0f} | {s['frames'] / dt / ref:.3f} | {1000 * (time.process_time() - c0) / s['frames']:.0f} |",
        flush=True,
    )
