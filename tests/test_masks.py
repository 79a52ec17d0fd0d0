from __future__ import annotations

import numpy as np
import pytest

from mosegpipe.errors import InputError
from mosegpipe.io.read import default_palette
from mosegpipe.masks import UNKNOWN, MaskConfig, labels_to_mask, labels_to_masks, overlay_mask
from mosegpipe.types import Tracks

NEAREST = MaskConfig(method="nearest", max_distance_px=100)


def test_two_points_split_the_image_at_the_bisector() -> None:
    xy = np.array([[2.0, 2.0], [7.0, 2.0]], np.float32)
    mask = labels_to_mask(xy, np.array([0, 1]), (5, 10), NEAREST)
    expected = np.zeros((5, 10), np.uint8)
    expected[:, 5:] = 1  # columns 0..4 are nearer x = 2 (bisector at 4.5); the value is the label
    np.testing.assert_array_equal(mask, expected)
    assert mask.dtype == np.uint8


@pytest.mark.parametrize("method", ["nearest", "watershed"])
def test_pixels_far_from_every_point_are_unknown(method: str) -> None:
    image = np.full((21, 31, 3), 90, np.uint8)
    cfg = MaskConfig(max_distance_px=6, method=method, min_agree=1)
    mask = labels_to_mask(np.array([[10.0, 10.0]]), np.array([3]), (21, 31), cfg, image)
    yy, xx = np.mgrid[0:21, 0:31]
    dist = np.hypot(xx - 10, yy - 10)
    clear = np.abs(dist - 6) > 0.5  # the distance transform is approximate right at the radius
    np.testing.assert_array_equal(mask[clear], np.where(dist[clear] <= 6, 3, UNKNOWN))


def test_points_outside_the_image_or_not_finite_are_ignored() -> None:
    xy = np.array([[1.0, 1.0], [-5.0, 1.0], [np.nan, 2.0], [3.0, 40.0]], np.float32)
    mask = labels_to_mask(xy, np.array([1, 0, 0, 0]), (4, 4), MaskConfig(max_distance_px=50))
    np.testing.assert_array_equal(mask, np.full((4, 4), 1, np.uint8))
    empty = labels_to_mask(np.zeros((0, 2)), np.zeros(0, np.int64), (3, 5))
    np.testing.assert_array_equal(empty, np.full((3, 5), UNKNOWN, np.uint8))


