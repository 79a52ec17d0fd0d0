"""Regenerates the sample inputs in this folder (the outputs are committed; this script records how).

    python samples/make_samples.py [--data-root ../shared/data]

1. rendered/: a synthetic clip from mosegpipe.synth.render (static camera, 3 moving objects): a frame folder
   (JPEG, quality 95: a sixth of the PNG size) and ground-truth masks as palette PNGs (value = motion
   group: 0 background, 1..3 objects).
2. vtest_8f.avi: the first 8 frames of OpenCV's vtest.avi, resized to 384x288, MJPG.
3. basketball1.png, basketball2.png: an image pair from OpenCV's sample data, copied unchanged.
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

import cv2

from mosegpipe.io.read import iter_video, write_json, write_palette_png, write_video
from mosegpipe.synth.render import RenderConfig, render_clip

HERE = Path(__file__).resolve().parent
RENDER = RenderConfig(size_hw=(240, 320), frames=8, num_objects=3, seed=0, camera_motion="static")
"""The rendered sample: 320x240, 8 frames, 3 objects on a static textured wall."""
JPEG_QUALITY = 95
FPS = 10.0
VTEST_FRAMES = 8
VTEST_SIZE_WH = (384, 288)


def make_rendered(out: Path) -> None:
    """rendered/frames/NNNNNN.jpg, rendered/gt/NNNNNN.png and rendered/render_config.json."""
    clip = render_clip(RENDER)
    (out / "frames").mkdir(parents=True, exist_ok=True)
    for t, (frame, mask) in enumerate(zip(clip.frames, clip.masks)):
        path = out / "frames" / f"{t:06d}.jpg"
        if not cv2.imwrite(str(path), cv2.cvtColor(frame, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY]):
            raise OSError(f"{path}: could not write")
        write_palette_png(out / "gt" / f"{t:06d}.png", mask)
    config = {
        "size_hw": list(RENDER.size_hw),
        "frames": RENDER.frames,
        "num_objects": RENDER.num_objects,
        "seed": RENDER.seed,
        "camera_motion": RENDER.camera_motion,
        "object_ids": list(clip.object_ids),
    }
    write_json(out / "render_config.json", config)


def make_vtest(data_root: Path, out: Path) -> None:
    """vtest_8f.avi: the first frames of the OpenCV sample video, downscaled by 2."""
    frames = (
        cv2.resize(frame, VTEST_SIZE_WH, interpolation=cv2.INTER_AREA)
        for _, frame in iter_video(data_root / "videos" / "vtest.avi", max_frames=VTEST_FRAMES)
    )
    write_video(out, frames, FPS)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-root", type=Path, default=HERE.parent.parent / "shared" / "data")
    args = parser.parse_args()
    make_rendered(HERE / "rendered")
    make_vtest(args.data_root, HERE / "vtest_8f.avi")
    for name in ("basketball1.png", "basketball2.png"):
        shutil.copyfile(args.data_root / "videos" / name, HERE / name)
    for path in sorted(p for p in HERE.rglob("*") if p.is_file()):
        print(f"{path.stat().st_size:>8}  {path.relative_to(HERE)}")


if __name__ == "__main__":
    main()
