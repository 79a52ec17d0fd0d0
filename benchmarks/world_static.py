"""Static 3D structure under a moving camera: how much of the world the masks write as moving.

Renders clips with depth (a wall and a ground plane) seen by a moving camera with moving objects
(`mosegpipe.synth.render`), segments each as a whole video exactly as `moseg run --whole` writes it (mask
PNGs read back), and prints per clip: the share of static pixels (ground truth 0) written as moving (any
value but 0 and 255), the objects' foreground J (masks as written: every value but 0 and 255), and the
share of frames in which the label covering most of the static pixels is not 0.

`--scene near` (issue 54) renders the fault of near static structure instead: a camera trucking sideways
along the wall while turning slowly back to it, three still boxes 1.5-3 m away (pillars, rocks: their parallax
against the wall 10 m away is several times the wall's motion) and two movers, the first of which moves with
the camera (a mover the camera follows); it adds that followed mover's J (any label but 0 and 255 counts).

Seeds 0-9 are for development, 100-109 for validation (score those once, after choosing). The script uses
only what `moseg` has long had (the writer and the PNG reader), so an older checkout can be measured with it
too (`PYTHONPATH=<checkout> python benchmarks/world_static.py`).

    python benchmarks/world_static.py --seeds 0-9
    python benchmarks/world_static.py --seeds 0-9 --set world.enabled=false
    python benchmarks/world_static.py --scene near --seeds 0-9
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from mosegpipe.apps.video_outputs import write_video_outputs
from mosegpipe.embed.numpy_net import load_embedder
from mosegpipe.evaluation.metrics import jaccard
from mosegpipe.io.read import read_palette_png
from mosegpipe.pipeline import PipelineConfig
from mosegpipe.runtime import set_threads
from mosegpipe.synth.render import RenderConfig, render_clip

MOTIONS = ("forward", "handheld", "pan")


def seed_list(text: str) -> list[int]:
    """The seeds of '0-9' or '0-4,100-104'."""
    out: list[int] = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        out += list(range(int(lo), int(hi or lo) + 1))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", default="0-9", help="render seeds, e.g. 0-9 or 100-109 (validation)")
    parser.add_argument("--frames", type=int, default=25, help="frames per clip")
    parser.add_argument("--scene", choices=("depth", "near"), default="depth", help="what to render (docstring)")
    parser.add_argument("--set", action="append", default=[], help="a pipeline setting, dotted.path=value")
    parser.add_argument("--model", default=None, help="a checkpoint of cfg.frames frames (default: the shipped one)")
    args = parser.parse_args()
    set_threads(1)
    cfg = PipelineConfig().with_settings(args.set)
    model = load_embedder(cfg.frames, args.model)
    rows = []
    near = args.scene == "near"
    print(
        f"{'seed':>5} {'camera':>9} {'static written moving':>22} {'object J':>9} {'world off':>10}"
        + (f" {'followed J':>10}" if near else "")
        + f" {'s':>6}"
    )
    for seed in seed_list(args.seeds):
        motion = "truck" if near else MOTIONS[seed % len(MOTIONS)]
        clip = render_clip(
            RenderConfig(
                size_hw=(240, 320),
                frames=args.frames,
                seed=seed,
                camera_motion=motion,
                ground=True,
                num_objects=2,
                near_static=3 if near else 0,
                follow=near,
            )
        )
        with tempfile.TemporaryDirectory(prefix="moseg-world-") as tmp:
            folder = Path(tmp) / "frames"
            folder.mkdir()
            from PIL import Image

            for t, image in enumerate(clip.frames):
                Image.fromarray(image).save(folder / f"{t:06d}.png")
            t0 = time.perf_counter()
            write_video_outputs(folder, Path(tmp) / "out", cfg, model, rrd=False)
            seconds = time.perf_counter() - t0
            masks = np.stack(
                [read_palette_png(Path(tmp) / "out" / "masks" / f"{t:06d}.png") for t in range(clip.num_frames)]
            )
        static = clip.masks == 0
        written = (masks != 0) & (masks != 255)
        moving_share = float(written[static].mean())
        truth = ~static
        j = float(np.mean([jaccard(w, g) for w, g in zip(written, truth)]))
        followed = [(w, g) for w, g in zip(written, clip.masks == 1) if g.any()]  # the frames that show it
        followed_j = float(np.mean([jaccard(w, g) for w, g in followed])) if followed else float("nan")
        # frames in which the label covering most of the static pixels (255 aside) is not 0
        off = float(np.mean([np.bincount(m[s], minlength=256)[:255].argmax() != 0 for m, s in zip(masks, static)]))
        rows.append((moving_share, j, off, followed_j))
        extra = f" {followed_j:>10.3f}" if near else ""
        print(
            f"{seed:>5} {motion:>9} {100 * moving_share:>21.2f}% {j:>9.3f} {off:>10.2f}{extra} {seconds:>6.1f}",
            flush=True,
        )
    mean = np.nanmean(rows, axis=0)
    extra = f" {mean[3]:>10.3f}" if near else ""
    print(f"{'mean':>5} {'':>9} {100 * mean[0]:>21.2f}% {mean[1]:>9.3f} {mean[2]:>10.2f}{extra}")


if __name__ == "__main__":
    main()
