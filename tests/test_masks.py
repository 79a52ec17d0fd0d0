from __future__ import annotations

import numpy as np
import pytest

from mosegpipe.errors import InputError
from mosegpipe.io import default_palette
from mosegpipe.masks import MaskConfig, labels_to_mask, labels_to_masks, overlay_mask
from mosegpipe.types import Tracks


def test_two_points_split_the_image_at_the_bisector() -> None:
    xy = np.array([[2.0, 2.0], [7.0, 2.0]], np.float32)
    mask = labels_to_mask(xy, np.array([0, 1]), (5, 10), MaskConfig(max_distance_px=100))
    expected = np.zeros((5, 10), np.uint8)
    expected[:, :5] = 1  # columns 0..4 are nearer x = 2 (bisector at 4.5)
    expected[:, 5:] = 2
    np.testing.assert_array_equal(mask, expected)
    assert mask.dtype == np.uint8


def test_pixels_far_from_every_point_are_unknown() -> None:
    mask = labels_to_mask(np.array([[10.0, 10.0]]), np.array([3]), (21, 31), MaskConfig(max_distance_px=6))
    yy, xx = np.mgrid[0:21, 0:31]
    dist = np.hypot(xx - 10, yy - 10)
    clear = np.abs(dist - 6) > 0.5  # the distance transform is approximate right at the radius
    np.testing.assert_array_equal(mask[clear], np.where(dist[clear] <= 6, 4, 0))


def test_points_outside_the_image_or_not_finite_are_ignored() -> None:
    xy = np.array([[1.0, 1.0], [-5.0, 1.0], [np.nan, 2.0], [3.0, 40.0]], np.float32)
    mask = labels_to_mask(xy, np.array([1, 0, 0, 0]), (4, 4), MaskConfig(max_distance_px=50))
    np.testing.assert_array_equal(mask, np.full((4, 4), 2, np.uint8))
    empty = labels_to_mask(np.zeros((0, 2)), np.zeros(0, np.int64), (3, 5))
    np.testing.assert_array_equal(empty, np.zeros((3, 5), np.uint8))


def test_vote_outvotes_an_isolated_wrong_label() -> None:
    gy, gx = np.mgrid[4:40:6, 4:40:6]
    xy = np.stack([gx.ravel(), gy.ravel()], axis=1).astype(np.float32)
    labels = np.zeros(len(xy), np.int64)
    odd = int(np.flatnonzero((xy[:, 0] == 22) & (xy[:, 1] == 22))[0])
    labels[odd] = 1
    nearest = labels_to_mask(xy, labels, (44, 44), MaskConfig(max_distance_px=20))
    vote = labels_to_mask(xy, labels, (44, 44), MaskConfig(max_distance_px=20, method="vote", vote_downsample=2))
    assert nearest[22, 22] == 2 and (nearest == 2).sum() == 36  # the odd track's 6x6 Voronoi cell
    assert vote.shape == (44, 44) and (vote == 1).all()


def test_median_smoothing_removes_single_pixel_specks() -> None:
    gy, gx = np.mgrid[0:10, 0:10]
    xy = np.stack([gx.ravel(), gy.ravel()], axis=1).astype(np.float32)  # a track on every pixel
    labels = (xy[:, 0] >= 5).astype(np.int64)
    labels[4 * 10 + 2] = 1  # one speck at (x=2, y=4)
    raw = labels_to_mask(xy, labels, (10, 10), MaskConfig(max_distance_px=5))
    smooth = labels_to_mask(xy, labels, (10, 10), MaskConfig(max_distance_px=5, median_px=3))
    assert raw[4, 2] == 2
    expected = np.where(gx >= 5, 2, 1).astype(np.uint8)
    np.testing.assert_array_equal(smooth, expected)


def test_bad_labels_and_config() -> None:
    with pytest.raises(InputError, match="2 points but 1 labels"):
        labels_to_mask(np.zeros((2, 2)), np.array([0]), (4, 4))
    with pytest.raises(InputError, match="0..254"):
        labels_to_mask(np.zeros((1, 2)), np.array([255]), (4, 4))
    with pytest.raises(ValueError, match="method"):
        MaskConfig(method="watershed")
    with pytest.raises(ValueError, match="median_px"):
        MaskConfig(median_px=4)


def test_labels_to_masks_uses_points_visible_in_each_frame() -> None:
    xy = np.array(
        [
            [[2.0, 2.0], [3.0, 2.0]],  # track 0: label 0
            [[7.0, 2.0], [np.nan, np.nan]],  # track 1: label 1, lost in frame 1
            [[5.0, 4.0], [5.0, 4.0]],  # track 2: not labelled (not in track_ids)
        ],
        np.float32,
    )
    visible = np.array([[True, True], [True, False], [True, True]])
    tracks = Tracks(xy=xy, visible=visible, size_hw=(5, 10))
    masks = labels_to_masks(tracks, np.array([0, 1]), np.array([0, 1]), MaskConfig(max_distance_px=100))
    assert masks.shape == (2, 5, 10) and masks.dtype == np.uint8
    assert (masks[0, :, :5] == 1).all() and (masks[0, :, 5:] == 2).all()
    assert (masks[1] == 1).all()
    with pytest.raises(InputError, match="track ids"):
        labels_to_masks(tracks, np.array([0, 3]), np.array([0, 1]))


def test_overlay_mask_blends_only_known_pixels() -> None:
    image = np.full((2, 3, 3), 100, np.uint8)
    mask = np.array([[0, 1, 2], [0, 0, 1]], np.uint8)
    pal = default_palette()
    out = overlay_mask(image, mask, pal, alpha=0.5)
    np.testing.assert_array_equal(out[mask == 0], image[mask == 0])
    np.testing.assert_array_equal(out[0, 1], [114, 50, 50])  # (100 + 128) / 2, (100 + 0) / 2
    np.testing.assert_array_equal(out[0, 2], [50, 114, 50])
