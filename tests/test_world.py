"""The world's motion is label 0: told by where its tracks lie, kept across windows (mosegpipe.group.world)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from mosegpipe.apps.outputs import write_video_outputs
from mosegpipe.embed.model import SubspaceNet
from mosegpipe.errors import ConfigError
from mosegpipe.group.world import (
    WorldConfig,
    epipolar_residual,
    explain_parallax,
    static_share,
    world_cluster,
    world_epipolar,
    world_first,
    world_scores,
)
from mosegpipe.io.read import read_palette_png
from mosegpipe.pipeline import LabelBook, PipelineConfig, match_labels
from mosegpipe.points.flow import FrameMotion

from helpers import motion_checkpoint, write_frames

H, W = 240, 320


def _crowd_and_spread(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """300 tracks crowded on a 60x60 px object (motion 0, the most tracks) and 60 spread over the frame (motion 1)."""
    crowd = rng.uniform([130, 90], [190, 150], size=(300, 2))
    spread = rng.uniform([0, 0], [W, H], size=(60, 2))
    xy = np.concatenate([crowd, spread]).astype(np.float32)
    return xy, np.array([0] * 300 + [1] * 60, np.int64)


def test_the_world_is_where_the_tracks_spread_not_where_they_crowd() -> None:
    xy, labels = _crowd_and_spread(np.random.default_rng(0))
    scores = world_scores(xy, labels, 2, (H, W))
    assert scores[1] > 3 * scores[0]
    assert world_cluster(world_scores(xy, labels, 2, (H, W))) == 1
    # the old rule, for a summary written before this step: the motion with the most tracks
    assert world_cluster(world_scores(xy, labels, 2, (H, W)), WorldConfig(enabled=False)) == 0
    # several frames: (N, T, 2) positions vote in every frame
    moving = np.stack([xy, xy + np.float32([4.0, 0.0])], axis=1)
    assert world_cluster(world_scores(moving, labels, 2, (H, W))) == 1


def test_border_cells_count_more() -> None:
    # one track at the centre of each cell of the 16 x 16 grid: motion 1 holds the 60 border cells, motion 0 the 196 inside
    g = WorldConfig().grid
    cy, cx = np.mgrid[0:g, 0:g]
    xy = np.stack([(cx.ravel() + 0.5) * W / g, (cy.ravel() + 0.5) * H / g], axis=1).astype(np.float32)
    labels = (((cy == 0) | (cy == g - 1) | (cx == 0) | (cx == g - 1)).ravel()).astype(np.int64)
    assert world_scores(xy, labels, 2, (H, W), cfg=WorldConfig(border_weight=0.0)).tolist() == [196.0, 60.0]
    assert world_scores(xy, labels, 2, (H, W), cfg=WorldConfig(border_weight=3.0)).tolist() == [196.0, 240.0]
    assert world_cluster(world_scores(xy, labels, 2, (H, W), cfg=WorldConfig(border_weight=3.0))) == 1


def _object_filling_the_frame() -> tuple[np.ndarray, np.ndarray]:
    """300 tracks on an object close to the camera (two thirds of the frame, motion 0) and 80 on the world
    above and below it (motion 1)."""
    rng = np.random.default_rng(1)
    big = rng.uniform([30, 40], [W - 30, H - 40], size=(300, 2))
    rim = np.concatenate([rng.uniform([0, 0], [W, 30], size=(40, 2)), rng.uniform([0, H - 30], [W, H], size=(40, 2))])
    return np.concatenate([big, rim]).astype(np.float32), np.array([0] * 300 + [1] * 80, np.int64)


def test_the_world_of_the_window_before_keeps_its_role_when_an_object_fills_the_frame() -> None:
    xy, labels = _object_filling_the_frame()
    assert world_cluster(world_scores(xy, labels, 2, (H, W))) == 0  # alone, the area says the object
    was_world = labels == 1
    assert world_cluster(world_scores(xy, labels, 2, (H, W), was_world, np.ones(380, bool))) == 1
    # tracks that were unlabelled before say nothing
    assert world_cluster(world_scores(xy, labels, 2, (H, W), was_world, labels == 0)) == 0


def test_the_camera_evidence_outweighs_the_area() -> None:
    xy, labels = _object_filling_the_frame()
    # the dense flow (at half scale): the camera's motion explains the bands above and below the object only
    residual = np.full((2, H // 2, W // 2), 5.0, np.float32)
    residual[:, :20] = 0.2
    residual[:, -20:] = 0.2
    static = static_share(np.stack([xy, xy], axis=1), residual, 0.5, 1.0)
    assert static[:300].max() == 0.0 and static[300:].min() == 1.0
    assert world_cluster(world_scores(xy, labels, 2, (H, W))) == 0
    assert world_cluster(world_scores(xy, labels, 2, (H, W), static=static)) == 1


def test_world_first_renumbers_hand_computed() -> None:
    labels = np.array([0, 1, 2, 3, -1, 2])
    assert world_first(labels, 2).tolist() == [1, 2, 0, 3, -1, 0]
    assert world_first(labels, 0) is labels
    assert world_first(labels, 3).tolist() == [1, 2, 3, 0, -1, 3]


def test_world_config_refuses_bad_values() -> None:
    for bad in ({"grid": 1}, {"border_weight": float("nan")}, {"continuity": -1.0}):
        with pytest.raises(ConfigError, match=f"^{next(iter(bad))}: "):
            WorldConfig(**bad)  # type: ignore[arg-type]


def test_match_labels_gives_0_to_the_world_cluster_only() -> None:
    # The window before merged the object (tracks 5-9) into the world (label 0); now the world is told
    # apart (cluster 0: tracks 1-4 and 10-12) from the object (cluster 1), which shares more tracks with 0.
    prev = {i: 0 for i in range(1, 10)}
    ids = np.arange(1, 13)
    clusters = np.array([0, 0, 0, 0, 1, 1, 1, 1, 1, 0, 0, 0])
    book = LabelBook(next_label=1)
    labels = match_labels(prev, ids, clusters, 2, book, world=True)
    assert labels.tolist() == [0] * 12  # the object is a split candidate: 0 for now
    labels = match_labels(dict(zip(ids.tolist(), labels.tolist())), ids, clusters, 2, book, window=1, world=True)
    assert labels[clusters == 0].tolist() == [0] * 7 and set(labels[clusters == 1].tolist()) == {1}
    # Without the world rule the Hungarian pairing hands 0 to the object (5 shared tracks against 4).
    book = LabelBook(next_label=1)
    plain = match_labels(prev, ids, clusters, 2, book)
    plain = match_labels(dict(zip(ids.tolist(), plain.tolist())), ids, clusters, 2, book, window=1)
    assert set(plain[clusters == 1].tolist()) == {0} and set(plain[clusters == 0].tolist()) == {1}


def test_first_window_world_takes_0_and_new_motions_count_from_1() -> None:
    book = LabelBook()
    labels = match_labels({}, np.arange(40), np.array([0] * 20 + [1] * 20), 2, book, world=True)
    assert labels.tolist() == [0] * 20 + [1] * 20 and book.next_label == 2


def _textured_object_over_plain_world(frames: int, stop: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """A camera panning over a softly textured world (good flow, weak corners) while a high-contrast object
    (a quarter of the frame, far more corners than the world: the corner detector's quality threshold is
    relative to the strongest) enters from the right and crosses the frame; from frame `stop` on (None: never) it
    stands still in the world (it moves with the panning background). Returns (T, H, W, 3) frames and (T, H, W)
    truth (the object, moving or not)."""
    rng = np.random.default_rng(3)
    world = cv2.GaussianBlur(rng.random((H, W + 8 * frames)).astype(np.float32), (0, 0), 3.0)
    world = np.clip((world - world.mean()) / world.std() * 18 + 110, 0, 255).astype(np.uint8)
    texture = (rng.random((24, 30)) > 0.5).astype(np.uint8) * 200 + 25
    texture = cv2.resize(texture, (150, 120), interpolation=cv2.INTER_NEAREST)
    images, truth = [], []
    for t in range(frames):
        frame = world[:, 8 * t : 8 * t + W].copy()
        x0 = W + 10 - 14 * t if stop is None or t < stop else W + 10 - 14 * stop - 8 * (t - stop)  # its left edge
        gt = np.zeros((H, W), bool)
        if x0 < W:
            seen = slice(max(x0, 0), min(x0 + 150, W))
            frame[60:180, seen] = texture[:, seen.start - x0 : seen.stop - x0]
            gt[60:180, seen] = True
        images.append(np.repeat(frame[..., None], 3, axis=2))
        truth.append(gt)
    return np.stack(images), np.stack(truth)


def test_whole_video_writes_the_world_as_0_in_every_frame(tmp_path: Path) -> None:
    frames, truth = _textured_object_over_plain_world(21)
    folder = write_frames(tmp_path / "frames", frames)
    model = SubspaceNet.from_checkpoint(motion_checkpoint(tmp_path / "m.pt", 5))
    cfg = PipelineConfig(frames=5)
    write_video_outputs(folder, tmp_path / "out", cfg, model, rrd=False)
    masks = np.stack([read_palette_png(tmp_path / "out" / "masks" / f"{t:06d}.png") for t in range(len(frames))])
    for t, (mask, gt) in enumerate(zip(masks, truth)):
        assert np.bincount(mask[~gt], minlength=256).argmax() == 0, t  # the world is 0 as written
        assert not gt.any() or np.mean(mask[gt] != 0) > 0.5, t  # and the object is not


def test_an_object_that_stops_joins_the_world_and_the_world_stays_0(tmp_path: Path) -> None:
    frames, truth = _textured_object_over_plain_world(21, stop=11)
    folder = write_frames(tmp_path / "frames", frames)
    model = SubspaceNet.from_checkpoint(motion_checkpoint(tmp_path / "m.pt", 5))
    write_video_outputs(folder, tmp_path / "out", PipelineConfig(frames=5), model, rrd=False)
    masks = np.stack([read_palette_png(tmp_path / "out" / "masks" / f"{t:06d}.png") for t in range(len(frames))])
    for t, (mask, gt) in enumerate(zip(masks, truth)):
        assert np.bincount(mask[~gt], minlength=256).argmax() == 0, t
    # once it has stood still for a window, the object is the world's: written 0 as well
    assert all(np.mean(mask[gt] == 0) > 0.8 for mask, gt in zip(masks[16:], truth[16:]))


def test_the_world_is_0_on_both_sides_of_a_shot_cut(tmp_path: Path) -> None:
    from helpers import render_scene

    shots = [render_scene(11, seed=0), render_scene(9, seed=1)]
    frames = np.concatenate([s.frames for s in shots])
    static = np.concatenate([s.masks == 0 for s in shots])
    folder = write_frames(tmp_path / "cut", frames)
    model = SubspaceNet.from_checkpoint(motion_checkpoint(tmp_path / "m.pt", 5))
    summary = write_video_outputs(folder, tmp_path / "out", PipelineConfig(frames=5), model, rrd=False)
    assert summary["shot_cuts"] == [11]
    masks = np.stack([read_palette_png(tmp_path / "out" / "masks" / f"{t:06d}.png") for t in range(len(frames))])
    for t, (mask, world) in enumerate(zip(masks, static)):
        assert np.bincount(mask[world], minlength=256).argmax() == 0, t


# ---------------------------------------------------------------------------------------------
# The world's 3D structure: parallax is not motion
# ---------------------------------------------------------------------------------------------

K_PX = np.array([[300.0, 0.0, W / 2], [0.0, 300.0, H / 2], [0.0, 0.0, 1.0]])


def _project(points: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """(n, 2) pixels of 3D points (n, 3) seen by the camera moved by `shift` (no rotation)."""
    cam = (points - shift) @ K_PX.T
    return (cam[:, :2] / cam[:, 2:3]).astype(np.float32)


def _scene(rng: np.random.Generator, depths: tuple[float, ...]) -> np.ndarray:
    """3D points in front of the camera, at the given depths (metres), spread over the view."""
    points = []
    for z in depths:
        uv = rng.uniform([0, 0], [W, H], size=(60, 2))
        ray = np.concatenate([(uv - K_PX[:2, 2]) / 300.0, np.ones((60, 1))], axis=1)
        points.append(ray * z)
    return np.concatenate(points)


def test_a_deep_scene_under_a_moving_camera_needs_a_fundamental_matrix_a_plane_does_not() -> None:
    rng = np.random.default_rng(5)
    shift = np.array([0.3, 0.0, 0.0])
    deep = _scene(rng, (2.0, 4.0, 12.0))
    fm = world_epipolar(_project(deep, np.zeros(3)), _project(deep, shift))
    assert fm is not None
    flat = _scene(rng, (6.0, 6.0, 6.0))
    assert world_epipolar(_project(flat, np.zeros(3)), _project(flat, shift)) is None
    few = deep[:20]
    assert world_epipolar(_project(few, np.zeros(3)), _project(few, shift)) is None  # too few tracks to say


def test_flow_along_the_epipolar_line_has_no_residual_across_it_has() -> None:
    rng = np.random.default_rng(6)
    shift = np.array([0.3, 0.0, 0.0])  # sideways: the epipolar lines are horizontal
    deep = _scene(rng, (2.0, 4.0, 12.0))
    fm = world_epipolar(_project(deep, np.zeros(3)), _project(deep, shift))
    assert fm is not None
    flow = np.zeros((H // 2, W // 2, 2), np.float32)
    flow[..., 0] = -7.0  # along the lines (any depth)
    assert float(np.median(epipolar_residual(flow, fm, 0.5))) < 0.3
    flow[..., 1] = 4.0  # and across them
    assert float(np.median(epipolar_residual(flow, fm, 0.5))) > 1.5


def test_explain_parallax_clears_the_worlds_depth_but_not_a_mover_among_its_own_tracks() -> None:
    rng = np.random.default_rng(7)
    shift = np.array([0.3, 0.0, 0.0])
    deep = _scene(rng, (1.5, 3.0, 12.0))
    p0, p1 = _project(deep, np.zeros(3)), _project(deep, shift)
    keep = (p0[:, 0] < 200) & (p1[:, 0] > 2)  # the world's tracks, left of the mover
    p0, p1 = p0[keep], p1[keep]
    mover = np.array([[x, y] for x in range(240, 320, 10) for y in range(20, 220, 20)], np.float32)
    xy = np.concatenate([np.stack([p0, p1], axis=1), np.stack([mover, mover + np.float32([-6, 0])], axis=1)])
    labels = np.array([0] * len(p0) + [1] * len(mover), np.int64)
    h, w = H // 2, W // 2
    forward = np.zeros((1, h, w, 2), np.float32)
    forward[..., 0] = -3.0  # half scale: the world's parallax and the mover's motion are both horizontal
    residual = np.full((2, h, w), 2.0, np.float32)  # what the homography left: all of it
    motion = FrameMotion(residual, np.zeros_like(residual), 0.5, forward, forward.copy())
    out = explain_parallax(motion, xy, labels)
    assert float(np.median(out.residual[0, :, :80])) < 0.3  # the world's pixels: explained
    assert float(out.residual[0, :, 130:].min()) == 2.0  # the mover's pixels: its own tracks keep it
    assert explain_parallax(motion, xy, labels, WorldConfig(parallax=False)) is motion
