"""The mask step alone at 640x480, one thread: the "learned" masks (features + network + the steps after it, and
the network's probability only thresholded) against the "motion" chain (`moving_from_motion`), on the same frames
and the same flow evidence, in the same run; CPU ms per frame (process time), alternating them so that the
machine's load hits all alike. The flow (shared by
both, and by the tracks) is computed once beforehand and not counted.

Frames: 5-frame windows of DAVIS development clips resized to 640x480 (with the frame after as evidence, as a
clip run has it). Last, the per-motion step (`MaskConfig.which` "learned", `which.which_motion`) on the same frames
for 2 and 3 moving motions (the frame's corners labelled by vertical bands, the left quarter the world), its
inputs (the features) counted apart. Usage: python benchmarks/learned_masks.py [DATA_ROOT] [ROUNDS]
"""

import sys
import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from mosegpipe.data.davis import read_davis_clip
from mosegpipe.masks.learned.features import LearnedMaskConfig, clip_features
from mosegpipe.masks.learned.net import load_masknet, predict
from mosegpipe.masks.learned.probability import learned_moving
from mosegpipe.masks.learned.which import which_motion
from mosegpipe.masks.moving_pixels import MotionMaskConfig, moving_from_motion, stack_motion
from mosegpipe.runtime import set_threads
from mosegpipe.training.masks.whichnet import frame_corners

set_threads(1)
root = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parents[1].parent / "shared" / "data"
rounds = int(sys.argv[2]) if len(sys.argv) > 2 else 3
motion_cfg, learned_cfg = MotionMaskConfig(), LearnedMaskConfig()
plain_cfg = replace(learned_cfg, temporal_weight=0.0, refine_scale=0.0, min_component=0.0)
stacks = []
for name in ("bear", "dance-jump", "hockey", "soccerball"):
    clip = read_davis_clip(root, name, max_frames=6)
    images = np.stack([cv2.resize(im, (640, 480), interpolation=cv2.INTER_AREA) for im in clip.images])
    stacks.append((images[:5], stack_motion(images[:5], motion_cfg, after=images[5])))
net = load_masknet()
learned_moving(*stacks[0], learned_cfg)  # torch's first call
cpu = {"motion": 0.0, "learned": 0.0, "plain": 0.0, "features": 0.0, "network": 0.0}
frames = 0
for _ in range(rounds):
    for images, motion in stacks:
        c0 = time.process_time()
        moving_from_motion(images, motion, motion_cfg)
        c1 = time.process_time()
        learned_moving(images, motion, learned_cfg)
        c2 = time.process_time()
        feats = clip_features(images, motion, learned_cfg.scale)
        c3 = time.process_time()
        predict(net, feats)
        c4 = time.process_time()
        learned_moving(images, motion, plain_cfg)
        c5 = time.process_time()
        cpu["plain"] += c5 - c4
        cpu["motion"] += c1 - c0
        cpu["learned"] += c2 - c1
        cpu["features"] += c3 - c2
        cpu["network"] += c4 - c3
        frames += len(images)
print("| mask step, 640x480, one thread | CPU ms / frame |")
print("|---|---|")
print(f"| motion chain (`moving_from_motion`) | {1000 * cpu['motion'] / frames:.1f} |")
print(f"| learned (`learned_moving`, defaults) | {1000 * cpu['learned'] / frames:.1f} |")
print(
    f"| learned, probability only thresholded (no temporal carry, refinement, components) | {1000 * cpu['plain'] / frames:.1f} |"
)
print(f"| of which features | {1000 * cpu['features'] / frames:.1f} |")
print(f"| of which network | {1000 * cpu['network'] / frames:.1f} |")
print(f"({frames} frames per method; load {open('/proc/loadavg').read().split()[0]})")


def _band(x: np.ndarray, width: int, k: int) -> np.ndarray:
    """Label of each x: 0 (the world) in the left quarter, then k equal bands 1..k."""
    return np.where(x < width / 4, 0, 1 + np.minimum(((x - width / 4) / (0.75 * width / k)).astype(int), k - 1))


def _banded(image: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A frame's mask and corners labelled by vertical bands (`_band`)."""
    width = image.shape[1]
    xy = frame_corners(image)
    mask = _band(np.arange(width, dtype=np.float32), width, k)[None].repeat(image.shape[0], 0).astype(np.uint8)
    return mask, xy, _band(xy[:, 0], width, k).astype(np.int64)


which_cpu = {2: 0.0, 3: 0.0}
which_frames = 0
for images, motion in stacks:
    feats = clip_features(images, motion, learned_cfg.scale)
    for t, image in enumerate(images):
        for k in which_cpu:
            mask, xy, labels = _banded(image, k)
            which_motion(mask, feats[t], xy, labels)  # torch's first call of this network
            c0 = time.process_time()
            for _ in range(rounds):
                which_motion(mask, feats[t], xy, labels)
            which_cpu[k] += time.process_time() - c0
        which_frames += rounds
print()
print("| per-motion step (`which_motion`), 640x480, one thread, features apart | CPU ms / frame |")
print("|---|---|")
for k, c in which_cpu.items():
    print(f"| {k} moving motions | {1000 * c / which_frames:.1f} |")
print(f"({which_frames} frames each; load {open('/proc/loadavg').read().split()[0]})")
