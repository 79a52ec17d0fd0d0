"""Point trajectories from dense optical flow: a regular grid of points carried along the DIS flow.

KLT follows corners, so its points sit where the texture is, not where the objects are: an object
with little texture gets few tracks, and a small or slow one may get too few for the clustering to
see it. `track_flow` seeds a regular grid over the first frame instead and carries every point from
frame to frame along the dense flow (`mosegpipe.points.flow`, the flows the motion masks compute anyway),
as dense point trajectories are built from optical flow in the literature (Sundaram, Brox and
Keutzer, ECCV 2010). A point is dropped (invisible from then on) when

- its forward flow and the backward flow at its end point disagree: |w + w'|^2 > fb_rel (|w|^2 +
  |w'|^2) + fb_abs_px^2 (occlusions, flow failures, dynamic textures);
- it sits on a motion boundary, where the flow's spatial gradient is large against the flow itself
  (the flow is smoothed across the border there, so the point belongs to neither side);
- its brightness changes by more than `max_brightness` grey levels between its two ends (smoothed
  images): where the image gives the flow nothing to match (noise, an occluder that appears), DIS
  fills the flow in smoothly from the surroundings in both directions, so the two flows agree and
  only the images show the mismatch;
- it leaves the image (`border_px`).

Seeds in flat areas can be left out (`min_texture`): the flow there is the smoothness term's
interpolation from the area's border, right for a rigid object, wrong next to another motion.

`combine_tracks` joins KLT corners and flow points (the flow points nearer than `klt_distance_px` to a
corner are dropped), for `PipelineConfig.tracker` "klt+flow".
"""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe.configs.tracking import FlowTrackConfig
from mosegpipe.points.flow import FlowConfig, FrameMotion, frame_motion, to_gray
from mosegpipe.types import Tracks


def grid_seeds(image: npt.NDArray[np.uint8], cfg: FlowTrackConfig = FlowTrackConfig()) -> npt.NDArray[np.float32]:
    """(N, 2) float32 grid points of the first image (x, y), flat areas left out by cfg.min_texture."""
    h, w = image.shape[:2]
    step = max(float(cfg.min_step_px), float(np.sqrt(h * w / cfg.max_points)))
    margin = max(cfg.border_px, step / 2)
    xs = np.arange(margin, w - margin, step, dtype=np.float32)
    ys = np.arange(margin, h - margin, step, dtype=np.float32)
    gx, gy = np.meshgrid(xs, ys)
    seeds = np.stack([gx.ravel(), gy.ravel()], axis=1).astype(np.float32)
    if cfg.min_texture > 0 and len(seeds):
        gray = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
        eig = cv2.cornerMinEigenVal(gray, blockSize=7, ksize=3)
        at = eig[np.round(seeds[:, 1]).astype(np.int64), np.round(seeds[:, 0]).astype(np.int64)]
        seeds = seeds[at >= cfg.min_texture * float(eig.mean())]
    return seeds


