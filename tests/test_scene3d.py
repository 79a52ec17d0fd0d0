"""Every pixel judged against the camera's 3D motion: near structure in front of a translating camera is static,
a mover across the epipolar lines is not, and a planar scene keeps the homography's residual; a moving
region the world's tracks hold stays with the world."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from mosegpipe.colours import WORLD
from mosegpipe.configs.grouping import WorldConfig
from mosegpipe.masks import MaskConfig
from mosegpipe.masks.compose import moving_to_labels, world_held
from mosegpipe.masks.scene3d import explain_rigid_scene, partners
from mosegpipe.points.flow import FrameMotion, camera_residual, fit_camera

H, W, T = 96, 128, 5
SQUARE = (slice(10, 30), slice(60, 84))  # the mover, in the far part
NEAR = 40  # rows from here on are near


def _scene(near_px: float) -> tuple[FrameMotion, np.ndarray, np.ndarray]:
    """A camera sliding sideways: rows above NEAR far (0.5 px a frame), the rest near (`near_px`), a square
    in the far part moving down 1.5 px a frame (across its epipolar lines, the rows). Flows the same every frame."""
    flow = np.zeros((H, W, 2), np.float32)
    flow[:NEAR, :, 0] = -0.5
    flow[NEAR:, :, 0] = -near_px
    flow[SQUARE] = (0.0, 1.5)
    forward = np.repeat(flow[None], T - 1, axis=0)
    backward = -forward
    residual = np.stack([camera_residual(flow, fit_camera(flow, None))] * T)
    motion = FrameMotion(residual, np.zeros((T, H, W), np.float32), 1.0, forward, backward)
    ys, xs = np.mgrid[2:H:6, 2:W:6].reshape(2, -1).astype(np.float32)
    mover = (ys >= 10) & (ys < 30) & (xs >= 60) & (xs < 84)
    xy = np.zeros((ys.size, T, 2), np.float32)
    for t in range(T):
        xy[:, t, 0] = xs + t * flow[ys.astype(int), xs.astype(int), 0]
        xy[:, t, 1] = ys + t * flow[ys.astype(int), xs.astype(int), 1]
    xy += np.random.default_rng(0).normal(0, 0.05, xy.shape).astype(np.float32)
    return motion, xy, mover.astype(np.int64)


def test_partners_are_the_farthest_frames_either_side() -> None:
    assert partners(0, 5) == [4, 2] and partners(4, 5) == [0, 2] and partners(1, 5) == [4, 0]
    assert partners(2, 5) == [0, 4] and partners(0, 2) == [1] and partners(1, 2) == [0]


def _static(residual: np.ndarray) -> np.ndarray:
    """The static pixels' residuals away from the image border, the depth edge and the mover."""
    keep = np.zeros((H, W), bool)
    keep[4 : NEAR - 4, 4:-4] = keep[NEAR + 4 : -4, 4:-4] = True
    keep[6:34, 56:88] = False
    return residual[keep]


def test_the_world_of_two_depths_becomes_static_and_the_mover_stays() -> None:
    motion, xy, labels = _scene(near_px=4.0)
    for t in range(T):
        assert np.percentile(_static(motion.residual[t]), 75) > 1.0  # one homography: one of the depths "moves"
    for gate in ("gric", "parallax"):
        for region in ("all", "world"):
            cfg = WorldConfig(rigid_scene=True, rigid_scene_region=region, rigid_scene_gate=gate)
            out = explain_rigid_scene(motion, xy, labels, cfg)
            for t in range(T):
                assert np.percentile(_static(out.residual[t]), 75) < 0.3, (gate, region, t)
                assert np.median(out.residual[t][SQUARE]) > 1.0, (gate, region, t)
    assert explain_rigid_scene(motion, xy, labels, WorldConfig()) is motion  # off by default


def test_a_planar_scene_keeps_the_homography_residual() -> None:
    motion, xy, labels = _scene(near_px=0.5)  # one depth: a homography explains the world
    for gate in ("gric", "parallax"):
        out = explain_rigid_scene(motion, xy, labels, WorldConfig(rigid_scene=True, rigid_scene_gate=gate))
        assert np.array_equal(out.residual, motion.residual), gate


def test_a_moving_region_full_of_world_tracks_stays_with_the_world() -> None:
    moving = np.zeros((40, 60), bool)
    moving[2:12, 2:20] = True  # water: 12 world tracks in it
    moving[20:35, 30:50] = True  # a mover: 10 tracks of its own and 2 of the world at its edge
    water = [(x, y) for x in range(4, 19, 5) for y in (4, 7, 10, 11)]
    mover = [(x, y) for x in range(32, 49, 4) for y in (22, 30)]
    xy = np.array(water + mover + [(30, 20), (49, 34)], np.float32)
    labels = np.array([WORLD] * len(water) + [3] * len(mover) + [WORLD, WORLD])
    held = world_held(moving, xy, labels, WORLD, share=0.95, min_tracks=10)
    assert not held[2:12, 2:20].any() and held[20:35, 30:50].all()
    assert world_held(moving, xy, labels, WORLD, share=0.95, min_tracks=20) is moving  # too few tracks to judge
    mask = moving_to_labels(moving, xy, labels, WORLD, cfg=MaskConfig(world_regions=0.95, world_region_tracks=10))
    assert (mask[2:12, 2:20] == WORLD).all() and (mask[20:35, 30:50] == 3).all()
    assert (moving_to_labels(moving, xy, labels, WORLD)[2:12, 2:20] == 3).all()  # off: the nearest mover's


def test_a_world_without_depth_leaves_a_mover_along_the_epipolar_lines_alone() -> None:
    # a far, planar world (0.5 px a frame) and a block sliding along the rows 3 px a frame: one F holds both
    # (any epipole on the rows' line), so judged over every pixel the block would be explained as near structure
    block = (slice(8, 40), slice(40, 100))
    flow = np.zeros((H, W, 2), np.float32)
    flow[..., 0] = -0.5
    flow[block] = (-3.0, 0.0)
    forward = np.repeat(flow[None], T - 1, axis=0)
    residual = np.stack([camera_residual(flow, fit_camera(flow, None))] * T)
    motion = FrameMotion(residual, np.zeros((T, H, W), np.float32), 1.0, forward, -forward)
    ys, xs = np.mgrid[2:H:6, 2:W:6].reshape(2, -1).astype(np.float32)
    inside = (ys >= 8) & (ys < 40) & (xs >= 40) & (xs < 100)
    xy = np.zeros((ys.size, T, 2), np.float32)
    for t in range(T):
        xy[:, t, 0] = xs + t * np.where(inside, -3.0, -0.5)
        xy[:, t, 1] = ys
    xy += np.random.default_rng(0).normal(0, 0.05, xy.shape).astype(np.float32)
    labels = inside.astype(np.int64)
    base = WorldConfig(rigid_scene=True, rigid_scene_gate="parallax", rigid_scene_region="all")
    swallowed = explain_rigid_scene(motion, xy, labels, base)
    assert np.median(swallowed.residual[2][block]) < 1.0  # without the world's own depth: taken for the world
    gated = explain_rigid_scene(motion, xy, labels, replace(base, rigid_scene_world_depth=0.05))
    assert np.array_equal(gated.residual, motion.residual)
    # a world with depth passes the same gate
    motion3d, xy3d, labels3d = _scene(near_px=4.0)
    out = explain_rigid_scene(motion3d, xy3d, labels3d, replace(base, rigid_scene_world_depth=0.05))
    assert np.percentile(_static(out.residual[2]), 75) < 0.3
