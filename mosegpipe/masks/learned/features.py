"""The learned masks' per-pixel inputs, from the flow evidence the pipeline already computes.

Per frame t of a stack (a clip, or a whole video's window), at `LearnedMaskConfig.scale` of the frame
size (1/4: 854x480 -> 214x120, 640x480 -> 160x120), `NUM_CHANNELS` float32 channels:

0. log(1 + camera residual), full-resolution pixels (`flow.camera_residual`, the smaller of both
   directions where the stack has them, as the "motion" masks use it);
1. the same minus its median over the frame (a frame-relative score: slow and fast movers alike);
2. the mean of channel 1 of the frames before and after, each sampled where t's flow leads into it
   (the evidence of the neighbours, as the "motion" masks' temporal step carries it; t's own where
   the stack has no neighbour);
3. log(1 + forward-backward error), clipped at 50 px;
4-5. the flow away from the frame (into it, for the last) minus its median, / 8 px, clipped to +-4;
6-8. the frame in CIE Lab (OpenCV's 8-bit), L / 128 and a, b / 32 around their middle.

Everything is a pure function of the frames and the `FrameMotion`: training computes these with the
same code (`clip_features`) as inference does, so the network sees the same inputs in both.
This module needs NumPy and OpenCV only (not torch).
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe.configs.masks import LearnedMaskConfig
from mosegpipe.points.flow import FrameMotion

__all__ = ["NUM_CHANNELS", "LearnedMaskConfig", "clip_features", "neighbours_along", "net_flows", "net_size"]

NUM_CHANNELS = 9
"""Input channels of the mask network (see the module docstring)."""

_LAB_SCALE = np.array([128.0, 32.0, 32.0], np.float32)
"""OpenCV's 8-bit Lab minus 128, divided by this: L spans 255 levels, a and b of natural images a few tens."""


def net_size(size_hw: tuple[int, int], scale: float) -> tuple[int, int]:
    """(h, w) of the network's input for frames of `size_hw`."""
    return max(8, round(size_hw[0] * scale)), max(8, round(size_hw[1] * scale))


def _area(x: npt.NDArray[np.float32], hw: tuple[int, int]) -> npt.NDArray[np.float32]:
    if x.shape[:2] == hw:
        return x.astype(np.float32, copy=False)
    out: npt.NDArray[np.float32] = cv2.resize(x, (hw[1], hw[0]), interpolation=cv2.INTER_AREA)
    return out


def net_flows(
    motion: FrameMotion, hw: tuple[int, int]
) -> tuple[list[npt.NDArray[np.float32]], list[npt.NDArray[np.float32]]]:
    """The stack's forward and backward flows at net size `hw`, in net-size pixels (empty when not kept)."""
    to_net = np.float32(hw[1] / motion.residual.shape[2])
    forward = [] if motion.forward is None else [_area(f, hw) * to_net for f in motion.forward]
    backward = [] if motion.backward is None else [_area(f, hw) * to_net for f in motion.backward]
    return forward, backward


def _sample(
    values: npt.NDArray[np.float32], flow: npt.NDArray[np.float32], grid: tuple[npt.NDArray[np.float32], ...]
) -> npt.NDArray[np.float32]:
    """`values` read where `flow` (net-size pixels) leads each pixel (border pixels repeated)."""
    out: npt.NDArray[np.float32] = cv2.remap(
        values, grid[0] + flow[..., 0], grid[1] + flow[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
    )
    return out


def neighbours_along(
    values: Sequence[npt.NDArray[np.float32]],
    forward: Sequence[npt.NDArray[np.float32]],
    backward: Sequence[npt.NDArray[np.float32]],
    t: int,
    grid: tuple[npt.NDArray[np.float32], ...],
) -> list[npt.NDArray[np.float32]]:
    """Frame t's neighbours' `values` carried to it: frame t-1's read along t's flow back, frame t+1's along its
    flow forward (`net_flows`), each when that frame and flow exist."""
    near = []
    if t > 0 and len(backward) >= t:
        near.append(_sample(values[t - 1], backward[t - 1], grid))
    if t + 1 < len(values) and len(forward) > t:
        near.append(_sample(values[t + 1], forward[t], grid))
    return near


def clip_features(
    images: npt.NDArray[np.uint8],
    motion: FrameMotion,
    scale: float = 0.25,
    first: int = 0,
    flows: tuple[list[npt.NDArray[np.float32]], list[npt.NDArray[np.float32]]] | None = None,
) -> npt.NDArray[np.float32]:
    """The network's input for frames first..T-1 of a stack.

    Args:
        images: (T, H, W, 3) uint8 RGB, T >= 2.
        motion: the stack's flow evidence (`moving_pixels.stack_motion` or a `FlowStream`'s), with its flows.
        scale: the network's input scale (`LearnedMaskConfig.scale`).
        first: features of frames first..T-1 only (the frames before serve as neighbours).
        flows: `net_flows(motion, net_size(...))` when the caller has them already (they are computed otherwise).

    Returns:
        (T - first, NUM_CHANNELS, h, w) float32, (h, w) = `net_size`.
    """
    num, height, width = images.shape[:3]
    hw = net_size((height, width), scale)
    to_full = np.float32(1.0 / motion.scale)
    to_net = np.float32(hw[1] / motion.residual.shape[2])
    forward, backward = net_flows(motion, hw) if flows is None else flows
    logs, rel = [], []
    for t in range(num):
        lg = np.log1p(_area(motion.residual[t] * to_full, hw))
        logs.append(lg)
        rel.append(lg - np.float32(np.median(lg)))
    ys, xs = np.mgrid[0 : hw[0], 0 : hw[1]].astype(np.float32)
    grid = (xs, ys)
    out = np.empty((num - first, NUM_CHANNELS, *hw), np.float32)
    for t in range(first, num):
        c = out[t - first]
        c[0], c[1] = logs[t], rel[t]
        near = neighbours_along(rel, forward, backward, t, grid)
        c[2] = np.mean(near, axis=0) if near else rel[t]
        err = np.minimum(np.nan_to_num(motion.fb_error[t], nan=1e3, posinf=1e3), 1e3) * to_full
        c[3] = np.log1p(np.minimum(_area(err.astype(np.float32), hw), 50.0))
        flow = forward[t] if t < len(forward) else (backward[t - 1] if backward and t >= 1 else None)
        if flow is None:
            c[4:6] = 0.0
        else:
            full = flow / to_net * to_full  # full-resolution pixels
            med = np.median(full.reshape(-1, 2), axis=0)
            c[4:6] = np.clip((full - med) / 8.0, -4.0, 4.0).transpose(2, 0, 1)
        small = cv2.resize(images[t], (hw[1], hw[0]), interpolation=cv2.INTER_AREA)
        lab = cv2.cvtColor(small, cv2.COLOR_RGB2LAB).astype(np.float32)
        c[6:9] = ((lab - 128.0) / _LAB_SCALE).transpose(2, 0, 1)
    return out
