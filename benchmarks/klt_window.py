"""KLT's CPU per frame by Lucas-Kanade window and pyramid levels, side by side in one run.

    python benchmarks/klt_window.py            # vtest.avi at 640x480 and DAVIS bear at 854x480

The whole-video tracker (`KLTTracker`, re-seeding every 4 frames as windows of 5 frames do), one thread,
interleaved rounds; prints the median CPU ms per frame of each setting and its ratio to the default.
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from mosegpipe.configs.tracking import TrackConfig
from mosegpipe.io.read import iter_video, read_image
from mosegpipe.points.klt import KLTTracker

_DATA = Path(os.environ.get("MOSEG_DATA", Path(__file__).resolve().parents[1] / ".." / "shared" / "data"))
VARIANTS: dict[str, dict[str, int]] = {
    "window 21, 3 levels (default)": {},
    "window 15, 2 levels": {"win_size_px": 15, "max_level": 2},
    "window 15, 3 levels": {"win_size_px": 15},
    "window 11, 3 levels (fast, balanced)": {"win_size_px": 11},
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data-root", type=Path, default=_DATA)
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    cv2.setNumThreads(1)
    video = args.data_root / "videos" / "vtest.avi"
    inputs = {
        "vtest 640x480": [cv2.resize(rgb, (640, 480), interpolation=cv2.INTER_AREA) for _, rgb in iter_video(video, max_frames=100)],
        "bear 854x480": [read_image(p) for p in sorted((args.data_root / "davis2016-train" / "bear" / "frames").glob("*.jpg"))[:80]],
    }  # fmt: skip
    ms: dict[tuple[str, str], list[float]] = {(v, n): [] for v in VARIANTS for n in inputs}
    for _ in range(args.rounds):
        for name, settings in VARIANTS.items():
            for label, frames in inputs.items():
                tracker = KLTTracker(replace(TrackConfig(), reseed=True, reseed_every=4, **settings))
                start = time.thread_time()
                for frame in frames:
                    tracker.step(frame)
                ms[(name, label)].append((time.thread_time() - start) / len(frames) * 1000)
    print(f"load average {os.getloadavg()[0]:.1f}; CPU ms per frame, median of {args.rounds} rounds (x the default)")
    default = next(iter(VARIANTS))
    for (name, label), values in ms.items():
        base = float(np.median(ms[(default, label)]))
        print(f"{name:40s} {label:14s} {np.median(values):6.2f}  x{np.median(values) / base:.2f}")


if __name__ == "__main__":
    main()
