from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from mosegpipe.errors import InputError
from mosegpipe.group.twoview import sampson_px as _sampson_px
from mosegpipe.synth.trajectories import (
    PAIR_CONFIG,
    SyntheticConfig,
    SyntheticDataset,
    generate_clip,
    generate_pair,
)

NOISE_FREE = SyntheticConfig(noise_px=(0.0, 0.0), drift_px=(0.0, 0.0))


def _xy(traj: np.ndarray) -> np.ndarray:
    """(N, 2F) -> (N, F, 2)."""
    return traj.reshape(len(traj), -1, 2)


def test_shapes_dtypes_and_contiguous_labels() -> None:
    rng = np.random.default_rng(0)
    for _ in range(20):
        clip = generate_clip(rng)
        n = clip.num_points
        assert clip.traj.shape == (n, 10) and clip.traj.dtype == np.float32
        assert clip.labels.shape == (n,) and clip.labels.dtype == np.int64
        assert clip.dataset == "synthetic"
        np.testing.assert_array_equal(np.unique(clip.labels), np.arange(clip.k))
        assert len(clip.meta["body_kinds"]) == clip.k
        assert clip.meta["camera_motion"] in SyntheticConfig().camera_motions
        assert clip.meta["is_outlier"].shape == (n,) and not clip.meta["is_outlier"].any()
        assert clip.meta["outlier_label"] is None
        assert np.bincount(clip.labels).min() >= 8
        assert 1 <= clip.k <= 6 and n <= 1000
        if clip.meta["background_kind"] is not None:
            assert clip.meta["body_kinds"][0] == "background"


def test_same_seed_same_clip_and_dataset_is_deterministic() -> None:
    a = generate_clip(np.random.default_rng(42))
    b = generate_clip(np.random.default_rng(42))
    c = generate_clip(np.random.default_rng(43))
    np.testing.assert_array_equal(a.traj, b.traj)
    np.testing.assert_array_equal(a.labels, b.labels)
    assert a.traj.shape != c.traj.shape or not np.array_equal(a.traj, c.traj)

    ds = SyntheticDataset(1000, base_seed=7)
    assert len(ds) == 1000
    first = ds[5]
    again = SyntheticDataset(1000, base_seed=7)[5]
    np.testing.assert_array_equal(first.traj, again.traj)
    assert first.name == again.name == "synthetic/7/0000005"
    np.testing.assert_array_equal(ds[-1].traj, ds[999].traj)
    other = SyntheticDataset(1000, base_seed=8)[5]
    assert other.traj.shape != first.traj.shape or not np.array_equal(other.traj, first.traj)
    assert [c.name for c in ds[2:4]] == ["synthetic/7/0000002", "synthetic/7/0000003"]
    with pytest.raises(IndexError):
        ds[1000]


def test_points_inside_image_including_outliers() -> None:
    rng = np.random.default_rng(1)
    cfg = SyntheticConfig(outlier_ratio=(0.0, 0.3), noise_px=(1.5, 1.5), drift_px=(0.3, 0.3))
    for _ in range(20):
        clip = generate_clip(rng, cfg)
        h, w = clip.meta["image_size_hw"]
        xy = _xy(clip.traj)
        assert (xy >= 0).all()
        assert (xy[..., 0] <= w - 1).all() and (xy[..., 1] <= h - 1).all()


def test_static_camera_background_is_still_and_objects_move() -> None:
    cfg = replace(NOISE_FREE, camera_motions=("static",), num_bodies=(2, 4), relative_motion_px=(3.0, 30.0))
    rng = np.random.default_rng(2)
    for _ in range(5):
        clip = generate_clip(rng, cfg)
        assert clip.meta["body_kinds"][0] == "background"
        xy = _xy(clip.traj)
        bg = xy[clip.labels == 0]
        np.testing.assert_array_equal(bg, np.broadcast_to(bg[:, :1], bg.shape))
        for label in range(1, clip.k):
            own = xy[clip.labels == label]
            disp = np.linalg.norm(own[:, -1] - own[:, 0], axis=1)
            # With a static camera the motion relative to the scene is the image motion.
            assert 0.7 * 3.0 < disp.mean() < 1.3 * 30.0
            assert disp.mean() == pytest.approx(clip.meta["relative_motion_px"][label], rel=0.3)


def test_relative_motion_hits_the_requested_magnitude() -> None:
    cfg = replace(NOISE_FREE, camera_motions=("static",), num_bodies=(2, 2), relative_motion_px=(5.0, 5.0))
    rng = np.random.default_rng(3)
    measured = []
    for _ in range(10):
        clip = generate_clip(rng, cfg)
        measured.append(clip.meta["relative_motion_px"][1])
    # One secant step: most objects land within a few per cent of the target.
    assert np.median(measured) == pytest.approx(5.0, rel=0.1)


def test_gaussian_noise_has_the_sampled_spread() -> None:
    cfg = SyntheticConfig(camera_motions=("static",), noise_px=(1.0, 1.0), drift_px=(0.0, 0.0), num_points=(1000, 1000))
    clip = generate_clip(np.random.default_rng(4), cfg)
    xy = _xy(clip.traj)[clip.labels == 0]
    diff = xy[:, -1] - xy[:, 0]  # two independent N(0, 1) draws per coordinate
    assert diff.std() == pytest.approx(np.sqrt(2.0), rel=0.1)
    assert clip.meta["noise_px"] == 1.0


