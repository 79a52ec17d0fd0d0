"""The DAVIS protocol's classical baseline (mosegpipe.evaluation.davis, method "flow-homography"):
the pixels that the dominant homography of the dense optical flow does not explain, as one moving object."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe.errors import check_choice
from mosegpipe.points.flow import DenseFlow, FlowConfig, camera_residual, fit_camera, to_gray
from mosegpipe.types import CameraFit, DisPreset

# ---------------------------------------------------------------------------------------------
# Methods


@dataclass(frozen=True)
class FlowHomographyConfig:
    """Settings of the flow-homography baseline, chosen on the 20 DEV clips only (all 25 frames).

    Measured there (mean J, no-oracle foreground): DIS "medium" 0.465 vs "fast" 0.411 at their best
    thresholds, at 1.4 s vs 0.6 s per 25-frame clip (flow + fit, one core): medium is kept. Over
    threshold_px 1-4 x noise_factor 0-5, 1.5 px / 3 scored best (1.0-2.0 px with 3: within 0.005).
    Medium underestimates the flow on tiny images (under ~100 px a side): use "fast" there.

    Attributes:
        preset: DIS preset, "medium" or "fast".
        grid_step_px: spacing of the flow samples the homography is fitted to, pixels.
        ransac_px: reprojection threshold of the robust fit, pixels.
        camera_fit: the robust fit (`FlowConfig.camera_fit`): USAC MAGSAC, as the baseline was first
            measured (the pipeline's motion masks fit with RANSAC since; the baseline stays as defined).
        threshold_px: a pixel is foreground where |flow - homography flow| exceeds this, pixels ...
        noise_factor: ... or this many robust noise scales (1.4826 x median residual), whichever is larger.
        open_px: side of the square opening that removes isolated specks, pixels (0 = none).
        close_px: side of the square closing that fills small holes, pixels (0 = none).
    """

    preset: DisPreset = "medium"
    grid_step_px: int = 8
    ransac_px: float = 1.0
    camera_fit: CameraFit = "magsac"
    threshold_px: float = 1.5
    noise_factor: float = 3.0
    open_px: int = 5
    close_px: int = 9


def _residual_foreground(
    flow: DenseFlow, a: npt.NDArray[np.uint8], b: npt.NDArray[np.uint8], cfg: FlowHomographyConfig
) -> npt.NDArray[np.bool_]:
    """(H, W) pixels of gray image `a` whose flow to `b` the best homography does not explain."""
    fwd = flow(a, b)
    fit = FlowConfig(
        preset=cfg.preset, grid_step_px=cfg.grid_step_px, ransac_px=cfg.ransac_px, camera_fit=cfg.camera_fit
    )
    residual = camera_residual(fwd, fit_camera(fwd, None, fit))
    fg = (residual > max(cfg.threshold_px, cfg.noise_factor * 1.4826 * float(np.median(residual)))).astype(np.uint8)
    if cfg.open_px:
        fg = cv2.morphologyEx(fg, cv2.MORPH_OPEN, np.ones((cfg.open_px, cfg.open_px), np.uint8))
    if cfg.close_px:
        fg = cv2.morphologyEx(fg, cv2.MORPH_CLOSE, np.ones((cfg.close_px, cfg.close_px), np.uint8))
    return fg > 0


def flow_homography_labels(
    images: npt.NDArray[np.uint8], cfg: FlowHomographyConfig = FlowHomographyConfig()
) -> npt.NDArray[np.uint8]:
    """What geometry alone gets: foreground = flow that the camera's homography does not explain.

    Per consecutive frame pair: DIS optical flow on grayscale, a homography fitted robustly to the
    flow on a grid of pixels (the dominant, i.e. camera, motion), residual = |flow - homography
    flow| per pixel, foreground = residual above a threshold, then a morphological opening and
    closing. Frame t uses the flow t -> t + 1; the last frame the backward flow T-1 -> T-2.

    Args:
        images: (T, H, W, 3) uint8 RGB.
        cfg: settings.

    Returns:
        (T, H, W) uint8: 0 = background (camera motion), 1 = foreground. A single frame is all 0.
    """
    check_choice("preset", cfg.preset, ("fast", "medium"))
    gray = [to_gray(im, 1.0) for im in images]
    dis = DenseFlow(FlowConfig(preset=cfg.preset))
    out = np.zeros(np.asarray(images).shape[:3], dtype=np.uint8)
    if len(gray) < 2:
        return out
    for t in range(len(gray)):
        nxt = t + 1 if t + 1 < len(gray) else t - 1
        out[t] = _residual_foreground(dis, gray[t], gray[nxt], cfg)
    return out
