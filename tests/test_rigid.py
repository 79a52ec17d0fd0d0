from __future__ import annotations

from dataclasses import replace

import numpy as np
import numpy.typing as npt
import pytest

from mosegpipe.errors import InputError
from mosegpipe.group.rigid import (
    MAX_CHECKED_POINTS,
    RigidCheckConfig,
    fit_rigid_motion,
    label_by_rigid_motion,
    split_by_rigid_motion,
)
from mosegpipe.pipeline import PipelineConfig, check_rigid
from mosegpipe.types import Clustering

SIZE_HW = (480, 640)
FOCAL = 500.0


def _project(points: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Pinhole projection of (..., 3) camera-frame points, principal point at the image centre."""
    return FOCAL * points[..., :2] / points[..., 2:] + np.array([SIZE_HW[1] / 2, SIZE_HW[0] / 2])


def _static_background(rng: np.random.Generator, count: int = 400) -> npt.NDArray[np.float64]:
    """(count, 3) camera-frame points of a static scene at depths 4-40, spread over the image."""
    pix = rng.uniform([40, 40], [SIZE_HW[1] - 40, SIZE_HW[0] - 40], size=(count, 2))
    depth = rng.uniform(4.0, 40.0, size=count)
    return np.c_[(pix - [SIZE_HW[1] / 2, SIZE_HW[0] / 2]) * depth[:, None] / FOCAL, depth]


def scene(
    camera: str,
    object_points: int = 25,
    frames: int = 5,
    background: int = 400,
    noise_px: float = 0.2,
    seed: int = 0,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]:
    """(N, 2F) trajectories of a static scene at depths 4-40 seen by a moving camera, plus one object.

    camera "forward": the camera moves 0.3 units along its axis per frame and turns a little (strong
    parallax, so no homography explains the background); "static": it does not move. The object is
    a compact rigid box that moves sideways by 0.08 units per frame at depth ~8 (object_points = 0:
    none). Returns the trajectories and the true labels (0 background, 1 object).
    """
    rng = np.random.default_rng(seed)
    world = _static_background(rng, background)
    centre = np.array([0.6, 0.2, 8.0])
    box = centre + rng.uniform(-0.3, 0.3, size=(object_points, 3))
    tracks = []
    for t in range(frames):
        if camera == "forward":
            angle = 0.004 * t
            rot = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]])
            cam = (world - [0, 0, 0.3 * t]) @ rot.T
            obj = (box + [0.08 * t, 0, 0] - [0, 0, 0.3 * t]) @ rot.T
        else:
            cam = world
            obj = box + [0.08 * t, 0, 0]
        tracks.append(_project(np.r_[cam, obj]))
    xy = np.stack(tracks, axis=1) + rng.normal(scale=noise_px, size=(background + object_points, frames, 2))
    labels = np.r_[np.zeros(background, np.int64), np.ones(object_points, np.int64)]
    return xy.reshape(len(xy), -1), labels


@pytest.mark.parametrize("camera", ["forward", "static"])
def test_split_off_an_object_left_in_the_background_cluster(camera: str) -> None:
    points, truth = scene(camera)
    labels, split = split_by_rigid_motion(points, np.zeros(len(points), np.int64), SIZE_HW)
    assert split == 1
    assert labels.max() == 1
    # The new cluster is the object, but for object points that the background's model explains
    # as well (forward camera: those near their epipolar lines; 22 of 25 are found).
    found = labels == 1
    assert (found & (truth == 1)).sum() >= 20
    assert (found & (truth == 0)).sum() <= 1


def test_a_moving_camera_over_a_deep_scene_is_one_motion() -> None:
    # Parallax is not a second motion: the fundamental matrix explains it, no homography does.
    points, _ = scene("forward", object_points=0)
    xy = points.reshape(len(points), -1, 2)
    forced_h = fit_rigid_motion(xy, replace(RigidCheckConfig(), homography_ratio=0.0))  # the homography
    chosen = fit_rigid_motion(xy)
    assert forced_h is not None and chosen is not None
    assert np.mean(forced_h(xy) > 1.5) > 0.3
    assert np.mean(chosen(xy) > 1.5) < 0.05
    labels, split = split_by_rigid_motion(points, np.zeros(len(points), np.int64), SIZE_HW)
    assert split == 0
    assert np.all(labels == 0)


def test_scattered_outlier_tracks_stay_where_they_are() -> None:
    points, _ = scene("forward", object_points=0)
    rng = np.random.default_rng(1)
    bad = rng.choice(len(points), 40, replace=False)
    xy = points.reshape(len(points), -1, 2).copy()
    xy[bad, 1:] += rng.normal(scale=6.0, size=(40, xy.shape[1] - 1, 2))  # each its own wrong motion
    labels, split = split_by_rigid_motion(xy.reshape(len(xy), -1), np.zeros(len(xy), np.int64), SIZE_HW)
    assert split == 0
    assert np.all(labels == 0)


def test_small_groups_and_small_clusters_are_not_split() -> None:
    points, _ = scene("static", object_points=8)  # fewer than min_tracks
    _, split = split_by_rigid_motion(points, np.zeros(len(points), np.int64), SIZE_HW)
    assert split == 0
    points, truth = scene("static")
    strict = replace(RigidCheckConfig(), min_host=len(points))  # the split would leave too few behind
    _, split = split_by_rigid_motion(points, np.zeros(len(points), np.int64), SIZE_HW, strict)
    assert split == 0


def test_each_cluster_is_checked_and_labels_come_ordered_by_size() -> None:
    a, truth_a = scene("static", seed=0)
    b, truth_b = scene("static", seed=1)
    b = b + np.tile([0.0, 600.0], b.shape[1] // 2)  # a second, separate scene below the first
    points = np.r_[a, b]
    given = np.r_[np.zeros(len(a), np.int64), np.ones(len(b), np.int64)]
    labels, split = split_by_rigid_motion(points, given, (1100, 640))
    assert split == 2
    assert np.bincount(labels).tolist() == sorted(np.bincount(labels).tolist(), reverse=True)
    objects = np.r_[truth_a, truth_b] == 1
    assert len(np.unique(labels[objects])) == 2  # one object per scene, each its own cluster
    assert set(np.unique(labels[objects])).isdisjoint(np.unique(labels[~objects]))


def test_pieces_of_one_rigid_motion_are_merged() -> None:
    # Two boxes far apart (more than the neighbourhood) that move alike: two coherent groups, one motion.
    points, truth = scene("static", object_points=20, seed=4)
    twin, _ = scene("static", object_points=20, seed=4)
    piece = twin[truth == 1] + np.tile([-400.0, 120.0], twin.shape[1] // 2)  # 420 px away, same motion
    points = np.r_[points, piece]
    truth = np.r_[truth, np.ones(len(piece), np.int64)]
    given = np.zeros(len(points), np.int64)
    labels, split = split_by_rigid_motion(points, given, SIZE_HW)
    assert split == 1
    assert np.array_equal(labels == 1, truth == 1)
    apart = replace(RigidCheckConfig(), merge_consistency=None)
    labels, split = split_by_rigid_motion(points, given, SIZE_HW, apart)
    assert split == 2


def _trajectories(
    rng: np.random.Generator, world: npt.NDArray[np.float64], parts: list[tuple[npt.NDArray[np.float64], tuple]]
) -> npt.NDArray[np.float64]:
    """(N, 2F) trajectories over 5 frames of a still camera: the static points, then each (points, motion per frame)."""
    frames = [_project(np.concatenate([world] + [p + np.asarray(m) * t for p, m in parts])) for t in range(5)]
    xy = np.stack(frames, axis=1) + rng.normal(scale=0.2, size=(len(frames[0]), 5, 2))
    return xy.reshape(len(xy), -1)


def test_two_objects_that_one_fundamental_matrix_explains_are_cut_apart() -> None:
    # Two boxes side by side moving at right angles (5 px per frame each), given as one cluster: one
    # fundamental matrix between two frames fits both, so steps 1-4 leave them together; step 5 does not.
    rng = np.random.default_rng(0)
    world = _static_background(rng)
    a = np.array([0.6, 0.2, 8.0]) + rng.uniform(-0.3, 0.3, size=(30, 3))
    b = np.array([-0.4, -0.1, 8.0]) + rng.uniform(-0.3, 0.3, size=(30, 3))
    points = _trajectories(rng, world, [(a, (0.08, 0, 0)), (b, (0, 0.08, 0))])
    truth = np.r_[np.zeros(len(world), np.int64), np.ones(30, np.int64), np.full(30, 2)]
    given = np.minimum(truth, 1)
    labels, split = split_by_rigid_motion(points, given, SIZE_HW, RigidCheckConfig(separate=False))
    assert split == 0 and np.array_equal(labels, given)
    labels, split = split_by_rigid_motion(points, given, SIZE_HW)
    assert split == 1
    assert [np.unique(labels[truth == g]).size for g in range(3)] == [1, 1, 1]
    assert np.unique(labels).size == 3
    # --k-max caps what the check adds
    labels, split = split_by_rigid_motion(points, given, SIZE_HW, max_k=2)
    assert split == 0 and np.array_equal(labels, given)


def test_many_points_are_cut_on_the_sample_and_the_rest_follow() -> None:
    # More than MAX_CHECKED_POINTS: step 5 runs on the sample, every other point follows its nearest
    # sampled member of its cluster.
    rng = np.random.default_rng(1)
    world = _static_background(rng, count=3000)
    a = np.array([0.6, 0.2, 8.0]) + rng.uniform(-0.3, 0.3, size=(300, 3))
    b = np.array([-0.4, -0.1, 8.0]) + rng.uniform(-0.3, 0.3, size=(300, 3))
    points = _trajectories(rng, world, [(a, (0.08, 0, 0)), (b, (0, 0.08, 0))])
    truth = np.r_[np.zeros(len(world), np.int64), np.ones(300, np.int64), np.full(300, 2)]
    assert len(points) > MAX_CHECKED_POINTS
    labels, split = split_by_rigid_motion(points, np.minimum(truth, 1), SIZE_HW)
    assert split == 1
    assert [np.unique(labels[truth == g]).size for g in range(3)] == [1, 1, 1]
    assert np.unique(labels).size == 3


def test_the_near_and_far_ends_of_a_deep_object_stay_one_motion() -> None:
    # A block 6-9 and 12-20 units deep moving sideways: its near end moves 81 px, its far end 35 px,
    # in one direction; no homography explains it, one fundamental matrix does, and the ends touch.
    rng = np.random.default_rng(0)
    world = _static_background(rng)
    near = np.c_[rng.uniform(-1.6, -1.0, 40), rng.uniform(0.0, 0.6, 40), rng.uniform(6.0, 9.0, 40)]
    far = np.c_[rng.uniform(-1.6, -1.0, 40), rng.uniform(0.0, 0.6, 40), rng.uniform(12.0, 20.0, 40)]
    points = _trajectories(rng, world, [(np.r_[near, far], (0.3, 0, 0.05))])
    truth = np.r_[np.zeros(len(world), np.int64), np.ones(80, np.int64)]
    labels, split = split_by_rigid_motion(points, truth, SIZE_HW)
    assert split == 0 and np.array_equal(labels, truth)
    # the direction test is what keeps them: at 0 degrees the two ends come apart
    _, split = split_by_rigid_motion(points, truth, SIZE_HW, RigidCheckConfig(max_angle_deg=0.0))
    assert split == 1


def test_the_result_is_deterministic() -> None:
    points, _ = scene("forward", seed=3)
    first = split_by_rigid_motion(points, np.zeros(len(points), np.int64), SIZE_HW)
    second = split_by_rigid_motion(points, np.zeros(len(points), np.int64), SIZE_HW)
    assert first[1] == second[1]
    assert np.array_equal(first[0], second[0])


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"residual_px": 0.0}, "^residual_px: 0.0 must"),
        ({"neighbour_frac": -0.1}, "^neighbour_frac: -0.1 must"),
        ({"consistency": 1.5}, "^consistency: 1.5 must"),
        ({"min_tracks": 0}, "^min_tracks: 0 must"),
        ({"merge_consistency": 2.0}, "^merge_consistency: 2.0 must"),
        ({"min_share": 1.5}, "^min_share: 1.5 must"),
        ({"max_angle_deg": 200.0}, "^max_angle_deg: 200.0 must"),
    ],
)
def test_bad_settings_are_refused(kwargs: dict[str, float], message: str) -> None:
    with pytest.raises(InputError, match=message):
        RigidCheckConfig(**kwargs)  # type: ignore[arg-type]


def test_check_rigid_in_the_pipeline() -> None:
    points, truth = scene("static")
    data = points.astype(np.float32)
    merged = Clustering(np.zeros(len(points), np.int64), 1, {1: 1.0}, "silhouette", "")
    checked = check_rigid(merged, data, SIZE_HW, PipelineConfig(method="subspacenet"))
    assert checked.k == 2
    assert checked.note == "the rigid-motion check split off 1 group (K = 1 -> 2)"
    assert checked.scores == merged.scores  # the sweep's evidence is kept as it was
    assert np.array_equal(checked.labels == 1, truth == 1)
    # K given, or the check off: the clustering is what automatic K (or the user) said.
    assert check_rigid(merged, data, SIZE_HW, PipelineConfig(method="subspacenet", k=1)) is merged
    off = PipelineConfig(method="subspacenet", rigid=RigidCheckConfig(enabled=False))
    assert check_rigid(merged, data, SIZE_HW, off) is merged
    noted = replace(merged, note="the K choice is ambiguous")
    assert check_rigid(noted, data, SIZE_HW, PipelineConfig(method="subspacenet")).note.startswith(
        "the K choice is ambiguous; the rigid"
    )


def test_the_config_round_trips_through_summary_json_form() -> None:
    from dataclasses import asdict

    cfg = PipelineConfig(rigid=RigidCheckConfig(residual_px=2.0, enabled=False))
    assert PipelineConfig.from_dict(asdict(cfg)) == cfg
    old = asdict(PipelineConfig())
    del old["rigid"]  # a summary written before the check existed: replayed as it ran, without it
    assert PipelineConfig.from_dict(old).rigid == RigidCheckConfig(enabled=False)


def test_label_by_rigid_motion_gives_each_track_the_motion_it_follows() -> None:
    points, truth = scene("forward", object_points=40, seed=5)
    known = np.arange(len(points)) % 2 == 0
    labels = label_by_rigid_motion(points[~known], points[known], truth[known])
    assert np.mean(labels == truth[~known]) > 0.9
    assert np.mean(labels[truth[~known] == 1] == 1) > 0.8  # the object's own tracks, not the wall's
    # Tracks that move like none of their neighbours get no label.
    rng = np.random.default_rng(2)
    wild = points[~known][:20].reshape(20, -1, 2).copy()
    wild[:, 1:] += rng.normal(scale=8.0, size=(20, wild.shape[1] - 1, 2))
    # (a fundamental matrix only constrains motion across epipolar lines: a few pass by chance)
    assert np.mean(label_by_rigid_motion(wild.reshape(20, -1), points[known], truth[known]) == -1) >= 0.8
    # A cluster of fewer than min_tracks tracks has no model: its label is never given.
    few = truth[known].copy()
    few[np.flatnonzero(few == 1)[5:]] = 0
    assert not np.any(label_by_rigid_motion(points[~known], points[known], few) == 1)
    assert label_by_rigid_motion(points[:0], points[known], truth[known]).shape == (0,)


def test_a_group_must_hold_a_share_of_many_points() -> None:
    # 25 object points among 400: split off at the default share (1 %), kept at 10 % (a group of 43 needed)
    points, _ = scene("static")
    _, split = split_by_rigid_motion(points, np.zeros(len(points), np.int64), SIZE_HW)
    assert split == 1
    _, split = split_by_rigid_motion(points, np.zeros(len(points), np.int64), SIZE_HW, RigidCheckConfig(min_share=0.1))
    assert split == 0