def test_pan_background_follows_a_homography() -> None:
    # A rotating camera maps any static scene by the homography K R K^-1, whatever the depths.
    cfg = replace(NOISE_FREE, camera_motions=("pan",), num_bodies=(1, 1))
    clip = generate_clip(np.random.default_rng(5), cfg)
    xy = _xy(clip.traj).astype(np.float64)
    hom, _ = cv2.findHomography(xy[:, 0], xy[:, -1], 0)
    proj = cv2.perspectiveTransform(xy[:, :1], hom)[:, 0]
    assert np.abs(proj - xy[:, -1]).max() < 0.01
    assert np.linalg.norm(xy[:, -1] - xy[:, 0], axis=1).mean() > 5.0


def test_rigid_body_in_a_pair_satisfies_the_epipolar_constraint() -> None:
    cfg = replace(
        PAIR_CONFIG,
        noise_px=(0.0, 0.0),
        outlier_ratio=(0.0, 0.0),
        num_bodies=(2, 2),
        background_prob=0.0,
        num_points=(400, 400),
        relative_motion_px=(20.0, 40.0),
    )
    rng = np.random.default_rng(6)
    for _ in range(3):
        clip = generate_pair(rng, cfg)
        assert clip.traj.shape[1] == 4 and clip.meta["body_kinds"] == ("rigid", "rigid")
        p1, p2 = clip.traj[:, :2].astype(np.float64), clip.traj[:, 2:].astype(np.float64)
        other_px = []
        for label in (0, 1):
            sel = clip.labels == label
            fmat, _ = cv2.findFundamentalMat(p1[sel], p2[sel], cv2.FM_8POINT)
            assert np.median(_sampson_px(fmat, p1[sel], p2[sel])) < 0.01
            other_px.append(np.median(_sampson_px(fmat, p1[~sel], p2[~sel])))
        # The two bodies move differently: one body's epipolar geometry misfits the other by
        # pixels (2.5 px at least over 200 seeds).
        assert max(other_px) > 0.5


def test_pair_outliers_are_their_own_group() -> None:
    rng = np.random.default_rng(7)
    for _ in range(10):
        clip = generate_pair(rng)
        ratio = clip.meta["outlier_ratio"]
        label = clip.meta["outlier_label"]
        assert clip.num_frames == 2
        assert label == clip.k - 1 and clip.meta["body_kinds"][-1] == "outlier"
        np.testing.assert_array_equal(clip.meta["is_outlier"], clip.labels == label)
        assert 0.09 <= ratio <= 0.61
        assert np.mean(clip.labels == label) == pytest.approx(ratio)
        h, w = clip.meta["image_size_hw"]
        assert (h, w) == (480, 640)
        assert clip.traj[:, [0, 2]].max() <= w - 1 and clip.traj[:, [1, 3]].max() <= h - 1


def test_outliers_assigned_to_bodies_when_not_a_group() -> None:
    cfg = SyntheticConfig(outlier_ratio=(0.2, 0.2), outliers_as_group=False, num_bodies=(2, 4))
    clip = generate_clip(np.random.default_rng(8), cfg)
    assert clip.meta["outlier_label"] is None
    assert "outlier" not in clip.meta["body_kinds"]
    assert len(clip.meta["body_kinds"]) == clip.k
    assert clip.meta["is_outlier"].mean() == pytest.approx(0.2, abs=0.01)
    grouped = generate_clip(np.random.default_rng(8), replace(cfg, outliers_as_group=True))
    assert grouped.k == clip.k + 1


def test_group_sizes_are_unequal_and_at_least_two_bodies_when_asked() -> None:
    cfg = SyntheticConfig(num_bodies=(2, 6))
    rng = np.random.default_rng(9)
    smallest, largest = [], []
    for _ in range(30):
        clip = generate_clip(rng, cfg)
        counts = np.bincount(clip.labels)
        assert clip.k >= 2
        smallest.append(counts.min())
        largest.append(counts.max())
    assert min(smallest) <= 20 and max(largest) >= 200


@pytest.mark.parametrize(
    "kwargs",
    [
        {"frames": 1},
        {"num_bodies": (3, 2)},
        {"camera_motions": ("flying",)},
        {"object_kinds": ("blob",)},
        {"outlier_ratio": (0.0, 1.0)},
        {"min_points_per_group": 0},
    ],
)
def test_bad_config_raises(kwargs: dict) -> None:
    with pytest.raises(InputError):
        SyntheticConfig(**kwargs)


def test_config_that_cannot_fit_its_bodies_raises() -> None:
    with pytest.raises(InputError, match="min_points_per_group=50"):
        SyntheticConfig(num_bodies=(2, 2), num_points=(20, 80), min_points_per_group=50)


def test_gives_up_after_many_failed_draws(monkeypatch: pytest.MonkeyPatch) -> None:
    # Every draw culls all but one body: the generator must stop and say why, not loop forever.
    import mosegpipe.synth.trajectories as synthetic

    monkeypatch.setattr(synthetic, "_draw", lambda *args: None)
    with pytest.raises(InputError, match="8 visible points"):
        generate_clip(np.random.default_rng(0), SyntheticConfig(num_bodies=(2, 3)))


def test_small_budget_still_gives_every_body_its_minimum() -> None:
    cfg = SyntheticConfig(num_bodies=(2, 6), num_points=(40, 40), min_points_per_group=10)
    rng = np.random.default_rng(10)
    for _ in range(10):
        clip = generate_clip(rng, cfg)
        assert clip.k >= 2 and np.bincount(clip.labels).min() >= 10
        assert clip.num_points <= 40
