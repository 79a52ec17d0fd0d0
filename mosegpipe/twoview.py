"""Two-view geometry: the homography and the fundamental matrix of point correspondences, their
residuals, the penalised criterion that chooses between them, and plane + parallax.

A camera that rotates, zooms or sees a distant or planar scene moves every static point by one
homography H; a camera that translates in a scene with depth moves them by a fundamental matrix F
(each point stays on its epipolar line, at a position set by its depth). Torr's GRIC (geometric
robust information criterion; Torr, "Bayesian model estimation and selection for epipolar
geometry and generic manifold fitting", IJCV 2002) weighs each model's robust residuals against its
degrees of freedom, so that F is chosen only where the parallax is real.

Plane + parallax (Irani & Anandan 1996; Sawhney 1994): with H induced by a plane and compatible with
F, a static point x of the reference image is seen at x' = (H x + g e') / (h3 . x + g e'3) in the
other, with e' the epipole and g one projective depth per point that every other frame of the same
rigid scene shares (up to one scale per frame). A mover that slides along its epipolar lines
satisfies each F, but not one depth in all frames.

Points are (N, 2) float pixel coordinates (x, y); matrices (3, 3) float64 map the first image's
homogeneous points to the second's.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import numpy.typing as npt

Points = npt.NDArray[np.floating]


def _homogeneous(p: Points) -> npt.NDArray[np.float64]:
    p = np.asarray(p, np.float64).reshape(-1, 2)
    return np.concatenate([p, np.ones((p.shape[0], 1))], axis=1)


def fit_homography(
    p: Points, q: Points, threshold_px: float = 1.0, iterations: int = 2000
) -> tuple[npt.NDArray[np.float64] | None, npt.NDArray[np.bool_]]:
    """The homography q ~ H p fitted by OpenCV's USAC MAGSAC++.

    Args:
        p, q: (N, 2) float corresponding points (pixels).
        threshold_px: the inlier threshold on the transfer error (pixels).
        iterations: at most this many robust iterations.

    Returns:
        (H (3, 3) float64 or None when N < 4 or the fit fails, inliers (N,) bool).
    """
    p32, q32 = np.asarray(p, np.float32).reshape(-1, 2), np.asarray(q, np.float32).reshape(-1, 2)
    none = np.zeros(p32.shape[0], bool)
    if p32.shape[0] < 4:
        return None, none
    hom, mask = cv2.findHomography(p32, q32, cv2.USAC_MAGSAC, threshold_px, maxIters=iterations, confidence=0.999)
    if hom is None or mask is None:
        return None, none
    return hom.astype(np.float64), mask.ravel().astype(bool)


def fit_fundamental(
    p: Points, q: Points, threshold_px: float = 1.0, iterations: int = 2000
) -> tuple[npt.NDArray[np.float64] | None, npt.NDArray[np.bool_]]:
    """The fundamental matrix (q^T F p = 0) fitted by OpenCV's USAC MAGSAC++.

    Args:
        p, q: (N, 2) float corresponding points (pixels).
        threshold_px: the inlier threshold on the distance to the epipolar line (pixels).
        iterations: at most this many robust iterations.

    Returns:
        (F (3, 3) float64 or None when N < 8 or the fit fails, inliers (N,) bool).
    """
    p32, q32 = np.asarray(p, np.float32).reshape(-1, 2), np.asarray(q, np.float32).reshape(-1, 2)
    none = np.zeros(p32.shape[0], bool)
    if p32.shape[0] < 8:
        return None, none
    fun, mask = cv2.findFundamentalMat(p32, q32, cv2.USAC_MAGSAC, threshold_px, 0.999, iterations)
    if fun is None or mask is None or fun.shape != (3, 3):
        return None, none
    return fun.astype(np.float64), mask.ravel().astype(bool)


def transfer_error(hom: npt.NDArray[np.float64], p: Points, q: Points) -> npt.NDArray[np.float64]:
    """(N,) float64: |q - H p| per correspondence (pixels); inf where H sends p to infinity."""
    w = _homogeneous(p) @ np.asarray(hom, np.float64).T
    with np.errstate(divide="ignore", invalid="ignore"):
        err = np.linalg.norm(w[:, :2] / w[:, 2:] - np.asarray(q, np.float64).reshape(-1, 2), axis=1)
    return np.where(np.isfinite(err), err, np.inf)


def sampson_distance(fun: npt.NDArray[np.float64], p: Points, q: Points) -> npt.NDArray[np.float64]:
    """(N,) float64: the Sampson distance of each correspondence to F (pixels).

    The first-order geometric distance of (p, q) to the variety q^T F p = 0: the square root of
    (q^T F p)^2 / ((F p)_1^2 + (F p)_2^2 + (F^T q)_1^2 + (F^T q)_2^2); 0 for an exact match.
    """
    f = np.asarray(fun, np.float64)
    ph, qh = _homogeneous(p), _homogeneous(q)
    fp, ftq = ph @ f.T, qh @ f
    algebraic = np.sum(qh * fp, axis=1)
    norm = fp[:, 0] ** 2 + fp[:, 1] ** 2 + ftq[:, 0] ** 2 + ftq[:, 1] ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        dist = np.abs(algebraic) / np.sqrt(norm)
    return np.where(norm > 0, dist, 0.0)


GRIC_MODELS: dict[str, tuple[int, int]] = {"homography": (2, 8), "fundamental": (3, 7)}
"""Model -> (d, the dimension of the variety it constrains correspondences to; k, its parameters)."""


def gric(residuals_px: npt.ArrayLike, sigma_px: float, model: str) -> float:
    """Torr's GRIC of a model's residuals: lower is better.

    GRIC = sum_i min(e_i^2 / sigma^2, 2 (r - d)) + log(r) d n + log(r n) k, with r = 4 (two 2-D
    points per correspondence) and (d, k) from GRIC_MODELS: the robust cost of the residuals plus the
    price of the variety's dimension and of the model's parameters.

    Args:
        residuals_px: (N,) residuals in pixels (transfer error for H, Sampson distance for F).
        sigma_px: the residuals' noise standard deviation (pixels), > 0.
        model: "homography" or "fundamental".

    Returns:
        The criterion (a float).

    Raises:
        ValueError: unknown model or sigma <= 0.
    """
    if model not in GRIC_MODELS:
        raise ValueError(f"model {model!r} is not one of {', '.join(GRIC_MODELS)}")
    if not sigma_px > 0:
        raise ValueError(f"sigma_px={sigma_px} must be > 0")
    d, k = GRIC_MODELS[model]
    e2 = np.square(np.asarray(residuals_px, np.float64).ravel()) / sigma_px**2
    n, r = e2.size, 4
    robust = np.minimum(np.nan_to_num(e2, nan=np.inf, posinf=np.inf), 2.0 * (r - d))
    return float(robust.sum() + math.log(r) * d * n + math.log(r * max(n, 1)) * k)


def epipole(fun: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """(3,) float64 unit vector: the epipole in the second image (e'^T F = 0), homogeneous."""
    _, _, vt = np.linalg.svd(np.asarray(fun, np.float64).T)
    e: npt.NDArray[np.float64] = vt[-1] / np.linalg.norm(vt[-1])
    return e


def compatible_homography(
    fun: npt.NDArray[np.float64], hom: npt.NDArray[np.float64], p: Points, q: Points
) -> npt.NDArray[np.float64]:
    """The homography compatible with F (H^T F skew-symmetric) closest to explaining (p, q).

    Every such homography is [e']x F + e' a^T (the plane's vector a free, Hartley & Zisserman
    result 13.3); a is solved by linear least squares from q x (H p) = 0 over the given points,
    those of the reference plane (e.g. the inliers of `hom`). Falls back to `hom` when fewer than
    3 points are given.

    Args:
        fun: (3, 3) F.
        hom: (3, 3) a homography of the plane (the fallback).
        p, q: (N, 2) the plane's corresponding points (pixels).

    Returns:
        (3, 3) float64, scaled so that its last entry is 1 where it is not near 0.
    """
    ph, qh = _homogeneous(p), _homogeneous(q)
    if ph.shape[0] < 3:
        return np.asarray(hom, np.float64)
    e = epipole(fun)
    ex = np.array([[0.0, -e[2], e[1]], [e[2], 0.0, -e[0]], [-e[1], e[0], 0.0]])
    base = ex @ np.asarray(fun, np.float64)
    # q x (base p) + (q x e') (p . a) = 0: three equations per point, linear in a.
    left = np.cross(qh, np.broadcast_to(e, qh.shape))[:, :, None] * ph[:, None, :]  # (N, 3, 3)
    right = -np.cross(qh, ph @ base.T)  # (N, 3)
    a = np.linalg.lstsq(left.reshape(-1, 3), right.reshape(-1), rcond=None)[0]
    out = base + np.outer(e, a)
    return out / out[2, 2] if abs(out[2, 2]) > 1e-12 else out


def parallax_basis(
    hom: npt.NDArray[np.float64], e: npt.NDArray[np.float64], p: Points
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Where the plane sends each point and the direction its parallax takes, to first order.

    A static point with projective depth g is seen at H p + g v (pixels) with
    v = (e'_xy - e'_3 H p) / (h3 . p) for small parallax: along the line from H p to the epipole.

    Args:
        hom: (3, 3) the plane's homography (compatible with the epipole's F).
        e: (3,) the epipole in the second image (homogeneous).
        p: (N, 2) points of the first image (pixels).

    Returns:
        (H p (N, 2), v (N, 2)), float64 pixels.
    """
    w = _homogeneous(p) @ np.asarray(hom, np.float64).T
    w3 = np.where(np.abs(w[:, 2:]) > 1e-12, w[:, 2:], 1e-12)
    mapped = w[:, :2] / w3
    v = (e[None, :2] - e[2] * mapped) / w3
    return mapped, v


def shared_depth_residual(
    parallax: list[npt.NDArray[np.float64]], basis: list[npt.NDArray[np.float64]], scales: npt.ArrayLike
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Each point's one projective depth over several frames, and how far its parallax is from it.

    Frame u's parallax of a static point is g c_u v_u (`parallax_basis`): g the point's, c_u the
    frame's. g is solved by least squares over the frames, and the residual is the root of the sum
    of |parallax_u - g c_u v_u|^2: the distance off the epipolar lines and the disagreement of
    the depths, in pixels.

    Args:
        parallax: per frame u, (N, 2) q_u - H_u p (pixels).
        basis: per frame u, (N, 2) v_u.
        scales: (U,) c_u (the first is usually 1).

    Returns:
        (g (N,), residual (N,)), float64.
    """
    c = np.asarray(scales, np.float64).ravel()
    num = sum(cu * np.sum(r * v, axis=1) for cu, r, v in zip(c, parallax, basis))
    den = sum(cu**2 * np.sum(v * v, axis=1) for cu, v in zip(c, basis))
    g = np.asarray(num, np.float64) / np.maximum(np.asarray(den, np.float64), 1e-12)
    sq = sum(np.sum(np.square(r - (g * cu)[:, None] * v), axis=1) for cu, r, v in zip(c, parallax, basis))
    return g, np.sqrt(np.asarray(sq, np.float64))


def depth_scale(
    parallax: npt.NDArray[np.float64], basis: npt.NDArray[np.float64], reference: npt.NDArray[np.float64]
) -> float:
    """The scale c of one frame's depths against the reference frame's: g_u = c g_ref by robust least squares.

    Args:
        parallax, basis: (N, 2) the frame's parallax and its directions (static points, e.g. F's inliers).
        reference: (N,) the same points' depths in the reference frame (its c = 1).

    Returns:
        c (0.0 when the reference depths are all 0).
    """
    v2 = np.sum(basis * basis, axis=1)
    g = np.sum(parallax * basis, axis=1) / np.maximum(v2, 1e-12)
    ref = np.asarray(reference, np.float64)
    w = ref * ref
    if not w.sum() > 0:
        return 0.0
    c = float(np.sum(ref * g) / w.sum())
    # one reweighting: points far off the first line (other motions left in the inliers) count less
    off = np.abs(g - c * ref)
    keep = off <= 3.0 * max(float(np.median(off)), 1e-9)
    return float(np.sum((ref * g)[keep]) / max(float(w[keep].sum()), 1e-12)) if keep.any() else c
