""" "learned" masks' moving pixels: the mask network's probability of "not the world", thresholded.

The drop-in for `moving_pixels.moving_from_motion` (same inputs, same output): `masks.motion_masks` and the whole
video's windows call this instead when `MaskConfig.method` is "learned"; the moving pixels then get the
tracks' labels exactly as the "motion" masks' do. Torch is imported on the first call only.

Steps after the network, each a setting of `LearnedMaskConfig` (measured in docs/RESULTS.md, "Learned masks"):
the probability carried along the flow from the neighbouring frames and averaged (`temporal_weight`), its
edges moved onto the image's by the motion chain's guided filter and global smoother at `refine_scale` of the
frame (instead of plain upsampling), and regions weaker than a share of the frame's strongest dropped as the
chain drops them (`min_component`; strength = area x mean camera residual^2: flow noise, parallax of thin
structures, ripples).
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe.configs.masks import MaskConfig, MotionMaskConfig
from mosegpipe.errors import CheckpointError
from mosegpipe.masks.learned.features import (
    NUM_CHANNELS,
    LearnedMaskConfig,
    clip_features,
    neighbours_along,
    net_flows,
    net_size,
)
from mosegpipe.masks.moving_pixels import keep_strong, refined_scores
from mosegpipe.points.flow import FrameMotion

EDGE_STEPS = replace(MotionMaskConfig(), local_colour_weight=0.0, superpixels=0)
"""The motion chain's settings whose edge steps (guided filter, global smoother) `refine_scale` runs, and whose
`component_power` measures a region's strength for `min_component`."""


def carried_probability(
    prob: npt.NDArray[np.float32],
    flows: tuple[list[npt.NDArray[np.float32]], list[npt.NDArray[np.float32]]],
    weight: float,
) -> npt.NDArray[np.float32]:
    """Each frame's probability averaged, with `weight`, with its neighbours' read where its flow leads (`flows`:
    the frames' `net_flows` at the probability's size)."""
    forward, backward = flows
    ys, xs = np.mgrid[0 : prob.shape[1], 0 : prob.shape[2]].astype(np.float32)
    grid = (xs, ys)
    out = np.empty_like(prob)
    frames = list(prob)
    for t, p in enumerate(frames):
        near = neighbours_along(frames, forward, backward, t, grid)
        out[t] = p if not near else (1 - np.float32(weight)) * p + np.float32(weight) * np.mean(near, axis=0)
    return out


def learned_probability(
    images: npt.NDArray[np.uint8], motion: FrameMotion, cfg: LearnedMaskConfig = LearnedMaskConfig(), first: int = 0
) -> npt.NDArray[np.float32]:
    """(T - first, h, w) float32 probability of "not the world" at the network's size (`features.net_size`).

    Args:
        images: (T, H, W, 3) uint8 RGB, T >= 2.
        motion: the frames' flow evidence with its flows (`moving_pixels.stack_motion`, a `FlowStream`'s).
        cfg: the network's settings (its weights, input scale, `temporal_weight`).
        first: frames first..T-1 only (the frames before are the first one's neighbours; with
            `temporal_weight`, their probability is carried into the first one's too).
    """
    from mosegpipe.masks.learned.net import load_masknet, predict

    net = load_masknet(cfg.weights)
    if cfg.temporal_weight <= 0:
        return predict(net, clip_features(images, motion, cfg.scale, first))
    start = max(0, first - 1)
    flows = net_flows(motion, net_size(images.shape[1:3], cfg.scale))  # one resize for the features and the carry
    prob = predict(net, clip_features(images, motion, cfg.scale, start, flows))
    carried = carried_probability(prob, (flows[0][start:], flows[1][start:]), cfg.temporal_weight)
    return carried[first - start :]


