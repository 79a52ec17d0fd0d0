"""Wall time and peak memory of `moseg tracks` against the number of tracks: memory should grow linearly.

    python benchmarks/tracks_scale.py [--sizes 10000 100000 1000000] [--frames 8] [--keep DIR]

Writes one synthetic tracks file per size (`xy` (N, F, 2) float32, our layout): a 640x480 view of
three motions (the background drifting right, a rectangle moving down-right, another moving up-left,
each point with 0.3 px of Gaussian tracking noise), then runs the real command, `moseg tracks FILE`,
in a fresh child process per size and reads the child's peak resident set size from os.wait4's
rusage (ru_maxrss). Prints a Markdown table: N, seconds, peak MiB, K found. One thread throughout.
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

import numpy as np

_SIZE_WH = (640, 480)


def synthetic_tracks(n: int, frames: int, seed: int = 0) -> np.ndarray:
    """(N, F, 2) float32 pixel tracks of three motions (half background, a quarter each object)."""
    rng = np.random.default_rng(seed)
    w, h = _SIZE_WH
    motion = rng.integers(0, 4, n).clip(max=2)  # 0 background (half), 1 and 2 objects (a quarter each)
    start = np.empty((n, 2))
    boxes = {0: (0, 0, w, h), 1: (60, 60, 260, 220), 2: (360, 240, 600, 440)}
    for m, (x0, y0, x1, y1) in boxes.items():
        sel = motion == m
        start[sel] = rng.uniform((x0, y0), (x1, y1), (int(sel.sum()), 2))
    velocity = np.array([[1.0, 0.0], [3.0, 2.5], [-2.5, -3.0]])[motion]  # px per frame
    t = np.arange(frames, dtype=np.float64)[None, :, None]
    xy = start[:, None, :] + t * velocity[:, None, :] + rng.normal(0, 0.3, (n, frames, 2))
    return xy.astype(np.float32)


def run_one(path: Path, out: Path) -> tuple[float, float, str]:
    """(seconds, peak MiB, K) of `moseg tracks path --out out` in a child process."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    cmd = [sys.executable, "-m", "mosegpipe.cli.main", "tracks", str(path), "--out", str(out), "--overwrite"]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    _, status, usage = os.wait4(proc.pid, 0)
    seconds = time.perf_counter() - t0
    stdout, stderr = proc.stdout.read(), proc.stderr.read()  # type: ignore[union-attr]
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        return seconds, usage.ru_maxrss / 1024.0, f"exit {proc.returncode}: {stderr.strip().splitlines()[-1:]}"
    k = json.loads((out / "summary.json").read_text()).get("k", "?")
    del stdout
    return seconds, usage.ru_maxrss / 1024.0, str(k)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000, 1_000_000])
    parser.add_argument("--frames", type=int, default=8)
    parser.add_argument(
        "--keep", type=Path, default=None, help="folder for the inputs and outputs (default: temporary)"
    )
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.keep or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        print(f"`moseg tracks FILE` on synthetic tracks, 3 motions, {args.frames} frames, 1 thread\n")
        print("| tracks N | seconds | peak RSS (MiB) | K |")
        print("|---:|---:|---:|---|")
        for n in args.sizes:
            path = folder / f"tracks_{n}.npz"
            np.savez(path, xy=synthetic_tracks(n, args.frames))
            seconds, peak, k = run_one(path, folder / f"out_{n}")
            print(f"| {n:,} | {seconds:.1f} | {peak:.0f} | {k} |", flush=True)


if __name__ == "__main__":
    main()
