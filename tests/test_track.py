from __future__ import annotations

import cv2
import numpy as np
import pytest

from mosegpipe.errors import InputError
from mosegpipe.points.klt import KLTTracker, TrackConfig, spread_corners, track_klt, track_points
from mosegpipe.types import Frames

from helpers import TEXTURE_H, TEXTURE_PAD, TEXTURE_W, gray_to_rgb, shifted_view, smooth_texture

H, W, PAD = TEXTURE_H, TEXTURE_W, TEXTURE_PAD
_texture, _view, _rgb = smooth_texture, shifted_view, gray_to_rgb


def _clip(step: tuple[float, float], num: int = 3, seed: int = 0) -> Frames:
    base = _texture(seed)
    return Frames(np.stack([_rgb(_view(base, step[0] * t, step[1] * t)) for t in range(num)]))


def test_known_translation_recovered_subpixel() -> None:
    tracks = track_klt(_clip((3.0, -2.0)), TrackConfig(max_corners=300))

    assert tracks.xy.shape == (tracks.num_tracks, 3, 2) and tracks.xy.dtype == np.float32
    assert tracks.size_hw == (H, W)
    full = tracks.visible.all(axis=1)
    assert tracks.num_tracks >= 200 and full.mean() > 0.9
    steps = np.diff(tracks.xy[full], axis=1)  # (n, 2, 2)
    assert np.abs(steps - np.array([3.0, -2.0])).max() < 0.1


def test_subpixel_translation() -> None:
    tracks = track_klt(_clip((0.4, 1.3)), TrackConfig(max_corners=200))
    full = tracks.visible.all(axis=1)
    steps = np.diff(tracks.xy[full], axis=1)
    assert np.abs(steps - np.array([0.4, 1.3])).max() < 0.1


def _noise_patch_clip() -> tuple[Frames, tuple[slice, slice]]:
    """Frame 1 = frame 0 shifted by (3, -2), except a square replaced by white noise."""
    base = _texture(0)
    f0, f1 = _view(base, 0, 0), _view(base, 3, -2)
    region = (slice(40, 120), slice(80, 160))
    f1[region] = np.random.default_rng(5).integers(0, 256, (80, 80), dtype=np.uint8)
    return Frames(np.stack([_rgb(f0), _rgb(f1)])), region


def test_forward_backward_check_rejects_points_on_replaced_region() -> None:
    frames, (rows, cols) = _noise_patch_clip()
    with_fb = track_klt(frames, TrackConfig(max_corners=400, fb_threshold_px=1.0))
    without = track_klt(frames, TrackConfig(max_corners=400, fb_threshold_px=None))

    def split(tracks):
        x0, y0 = tracks.xy[:, 0, 0], tracks.xy[:, 0, 1]
        # Inside: the LK window (21 px) lies wholly in the replaced square; outside: far from it.
        inside = (x0 > cols.start + 12) & (x0 < cols.stop - 12) & (y0 > rows.start + 12) & (y0 < rows.stop - 12)
        outside = (x0 < cols.start - 25) | (x0 > cols.stop + 25) | (y0 < rows.start - 25) | (y0 > rows.stop + 25)
        outside &= (x0 > 15) & (x0 < W - 16) & (y0 > 15) & (y0 < H - 16)  # not leaving via the border
        return inside, outside

    inside, outside = split(with_fb)
    assert inside.sum() >= 20
    # LK itself reports success for every point on the noise; the round trip rejects most of
    # them (a few land on a consistent local minimum by chance: 24 % here) and keeps the rest.
    inside_nofb, _ = split(without)
    assert without.visible[inside_nofb, 1].mean() > 0.9
    assert with_fb.visible[inside, 1].mean() < 0.4
    assert with_fb.visible[outside, 1].mean() > 0.95


def test_points_leaving_the_image_are_lost_for_good() -> None:
    step = 9.0
    cfg = TrackConfig(max_corners=300)
    tracks = track_klt(_clip((step, 0.0), num=5), cfg)
    vis = tracks.visible
    # Once lost, never visible again.
    assert not (~vis[:, :-1] & vis[:, 1:]).any()
    x0 = tracks.xy[:, 0, 0]
    limit = W - 1 - cfg.border_px
    for t in range(5):
        true_x = x0 + step * t
        clearly_in = true_x < limit - 1
        clearly_out = true_x > limit + 1
        assert vis[clearly_out, t].sum() == 0
        assert vis[clearly_in, t].mean() > 0.95
    assert np.isnan(tracks.xy[~vis]).all()