def refined_probability(
    prob: npt.NDArray[np.float32], image: npt.NDArray[np.uint8], cfg: LearnedMaskConfig
) -> npt.NDArray[np.bool_]:
    """Moving pixels at `cfg.refine_scale` of the frame: the probability minus the threshold, resized (linear),
    guided filter with the grey frame as guide, then global smoother with the colour frame as guide, > 0."""
    height, width = image.shape[:2]
    hw = (max(1, round(height * cfg.refine_scale)), max(1, round(width * cfg.refine_scale)))
    small = image if hw == (height, width) else cv2.resize(image, (hw[1], hw[0]), interpolation=cv2.INTER_AREA)
    z = cv2.resize(prob, (hw[1], hw[0]), interpolation=cv2.INTER_LINEAR) - np.float32(cfg.threshold)
    out: npt.NDArray[np.bool_] = refined_scores([small], [z], EDGE_STEPS)[0] > 0
    return out


def learned_moving(
    images: npt.NDArray[np.uint8],
    motion: FrameMotion,
    cfg: LearnedMaskConfig = LearnedMaskConfig(),
    first: int = 0,
) -> npt.NDArray[np.bool_]:
    """Masks of the moving pixels of frames first..T-1: (T - first, H, W) bool, True = not the world.

    The probability is resized to the frame's size (linear; or refined, `cfg.refine_scale`) and compared with
    `cfg.threshold`; with `cfg.min_component`, weak regions are dropped.
    """
    height, width = images.shape[1:3]
    prob = learned_probability(images, motion, cfg, first)
    out = np.empty((len(prob), height, width), bool)
    for t, p in enumerate(prob):
        if cfg.refine_scale > 0:
            small = refined_probability(p, images[first + t], cfg)
        else:
            small = cv2.resize(p, (width, height), interpolation=cv2.INTER_LINEAR) > np.float32(cfg.threshold)
        if cfg.min_component > 0:
            residual = motion.residual[first + t] * np.float32(1.0 / motion.scale)  # full-resolution pixels
            residual = cv2.resize(residual, (small.shape[1], small.shape[0]), interpolation=cv2.INTER_LINEAR)
            small = keep_strong(small, residual, cfg.min_component, EDGE_STEPS.component_power)
        if small.shape != (height, width):
            small = cv2.resize(small.astype(np.uint8), (width, height), interpolation=cv2.INTER_NEAREST) > 0
        out[t] = small
    return out


MASK_NETWORK_SETTINGS = {"moving": "mask.learned.weights", "which": "mask.learned.which_weights"}
"""The setting (`--set`) that names each output's checkpoint."""


def check_mask_networks(cfg: MaskConfig) -> None:
    """Loads the mask networks that settings `cfg` use (`load_masknet`, once per process): the mask network of
    method "learned", the per-motion network of `which` "learned" (with the "motion" and "learned" masks), so
    that a checkpoint that cannot be used is refused before any work, not only when a frame needs it.

    Raises:
        CheckpointError: a checkpoint that is missing, unreadable, of another kind or does not fit, named by
            its setting (`mask.learned.weights: PATH: no mask network checkpoint there`).
    """
    asked = {"moving": cfg.learned.weights} if cfg.method == "learned" else {}
    if cfg.which == "learned" and cfg.method in ("motion", "learned"):
        asked["which"] = cfg.learned.which_weights
    if not asked:
        return
    from mosegpipe.masks.learned.net import load_masknet, shipped_path  # torch: only when a network is asked for
    from mosegpipe.masks.learned.which import QUERY_CHANNELS

    inputs = {"moving": NUM_CHANNELS, "which": NUM_CHANNELS + QUERY_CHANNELS}
    for output, path in asked.items():
        try:
            net = load_masknet(path, output)
            if net.in_channels != inputs[output]:
                raise CheckpointError(
                    f"{path or shipped_path(output)}: a mask network of {net.in_channels} input channels, "
                    f"not {inputs[output]}"
                )
        except CheckpointError as exc:
            raise CheckpointError(f"{MASK_NETWORK_SETTINGS[output]}: {exc}") from exc
