from __future__ import annotations

import cv2
import numpy as np
import pytest

from mosegpipe.errors import InputError
from mosegpipe.points.sift import MatchConfig, match_sift


def _scene(h: int = 240, w: int = 320) -> np.ndarray:
    """Blob texture plus a few rectangles: plenty of SIFT keypoints at several scales."""
    rng = np.random.default_rng(0)
    noise = cv2.GaussianBlur(rng.random((h, w)).astype(np.float32), (0, 0), 3.0)
    img = cv2.normalize(noise, None, 0, 200, cv2.NORM_MINMAX)
    for _ in range(12):
        x, y = rng.integers(0, w - 30), rng.integers(0, h - 30)
        cv2.rectangle(img, (int(x), int(y)), (int(x + rng.integers(8, 30)), int(y + rng.integers(8, 30))), 255, -1)
    return np.repeat(img.astype(np.uint8)[:, :, None], 3, axis=2)


@pytest.fixture(scope="module")
def pair() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    img1 = _scene()
    affine = cv2.getRotationMatrix2D((160, 120), 25, 0.8)  # rotate 25 deg, scale 0.8
    affine[:, 2] += [10, -5]
    img2 = cv2.warpAffine(img1, affine, (300, 220))  # a different size too
    return img1, img2, affine


def test_rotated_scaled_copy_matches_are_geometrically_consistent(pair) -> None:
    img1, img2, affine = pair
    m = match_sift(img1, img2)

    assert m.size1_hw == (240, 320) and m.size2_hw == (220, 300)
    assert m.num_matches >= 100
    assert m.xy1.dtype == m.xy2.dtype == m.score.dtype == np.float32
    _, inliers = cv2.findHomography(m.xy1, m.xy2, cv2.RANSAC, 3.0)
    assert inliers.mean() > 0.8
    predicted = m.xy1 @ affine[:, :2].T + affine[:, 2]
    err = np.linalg.norm(predicted - m.xy2, axis=1)
    assert np.median(err) < 0.5 and (err < 3).mean() > 0.9


def test_one_match_per_keypoint_scores_sorted_below_ratio(pair) -> None:
    img1, img2, _ = pair
    cfg = MatchConfig(ratio=0.7)
    m = match_sift(img1, img2, cfg)
    assert len(np.unique(np.round(m.xy2, 2), axis=0)) == m.num_matches
    assert len(np.unique(np.round(m.xy1, 2), axis=0)) == m.num_matches
    assert (m.score < cfg.ratio).all() and (m.score >= 0).all()
    assert (np.diff(m.score) >= 0).all()


def test_stricter_ratio_keeps_fewer_matches(pair) -> None:
    img1, img2, _ = pair
    loose = match_sift(img1, img2, MatchConfig(ratio=0.9, cross_check=False))
    strict = match_sift(img1, img2, MatchConfig(ratio=0.5, cross_check=False))
    assert 0 < strict.num_matches < loose.num_matches


def test_flann_agrees_with_brute_force(pair) -> None:
    img1, img2, _ = pair
    bf = match_sift(img1, img2, MatchConfig(matcher="bf"))
    flann = match_sift(img1, img2, MatchConfig(matcher="flann"))
    common = {tuple(r) for r in np.round(np.hstack([bf.xy1, bf.xy2]), 2)} & {
        tuple(r) for r in np.round(np.hstack([flann.xy1, flann.xy2]), 2)
    }
    assert len(common) > 0.9 * bf.num_matches


def test_blank_image_gives_no_matches() -> None:
    blank = np.zeros((50, 60, 3), np.uint8)
    m = match_sift(blank, _scene())
    assert m.num_matches == 0
    assert m.xy1.shape == (0, 2) and m.xy2.shape == (0, 2) and m.score.shape == (0,)
    assert m.size1_hw == (50, 60) and m.size2_hw == (240, 320)


def test_bad_inputs() -> None:
    with pytest.raises(InputError, match="img1 must be uint8"):
        match_sift(np.zeros((10, 10), np.float32), np.zeros((10, 10), np.uint8))
    with pytest.raises(InputError, match="img2"):
        match_sift(np.zeros((10, 10), np.uint8), np.zeros((10, 10, 4), np.uint8))
    with pytest.raises(ValueError, match="ratio"):
        MatchConfig(ratio=1.5)