def _two_regions() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A 60x80 image, dark left of x = 50 and bright right of it, with tracks on a 10 px grid."""
    image = np.zeros((60, 80, 3), np.uint8)
    image[:, 50:] = 200
    gy, gx = np.mgrid[5:60:10, 5:80:10]
    xy = np.stack([gx.ravel(), gy.ravel()], axis=1).astype(np.float32)
    labels = (xy[:, 0] > 50).astype(np.int64)
    return image, xy, labels


def test_watershed_puts_the_border_on_the_image_edge() -> None:
    image, xy, labels = _two_regions()
    cfg = MaskConfig(method="watershed", max_distance_px=100)
    mask = labels_to_mask(xy, labels, (60, 80), cfg, image)
    expected = np.where(np.arange(80) >= 50, 1, 0)[None].repeat(60, axis=0)
    np.testing.assert_array_equal(mask, expected)
    # Half-way between the tracks at x = 45 and 55 is x = 50 too; move the edge to see the difference.
    image2 = np.zeros_like(image)
    image2[:, 47:] = 200
    labels2 = (xy[:, 0] > 47).astype(np.int64)
    ws = labels_to_mask(xy, labels2, (60, 80), cfg, image2)
    near = labels_to_mask(xy, labels2, (60, 80), NEAREST)
    assert (ws[:, 47:50] == 1).all() and (near[:, 47:50] == 0).all()


def test_watershed_ignores_an_isolated_wrong_track() -> None:
    image, xy, labels = _two_regions()
    odd = int(np.flatnonzero((xy[:, 0] == 25) & (xy[:, 1] == 25))[0])
    labels[odd] = 2
    seeded = labels_to_mask(
        xy, labels, (60, 80), MaskConfig(method="watershed", max_distance_px=100, min_agree=1), image
    )
    robust = labels_to_mask(
        xy, labels, (60, 80), MaskConfig(method="watershed", max_distance_px=100, min_agree=2), image
    )
    assert (seeded == 2).sum() > 0  # with every track seeding, the odd one floods a region
    assert (robust == 2).sum() == 0 and (robust[:, :50] == 0).all()


def test_watershed_without_an_image_is_the_nearest_partition() -> None:
    _, xy, labels = _two_regions()
    ws = labels_to_mask(xy, labels, (60, 80), MaskConfig(method="watershed", max_distance_px=100))
    np.testing.assert_array_equal(ws, labels_to_mask(xy, labels, (60, 80), NEAREST))


def test_vote_outvotes_an_isolated_wrong_label() -> None:
    gy, gx = np.mgrid[4:40:6, 4:40:6]
    xy = np.stack([gx.ravel(), gy.ravel()], axis=1).astype(np.float32)
    labels = np.zeros(len(xy), np.int64)
    odd = int(np.flatnonzero((xy[:, 0] == 22) & (xy[:, 1] == 22))[0])
    labels[odd] = 1
    nearest = labels_to_mask(xy, labels, (44, 44), MaskConfig(method="nearest", max_distance_px=20))
    vote = labels_to_mask(xy, labels, (44, 44), MaskConfig(max_distance_px=20, method="vote", vote_downsample=2))
    assert nearest[22, 22] == 1 and (nearest == 1).sum() == 36  # the odd track's 6x6 Voronoi cell
    assert vote.shape == (44, 44) and (vote == 0).all()


def test_median_smoothing_removes_single_pixel_specks() -> None:
    gy, gx = np.mgrid[0:10, 0:10]
    xy = np.stack([gx.ravel(), gy.ravel()], axis=1).astype(np.float32)  # a track on every pixel
    labels = (xy[:, 0] >= 5).astype(np.int64)
    labels[4 * 10 + 2] = 1  # one speck at (x=2, y=4)
    raw = labels_to_mask(xy, labels, (10, 10), MaskConfig(method="nearest", max_distance_px=5))
    smooth = labels_to_mask(xy, labels, (10, 10), MaskConfig(method="nearest", max_distance_px=5, median_px=3))
    assert raw[4, 2] == 1
    expected = np.where(gx >= 5, 1, 0).astype(np.uint8)
    np.testing.assert_array_equal(smooth, expected)


def test_bad_labels_and_config() -> None:
    with pytest.raises(InputError, match="2 points but 1 labels"):
        labels_to_mask(np.zeros((2, 2)), np.array([0]), (4, 4))
    with pytest.raises(InputError, match="0..254"):
        labels_to_mask(np.zeros((1, 2)), np.array([255]), (4, 4))
    with pytest.raises(ValueError, match="method"):
        MaskConfig(method="grabcut")
    with pytest.raises(ValueError, match="median_px"):
        MaskConfig(median_px=4)
    with pytest.raises(ValueError, match="min_agree"):
        MaskConfig(min_agree=9)
    with pytest.raises(ValueError, match="image is"):
        labels_to_mask(np.zeros((1, 2)), np.array([0]), (4, 4), image=np.zeros((5, 4, 3), np.uint8))


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
    masks = labels_to_masks(tracks, np.array([0, 1]), np.array([0, 1]), NEAREST)
    assert masks.shape == (2, 5, 10) and masks.dtype == np.uint8
    assert (masks[0, :, :5] == 0).all() and (masks[0, :, 5:] == 1).all()
    assert (masks[1] == 0).all()
    with pytest.raises(InputError, match="track ids"):
        labels_to_masks(tracks, np.array([0, 3]), np.array([0, 1]))


def test_overlay_mask_tints_moving_motions_and_greys_unknown() -> None:
    image = np.full((2, 3, 3), 100, np.uint8)
    mask = np.array([[0, 1, 2], [0, UNKNOWN, 1]], np.uint8)
    pal = default_palette()
    out = overlay_mask(image, mask, pal, alpha=0.5)
    np.testing.assert_array_equal(out[mask == 0], image[mask == 0])  # motion 0 (background) as it is
    np.testing.assert_array_equal(out[0, 1], [114, 50, 50])  # (100 + 128) / 2, (100 + 0) / 2
    np.testing.assert_array_equal(out[0, 2], [50, 114, 50])
    np.testing.assert_array_equal(out[1, 1], [130, 130, 130])  # the unknown grey blended as any value: (100 + 160) / 2


def test_carry_unclustered_gives_an_anonymous_mover_the_label_it_had_in_the_frame_before() -> None:
    from mosegpipe.masks import MOVING_UNCLUSTERED, carry_unclustered

    previous = np.zeros((40, 60), np.uint8)
    previous[5:20, 5:20] = 3  # an object labelled 3
    previous[25:35, 40:55] = 7  # another, labelled 7
    mask = np.zeros((40, 60), np.uint8)
    mask[7:22, 7:22] = MOVING_UNCLUSTERED  # the first moved 2 px; no clustered motion reached it
    mask[25:35, 5:15] = MOVING_UNCLUSTERED  # a new mover where nothing moved before
    mask[0:3, 50:60] = UNKNOWN
    out = carry_unclustered(mask, previous)
    assert (out[7:22, 7:22] == 3).all()  # most of it was 3 in the frame before
    assert (out[25:35, 5:15] == MOVING_UNCLUSTERED).all()  # nothing to carry: stays anonymous
    assert (out[0:3, 50:60] == UNKNOWN).all() and (out[mask == 0] == 0).all()
    assert carry_unclustered(mask, None) is mask  # the first frame of a shot
    # A label that covers too little of the region, or is this frame's background, is not taken.
    sliver = np.zeros_like(previous)
    sliver[7:9, 7:22] = 3
    assert (carry_unclustered(mask, sliver)[7:22, 7:22] == MOVING_UNCLUSTERED).all()
    assert (carry_unclustered(mask, np.zeros_like(previous)) == mask).all()


def test_name_unclustered_gives_each_large_anonymous_mover_a_label_of_its_own() -> None:
    from mosegpipe.group.labels import LabelBook
    from mosegpipe.masks import MOVING_UNCLUSTERED, name_unclustered

    mask = np.zeros((40, 60), np.uint8)
    mask[5:20, 5:20] = MOVING_UNCLUSTERED  # 225 px: the larger mover
    mask[5:20, 21:23] = MOVING_UNCLUSTERED  # a limb 1 px off it: the same region
    mask[25:35, 40:50] = MOVING_UNCLUSTERED  # 100 px, far off
    mask[38, 5] = MOVING_UNCLUSTERED  # one pixel: speckle, stays anonymous
    mask[0:3, 50:60] = 4  # a clustered motion
    book = LabelBook(next_label=9)
    out = name_unclustered(mask, book, 0.02)  # 48 px of 2400 at least
    assert (out[5:20, 5:20] == 9).all() and (out[5:20, 21:23] == 9).all() and (out[25:35, 40:50] == 10).all()
    assert out[38, 5] == MOVING_UNCLUSTERED and (out[0:3, 50:60] == 4).all() and (out[mask == 0] == 0).all()
    assert (mask[5:20, 5:20] == MOVING_UNCLUSTERED).all() and book.dense == {9, 10}  # a copy; the labels known
    # nothing large enough: the mask itself, no label handed out
    assert name_unclustered(mask, book, 0.5) is mask and book.next_label == 11
    # a named mover that jumped off its mask of the frame before (the carry lost it) takes its label back
    jumped = np.zeros_like(mask)
    jumped[5:20, 24:36] = MOVING_UNCLUSTERED
    again = name_unclustered(jumped, book, 0.02, previous=out)
    assert (again[5:20, 24:36] == 9).all() and book.next_label == 11  # 9 is nearer than 10
    # ... but not from across the frame (beyond the gate), and never a label this frame shows already
    assert (name_unclustered(jumped, book, 0.02, previous=out, gate=0.1)[5:20, 24:36] == 11).all()
    shown = jumped.copy()
    shown[0:2, 0:2] = 9
    assert name_unclustered(shown, book, 0.02, previous=out)[10, 30] == 12  # 9 shown, 10 beyond the gate: new


def test_name_unclustered_gives_a_remembered_motion_back_its_label_where_it_was_last_seen() -> None:
    """A motion the grouping lost for a few windows (LabelBook.memory, its last mask in LabelBook.shapes) and
    that comes back as an unclustered mover near where it was last seen takes its label back."""
    from mosegpipe.group.label_shapes import label_shapes
    from mosegpipe.group.labels import LabelBook, LabelTrace
    from mosegpipe.masks import MOVING_UNCLUSTERED, name_unclustered

    last = np.zeros((40, 60), np.uint8)
    last[5:15, 5:15] = 3  # where motion 3 was last seen, windows ago
    book = LabelBook(next_label=5)
    book.memory[3] = LabelTrace({}, 0, 4, np.array([10.0, 10.0]), np.zeros(2), 16.0)
    book.shapes = label_shapes(last, 4)
    assert set(book.remembered()) == {3} and np.allclose(book.remembered()[3], [9.5, 9.5])
    back = np.zeros((40, 60), np.uint8)
    back[8:18, 10:20] = MOVING_UNCLUSTERED
    assert (name_unclustered(back, book, 0.02)[8:18, 10:20] == 3).all() and book.next_label == 5
    # beyond the gate, or while the frame shows motion 3 elsewhere: a new label
    assert (name_unclustered(back, book, 0.02, gate=0.05)[8:18, 10:20] == 5).all()
    back[30:35, 50:55] = 3
    assert (name_unclustered(back, book, 0.02)[8:18, 10:20] == 6).all()
    # forgotten (no longer in memory): never taken back
    del book.memory[3]
    back[30:35, 50:55] = 0
    assert book.remembered() == {} and (name_unclustered(back, book, 0.02)[8:18, 10:20] == 7).all()


def _two_movers(b_flow: np.ndarray) -> tuple:
    """A 120x160 frame: region A (tracked, motion 1, moving +3 px in x) and region B (no tracks, flow
    `b_flow`), both labelled 1 as the nearest-track rule labels them; background tracks static."""
    h, w = 120, 160
    moving = np.zeros((h, w), bool)
    moving[30:70, 20:60] = True  # A
    moving[30:70, 100:140] = True  # B
    mask = np.where(moving, 1, 0).astype(np.uint8)
    flow = np.zeros((h, w, 2), np.float32)
    flow[30:70, 20:60] = (3.0, 0.0)
    flow[30:70, 100:140] = b_flow
    rng = np.random.default_rng(0)
    on_a = np.stack([rng.uniform(22, 58, 30), rng.uniform(32, 68, 30)], axis=1).astype(np.float32)
    still = np.stack([rng.uniform(0, 160, 60), rng.uniform(80, 120, 60)], axis=1).astype(np.float32)
    xy = np.concatenate([on_a, still])
    xy_next = np.concatenate([on_a + np.float32([3.0, 0.0]), still])
    labels = np.array([1] * 30 + [0] * 60, np.int64)
    return mask, moving, (xy, xy_next), labels, flow


def test_an_untracked_region_moving_otherwise_takes_the_unclustered_label() -> None:
    from mosegpipe.masks import MOVING_UNCLUSTERED, split_unexplained

    mask, moving, step, labels, flow = _two_movers(np.float32([0.0, -4.0]))
    out = split_unexplained(mask, moving, step, labels, 0, flow, 1.0)
    assert (out[30:70, 100:140] == MOVING_UNCLUSTERED).mean() > 0.95
    assert (out[30:70, 20:60] == 1).all()  # the tracked region keeps its motion
    assert (out[~moving] == 0).all()
    assert (mask[30:70, 100:140] == 1).all()  # the input is left as it was
    # The same at half the flow's resolution (flows in half-resolution pixels).
    small = np.ascontiguousarray(flow[::2, ::2] / 2)
    half = split_unexplained(mask, moving, step, labels, 0, small, 0.5)
    assert (half[32:68, 102:138] == MOVING_UNCLUSTERED).all() and (half[30:70, 20:60] == 1).all()


def test_a_region_moving_with_its_label_or_not_rigid_or_small_keeps_it() -> None:
    from mosegpipe.masks import split_unexplained

    mask, moving, step, labels, flow = _two_movers(np.float32([3.0, 0.0]))  # a piece cut off from its tracks
    assert split_unexplained(mask, moving, step, labels, 0, flow, 1.0) is mask
    mask, moving, step, labels, flow = _two_movers(np.float32([0.0, -4.0]))
    rng = np.random.default_rng(1)
    flow[30:70, 100:140] = rng.uniform(-8, 8, (40, 40, 2))  # no rigid motion of its own (flow noise, water)
    assert split_unexplained(mask, moving, step, labels, 0, flow, 1.0) is mask
    flow[30:70, 100:140] = (0.0, -4.0)
    assert split_unexplained(mask, moving, step, labels, 0, flow, 1.0, MaskConfig(unexplained_area=0.1)) is mask
    few = labels.copy()
    few[5:30] = 0  # motion 1 has 5 tracks: not judged
    assert split_unexplained(mask, moving, step, few, 0, flow, 1.0) is mask


def _bled_movers() -> tuple:
    """A 120x160 frame: motion 1 (x 20..79, +3 px in x) and motion 2 (x 80..139, -3 px in x) touch; the
    nearest-track labels let motion 1 bleed over x 80..99; each motion has 20 tracks, the world 40 still ones."""
    h, w = 120, 160
    mask = np.zeros((h, w), np.uint8)
    mask[30:70, 20:100] = 1
    mask[30:70, 100:140] = 2
    flow = np.zeros((h, w, 2), np.float32)
    flow[30:70, 20:80] = (3.0, 0.0)
    flow[30:70, 80:140] = (-3.0, 0.0)
    rng = np.random.default_rng(1)
    one = np.stack([rng.uniform(22, 78, 20), rng.uniform(32, 68, 20)], axis=1).astype(np.float32)
    two = np.stack([rng.uniform(102, 138, 20), rng.uniform(32, 68, 20)], axis=1).astype(np.float32)
    still = np.stack([rng.uniform(0, 160, 40), rng.uniform(80, 120, 40)], axis=1).astype(np.float32)
    xy = np.concatenate([one, two, still])
    xy_next = np.concatenate([one + np.float32([3, 0]), two - np.float32([3, 0]), still])
    labels = np.array([1] * 20 + [2] * 20 + [0] * 40, np.int64)
    return mask, (xy, xy_next), labels, flow


def test_moving_pixels_take_the_motion_whose_step_explains_their_flow() -> None:
    from mosegpipe.masks import reassign_by_flow

    mask, step, labels, flow = _bled_movers()
    out = reassign_by_flow(mask, step, labels, flow, 1.0, 0.5)
    assert (out[30:70, 82:140] == 2).all() and (out[30:70, 20:78] == 1).all()  # the bled part goes back to 2
    assert (out == 0).sum() == (mask == 0).sum()  # which pixels are moving does not change
    assert (mask[30:70, 80:100] == 1).all()  # the input is left as it was
    # at half the flow's resolution (flows in half-resolution pixels), the same
    half = reassign_by_flow(mask, step, labels, np.ascontiguousarray(flow[::2, ::2] / 2), 0.5, 0.5)
    assert (half[30:70, 84:140] == 2).all() and (half[30:70, 20:76] == 1).all()


def test_reassignment_needs_two_fitted_motions_and_a_clear_winner() -> None:
    from mosegpipe.masks import reassign_by_flow

    mask, (xy, xy_next), labels, flow = _bled_movers()
    few = labels.copy()
    few[25:40] = 0  # motion 2 keeps 5 tracks: too few to fit, nothing to choose between
    assert reassign_by_flow(mask, (xy, xy_next), few, flow, 1.0, 0.5) is mask
    # the bled pixels' flow halfway between both motions: neither explains it clearly better
    blurred = flow.copy()
    blurred[30:70, 80:100] = (0.0, 0.0)
    out = reassign_by_flow(mask, (xy, xy_next), labels, blurred, 1.0, 0.5)
    assert (out[30:70, 82:98] == 1).all()
    with pytest.raises(Exception, match="reassign_ratio"):
        MaskConfig(reassign_ratio=1.0)


def test_reassignment_along_matches_the_tracks_by_id() -> None:
    from mosegpipe.masks import reassign_along, reassign_by_flow

    mask, (xy, xy_next), labels, flow = _bled_movers()
    ids = np.arange(len(xy), dtype=np.int64) + 100
    order = np.random.default_rng(2).permutation(len(xy))[5:]  # the neighbour frame: shuffled, 5 tracks lost
    out = reassign_along(mask, (ids, xy, ids[order], xy_next[order]), labels, flow, 1.0, 0.5)
    kept = np.isin(ids, ids[order])
    assert (out == reassign_by_flow(mask, (xy[kept], xy_next[kept]), labels[kept], flow, 1.0, 0.5)).all()
    assert (out[30:70, 82:140] == 2).all()
    none = reassign_along(mask, (ids, xy, ids[:0], xy_next[:0]), labels, flow, 1.0, 0.5)
    assert none is mask  # no track seen in both frames: nothing to fit


def _slow_mover() -> tuple:
    """A 120x160 frame of a static camera: motion 1 (x 100..139, +3 px in x) is moving in the mask; motion 2
    (x 20..59, -0.8 px in y: slower than the frame's threshold) is not, its 20 tracks lie on world pixels; 40
    still world tracks; the camera residual is each pixel's flow (a little noise elsewhere)."""
    h, w = 120, 160
    mask = np.zeros((h, w), np.uint8)
    mask[30:70, 100:140] = 1
    flow = np.zeros((h, w, 2), np.float32)
    flow[30:70, 100:140] = (3.0, 0.0)
    flow[30:70, 20:60] = (0.0, -0.8)
    residual = np.linalg.norm(flow, axis=2) + np.float32(0.05)
    rng = np.random.default_rng(3)
    one = np.stack([rng.uniform(102, 138, 20), rng.uniform(32, 68, 20)], axis=1).astype(np.float32)
    two = np.stack([rng.uniform(22, 58, 20), rng.uniform(32, 68, 20)], axis=1).astype(np.float32)
    still = np.stack([rng.uniform(0, 160, 40), rng.uniform(80, 120, 40)], axis=1).astype(np.float32)
    xy = np.concatenate([one, two, still])
    xy_next = np.concatenate([one + np.float32([3, 0]), two + np.float32([0, -0.8]), still])
    labels = np.array([1] * 20 + [2] * 20 + [0] * 40, np.int64)
    return mask, (xy, xy_next), labels, flow, residual


def test_a_mover_the_moving_pixels_missed_takes_its_tracks_motion() -> None:
    from mosegpipe.masks import missed_movers

    mask, step, labels, flow, residual = _slow_mover()
    out = missed_movers(mask, step, labels, flow, residual, 1.0)
    assert (out[31:69, 21:59] == 2).all()  # the slow mover, written as the world before
    assert (out[30:70, 100:140] == 1).all() and (out[:, 60:100] == 0).all() and (out[75:, :] == 0).all()
    assert (mask[30:70, 20:60] == 0).all()  # the input is left as it was
    # the same at half the flow's resolution (flows and residuals in half-resolution pixels)
    half = missed_movers(mask, step, labels, flow[::2, ::2] / 2, residual[::2, ::2] / 2, 0.5)
    assert (half[32:68, 22:58] == 2).all() and (half[:, 62:98] == 0).all()


def test_a_missed_region_needs_its_motion_its_tracks_and_a_residual_above_the_floor() -> None:
    from mosegpipe.masks import missed_movers

    mask, (xy, xy_next), labels, flow, residual = _slow_mover()
    # the region's flow is not its tracks' motion (they step -0.8 px in y, it moves +0.8 px in x)
    other = flow.copy()
    other[30:70, 20:60] = (0.8, 0.0)
    assert missed_movers(mask, (xy, xy_next), labels, other, residual, 1.0) is mask
    # the region's residual under the moving pixels' floor (0.5 px by default): noise, not a mover
    assert missed_movers(mask, (xy, xy_next), labels, flow, residual * np.float32(0.5), 1.0) is mask
    # its tracks are the world's but for two (below missed_tracks, 3), or unlabelled
    few = labels.copy()
    few[22:40] = 0
    assert missed_movers(mask, (xy, xy_next), few, flow, residual, 1.0) is mask
    few[22:40] = -1
    assert missed_movers(mask, (xy, xy_next), few, flow, residual, 1.0) is mask
    # the world's own tracks there outnumber the mover's
    world = labels.copy()
    world[20:32] = 0
    assert missed_movers(mask, (xy, xy_next), world, flow, residual, 1.0) is mask
    # the world's tracks moving as much (the camera fit misses them all): the floor rises above the region's residual
    loud = residual.copy()
    loud[80:120] = 2.0
    assert missed_movers(mask, (xy, xy_next), labels, flow, loud, 1.0) is mask


def test_a_mover_the_mask_shows_or_a_flow_mostly_the_cameras_is_not_missed() -> None:
    from mosegpipe.masks import missed_movers

    mask, (xy, xy_next), labels, flow, residual = _slow_mover()
    shown = mask.copy()
    shown[30:70, 20:50] = 2  # most of motion 2's tracks lie on its own pixels: the moving pixels did not miss it
    assert missed_movers(shown, (xy, xy_next), labels, flow, residual, 1.0) is shown
    # the region and its tracks step 5 px in x, 4.2 px of it the camera's (the residual 0.8 px): the world's flow
    # a little off (parallax, the camera fit's error), not a mover
    panned = flow.copy()
    panned[30:70, 20:60] = (5.0, -0.8)
    step = (xy, xy_next + np.where(labels[:, None] == 2, np.float32([5.0, 0.0]), np.float32([0.0, 0.0])))
    assert missed_movers(mask, step, labels, panned, residual, 1.0) is mask


def test_a_motion_whose_tracks_lie_mostly_outside_the_region_is_not_a_missed_mover() -> None:
    from mosegpipe.masks import missed_movers

    mask, (xy, xy_next), labels, flow, residual = _slow_mover()
    # 25 more tracks of motion 2 scattered over the still part of the frame: the region holds 20 of its 45
    rng = np.random.default_rng(4)
    scattered = np.stack([rng.uniform(0, 160, 25), rng.uniform(80, 120, 25)], axis=1).astype(np.float32)
    xy = np.concatenate([xy, scattered])
    xy_next = np.concatenate([xy_next, scattered + np.float32([0.0, -0.8])])
    labels = np.concatenate([labels, np.full(25, 2, np.int64)])
    assert missed_movers(mask, (xy, xy_next), labels, flow, residual, 1.0) is mask
