""" "learned" masks' moving pixels: the mask network's probability of "not the world", thresholded.

The drop-in for `motion.moving_from_motion` (same inputs, same output): `masks.motion_masks` and the whole
video's windows call this instead when `MaskConfig.method` is "learned"; the moving pixels then get the
tracks' labels exactly as the "motion" masks' do. Torch is imported on the first call only.
"""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe.flow import FrameMotion
from mosegpipe.learned.features import LearnedMaskConfig, clip_features


def learned_probability(
    images: npt.NDArray[np.uint8], motion: FrameMotion, cfg: LearnedMaskConfig = LearnedMaskConfig(), first: int = 0
) -> npt.NDArray[np.float32]:
    """(T - first, h, w) float32 probability of "not the world" at the network's size (`features.net_size`).

    Args:
        images: (T, H, W, 3) uint8 RGB, T >= 2.
        motion: the frames' flow evidence with its flows (`motion.stack_motion`, a `FlowStream`'s).
        cfg: the network's settings (its weights, input scale).
        first: frames first..T-1 only (the frames before are the first one's neighbours).
    """
    from mosegpipe.learned.net import load_masknet, predict

    return predict(load_masknet(cfg.weights), clip_features(images, motion, cfg.scale, first))


def learned_moving(
    images: npt.NDArray[np.uint8], motion: FrameMotion, cfg: LearnedMaskConfig = LearnedMaskConfig(), first: int = 0
) -> npt.NDArray[np.bool_]:
    """Masks of the moving pixels of frames first..T-1: (T - first, H, W) bool, True = not the world.

    The probability is resized to the frame's size (linear) and compared with `cfg.threshold`.
    """
    height, width = images.shape[1:3]
    prob = learned_probability(images, motion, cfg, first)
    out = np.empty((len(prob), height, width), bool)
    for t, p in enumerate(prob):
        out[t] = cv2.resize(p, (width, height), interpolation=cv2.INTER_LINEAR) > np.float32(cfg.threshold)
    return out
