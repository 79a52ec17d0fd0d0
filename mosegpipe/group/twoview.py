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
- Plane + parallax (Irani & Anandan 1996; Sawhney 1994; `epipole`, `compatible_homography`, `parallax_basis`,
  `depth_scale`, `shared_depth_residual`): with H induced by a plane and compatible with F, a static point x of
  the reference image is seen at x' = (H x + g e') / (h3 . x + g e'3) in the other, with e' the epipole and g
  one projective depth per point that every other frame of the same rigid scene shares (up to one scale per
  frame). A mover that slides along its epipolar lines satisfies each F, but not one depth in all frames.

Points are (n, 2) float64 pixels; matrices (3, 3) float64 map a -> b (b^T F a = 0 for F).
"""

from __future__ import annotations

from typing import Literal

import cv2
import numpy as np
import numpy.typing as npt

Kind = Literal["homography", "fundamental"]
Points = npt.NDArray[np.floating]
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
    try:
        if kind == "homography":  # OpenCV's defaults: 2000 iterations, confidence 0.995
            iters, conf = 2000 if max_iters is None else max_iters, 0.995 if confidence is None else confidence
            mat, mask = cv2.findHomography(a, b, flag, threshold_px, maxIters=iters, confidence=conf)
        else:  # OpenCV's defaults: confidence 0.99, 1000 iterations
            conf, iters = 0.99 if confidence is None else confidence, 1000 if max_iters is None else max_iters
            mat, mask = cv2.findFundamentalMat(a, b, flag, threshold_px, conf, iters)
    except cv2.error:  # USAC asserts on some degenerate samples (every point on a line, or nearly still)
        return None, None
    if mat is None or mat.shape != (3, 3):
        return None, None
    inliers = None if mask is None or len(mask) != len(a) else np.asarray(mask.ravel().astype(bool))
    return np.asarray(mat, dtype=np.float64), inliers


def fit_with_inliers(
    kind: Kind, p: Points, q: Points, threshold_px: float, iterations: int = 2000
) -> tuple[npt.NDArray[np.float64] | None, npt.NDArray[np.bool_]]:
    """The model of most correspondences p -> q by MAGSAC++ (confidence 0.999), with an inlier mask always.

    Args:
        kind: homography or fundamental matrix.
        p, q: (N, 2) float corresponding points (pixels).
        threshold_px: the inlier distance (transfer error / Sampson distance), pixels.
        iterations: at most this many robust iterations.

    Returns:
        ((3, 3) float64 model, or None with fewer than 4 (H) / 8 (F) points or no fit; (N,) bool inliers,
        all False without a model).
    """
    a, b = np.asarray(p, np.float32).reshape(-1, 2), np.asarray(q, np.float32).reshape(-1, 2)
    none = np.zeros(a.shape[0], bool)
    if a.shape[0] < (4 if kind == "homography" else 8):
        return None, none
    mat, inliers = robust_fit(kind, a, b, "magsac", threshold_px, iterations, 0.999)
    if mat is None or inliers is None:
        return None, none
    return mat, inliers


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


def _homogeneous(p: Points) -> npt.NDArray[np.float64]:
    p = np.asarray(p, np.float64).reshape(-1, 2)
    return np.concatenate([p, np.ones((p.shape[0], 1))], axis=1)


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


def near_sign(depths: npt.NDArray[np.float64]) -> float:
    """+1 or -1: the sign of the near side of the reference plane among projective depths (the side whose depths
    reach farthest from the plane: points in front of it can come arbitrarily near the camera, those behind it
    only as far as infinity)."""
    lo, hi = np.percentile(depths, [1, 99])
    return 1.0 if abs(hi) >= abs(lo) else -1.0


def farthest_depth(static: npt.NDArray[np.float64]) -> float:
    """The farthest depth a static point may have, from the static points' signed depths (near side positive):
    their 2nd percentile less a tenth of their spread (-inf without any); farther is not the static world's."""
    if not static.size:
        return -np.inf
    return float(np.percentile(static, 2) - 0.1 * np.ptp(static))


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