def _sample(field: npt.NDArray[np.float32], xy: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
    """(N, C) bilinear samples of an (h, w, C) field at (N, 2) positions of the field's own pixels."""
    mx = np.ascontiguousarray(xy[:, 0].reshape(-1, 1))
    my = np.ascontiguousarray(xy[:, 1].reshape(-1, 1))
    out = cv2.remap(field, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return np.asarray(out, np.float32).reshape(len(xy), -1)


def _smoothed(image: npt.NDArray[np.uint8], scale: float) -> npt.NDArray[np.float32]:
    """(h, w, 1) float32 grey image at the flow's scale, smoothed by a Gaussian of sigma 1 px."""
    grey = to_gray(image, scale).astype(np.float32)
    return cv2.GaussianBlur(grey, (0, 0), 1.0)[..., None]


def _flow_gradient(flow: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
    """(h, w, 1) float32 |grad u|^2 + |grad v|^2 of a flow field (central differences, per pixel)."""
    total = np.zeros(flow.shape[:2], np.float32)
    for c in range(2):
        gx = cv2.Sobel(flow[..., c], cv2.CV_32F, 1, 0, ksize=1, scale=0.5)
        gy = cv2.Sobel(flow[..., c], cv2.CV_32F, 0, 1, ksize=1, scale=0.5)
        total += gx * gx + gy * gy
    return total[..., None]


def track_flow(
    images: npt.NDArray[np.uint8],
    cfg: FlowTrackConfig = FlowTrackConfig(),
    flow: FlowConfig = FlowConfig(),
    motion: FrameMotion | None = None,
) -> Tracks:
    """Grid points of the first frame carried along the dense flow through a stack of frames.

    Args:
        images: (T, H, W, 3) uint8 RGB.
        cfg: grid and checks.
        flow: the dense flow's settings (used when `motion` is None).
        motion: the stack's flows, if already computed (`frame_motion` with its forward and backward
            flows, at its own scale).

    Returns:
        Tracks (N, T) in full-resolution pixels, visible from frame 0 until lost; N = 0 for a stack
        whose frames are too small for a grid.
    """
    num, h, w = images.shape[0], images.shape[1], images.shape[2]
    seeds = grid_seeds(images[0], cfg)
    xy = np.full((len(seeds), num, 2), np.nan, np.float32)
    visible = np.zeros((len(seeds), num), bool)
    xy[:, 0], visible[:, 0] = seeds, True
    if num < 2 or not len(seeds):
        return Tracks(xy=xy, visible=visible, size_hw=(h, w))
    if motion is None or motion.forward is None or motion.backward is None:
        motion = frame_motion(images, flow)
    assert motion.forward is not None and motion.backward is not None
    s = motion.scale
    alive = np.ones(len(seeds), bool)
    grey = [_smoothed(image, s) for image in images] if cfg.max_brightness > 0 else []
    for t in range(num - 1):
        idx = np.flatnonzero(alive)
        p = xy[idx, t] * s  # at the flow's scale
        fwd = _sample(motion.forward[t], p)
        q = p + fwd
        back = _sample(motion.backward[t], q)
        ok = (
            np.sum((fwd + back) ** 2, axis=1)
            <= cfg.fb_rel * (np.sum(fwd**2, axis=1) + np.sum(back**2, axis=1)) + cfg.fb_abs_px**2 * s * s
        )
        if cfg.boundary_rel >= 0:
            grad = _sample(_flow_gradient(motion.forward[t]), p)[:, 0]
            ok &= grad <= cfg.boundary_rel * np.sum(fwd**2, axis=1) + cfg.boundary_abs
        if grey:
            ok &= np.abs(_sample(grey[t], p)[:, 0] - _sample(grey[t + 1], q)[:, 0]) <= cfg.max_brightness
        q = q / s
        b = cfg.border_px
        ok &= (q[:, 0] >= b) & (q[:, 0] <= w - 1 - b) & (q[:, 1] >= b) & (q[:, 1] <= h - 1 - b)
        alive[idx[~ok]] = False
        xy[idx[ok], t + 1] = q[ok]
        visible[idx[ok], t + 1] = True
    return Tracks(xy=xy, visible=visible, size_hw=(h, w))


def combine_tracks(klt: Tracks, dense: Tracks, distance_px: float) -> Tracks:
    """KLT tracks followed by the flow tracks that start farther than distance_px from every KLT
    point of the first frame (the same frames, so the same T)."""
    first = klt.xy[klt.visible[:, 0], 0]
    keep = np.ones(dense.num_tracks, bool)
    if len(first) and dense.num_tracks and distance_px > 0:
        from scipy.spatial import cKDTree  # on first use: see runtime.import_ahead

        dist, _ = cKDTree(first).query(dense.xy[:, 0], k=1)
        keep = dist > distance_px
    return Tracks(
        xy=np.concatenate([klt.xy, dense.xy[keep]]),
        visible=np.concatenate([klt.visible, dense.visible[keep]]),
        size_hw=klt.size_hw,
    )
