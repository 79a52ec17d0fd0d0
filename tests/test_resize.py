"""`--max-side` (PipelineConfig.max_side, mosegpipe.pipeline.resize): frames are segmented shrunk and the masks come
back at the input's size with nothing but the labels found on the small grid."""

from __future__ import annotations

from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
import pytest

from mosegpipe.errors import ConfigError
from mosegpipe.io.read import read_palette_png
from mosegpipe.pipeline import PipelineConfig, segment_frames
from mosegpipe.pipeline.resize import dense_sized, shrink_factor, snap_labels, upscale_labels, upscale_mask, upscale_xy
from mosegpipe.types import Frames

from helpers import moseg, render_scene, write_avi


def test_shrink_factor_never_enlarges() -> None:
    assert shrink_factor((480, 854), 427) == pytest.approx(0.5)
    assert shrink_factor((1080, 1920), 480) == pytest.approx(0.25)
    assert shrink_factor((240, 320), 480) == 1.0
    assert shrink_factor((240, 320), None) == 1.0


def test_upscaled_labels_are_the_small_masks_labels_only() -> None:
    small = np.zeros((30, 40), np.uint8)
    small[5:15, 10:20] = 2
    small[20:, :5] = 255
    big = upscale_labels(small, (120, 160))
    assert big.shape == (120, 160)
    assert set(np.unique(big)) == {0, 2, 255}  # nearest neighbour: no blended value
    assert (big[20:60, 40:80] == 2).all() and (big[:20] == 0).all()
    np.testing.assert_allclose(
        upscale_xy(np.array([[0.0, 0.0], [39.0, 29.0]], np.float32), 0.25), [[1.5, 1.5], [157.5, 117.5]]
    )


def test_snapped_masks_follow_the_frames_edges() -> None:
    """The object's edge in the full-size frame (column 322) lies between two small pixels: nearest-neighbour
    upsampling puts the label's edge on the small grid (column 320), snapping moves it onto the frame's."""
    image = np.zeros((480, 640, 3), np.uint8)
    image[:, 322:] = 200
    image[100:140, 500:540] = 60  # texture inside the object: no label change there
    small = np.zeros((120, 160), np.uint8)
    small[:, 80:] = 3
    nearest = upscale_labels(small, (480, 640))
    snapped = snap_labels(small, image, 8)
    assert np.flatnonzero(nearest[240])[0] == 320
    assert np.flatnonzero(snapped[240])[0] == 322
    assert set(np.unique(snapped)) == {0, 3} and (snapped[:, 340:] == 3).all() and (snapped[:, :300] == 0).all()
    np.testing.assert_array_equal(upscale_mask(small, image), snap_labels(small, image, 8))  # radius 2 small px
    one = np.full((120, 160), 7, np.uint8)
    assert (snap_labels(one, image, 8) == 7).all()


def test_max_side_is_checked() -> None:
    with pytest.raises(ConfigError, match="max_side"):
        PipelineConfig().with_settings(["max_side=8"])


def test_a_clip_segmented_shrunk_is_written_at_its_size() -> None:
    scene = render_scene(5)
    frames = Frames(scene.frames)
    result = segment_frames(frames, replace(PipelineConfig(), max_side=160))
    assert result.masks.shape == (5, 240, 320)
    assert result.frames is frames and result.tracks.size_hw == (240, 320)
    assert "resize" in result.timings
    xy = result.tracks.xy[result.trajectories.track_ids]
    assert xy[..., 0].max() > 200 and xy[..., 0].max() < 320  # on the input's grid, not the 160-px one
    # the objects are found at half size too: most of each object's pixels carry one moving label
    for obj in (1, 2):
        inside = result.masks[0][scene.masks[0] == obj]
        values, counts = np.unique(inside, return_counts=True)
        assert values[counts.argmax()] not in (0, 255) and counts.max() > 0.6 * inside.size


def test_a_whole_video_with_max_side_writes_full_size_masks(tmp_path: Path) -> None:
    video = write_avi(tmp_path / "clip.avi", render_scene(9).frames)
    code, _, err = moseg("run", video, "--whole", "--max-side", "160", "-o", tmp_path / "out", "--no-rrd")
    assert code == 0, err
    masks = [read_palette_png(p) for p in sorted((tmp_path / "out" / "masks").glob("*.png"))]
    assert len(masks) == 9 and all(m.shape == (240, 320) for m in masks)
    assert any(((m > 0) & (m < 255)).any() for m in masks)  # something moves


def test_the_dense_stage_of_a_large_frame_runs_at_max_side_px() -> None:
    cfg = PipelineConfig()  # flow at 1.0, mask steps at 0.75, at most 1280 px
    hd = dense_sized(cfg, (1080, 1920))
    assert hd.mask.motion.flow.scale == pytest.approx(2 / 3) and hd.mask.motion.work_scale == pytest.approx(0.5)
    assert hd.mask.motion.flow.patch_stride == cfg.mask.motion.flow.patch_stride  # only the scales change
    assert dense_sized(cfg, (720, 1280)) is cfg and dense_sized(cfg, (480, 854)) is cfg
    off = cfg.with_settings(["mask.motion.max_side_px=null"])
    assert dense_sized(off, (2160, 3840)) is off
    old = asdict(cfg)
    del old["mask"]["motion"]["max_side_px"]  # a summary from before the limit replays without it
    assert PipelineConfig.from_dict(old) == off and PipelineConfig.from_dict(asdict(cfg)) == cfg
    with pytest.raises(ConfigError, match="max_side_px"):
        cfg.with_settings(["mask.motion.max_side_px=10"])


@pytest.mark.parametrize("whole", [False, True])
def test_clips_and_videos_compute_their_flow_at_max_side_px(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, whole: bool
) -> None:
    from mosegpipe.points import flow as flow_module

    scales: list[float] = []
    start = flow_module.FlowStream.__init__

    def recorded(self: flow_module.FlowStream, cfg: flow_module.FlowConfig = flow_module.FlowConfig()) -> None:
        scales.append(cfg.scale)
        start(self, cfg)

    monkeypatch.setattr(flow_module.FlowStream, "__init__", recorded)
    scene = render_scene(9)
    cfg = PipelineConfig().with_settings(["mask.motion.max_side_px=160"])  # 320x240 frames: flow at half size
    if whole:
        from mosegpipe.pipeline import segment_video

        video = write_avi(tmp_path / "clip.avi", scene.frames)
        masks = [fr.mask for w in segment_video(video, cfg) for fr in w.frames]
    else:
        masks = list(segment_frames(Frames(scene.frames[:5]), cfg).masks)
    assert scales and set(scales) == {0.5}
    assert all(m is not None and m.shape == (240, 320) for m in masks)
    for obj in (1, 2):  # the objects are still found, at the frame's size
        inside = masks[0][scene.masks[0] == obj]
        values, counts = np.unique(inside, return_counts=True)
        assert values[counts.argmax()] not in (0, 255) and counts.max() > 0.6 * inside.size