def test_blank_frames_give_zero_tracks() -> None:
    frames = Frames(np.full((4, 32, 48, 3), 128, np.uint8))
    tracks = track_klt(frames)
    assert tracks.xy.shape == (0, 4, 2) and tracks.visible.shape == (0, 4)
    assert tracks.size_hw == (32, 48)


def test_tracker_reseeds_only_where_tracks_are_missing() -> None:
    base = _texture(1)
    full = _view(base, 0, 0)
    left_only = full.copy()
    left_only[:, W // 2 :] = 128  # no corners on the right at first
    cfg = TrackConfig(max_corners=400, min_distance_px=8, reseed=True, reseed_every=2)
    tracker = KLTTracker(cfg)

    ids0, xy0 = tracker.step(left_only)
    assert len(ids0) > 50 and (xy0[:, 0] < W // 2 + 10).all()
    np.testing.assert_array_equal(ids0, np.arange(len(ids0)))

    ids1, _ = tracker.step(_rgb(full))  # frame 1: not a re-seed frame
    assert set(ids1) <= set(ids0)
    ids2, xy2 = tracker.step(full)  # frame 2: re-seed
    new = ids2 >= len(ids0)
    assert new.sum() > 50
    assert (xy2[new, 0] > W // 2 - 12).mean() > 0.95  # new corners fill the right half
    old_xy, new_xy = xy2[~new], xy2[new]
    gaps = np.linalg.norm(new_xy[:, None] - old_xy[None], axis=2).min(axis=1)
    assert gaps.min() >= cfg.min_distance_px - 1
    assert len(ids2) <= cfg.max_corners and len(np.unique(ids2)) == len(ids2)
    assert tracker.num_ids == int(ids2.max()) + 1


def test_restart_forgets_the_points_keeps_ids_growing_and_restarts_the_reseed_period() -> None:
    base = _texture(3)
    cfg = TrackConfig(max_corners=400, min_distance_px=8, reseed=True, reseed_every=3)
    tracker = KLTTracker(cfg)
    ids0, _ = tracker.step(_view(base, 0, 0))
    tracker.step(_view(base, 1, 0))
    other = _view(_texture(4), 0, 0)
    tracker.step(other)  # frame 2: a cut; a few points may survive on the new content
    ids, xy = tracker.restart(other)
    assert len(ids) > 50 and ids.min() > ids0.max()  # all detected afresh, no id reused
    assert tracker.num_ids == int(ids.max()) + 1
    last = ids
    for dx in (4, 8):  # frames 3 and 4: no re-seed any more, the period counts from the restart (frame 2)
        step_ids, _ = tracker.step(_view(_texture(4), dx, 0))
        assert set(step_ids) <= set(last) and len(step_ids) < len(ids)  # points leave, none come
        last = step_ids
    step_ids, _ = tracker.step(_view(_texture(4), 12, 0))  # frame 5 = restart + 3: re-seed
    assert (step_ids > last.max()).sum() > 5
    with pytest.raises(ValueError, match="frame of the last step"):
        KLTTracker().restart(other)


def test_track_klt_with_reseed_marks_late_tracks_invisible_before_birth() -> None:
    base = _texture(2)
    first = _view(base, 0, 0).copy()
    first[:, W // 2 :] = 128
    frames = Frames(np.stack([_rgb(first)] + [_rgb(_view(base, 0, 0))] * 2))
    tracks = track_klt(frames, TrackConfig(max_corners=400, reseed=True, reseed_every=1))
    born = tracks.visible.argmax(axis=1)
    assert (born == 0).sum() > 0 and (born == 1).sum() > 0
    late = born == 1
    assert not tracks.visible[late, 0].any() and tracks.visible[late, 1:].all()


def test_tracker_rejects_bad_frames_and_config() -> None:
    tracker = KLTTracker()
    tracker.step(np.zeros((20, 30), np.uint8))
    with pytest.raises(InputError, match="30x20"):
        tracker.step(np.zeros((20, 31), np.uint8))
    with pytest.raises(InputError, match="uint8"):
        KLTTracker().step(np.zeros((20, 30), np.float32))
    with pytest.raises(ValueError, match="fb_threshold_px"):
        TrackConfig(fb_threshold_px=0.0)


def test_real_kitti_clip(data_root) -> None:
    from mosegpipe.io.read import read_video

    frames = read_video(data_root / "kt3dmoseg" / "frames" / "Seq005_Clip01", max_frames=5)
    tracks = track_klt(frames)
    full = tracks.visible.all(axis=1)
    assert tracks.num_tracks > 500 and full.sum() > 300
    # Driving footage: steps of ~11 px per frame (max ~27 px measured); no wild jumps.
    steps = np.linalg.norm(np.diff(tracks.xy[full], axis=1), axis=2)
    assert steps.max() < 60


def test_tracks_from_steps_maps_ids_to_rows() -> None:
    from mosegpipe.points.klt import tracks_from_steps

    steps = [
        (np.array([5, 7]), np.array([[1, 1], [2, 2]], np.float32)),
        (np.array([7, 9]), np.array([[3, 3], [4, 4]], np.float32)),
    ]
    tracks, ids = tracks_from_steps(steps, (10, 20))
    np.testing.assert_array_equal(ids, [5, 7, 9])
    np.testing.assert_array_equal(tracks.visible, [[True, False], [True, True], [False, True]])
    np.testing.assert_array_equal(tracks.xy[1], [[2, 2], [3, 3]])
    assert np.isnan(tracks.xy[0, 1]).all() and tracks.size_hw == (10, 20)


def test_spread_corners_give_a_weakly_textured_half_its_share() -> None:
    base = _view(_texture(5), 0, 0).astype(np.float32)
    image = base.copy()
    image[:, W // 2 :] = 128 + 0.15 * (base[:, W // 2 :] - 128)  # the same texture at 15 % contrast
    image = image.astype(np.uint8)
    strongest = cv2.goodFeaturesToTrack(image, 150, 0.01, 7.0, blockSize=7).reshape(-1, 2)
    assert (strongest[:, 0] > W // 2).mean() < 0.05  # strongest first: the bright half takes them
    spread = spread_corners(image, 150)
    assert len(spread) == 150
    assert (spread[:, 0] > W // 2 + 5).mean() > 0.2  # its cells get their turn (24 % here)
    avoid = spread[:40]
    again = spread_corners(image, 150, avoid_xy=avoid)
    gaps = np.linalg.norm(again[:, None] - avoid[None], axis=2).min(axis=1)
    assert gaps.min() >= TrackConfig().min_distance_px - 1
    assert len(spread_corners(np.full((H, W), 128, np.uint8), 50)) == 0  # nothing to find


def test_track_points_follows_given_points_in_order() -> None:
    base = _texture(6)
    frames = np.stack([_rgb(_view(base, 2.0 * t, 1.0 * t)) for t in range(4)])
    xy = np.array([[60.0, 50.0], [150.0, 90.0], [200.0, 40.0]], dtype=np.float32)
    tracks = track_points(frames, xy)
    assert tracks.xy.shape == (3, 4, 2) and tracks.visible.all()
    expected = xy[:, None] + np.arange(4)[None, :, None] * np.array([2.0, 1.0])
    np.testing.assert_allclose(tracks.xy, expected, atol=0.1)
    tracker = KLTTracker()
    tracker.step(frames[0])
    with pytest.raises(ValueError, match="first call"):
        tracker.start(frames[0], xy)


def test_tracker_gray_is_the_last_frame_as_the_flow_converts_it() -> None:
    from mosegpipe.points.flow import to_gray

    rng = np.random.default_rng(3)
    frames = rng.integers(0, 256, size=(2, 40, 56, 3), dtype=np.uint8)
    tracker = KLTTracker()
    assert tracker.gray is None
    for frame in frames:
        tracker.step(frame)
        assert tracker.gray is not None
        np.testing.assert_array_equal(tracker.gray, to_gray(frame, 1.0))
        np.testing.assert_array_equal(to_gray(tracker.gray, 0.5), to_gray(frame, 0.5))  # the flow's resize
