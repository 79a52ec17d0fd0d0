"""The dense stage on HD frames: DAVIS dev clips upscaled to 1920x1080, with and without `mask.motion.max_side_px`.

    python benchmarks/hd_dense.py [--clips bear,bmx-bumps,breakdance-flare,bus,dance-jump] [--frames 25]
                                  [--size 1920x1080] [--data ../shared/data]

Each clip's first --frames frames are segmented as a whole video three ways: at DAVIS's own 854x480 (the
defaults), upscaled to --size (bicubic) with the dense stage at most 1280 px long (the default
`mask.motion.max_side_px`), and upscaled with no limit (`max_side_px` None: flow and mask steps at the full
1920x1080). The upscaled runs' masks are brought back to 854x480 (nearest) and all three are scored against
DAVIS's masks as `moseg eval davis` scores them (J, F, false-positive share of the union). The frames carry no
more detail upscaled than at 854x480, so the table says what the limit costs or saves on frames of that size,
not how HD footage's own detail would score. Seconds are wall-clock, one thread, same process, in turn.
Prints a Markdown table. Development clips only: no validation clip is used.
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--clips", default="bear,bmx-bumps,breakdance-flare,bus,dance-jump", help="DAVIS dev clips")
    ap.add_argument("--frames", type=int, default=25, help="frames of each clip (from its first)")
    ap.add_argument("--size", default="1920x1080", help="WxH the frames are upscaled to")
    ap.add_argument("--data", default=os.environ.get("MOSEG_DATA", "../shared/data"), help="data root")
    args = ap.parse_args()

    from mosegpipe.data.davis import DAVIS_DEV, read_davis_clip
    from mosegpipe.embed.numpy_net import load_embedder
    from mosegpipe.evaluation.davis import score_clip
    from mosegpipe.pipeline import PipelineConfig, segment_video
    from mosegpipe.runtime import set_threads

    set_threads(1)
    w, h = (int(v) for v in args.size.lower().split("x"))
    clips = [c for c in args.clips.split(",") if c]
    outside = [c for c in clips if c not in DAVIS_DEV]
    if outside:
        raise SystemExit(f"hd_dense.py: not development clips: {', '.join(outside)}")
    model = load_embedder(5, None)
    base = PipelineConfig(frames=5)
    runs = {
        "854x480 (DAVIS's size)": (False, base),
        f"{w}x{h}, dense stage at most 1280 px (default)": (True, base),
        f"{w}x{h}, no limit (max_side_px None)": (True, base.with_settings(["mask.motion.max_side_px=null"])),
    }
    scores: dict[str, list[tuple[float, float, float, float]]] = {name: [] for name in runs}
    print(f"machine: {platform.machine()}, nproc {os.cpu_count()}, load average {os.getloadavg()[0]:.2f}\n")
    for clip_name in clips:
        clip = read_davis_clip(args.data, clip_name, max_frames=args.frames)
        big = np.stack([cv2.resize(im, (w, h), interpolation=cv2.INTER_CUBIC) for im in clip.images])
        with tempfile.TemporaryDirectory(prefix="moseg-hd-") as tmp:
            folder = Path(tmp) / clip_name
            folder.mkdir()
            for t, image in enumerate(big):
                cv2.imwrite(str(folder / f"{t:05d}.png"), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
            for name, (upscaled, cfg) in runs.items():
                masks = np.full(clip.gt.shape, 255, np.uint8)
                t0 = time.perf_counter()
                for window in segment_video(
                    folder if upscaled else clip.frames_dir, cfg, model, max_frames=args.frames
                ):
                    for fr in window.frames:
                        assert fr.mask is not None
                        small = cv2.resize(fr.mask, clip.gt.shape[:0:-1], interpolation=cv2.INTER_NEAREST)
                        masks[fr.index] = small
                seconds = time.perf_counter() - t0
                row = score_clip(masks, clip.gt)
                scores[name].append((row["j_mean"], row["f_mean"], row["fp_share"], seconds))
                print(f"{clip_name}: {name}: J {row['j_mean']:.3f}, {seconds:.1f} s", flush=True)
    print(f"\n{len(clips)} DAVIS dev clips ({', '.join(clips)}), first {args.frames} frames each, whole video\n")
    print("| frames | J | F | false-positive share | seconds (all clips) |")
    print("|---|---|---|---|---|")
    for name, rows in scores.items():
        a = np.array(rows)
        print(f"| {name} | {a[:, 0].mean():.3f} | {a[:, 1].mean():.3f} | {a[:, 2].mean():.3f} | {a[:, 3].sum():.1f} |")


if __name__ == "__main__":
    main()
