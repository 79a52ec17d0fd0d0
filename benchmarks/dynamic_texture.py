"""Rippling water with nothing in it: how much of it the masks write as moving.

Renders clips of a procedural water surface and no object: a seeded smooth texture (blue-green, with foam
specks) warped every frame by a sum of travelling waves (random directions, wavelengths 12-60 px, speeds
0.5-2.5 px a frame, amplitudes 0.5-2.5 px), its brightness modulated by the waves' slope (glints), with
sensor noise; the camera holds still, pans or shakes (a whole-frame translation the world's camera model
explains). Every pixel is the world: the ground truth is 0 everywhere. Each clip is segmented as a whole
video exactly as `moseg run --whole` writes it (mask PNGs read back) and the script prints per clip the share
of pixels written as moving (any value but 0 and 255), the share written unknown (255) and the share of frames
with any pixel written as moving. Issue 42's target: at most 2 % of the pixels written as moving.

Measurement only: nothing in the pipeline is chosen from these clips (seeds 0-9; the mask network trains on
water clips of its own seeds, `learned.data.DataConfig.water_seed`, never these).

    python benchmarks/dynamic_texture.py                                  # the default masks (motion)
    python benchmarks/dynamic_texture.py --set mask.method=learned
    python benchmarks/dynamic_texture.py --preset fast
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
from world_static import seed_list  # benchmarks/ is the script's folder

from mosegpipe.apps.outputs import write_video_outputs
from mosegpipe.embed.numpy_net import load_embedder
from mosegpipe.io.read import read_palette_png
from mosegpipe.pipeline import PipelineConfig
from mosegpipe.runtime import set_threads
from mosegpipe.synth.water import CAMERAS, water_clip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", default="0-9", help="render seeds, e.g. 0-9")
    parser.add_argument("--frames", type=int, default=25, help="frames per clip")
    parser.add_argument("--size", default="240x320", help="HxW of the frames")
    parser.add_argument("--preset", default=None, help="best, balanced or fast (default: best)")
    parser.add_argument("--set", action="append", default=[], help="a pipeline setting, dotted.path=value")
    args = parser.parse_args()
    set_threads(1)
    h, w = (int(v) for v in args.size.split("x"))
    cfg = PipelineConfig.from_options(5, preset=args.preset, settings=args.set)
    model = load_embedder(cfg.frames)
    rows = []
    print(f"{'seed':>5} {'camera':>7} {'written moving':>15} {'unknown':>8} {'frames with moving':>19} {'s':>6}")
    for seed in seed_list(args.seeds):
        camera = CAMERAS[seed % len(CAMERAS)]
        frames = water_clip(seed, args.frames, (h, w), camera)
        with tempfile.TemporaryDirectory(prefix="moseg-water-") as tmp:
            folder = Path(tmp) / "frames"
            folder.mkdir()
            for t, image in enumerate(frames):
                cv2.imwrite(str(folder / f"{t:06d}.png"), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
            t0 = time.perf_counter()
            write_video_outputs(folder, Path(tmp) / "out", cfg, model, rrd=False)
            seconds = time.perf_counter() - t0
            masks = np.stack(
                [read_palette_png(Path(tmp) / "out" / "masks" / f"{t:06d}.png") for t in range(len(frames))]
            )
        moving = (masks != 0) & (masks != 255)
        row = (float(moving.mean()), float((masks == 255).mean()), float(moving.any(axis=(1, 2)).mean()))
        rows.append(row)
        print(
            f"{seed:>5} {camera:>7} {100 * row[0]:>14.2f}% {100 * row[1]:>7.2f}% {100 * row[2]:>18.0f}% {seconds:>6.1f}",
            flush=True,
        )
    mean = np.mean(rows, axis=0)
    print(f"{'mean':>5} {'':>7} {100 * mean[0]:>14.2f}% {100 * mean[1]:>7.2f}% {100 * mean[2]:>18.0f}%")


if __name__ == "__main__":
    main()
