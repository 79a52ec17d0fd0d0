"""Dense flow, camera residuals and motion masks (mosegpipe.points.flow, mosegpipe.masks.moving_pixels) on scenes the tests draw."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import cv2
import numpy as np
import pytest

from mosegpipe.masks import WORLD, label_moving_pixels
from mosegpipe.masks.moving_pixels import MotionMaskConfig, moving_masks
from mosegpipe.points.flow import FlowConfig, camera_residual, fit_camera, frame_motion


def _texture(h: int, w: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    noise = rng.uniform(0, 255, (h, w, 3)).astype(np.float32)
    return np.clip(cv2.GaussianBlur(noise, (0, 0), 2.0) * 3 - 255, 0, 255).astype(np.uint8)


def _scene(frames: int = 5, h: int = 144, w: int = 192) -> tuple[np.ndarray, np.ndarray]:
    """A textured background panning 1 px/frame right and a textured square moving 3 px/frame down-left."""
    bg = _texture(h + 40, w + 40, 0)
    obj = _texture(40, 40, 1)
    obj[..., 0] = 255 - obj[..., 0]  # a colour of its own
    images, gt = [], []
    for t in range(frames):
        im = bg[20 : 20 + h, 20 - t : 20 - t + w].copy()
        y, x = 40 + 3 * t, 100 - 3 * t
        im[y : y + 40, x : x + 40] = obj
        m = np.zeros((h, w), bool)
        m[y : y + 40, x : x + 40] = True
        images.append(im)
        gt.append(m)
    return np.stack(images), np.stack(gt)


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max((a | b).sum(), 1))


def _bare(**kw: float) -> MotionMaskConfig:
    """Motion-mask settings with every step but Otsu's threshold off, then `kw`."""
    base: dict[str, float] = dict(
        work_scale=1.0,
        colour_weight=0.0,
        fb_weight=0.0,
        temporal_weight=0.0,
        min_residual_px=0.0,
        noise_factor=0.0,
        min_component=0.0,
        spread_weight=0.0,
        guided_radius=0,
        local_colour_weight=0.0,
        smooth_lambda=0.0,
    )
    return MotionMaskConfig(**(base | kw))  # type: ignore[arg-type]


def test_camera_residual_of_a_pure_homography_is_zero() -> None:
    h, w = 60, 80
    hom = np.array([[1.01, 0.002, 2.0], [-0.003, 0.99, -1.5], [1e-5, 2e-5, 1.0]])
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    pts = np.stack([xs, ys], -1).reshape(1, -1, 2)
    flow = (cv2.perspectiveTransform(pts, hom).reshape(h, w, 2) - pts.reshape(h, w, 2)).astype(np.float32)
    fitted = fit_camera(flow, None, FlowConfig(grid_step_px=4))
    assert np.abs(camera_residual(flow, fitted)).max() < 0.05
    # a 2 px patch moving on its own shows as residual exactly there
    flow[10:20, 10:20, 0] += 2.0
    res = camera_residual(flow, fit_camera(flow, None, FlowConfig(grid_step_px=4)))
    assert res[12:18, 12:18].min() > 1.5
    assert np.median(res) < 0.05


def test_the_camera_fit_keeps_to_the_background_beside_a_large_slowly_moving_object() -> None:
    h, w = 120, 160
    hom = np.array([[1.01, 0.002, 3.0], [-0.001, 1.01, -1.5], [1e-5, 0.0, 1.0]])
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    pts = np.stack([xs, ys], -1).reshape(1, -1, 2)
    flow = (cv2.perspectiveTransform(pts, hom).reshape(h, w, 2) - pts.reshape(h, w, 2)).astype(np.float32)
    obj = np.zeros((h, w), bool)
    obj[20:100, 30:110] = True  # a third of the frame, 2.2 px against the camera
    flow[obj] += np.float32([2.0, 1.0])
    flow += np.random.default_rng(0).normal(0, 0.05, flow.shape).astype(np.float32)
    res = camera_residual(flow, fit_camera(flow, None, FlowConfig()))  # MAGSAC's fit: 0.77 px on the background
    assert np.median(res[~obj]) < 0.1 and np.median(res[obj]) > 2.0
    with pytest.raises(ValueError, match="camera_fit"):
        FlowConfig(camera_fit="lmeds")


