"""The long-span test of the static world's tracks (mosegpipe.masks.rigid_tracks) and the masks' use of it."""

from __future__ import annotations

import numpy as np
import pytest

from mosegpipe.colours import WORLD
from mosegpipe.configs.masks import MaskConfig, RigidTracksConfig
from mosegpipe.masks.compose import MaskSequence
from mosegpipe.masks.rigid_tracks import TrackHistory, judge, rigid_tracks, static_held
from mosegpipe.settings import SettingError

F_PX, CX, CY = 300.0, 160.0, 120.0
SPAN = 8


def _world(depths: tuple[float, float], n: int = 300, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(n, SPAN + 1, 2) pixels of still points at depths in `depths` (m) seen by a camera trucking 10 cm a frame
    to the right and turning slowly back, and (n,) bool: False (none of them moves)."""
    rng = np.random.default_rng(seed)
    z = rng.uniform(*depths, n)
    x = rng.uniform(-0.5, 0.5, n) * z * 320 / F_PX + 0.4
    y = rng.uniform(-0.4, 0.4, n) * z * 240 / F_PX
    return _project(np.stack([x, y, z], 1)[:, None, :].repeat(SPAN + 1, 1)), np.zeros(n, bool)


def _project(points: np.ndarray) -> np.ndarray:
    """(n, T, 3) world points -> (n, T, 2) pixels of the trucking camera, frame by frame."""
    out = np.zeros(points.shape[:2] + (2,))
    for t in range(points.shape[1]):
        yaw = -0.003 * t
        rot = np.array([[np.cos(yaw), 0, -np.sin(yaw)], [0, 1, 0], [np.sin(yaw), 0, np.cos(yaw)]])
        cam = (points[:, t] - [0.1 * t, 0, 0]) @ rot.T
        out[:, t] = F_PX * cam[:, :2] / cam[:, 2:] + [CX, CY]
    return out + np.random.default_rng(1).normal(0, 0.1, out.shape)


def _followed(n: int = 60) -> np.ndarray:
    """(n, SPAN + 1, 2) pixels of a walker the camera follows, 5 m away: its speed changes from frame to frame
    (a gait), always along the camera's direction (so along the epipolar lines of every frame pair)."""
    rng = np.random.default_rng(2)
    base = np.stack([rng.uniform(-0.3, 0.3, n), rng.uniform(-0.5, 0.8, n), np.full(n, 5.0)], 1)
    steps = 0.1 + 0.06 * np.sin(np.arange(SPAN + 1) * 1.3)
    travel = np.concatenate([[0.0], np.cumsum(steps[:-1])])
    pts = base[:, None, :] + travel[None, :, None] * np.array([1.0, 0, 0])
    return _project(pts)


def _judge(xy: np.ndarray, world: np.ndarray, cfg: RigidTracksConfig = RigidTracksConfig(span=SPAN, partners=SPAN)):
    ids = np.arange(len(xy))
    ref = (ids, xy[:, SPAN].astype(np.float32))
    partners = [xy[:, SPAN - g] for g in cfg.gaps]
    return judge(ref, partners, list(cfg.gaps), world, cfg)


def test_still_points_of_any_depth_are_static_and_a_followed_walker_is_not() -> None:
    still, _ = _world((2.0, 30.0))
    walker = _followed()
    xy = np.concatenate([still, walker])
    world = np.arange(len(xy)) < len(still)  # the clustering's world: the still points
    known, static = _judge(xy, world)
    assert known.all()
    assert static[: len(still)].mean() > 0.9
    assert static[len(still) :].mean() < 0.2


def test_a_world_without_depth_is_not_judged() -> None:
    still, _ = _world((29.9, 30.0))  # one depth: a homography explains it, F is free to take in the walker
    xy = np.concatenate([still, _followed()])
    known, static = _judge(xy, np.arange(len(xy)) < len(still))
    assert not known.any() and not static.any()


def test_rigid_tracks_reads_the_history_and_needs_the_whole_span() -> None:
    still, _ = _world((2.0, 30.0))
    ids = np.arange(len(still), dtype=np.int64)
    cfg = RigidTracksConfig(span=SPAN, partners=SPAN)
    history = TrackHistory(SPAN + 1)
    labels = np.full(len(still), WORLD, np.int64)
    for t in range(SPAN):
        history.add(t, (ids, still[:, t].astype(np.float32)))
    assert rigid_tracks(history, SPAN - 1, labels, cfg) is None  # frame SPAN - 1 has no partner SPAN frames back
    history.add(SPAN, (ids, still[:, SPAN].astype(np.float32)))
    history.add(SPAN, (ids[:1], still[:1, SPAN].astype(np.float32)))  # a frame held is not added twice
    verdict = rigid_tracks(history, SPAN, labels, cfg)
    assert verdict is not None and verdict.static.mean() > 0.9
    known, static = verdict.of(np.array([5, 10_000], np.int64))  # a track the verdict has, one it has not
    assert known.tolist() == [True, False] and static[1] == np.False_
    history.reset()
    assert rigid_tracks(history, SPAN, labels, cfg) is None


def test_static_held_keeps_with_the_world_the_regions_the_static_tracks_hold() -> None:
    moving = np.zeros((60, 80), bool)
    moving[5:25, 5:25] = True  # near structure: its tracks are the static world's
    moving[35:55, 45:75] = True  # a mover: its tracks are not
    grid = np.stack(np.meshgrid(np.arange(6, 24, 3), np.arange(6, 24, 3)), -1).reshape(-1, 2)
    near = grid.astype(np.float32)
    mover = (grid + [40, 30]).astype(np.float32)
    xy = np.concatenate([near, mover])
    static = np.arange(len(xy)) < len(near)
    known = np.ones(len(xy), bool)
    out = static_held(moving, xy, known, static, share=0.9, min_tracks=10)
    assert not out[5:25, 5:25].any() and out[35:55, 45:75].all()
    # tracks not known do not count: too few known tracks leave the region as it is
    few = static_held(moving, xy, np.arange(len(xy)) < 5, static, share=0.9, min_tracks=10)
    assert few[5:25, 5:25].all()


def test_the_settings_are_checked_and_a_video_keeps_a_history_that_a_shot_cut_clears() -> None:
    assert RigidTracksConfig(span=12, partners=3).gaps == (4, 8, 12)
    with pytest.raises(SettingError):
        RigidTracksConfig(span=4, partners=6)
    seq = MaskSequence(MaskConfig(rigid=RigidTracksConfig(enabled=True)), video=True)
    assert seq.history is not None and seq.history.frames.maxlen == 13
    seq.history.add(0, (np.zeros(0, np.int64), np.zeros((0, 2), np.float32)))
    seq.new_shot()
    assert len(seq.history.frames) == 0
    assert MaskSequence(MaskConfig(), video=True).history is None  # off by default
