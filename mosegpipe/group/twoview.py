"""Two-view models, in one place: fits (least squares and robust), residuals and the criterion that chooses.

Every caller that relates two frames' points — the camera's homography of the dense flow, the rigid check,
the geometric and joint groupings, the world's parallax, the masks' per-motion steps — goes through these:

- `least_squares(kind, a, b)`: the homography or fundamental matrix of all correspondences a -> b (DLT /
  eight-point, no sampling), None when degenerate.
- `robust_fit(kind, a, b, method, threshold_px, ...)`: the model of most correspondences (OpenCV's RANSAC or
  USAC MAGSAC++) and its inlier mask.
- `transfer_px(h, a, b)`: the homography's transfer error; `sampson_sq` / `sampson_px`: the first-order
  geometric distance to a fundamental matrix's epipolar constraint (Hartley & Zisserman eq. 11.9).
- `gric(...)`: Torr's geometric robust information criterion, which compares models of different
  dimension on the same correspondences (a planar or distant scene keeps the homography).

Points are (n, 2) float64 pixels; matrices (3, 3) float64 map a -> b (b^T F a = 0 for F).
"""

from __future__ import annotations

from typing import Literal

import cv2
import numpy as np
import numpy.typing as npt

Kind = Literal["homography", "fundamental"]
Method = Literal["ransac", "magsac"]

MIN_FUNDAMENTAL = 15
"""The fewest points a fundamental matrix is fitted to: 8 determine it, but barely constrain it."""

_ROBUST = {
    "ransac": {"homography": cv2.RANSAC, "fundamental": cv2.FM_RANSAC},
    "magsac": {"homography": cv2.USAC_MAGSAC, "fundamental": cv2.USAC_MAGSAC},
}


def _valid(mat: npt.NDArray[np.float64] | None) -> npt.NDArray[np.float64] | None:
    if mat is None or mat.shape != (3, 3) or not np.all(np.isfinite(mat)):
        return None
    return np.asarray(mat, dtype=np.float64)


def least_squares(kind: Kind, a: npt.NDArray[np.float64], b: npt.NDArray[np.float64]) -> npt.NDArray[np.float64] | None:
    """The (3, 3) model of all correspondences a -> b (no sampling), None when degenerate."""
    if kind == "homography":
        mat, _ = cv2.findHomography(a, b, 0)
    else:
        mat, _ = cv2.findFundamentalMat(a, b, cv2.FM_8POINT)
    return _valid(mat)


def robust_fit(
    kind: Kind,
    a: npt.NDArray[np.floating],
    b: npt.NDArray[np.floating],
    method: Method,
    threshold_px: float,
    max_iters: int | None = None,
    confidence: float | None = None,
) -> tuple[npt.NDArray[np.float64] | None, npt.NDArray[np.bool_] | None]:
    """The model of most correspondences a -> b and its inliers, by RANSAC or MAGSAC++ (OpenCV).

    Args:
        kind: homography or fundamental matrix.
        a, b: (n, 2) float32 or float64 points, pixels.
        method: "ransac" (OpenCV's RANSAC / FM_RANSAC) or "magsac" (USAC MAGSAC++).
        threshold_px: the inlier distance (transfer error / Sampson distance), pixels.
        max_iters, confidence: the sampler's limits (None: OpenCV's defaults).

    Returns:
        ((3, 3) float64 model or None, (n,) bool inliers or None): None where no model was found.
    """
    flag = _ROBUST[method][kind]
    if kind == "homography":  # OpenCV's defaults: 2000 iterations, confidence 0.995
        iters, conf = 2000 if max_iters is None else max_iters, 0.995 if confidence is None else confidence
        mat, mask = cv2.findHomography(a, b, flag, threshold_px, maxIters=iters, confidence=conf)
    else:  # OpenCV's defaults: confidence 0.99, 1000 iterations
        conf, iters = 0.99 if confidence is None else confidence, 1000 if max_iters is None else max_iters
        mat, mask = cv2.findFundamentalMat(a, b, flag, threshold_px, conf, iters)
    if mat is None or mat.shape != (3, 3):
        return None, None
    inliers = None if mask is None or len(mask) != len(a) else np.asarray(mask.ravel().astype(bool))
    return np.asarray(mat, dtype=np.float64), inliers


def transfer_sq(
    h_mat: npt.NDArray[np.float64], a: npt.NDArray[np.float64], b: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]:
    """(n,) squared transfer error of each correspondence a -> b under the homography, pixels^2."""
    p = np.c_[a, np.ones(len(a))] @ h_mat.T
    w = np.where(np.abs(p[:, 2:]) < 1e-12, 1e-12, p[:, 2:])
    return np.asarray(np.sum((p[:, :2] / w - b) ** 2, axis=1))


def transfer_px(
    h_mat: npt.NDArray[np.float64], a: npt.NDArray[np.float64], b: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]:
    """(n,) transfer error of each correspondence a -> b under the homography, pixels."""
    return np.asarray(np.sqrt(transfer_sq(h_mat, a, b)))


def sampson_sq(
    f_mat: npt.NDArray[np.float64], a: npt.NDArray[np.float64], b: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]:
    """(n,) squared Sampson distance of each correspondence a -> b to the epipolar constraint, pixels^2."""
    ah = np.c_[a, np.ones(len(a))]
    bh = np.c_[b, np.ones(len(b))]
    fa = ah @ f_mat.T  # epipolar lines in the second image
    fb = bh @ f_mat  # in the first
    num = np.sum(bh * fa, axis=1) ** 2
    return np.asarray(num / np.maximum(fa[:, 0] ** 2 + fa[:, 1] ** 2 + fb[:, 0] ** 2 + fb[:, 1] ** 2, 1e-12))


def sampson_px(
    f_mat: npt.NDArray[np.float64], a: npt.NDArray[np.float64], b: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]:
    """(n,) Sampson distance of each correspondence a -> b to the epipolar constraint, pixels."""
    return np.asarray(np.sqrt(sampson_sq(f_mat, a, b)))


def gric(errors_sq: npt.NDArray[np.float64], sigma_px: float, d: int, k: int, r: int = 4) -> float:
    """Torr's geometric robust information criterion of a two-view model (lower is better).

    Args:
        errors_sq: (n,) squared residuals of the correspondences, pixels^2.
        sigma_px: the noise of a correspondence, pixels.
        d: the dimension of the model's manifold (homography, affine, translation 2, fundamental matrix 3).
        k: the model's parameters (homography 8, fundamental matrix 7, affine 6, translation 2).
        r: the dimension of a correspondence (4: two image points).
    """
    n = errors_sq.size
    rho = np.minimum(errors_sq / sigma_px**2, 2.0 * (r - d))
    return float(rho.sum() + np.log(r) * d * n + np.log(r * max(n, 1)) * k)