def test_frame_motion_separate_the_moving_square() -> None:
    images, gt = _scene()
    motion = frame_motion(images, FlowConfig())
    res = motion.residual
    assert res.shape == gt.shape and motion.fb_error.shape == gt.shape
    inner = np.zeros_like(gt)
    for t in range(len(gt)):
        inner[t] = cv2.erode(gt[t].astype(np.uint8), np.ones((9, 9), np.uint8)) > 0
    assert np.median(res[inner]) > 2.0  # 3 px/frame against a 1 px/frame pan: about 4 px of residual
    assert np.median(res[~gt]) < 0.5


def test_both_directions_take_the_smaller_evidence_and_shrink_the_band_beside_the_mover() -> None:
    images, gt = _scene(frames=5)
    one = frame_motion(images, FlowConfig(both_directions=False))
    both = frame_motion(images, FlowConfig(both_directions=True))
    # The end frames have one flow each, the same either way; a middle frame takes the smaller residual.
    for t in (0, 4):
        np.testing.assert_array_equal(both.residual[t], one.residual[t])
    assert np.all(both.residual[1:4] <= one.residual[1:4]) and np.all(both.fb_error[1:4] <= one.fb_error[1:4])
    assert (both.residual[1:4] < one.residual[1:4]).any()
    # The flow to the next frame smears the square over a band beside it, the flow back does not there:
    # the band's residual drops, the square's own stays.
    band = np.zeros_like(gt[1:4])
    inner = np.zeros_like(gt[1:4])
    for i, m in enumerate(gt[1:4]):
        band[i] = (cv2.dilate(m.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0) & ~m
        inner[i] = cv2.erode(m.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0
    assert both.residual[1:4][band].mean() < 0.8 * one.residual[1:4][band].mean()
    assert np.median(both.residual[1:4][inner]) > 2.0


def test_frames_next_to_the_stack_give_its_end_frames_both_directions() -> None:
    from dataclasses import replace

    from mosegpipe.masks.moving_pixels import moving_from_motion
    from mosegpipe.points.flow import FrameMotion

    images, _ = _scene(frames=6)
    cfg = MotionMaskConfig()
    full = frame_motion(images, cfg.flow)
    inner = FrameMotion(full.residual[1:5], full.fb_error[1:5], full.scale, full.forward[1:4], full.backward[1:4])
    got = moving_masks(images[1:5], cfg, before=images[0], after=images[5])
    np.testing.assert_array_equal(got, moving_from_motion(images[1:5], inner, cfg))
    alone = frame_motion(images[1:5], cfg.flow)  # its end frames have one flow each
    for t in (0, 3):
        assert (inner.residual[t] <= alone.residual[t]).all() and (inner.residual[t] < alone.residual[t]).any()
    # Without both directions the neighbours take no part.
    one = replace(cfg, flow=replace(cfg.flow, both_directions=False))
    np.testing.assert_array_equal(
        moving_masks(images[1:5], one, before=images[0], after=images[5]), moving_masks(images[1:5], one)
    )


def test_frame_motion_at_half_scale_are_in_that_scale() -> None:
    images, _ = _scene(frames=2)
    motion = frame_motion(images, FlowConfig(scale=0.5))
    assert motion.residual.shape == (2, 72, 96) and motion.scale == 0.5
    with pytest.raises(ValueError, match="at least 2 frames"):
        frame_motion(images[:1])


def test_moving_masks_find_the_square_and_nothing_when_all_is_still() -> None:
    images, gt = _scene()
    cfg = MotionMaskConfig(superpixels=0, work_scale=1.0)  # SLIC cells cut through the noise texture drawn here
    masks = moving_masks(images, cfg)
    assert masks.shape == gt.shape and masks.dtype == bool
    assert np.mean([_iou(m, g) for m, g in zip(masks, gt)]) > 0.75
    still = np.repeat(images[:1], 4, axis=0)  # the camera and the square stand still: no residual anywhere
    assert not moving_masks(still, cfg).any()


def test_motion_mask_config_refuses_bad_values() -> None:
    with pytest.raises(ValueError, match="work_scale"):
        MotionMaskConfig(work_scale=0)
    with pytest.raises(ValueError, match="colour_bins"):
        MotionMaskConfig(colour_bins=1)
    with pytest.raises(ValueError, match="preset"):
        FlowConfig(preset="slow")


def test_label_moving_pixels_takes_the_nearest_moving_track() -> None:
    moving = np.zeros((10, 20), bool)
    moving[2:8, 1:6] = True
    moving[2:8, 14:19] = True
    xy = np.array([[3, 4], [16, 4], [10, 5], [18, 9]], np.float32)
    labels = np.array([1, 2, 0, 0])
    out = label_moving_pixels(moving, xy, labels, background=0, new_label=3)
    assert (out[~moving] == 0).all()
    assert (out[2:8, 1:6] == 1).all() and (out[2:8, 14:19] == 2).all()
    # no track of a moving motion: the moving pixels get the new label
    out = label_moving_pixels(moving, xy[2:], labels[2:], background=0, new_label=3)
    assert (out[moving] == 3).all() and (out[~moving] == 0).all()
    # one moving motion, however far its track: every moving pixel takes it
    out = label_moving_pixels(moving, xy[1:], labels[1:], background=0, new_label=3)
    assert (out[moving] == 2).all() and (out[~moving] == 0).all()


def test_segment_frames_with_motion_masks_marks_the_square_as_moving() -> None:
    from mosegpipe.masks import MaskConfig
    from mosegpipe.pipeline import PipelineConfig, segment_frames
    from mosegpipe.types import Frames

    images, gt = _scene()
    cfg = PipelineConfig(mask=MaskConfig(method="motion", motion=MotionMaskConfig(superpixels=0, work_scale=1.0)))
    result = segment_frames(Frames(images=images), cfg)
    moving = result.masks != WORLD
    assert result.masks.shape == gt.shape and not (result.masks == 255).any()
    assert np.mean([_iou(m, g) for m, g in zip(moving, gt)]) > 0.7


def test_video_frame_mask_uses_the_moving_pixels() -> None:
    from mosegpipe.masks import MOVING_UNCLUSTERED, MaskConfig
    from mosegpipe.pipeline import VideoFrame, frame_mask

    image = _texture(40, 60, 3)
    moving = np.zeros((40, 60), bool)
    moving[10:20, 30:45] = True
    xy = np.array([[5, 5], [50, 30], [10, 35], [36, 15]], np.float32)
    ids = np.arange(4)
    frame = VideoFrame(0, image, ids, xy, np.array([0, 0, 0, 3]), None, moving)
    mask = frame_mask(frame, MaskConfig(method="motion"))
    assert (mask[~moving] == 0).all() and (mask[moving] == 3).all()
    # only background tracks: the moving pixels are a motion of their own
    frame = VideoFrame(0, image, ids, xy, np.array([0, 0, 0, -1]), None, moving)
    assert (frame_mask(frame, MaskConfig(method="motion"))[moving] == MOVING_UNCLUSTERED).all()
    # another method ignores the moving pixels
    assert frame_mask(frame, MaskConfig(method="nearest"))[15, 40] == 0


def test_scores_carried_along_the_flow_fill_a_frame_whose_flow_missed_the_mover() -> None:
    from mosegpipe.masks.moving_pixels import moving_from_motion
    from mosegpipe.points.flow import FrameMotion

    num, h, w = 3, 40, 60
    images = np.stack([_texture(h, w, 5)] * num)
    residual = np.full((num, h, w), 0.05, np.float32)
    residual[0, 10:20, 10:20] = residual[2, 10:20, 30:40] = 5.0  # frame 1's flow missed the square
    residual[1, 30:35, 50:55] = 0.8  # and saw a speck of noise
    # the square moves 10 px right per frame: frame 0 -> 1 -> 2
    forward = np.zeros((num - 1, h, w, 2), np.float32)
    forward[..., 0] = 10.0
    backward = -forward
    fb_error = np.zeros_like(residual)
    motion = FrameMotion(residual, fb_error, 1.0, forward, backward)
    without = moving_from_motion(images, motion, _bare())
    carried = moving_from_motion(images, motion, _bare(temporal_weight=1.0))
    assert not without[1, 12:18, 22:28].any()
    assert carried[1, 12:18, 22:28].all()  # where the square is in frame 1
    assert carried[0, 12:18, 12:18].all() and carried[2, 12:18, 32:38].all()


def test_a_small_fast_mover_outweighs_a_large_slow_drift() -> None:
    from mosegpipe.masks.moving_pixels import moving_from_motion
    from mosegpipe.points.flow import FrameMotion

    num, h, w = 2, 60, 80
    images = np.stack([_texture(h, w, 9)] * num)
    residual = np.full((num, h, w), 0.05, np.float32)
    residual[:, 0:30, :] = 1.0  # a wide band drifting slowly (a stream behind the subject)
    residual[:, 40:50, 30:40] = 12.0  # a small object moving fast
    fb_error = np.zeros_like(residual)
    motion = FrameMotion(residual, fb_error, 1.0)
    by_area = moving_from_motion(images, motion, _bare(min_component=0.3, component_power=0.0))
    by_strength = moving_from_motion(images, motion, _bare(min_component=0.3))
    assert by_area[:, 5:25, 5:75].all() and not by_area[:, 42:48, 32:38].any()
    assert by_strength[:, 42:48, 32:38].all() and not by_strength[:, 5:25, 5:75].any()
    with pytest.raises(ValueError, match="component_power"):
        MotionMaskConfig(component_power=-1.0)


def test_a_weak_region_survives_when_the_tracks_say_it_is_a_motion_of_its_own() -> None:
    from mosegpipe.masks.moving_pixels import moving_from_motion
    from mosegpipe.points.flow import FrameMotion

    num, h, w = 2, 60, 80
    images = np.stack([_texture(h, w, 9)] * num)
    residual = np.full((num, h, w), 0.05, np.float32)
    residual[:, 5:25, 5:25] = 12.0  # a fast object
    residual[:, 35:55, 50:70] = 2.0  # a slow one: 36x weaker, dropped by strength alone
    motion = FrameMotion(residual, np.zeros_like(residual), 1.0)
    cfg = _bare(min_component=0.3, anchor_tracks=3)
    grid = np.stack(np.meshgrid(np.arange(8.0, 24, 4), np.arange(8.0, 24, 4)), -1).reshape(-1, 2)  # 16 points
    fast, slow = grid.astype(np.float32), (grid + [45, 30]).astype(np.float32)

    def held(slow_labels: list[int], fast_label: int = 1, shown_before: tuple[int, ...] = (1, 2)) -> bool:
        """Whether the slow region is moving with these labels on its points (background 0)."""
        xy = np.concatenate([fast, slow[: len(slow_labels)]])
        labels = np.array([fast_label] * len(fast) + slow_labels, np.int64)
        anchors = [(xy, labels, 0, np.array(shown_before, np.int64))] * num
        masks = moving_from_motion(images, motion, cfg, anchors=anchors)
        assert masks[:, 10:20, 10:20].all()
        return bool(masks[:, 40:50, 55:65].all())

    assert not held([])  # no points: strength decides
    assert held([2] * 3)  # a motion no kept region shows, shown in the frame before
    assert not held([2] * 3, shown_before=(1,))  # one the frame before did not show: a new mover must be strong
    assert not held([2] * 2)  # too few of its points
    assert not held([1] * 16)  # the fast region's motion: it shows already
    assert not held([0] * 16)  # the background's
    assert not held([2] * 3 + [0] * 4)  # more background points than the motion's
    assert held([2] * 16, fast_label=0)  # the fast region taken for the background: the slow one stays
    unanchored = moving_from_motion(images, motion, cfg)
    assert not unanchored[:, 40:50, 55:65].any()
    with pytest.raises(ValueError, match="anchor_tracks"):
        MotionMaskConfig(anchor_tracks=-1)


def test_flow_that_varies_from_pixel_to_pixel_is_weak_evidence_of_motion() -> None:
    from mosegpipe.masks.moving_pixels import moving_from_motion
    from mosegpipe.points.flow import FrameMotion

    num, h, w = 2, 60, 90
    rng = np.random.default_rng(3)
    images = np.stack([_texture(h, w, 4)] * num)
    residual = np.full((num, h, w), 0.05, np.float32)
    forward = np.zeros((num - 1, h, w, 2), np.float32)
    residual[:, 15:45, 10:40] = 3.0  # an object: every pixel moves 3 px right
    forward[:, 15:45, 10:40, 0] = 3.0
    residual[:, 15:45, 50:80] = 3.0  # water: 3 px too, each pixel its own way
    angle = rng.uniform(0, 2 * np.pi, (num - 1, 30, 30)).astype(np.float32)
    forward[:, 15:45, 50:80] = 3.0 * np.stack([np.cos(angle), np.sin(angle)], axis=-1)
    motion = FrameMotion(residual, np.zeros_like(residual), 1.0, forward, -forward)
    plain = moving_from_motion(images, motion, _bare())
    spread = moving_from_motion(images, motion, _bare(spread_weight=1.0))
    assert plain[:, 20:40, 15:35].all() and plain[:, 20:40, 55:75].all()
    assert spread[:, 20:40, 15:35].all() and spread[:, 20:40, 55:75].mean() < 0.1
    with pytest.raises(ValueError, match="spread_weight"):
        MotionMaskConfig(spread_weight=-1.0)


def _object_with_spill(colour: tuple[int, int, int]) -> Iterator[tuple[np.ndarray, np.ndarray, Any]]:
    """An object of one colour on a plain dark background (2 frames, 60x80), its true mask, and per case the
    frames' evidence: the flow's edge blurred across the object's border, and 3 px beyond two of them."""
    from mosegpipe.points.flow import FrameMotion

    num, h, w = 2, 60, 80
    images = np.full((num, h, w, 3), 40, np.uint8)
    images[:, 20:40, 20:50] = colour
    truth = np.zeros((h, w), bool)
    truth[20:40, 20:50] = True
    for spill_px in (0, 3):
        moving = np.zeros((h, w), np.float32)
        moving[20 : 40 + spill_px, 20 : 50 + spill_px] = 1.0
        residual = np.stack([0.1 + 3.0 * cv2.GaussianBlur(moving, (0, 0), 3.0)] * num)
        yield images, truth, FrameMotion(residual, np.zeros_like(residual), 1.0)


def test_the_guided_filter_moves_the_masks_edge_onto_the_images() -> None:
    from mosegpipe.masks.moving_pixels import moving_from_motion

    for images, truth, motion in _object_with_spill((200, 200, 200)):
        plain = moving_from_motion(images, motion, _bare())
        guided = moving_from_motion(images, motion, _bare(guided_radius=4))
        assert _iou(guided[0], truth) > _iou(plain[0], truth) + 0.09
    with pytest.raises(ValueError, match="guided_eps"):
        MotionMaskConfig(guided_eps=0.0)


def test_the_global_smoother_spreads_the_score_within_the_objects_colour() -> None:
    from mosegpipe.masks.moving_pixels import moving_from_motion

    for images, truth, motion in _object_with_spill((200, 120, 60)):
        plain = moving_from_motion(images, motion, _bare())
        smoothed = moving_from_motion(images, motion, _bare(smooth_lambda=16.0))
        assert _iou(smoothed[0], truth) > _iou(plain[0], truth) + 0.1  # measured: 0.77 -> 1.0, 0.62 -> 0.81
    with pytest.raises(ValueError, match="smooth_sigma"):
        MotionMaskConfig(smooth_sigma=0.0)


def test_the_colour_memory_keeps_what_moved_in_the_windows_before() -> None:
    from mosegpipe.masks.moving_pixels import ColourMemory, colour_log_ratio

    image = np.full((200, 200, 3), 128, np.uint8)  # (a frame's counts outweigh the histograms' prior)
    image[60:140, 60:140] = (220, 30, 30)  # a red object on grey
    red = np.zeros((200, 200), bool)
    red[60:140, 60:140] = True
    moved = np.where(red, 2.0, -2.0).astype(np.float32)  # window 1: the object moved
    still = np.full((200, 200), -2.0, np.float32)  # window 2: nothing moved
    cfg = MotionMaskConfig()
    memory = ColourMemory(0.9)
    assert colour_log_ratio([image], [moved], cfg, memory)[0][red].min() > 0
    assert colour_log_ratio([image], [still], cfg)[0][red].max() < 0  # window 2 alone: red is static
    assert colour_log_ratio([image], [still], cfg, memory)[0][red].min() > 0  # remembered
    memory.reset()
    assert colour_log_ratio([image], [still], cfg, memory)[0][red].max() < 0
    with pytest.raises(ValueError, match="decay"):
        ColourMemory(1.0)
    with pytest.raises(ValueError, match="colour_memory"):
        MotionMaskConfig(colour_memory=-0.1)


def test_the_local_colour_contrast_cuts_a_spill_that_the_clips_colour_model_cannot() -> None:
    from mosegpipe.masks.moving_pixels import local_colour_contrast, moving_from_motion
    from mosegpipe.points.flow import FrameMotion

    num, h, w = 2, 120, 240
    images = np.empty((num, h, w, 3), np.uint8)
    images[:, :, :120] = (60, 60, 60)  # left: a bright object on dark ground
    images[:, 40:80, 30:70] = (200, 200, 200)
    images[:, :, 120:] = (200, 200, 200)  # right: a dark object on bright ground
    images[:, 40:80, 150:190] = (60, 60, 60)
    truth = np.zeros((h, w), bool)
    truth[40:80, 30:70] = truth[40:80, 150:190] = True
    moving = np.zeros((h, w), np.float32)  # the flow's residual spills 8 px below both objects
    moving[40:88, 30:70] = moving[40:88, 150:190] = 1.0
    noise = np.random.default_rng(0).uniform(0.0, 1.5, (num, h, w)).astype(np.float32)
    residual = 6.0 * moving + noise
    motion = FrameMotion(residual, np.zeros_like(residual), 1.0)
    # both colours move and stand still alike: the clip's colour model is no help
    alone = moving_from_motion(images, motion, _bare(colour_weight=0.5))
    local = moving_from_motion(images, motion, _bare(colour_weight=0.5, local_colour_weight=1.5))
    assert _iou(alone[0], truth) < 0.85
    assert _iou(local[0], truth) > 0.95
    score = np.where(moving > 0, 1.0, -1.0).astype(np.float32)
    contrast = local_colour_contrast(images[0], score, 0.5, 61)
    assert contrast[84, 50] < -0.5 and contrast[84, 170] < -0.5  # the spills
    assert contrast[70, 50] > 0.5 and contrast[70, 170] > 0.5  # the objects
    assert contrast[10, 10] == 0  # a box that holds one class only
    assert local_colour_contrast(images[0], score, 0.5, 31)[60, 50] == 0
    assert (local_colour_contrast(images[0], np.full((h, w), -1.0, np.float32), 0.5, 31) == 0).all()  # no movers
    with pytest.raises(ValueError, match="local_colour_box_px"):
        MotionMaskConfig(local_colour_box_px=1)


def test_frames_too_small_for_dense_flow_fall_back_to_the_watershed() -> None:
    from dataclasses import replace

    from mosegpipe.masks import labels_to_masks
    from mosegpipe.pipeline import PipelineConfig
    from mosegpipe.pipeline.clip import clip_masks
    from mosegpipe.points.flow import flow_fits
    from mosegpipe.types import Tracks

    images = np.stack([_texture(10, 40, 7)] * 3)  # 10 px high: OpenCV's DIS refuses it
    xy = np.array([[[5, 5]] * 3, [[30, 5]] * 3], np.float32)
    tracks = Tracks(xy=xy, visible=np.ones((2, 3), bool), size_hw=(10, 40))
    ids, labels = np.arange(2), np.array([0, 1])
    cfg = PipelineConfig()
    assert cfg.mask.method == "motion" and not flow_fits((10, 40), cfg.mask.motion.flow)
    masks = clip_masks(images, tracks, ids, labels, cfg)
    watershed = replace(cfg.mask, method="watershed", extra_tracks=0)
    assert np.array_equal(masks, labels_to_masks(tracks, ids, labels, watershed, images))


def test_flow_stream_gives_what_frame_motion_gives_and_keeps_to_its_pairs() -> None:
    from mosegpipe.points.flow import FlowStream

    images, _ = _scene(frames=6, h=96, w=160)
    whole = frame_motion(images[1:5], FlowConfig())
    with FlowStream(FlowConfig()) as stream:
        for t, im in enumerate(images):
            stream.add(10 + t, im, new_shot=t == 3)  # a cut before frame 13
        with pytest.raises(ValueError, match="from frame 12 to frame 13"):
            stream.motion([11, 12, 13])
        part = stream.motion([10, 11, 12])
        np.testing.assert_array_equal(part.forward, frame_motion(images[:3], FlowConfig()).forward)
        stream.forget(12)
        with pytest.raises(ValueError, match="from frame 11"):
            stream.motion([11, 12])
        assert stream.motion([13, 14, 15]).residual.shape == (3, 96, 160)
    with FlowStream(FlowConfig(workers=1)) as stream:
        for t in range(1, 5):
            stream.add(t, images[t])
        got = stream.motion(range(1, 5))
    for name in ("residual", "fb_error", "forward", "backward"):
        np.testing.assert_array_equal(getattr(got, name), getattr(whole, name))
    # `after` (`before`): the last (first) frame also takes its flow to the frame after (before) it, as it would
    # inside a longer stack
    with FlowStream(FlowConfig()) as stream:
        for t in range(1, 5):
            stream.add(t, images[t])
        late, early = stream.motion([1, 2, 3], after=4), stream.motion([2, 3, 4], before=1)
        with pytest.raises(ValueError, match="from frame 4 to frame 5"):
            stream.motion([3, 4], after=5)
        with pytest.raises(ValueError, match="from frame 0 to frame 1"):
            stream.motion([1, 2], before=0)
    for name in ("residual", "fb_error", "forward"):
        np.testing.assert_array_equal(getattr(late, name), getattr(whole, name)[: len(getattr(late, name))])
        np.testing.assert_array_equal(getattr(early, name), getattr(whole, name)[1:])
    assert not np.array_equal(early.residual[0], frame_motion(images[2:5], FlowConfig()).residual[0])
    # a stream that dropped frames: the flow runs from the frame before to the next one added
    with FlowStream(FlowConfig()) as stream:
        stream.add(0, images[0])
        stream.add(2, images[2])
        np.testing.assert_array_equal(stream.motion([0, 2]).forward, frame_motion(images[[0, 2]]).forward)
        with pytest.raises(ValueError, match="increasing"):
            stream.add(1, images[1])


def test_masks_of_the_later_frames_only_are_those_of_the_whole_stack() -> None:
    from mosegpipe.masks.moving_pixels import moving_from_motion

    images, _ = _scene()
    motion = frame_motion(images, FlowConfig())
    cfg = MotionMaskConfig(superpixels=100)
    all_frames = moving_from_motion(images, motion, cfg)
    later = moving_from_motion(images, motion, cfg, first=1)
    assert later.shape == (4, *images.shape[1:3])
    np.testing.assert_array_equal(later, all_frames[1:])
    with pytest.raises(ValueError, match="first=5"):
        moving_from_motion(images, motion, cfg, first=5)


def test_moving_pixels_of_one_moving_motion_all_take_its_label_and_two_split_along_the_image() -> None:
    from mosegpipe.masks import moving_to_labels

    h, w = 60, 80
    image = np.zeros((h, w, 3), np.uint8)
    image[:, 40:] = 200  # an edge at x = 40
    moving = np.zeros((h, w), bool)
    moving[10:50, 20:60] = True
    bg = np.array([[2.0, 2.0], [77.0, 57.0], [2.0, 57.0]], np.float32)
    one = np.concatenate([bg, np.array([[25.0, 30.0]], np.float32)])
    out = moving_to_labels(moving, one, np.array([0, 0, 0, 3]), image=image)
    assert (out[moving] == 3).all() and (out[~moving] == 0).all()
    # two moving motions, their tracks both left of the edge: the flood's border follows the edge,
    # where the nearest-track border would run halfway between the tracks (x = 32)
    two = np.concatenate([bg, np.array([[22.0, 30.0], [42.0, 30.0]], np.float32)])
    out = moving_to_labels(moving, two, np.array([0, 0, 0, 3, 5]), image=image)
    assert (out[10:50, 20:40] == 3).mean() >= 0.85 and (out[10:50, 40:60] == 5).mean() >= 0.85


def test_dense_flow_takes_the_patch_stride_and_refinement_given() -> None:
    from mosegpipe.points.flow import DenseFlow

    dis = DenseFlow(FlowConfig(patch_stride=4, refinement_iterations=3))._dis
    assert (dis.getPatchStride(), dis.getVariationalRefinementIterations()) == (4, 3)
    preset = DenseFlow(FlowConfig())._dis  # None: the preset's own (medium: 3 and 5)
    assert (preset.getPatchStride(), preset.getVariationalRefinementIterations()) == (3, 5)
    assert MotionMaskConfig().flow.patch_stride == 4
    for bad in ({"patch_stride": 9}, {"patch_stride": 0}, {"refinement_iterations": -1}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            FlowConfig(**bad)  # type: ignore[arg-type]
