"""Two-view correspondences: OpenCV SIFT keypoints matched with Lowe's ratio test.

The AdelaideRMF benchmark that two-view SubspaceNet is evaluated on was built from SIFT matches;
this stage produces the same kind of input for any image pair.
"""

from __future__ import annotations

import logging

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe.configs.tracking import MatchConfig
from mosegpipe.errors import InputError
from mosegpipe.types import Matches

logger = logging.getLogger(__name__)


def _gray(image: npt.NDArray[np.uint8], name: str) -> npt.NDArray[np.uint8]:
    image = np.asarray(image)
    if image.dtype != np.uint8:
        raise InputError(f"{name} must be uint8, got {image.dtype}")
    if image.ndim == 2:
        return image
    if image.ndim == 3 and image.shape[2] == 3:
        return cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    raise InputError(f"{name} must be (H, W) gray or (H, W, 3) RGB, got shape {image.shape}")


def _detect(sift: cv2.SIFT, gray: npt.NDArray[np.uint8]) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
    keypoints, desc = sift.detectAndCompute(gray, None)
    if desc is None or not keypoints:
        return np.zeros((0, 2), np.float32), np.zeros((0, 128), np.float32)
    xy = np.array([kp.pt for kp in keypoints], dtype=np.float32)
    return xy, np.ascontiguousarray(desc, dtype=np.float32)


def _knn(
    matcher: cv2.DescriptorMatcher, query: npt.NDArray[np.float32], train: npt.NDArray[np.float32], k: int
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float32]]:
    """Indices (Q, k) into train and distances (Q, k); missing neighbours get index -1, distance inf."""
    idx = np.full((len(query), k), -1, dtype=np.int64)
    dist = np.full((len(query), k), np.inf, dtype=np.float32)
    for row in matcher.knnMatch(query, train, k=k):
        for j, m in enumerate(row[:k]):
            idx[m.queryIdx, j] = m.trainIdx
            dist[m.queryIdx, j] = m.distance
    return idx, dist


def _unique_best(keys: npt.NDArray[np.int64], score: npt.NDArray[np.float32]) -> npt.NDArray[np.int64]:
    """Positions of the lowest-score entry for each distinct key (rows of a 2-D key array)."""
    order = np.lexsort((score, *keys.T[::-1])) if keys.ndim == 2 else np.lexsort((score, keys))
    sorted_keys = keys[order]
    first = np.ones(len(order), dtype=bool)
    if len(order) > 1:
        diff = sorted_keys[1:] != sorted_keys[:-1]
        first[1:] = diff.any(axis=1) if keys.ndim == 2 else diff
    return np.sort(order[first])


def match_sift(
    img1: npt.NDArray[np.uint8],
    img2: npt.NDArray[np.uint8],
    cfg: MatchConfig = MatchConfig(),
) -> Matches:
    """Match SIFT keypoints between two images with the ratio test and one match per keypoint.

    Images may differ in size. SIFT finds several orientations at one location; such duplicates
    are merged so that each location in either image takes part in at most one match.

    Args:
        img1: (H1, W1, 3) uint8 RGB or (H1, W1) uint8 gray.
        img2: (H2, W2, 3) uint8 RGB or (H2, W2) uint8 gray.
        cfg: detection and matching settings.

    Returns:
        Matches with xy1, xy2 (N, 2) float32 pixels and score (N,) float32 = Lowe ratio
        (best / second-best descriptor distance, in [0, cfg.ratio); lower is more distinctive),
        sorted by score. N = 0 when either image has no keypoints.

    Raises:
        InputError: an image is not uint8 gray/RGB.
    """
    gray1, gray2 = _gray(img1, "img1"), _gray(img2, "img2")
    size1 = (int(gray1.shape[0]), int(gray1.shape[1]))
    size2 = (int(gray2.shape[0]), int(gray2.shape[1]))
    sift = cv2.SIFT_create(  # type: ignore[attr-defined]
        nfeatures=cfg.nfeatures,
        nOctaveLayers=cfg.n_octave_layers,
        contrastThreshold=cfg.contrast_threshold,
        edgeThreshold=cfg.edge_threshold,
        sigma=cfg.sigma,
    )
    xy1, desc1 = _detect(sift, gray1)
    xy2, desc2 = _detect(sift, gray2)
    empty = Matches(
        xy1=np.zeros((0, 2), np.float32),
        xy2=np.zeros((0, 2), np.float32),
        score=np.zeros(0, np.float32),
        size1_hw=size1,
        size2_hw=size2,
    )
    if len(xy1) == 0 or len(xy2) < 2:
        return empty
    if cfg.matcher == "flann":
        matcher: cv2.DescriptorMatcher = cv2.FlannBasedMatcher({"algorithm": 1, "trees": 4}, {"checks": 64})
    else:
        matcher = cv2.BFMatcher(cv2.NORM_L2)
    idx, dist = _knn(matcher, desc1, desc2, 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(dist[:, 1] > 0, dist[:, 0] / dist[:, 1], 1.0).astype(np.float32)
    keep = (idx[:, 0] >= 0) & (ratio < cfg.ratio)
    if cfg.cross_check:
        back_idx, _ = _knn(matcher, desc2, desc1, 1)
        keep &= back_idx[np.clip(idx[:, 0], 0, None), 0] == np.arange(len(idx))
    i1 = np.flatnonzero(keep)
    i2 = idx[i1, 0]
    score = ratio[i1]
    # One match per keypoint of image 2, then one per location in each image (SIFT duplicates a
    # keypoint per dominant orientation); the most distinctive (lowest ratio) wins each time.
    sel = _unique_best(i2, score)
    i1, i2, score = i1[sel], i2[sel], score[sel]
    for image in (1, 2):
        loc = np.round((xy1[i1] if image == 1 else xy2[i2]) * 100).astype(np.int64)
        sel = _unique_best(loc, score)
        i1, i2, score = i1[sel], i2[sel], score[sel]
    order = np.argsort(score, kind="stable")
    i1, i2, score = i1[order], i2[order], score[order]
    logger.debug("SIFT: %d / %d keypoints, %d matches", len(xy1), len(xy2), len(i1))
    return Matches(xy1=xy1[i1], xy2=xy2[i2], score=score, size1_hw=size1, size2_hw=size2)
