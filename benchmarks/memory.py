"""Peak memory of whole-video mode against video length: it should stay flat.

    python benchmarks/memory.py [--lengths 50 200 400] [--size 1280x720] [--rrd] [--model PATH]

Writes one synthetic video (a textured background panning back and forth and two textured
rectangles moving across it, MJPG) as long as the longest length, then segments its first L frames
in a fresh subprocess per length (mosegpipe.outputs.write_video_outputs, as `moseg run --whole`). Each
subprocess reports its peak resident set size (resource.getrusage ru_maxrss) right after the
imports and the model (the baseline) and after the run. Flat memory means the peak does not grow
with L. One thread throughout.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _maxrss_mib() -> float:
    import resource

    # Linux reports ru_maxrss in KiB.
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def make_video(path: Path, frames: int, size_wh: tuple[int, int], seed: int = 0) -> Path:
    """A synthetic MJPG video: a panning background and two moving rectangles, all textured."""
    import cv2
    import numpy as np

    rng = np.random.default_rng(seed)
    w, h = size_wh
    margin = 64

    def texture(tw: int, th: int) -> np.ndarray:
        small = rng.integers(0, 256, (th // 8 + 1, tw // 8 + 1, 3), dtype=np.uint8)
        return cv2.resize(small, (tw, th), interpolation=cv2.INTER_NEAREST)

    background = texture(w + 2 * margin, h + 2 * margin)
    objects = [texture(w // 5, h // 4), texture(w // 6, h // 5)]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (w, h))
    if not writer.isOpened():
        sys.exit(f"memory.py: cannot write {path}")
    for t in range(frames):
        # The camera pans on a slow ellipse so that the background stays inside its margin.
        dx = int(margin + 0.8 * margin * np.sin(2 * np.pi * t / 150))
        dy = int(margin + 0.5 * margin * np.cos(2 * np.pi * t / 150))
        frame = background[dy : dy + h, dx : dx + w].copy()
        for i, obj in enumerate(objects):
            oh, ow = obj.shape[:2]
            # Each object bounces horizontally across the frame at its own speed (px / frame).
            span = w - ow
            x = int(abs((t * (3 + 2 * i) + i * span // 2) % (2 * span) - span))
            y = int((h - oh) * (0.25 + 0.5 * i))
            frame[y : y + oh, x : x + ow] = obj
        writer.write(frame)
    writer.release()
    return path


def child(video: Path, frames: int, rrd: bool, model_path: Path | None) -> None:
    """Runs in the subprocess: segments the first `frames` frames, prints one JSON line."""
    import torch

    from mosegpipe.model import ModelConfig, SubspaceNet
    from mosegpipe.outputs import write_video_outputs
    from mosegpipe.pipeline import PipelineConfig
    from mosegpipe.runtime import set_threads

    set_threads(1)
    if model_path is not None:
        model = SubspaceNet.from_checkpoint(model_path)
    else:
        torch.manual_seed(0)
        model = SubspaceNet(ModelConfig(in_dim=10)).eval()
    if rrd:
        import rerun  # noqa: F401 - imported here so that the baseline includes it, as the run will

    baseline = _maxrss_mib()
    with tempfile.TemporaryDirectory(prefix="moseg_mem_") as tmp:
        t0 = time.perf_counter()
        summary = write_video_outputs(
            video, Path(tmp) / "out", PipelineConfig(frames=5), model, rrd=rrd, max_frames=frames
        )
        seconds = time.perf_counter() - t0
    tracks = [w["num_tracks"] for w in summary["windows"]]
    print(
        json.dumps(
            {
                "frames": summary["frames"],
                "baseline_mib": baseline,
                "peak_mib": _maxrss_mib(),
                "seconds": seconds,
                "mean_tracks": sum(tracks) / max(len(tracks), 1),
            }
        )
    )


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--lengths", type=int, nargs="+", default=[50, 200, 400], help="video lengths in frames")
    ap.add_argument("--size", default="1280x720", help="WxH of the synthetic video")
    ap.add_argument("--rrd", action="store_true", help="also write the Rerun recording")
    ap.add_argument("--model", type=Path, default=None, help="5-frame checkpoint (default: untrained, same size)")
    ap.add_argument("--child", type=Path, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--frames", type=int, default=0, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child is not None:
        child(args.child, args.frames, args.rrd, args.model)
        return

    w, h = (int(v) for v in args.size.lower().split("x"))
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    print(f"# whole-video peak memory, {w}x{h} MJPG, windows of 5 frames, recording {'on' if args.rrd else 'off'}\n")
    print(f"model: {args.model or 'untrained SubspaceNet (30 x 64, same size as the shipped one)'}\n")
    rows = []
    with tempfile.TemporaryDirectory(prefix="moseg_mem_video_") as tmp:
        video = Path(tmp) / "synthetic.avi"
        t0 = time.perf_counter()
        make_video(video, max(args.lengths), (w, h))
        print(
            f"wrote {max(args.lengths)} frames ({video.stat().st_size / 2**20:.0f} MiB) in {time.perf_counter() - t0:.1f} s\n"
        )
        for n in args.lengths:
            cmd = [sys.executable, __file__, "--child", str(video), "--frames", str(n)]
            cmd += ["--rrd"] if args.rrd else []
            cmd += ["--model", str(args.model)] if args.model else []
            out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
            if out.returncode != 0:
                sys.exit(f"memory.py: the run on {n} frames failed:\n{out.stderr}")
            rows.append(json.loads(out.stdout.strip().splitlines()[-1]))
    print(
        "| frames | mean tracks / window | peak RSS after imports + model (MiB) | peak RSS after the run (MiB) | growth (MiB) | wall s | frames/s |"
    )
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['frames']} | {r['mean_tracks']:.0f} | {r['baseline_mib']:.0f} | {r['peak_mib']:.0f} | "
            f"{r['peak_mib'] - r['baseline_mib']:.0f} | {r['seconds']:.1f} | {r['frames'] / r['seconds']:.1f} |"
        )
    if len(rows) > 1:
        first, last = rows[0], rows[-1]
        slope = (last["peak_mib"] - first["peak_mib"]) / max(last["frames"] - first["frames"], 1)
        print(
            f"\npeak growth from {first['frames']} to {last['frames']} frames: {last['peak_mib'] - first['peak_mib']:+.1f} MiB "
            f"({1024 * slope:+.1f} KiB per frame; one {w}x{h} RGB frame is {w * h * 3 / 2**10:.0f} KiB)"
        )


if __name__ == "__main__":
    main()
