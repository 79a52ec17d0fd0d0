"""Point trajectories from dense flow (mosegpipe.points.flow_grid): following a motion, the forward-backward
and border checks, the grid's budget and texture rule, joining KLT tracks, and the pipeline / CLI option."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest

from mosegpipe.errors import InputError
from mosegpipe.pipeline import PipelineConfig
from mosegpipe.points.flow_grid import FlowTrackConfig, combine_tracks, grid_seeds, track_flow
from mosegpipe.types import Tracks

from helpers import TEXTURE_H as H
from helpers import TEXTURE_W as W
from helpers import gray_to_rgb as _rgb
from helpers import moseg
from helpers import shifted_view as _view
from helpers import smooth_texture as _texture

ROOT = Path(__file__).resolve().parents[1]


def _translating(step: tuple[float, float], num: int = 4) -> npt.NDArray[np.uint8]:
    base = _texture(0)
    return np.stack([_rgb(_view(base, step[0] * t, step[1] * t)) for t in range(num)])


def test_grid_points_follow_a_translation() -> None:
    images = _translating((2.0, -1.0))
    tracks = track_flow(images, FlowTrackConfig(max_points=600))
    assert tracks.xy.shape[1:] == (4, 2) and tracks.size_hw == (H, W)
    assert 400 <= tracks.num_tracks <= 800  # about max_points seeds
    full = tracks.visible.all(axis=1)
    assert full.mean() > 0.8
    steps = np.diff(tracks.xy[full], axis=1)
    # DIS is not sub-pixel exact on a smooth texture; every point's step is within a quarter pixel
    assert np.median(np.abs(steps - np.array([2.0, -1.0]))) < 0.1
    assert np.abs(steps - np.array([2.0, -1.0])).max() < 0.5


def test_points_under_a_replaced_patch_are_dropped_and_lost_for_good() -> None:
    base = _texture(0)
    frames = [_view(base, 3.0 * t, 0.0) for t in range(3)]
    rows, cols = slice(40, 120), slice(80, 160)
    frames[1][rows, cols] = np.random.default_rng(5).integers(0, 256, (80, 80), dtype=np.uint8)
    tracks = track_flow(np.stack([_rgb(f) for f in frames]), FlowTrackConfig(max_points=1500))
    x0, y0 = tracks.xy[:, 0, 0], tracks.xy[:, 0, 1]
    inside = (x0 > cols.start + 10) & (x0 < cols.stop - 10) & (y0 > rows.start + 10) & (y0 < rows.stop - 10)
    far = (np.abs(x0 - 120) > 70) | (np.abs(y0 - 80) > 60)
    far &= (x0 > 12) & (x0 < W - 20)
    assert inside.sum() >= 30 and far.sum() >= 30
    # DIS fills the flow into the noise in smoothly from around it, both ways alike, so the
    # forward-backward check alone keeps a third of these points; the brightness check drops them.
    assert tracks.visible[inside, 1].mean() < 0.25
    unchecked = track_flow(np.stack([_rgb(f) for f in frames]), FlowTrackConfig(max_points=1500, max_brightness=0))
    assert unchecked.visible[inside, 1].mean() > 0.25
    assert tracks.visible[far, 1].mean() > 0.85
    assert not (~tracks.visible[:, :-1] & tracks.visible[:, 1:]).any()  # once lost, never visible again
    assert np.isnan(tracks.xy[~tracks.visible]).all()


def test_points_leaving_the_image_are_lost() -> None:
    cfg = FlowTrackConfig(max_points=500, border_px=4.0)
    tracks = track_flow(_translating((8.0, 0.0), num=4), cfg)
    x0 = tracks.xy[:, 0, 0]
    for t in range(1, 4):
        out = x0 + 8.0 * t > W - 1 - cfg.border_px + 1
        assert tracks.visible[out, t].sum() == 0
    assert tracks.visible[x0 + 24 < W - 12, 3].mean() > 0.8


def test_grid_budget_and_flat_areas() -> None:
    image = _rgb(_view(_texture(1), 0, 0))
    image[:, : W // 2] = 128  # the left half flat
    every = grid_seeds(image, FlowTrackConfig(max_points=400))
    assert 300 <= len(every) <= 500
    assert (every[:, 0] < W // 2).mean() == pytest.approx(0.5, abs=0.1)
    textured = grid_seeds(image, FlowTrackConfig(max_points=400, min_texture=0.1))
    assert (textured[:, 0] < W // 2 - 8).sum() == 0  # no seeds where the image is flat
    assert (textured[:, 0] > W // 2 + 8).sum() == (every[:, 0] > W // 2 + 8).sum()


def test_combine_keeps_klt_rows_first_and_drops_flow_points_near_corners() -> None:
    def tracks(points: list[tuple[float, float]]) -> Tracks:
        xy = np.array(points, np.float32)[:, None, :].repeat(2, axis=1)
        return Tracks(xy=xy, visible=np.ones((len(points), 2), bool), size_hw=(100, 100))

    klt = tracks([(10, 10), (50, 50)])
    flow = tracks([(11, 10), (30, 30), (50, 53), (80, 80)])
    both = combine_tracks(klt, flow, distance_px=4.0)
    assert both.xy[:, 0].tolist() == [[10, 10], [50, 50], [30, 30], [80, 80]]
    assert combine_tracks(klt, flow, distance_px=0.0).num_tracks == 6


def test_pipeline_config_checks_the_tracker() -> None:
    assert PipelineConfig().tracker == "klt"
    with pytest.raises(InputError, match="tracker"):
        PipelineConfig(tracker="sift")
    with pytest.raises(ValueError, match="max_points"):
        FlowTrackConfig(max_points=0)


def test_run_with_flow_points_segments_the_rendered_sample(tmp_path: Path) -> None:
    out = tmp_path / "flow"
    clip = ROOT / "samples" / "rendered" / "frames"
    code, _, stderr = moseg("run", clip, "--frames", "5", "--points", "flow", "--no-rrd", "-o", out)
    assert code == 0, stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["config"]["tracker"] == "flow"
    assert summary["k"] >= 2
    assert PipelineConfig.from_dict(summary["config"]).tracker == "flow"
    labels = np.load(out / "labels.npz")
    assert len(labels[next(iter(labels.files))]) >= 500  # a grid, not a few hundred corners


def test_flow_points_are_refused_for_whole_videos(tmp_path: Path) -> None:
    code, _, stderr = moseg(
        "run", ROOT / "samples" / "vtest_8f.avi", "--whole", "--points", "flow", "-o", tmp_path / "o"
    )
    assert code == 1
    assert "--points flow: clips only" in stderr and "Traceback" not in stderr
    assert not (tmp_path / "o").exists()


def test_eval_requests_take_the_points() -> None:
    from mosegpipe.evaluation.protocols import EvalRequest, pipeline_config

    assert pipeline_config(EvalRequest(out_dir=Path("x")), 5).tracker == "klt"
    assert pipeline_config(EvalRequest(out_dir=Path("x"), points="klt+flow"), 5).tracker == "klt+flow"
    with pytest.raises(InputError, match="^tracker: 'sift' must be one of klt, flow, klt\\+flow$"):
        pipeline_config(EvalRequest(out_dir=Path("x"), points="sift"), 5)
    changed = pipeline_config(EvalRequest(out_dir=Path("x"), settings=("mask.motion.fb_weight=0.5",)), 5)
    assert changed.mask.motion.fb_weight == 0.5 and changed.frames == 5


def test_a_bad_eval_setting_is_one_error_line(tmp_path: Path) -> None:
    code, _, stderr = moseg("eval", "rendered", "--out", tmp_path / "o", "--set", "mask.motion.fb_weight=high")
    assert code == 1
    assert stderr.strip() == "moseg: error: --set mask.motion.fb_weight: expected a number, got 'high'"
    assert not (tmp_path / "o").exists()


def test_klt_plus_flow_holds_the_corners_and_more() -> None:
    from mosegpipe.io.read import read_video
    from mosegpipe.pipeline import segment_frames
    from mosegpipe.pipeline.clip import clip_tracks

    frames = read_video(ROOT / "samples" / "rendered" / "frames", max_frames=3)
    klt = clip_tracks(frames, PipelineConfig(frames=3))
    both = clip_tracks(frames, PipelineConfig(frames=3, tracker="klt+flow"))
    assert both.num_tracks > klt.num_tracks
    np.testing.assert_array_equal(both.xy[: klt.num_tracks], klt.xy)  # the corners first, unchanged
    result = segment_frames(frames, PipelineConfig(frames=3, tracker="klt+flow"))
    assert result.tracks.num_tracks == both.num_tracks


def test_flow_points_and_motion_masks_share_one_computation_of_the_flows(monkeypatch: pytest.MonkeyPatch) -> None:
    import mosegpipe.masks.moving_pixels as motion_module
    import mosegpipe.points.flow_grid as flow_tracks_module
    from mosegpipe.io.read import read_video
    from mosegpipe.pipeline import segment_frames

    calls: list[int] = []

    def counted(original):  # type: ignore[no-untyped-def]
        def wrapper(images, cfg):  # type: ignore[no-untyped-def]
            calls.append(len(images))
            return original(images, cfg)

        return wrapper

    monkeypatch.setattr(motion_module, "frame_motion", counted(motion_module.frame_motion))
    monkeypatch.setattr(flow_tracks_module, "frame_motion", counted(flow_tracks_module.frame_motion))
    frames = read_video(ROOT / "samples" / "rendered" / "frames", max_frames=4)
    result = segment_frames(frames, PipelineConfig(frames=4, tracker="flow"))
    assert calls == [4]  # one stack of flows for the points and the masks
    assert result.masks.shape[0] == 4 and result.tracks.num_tracks >= 500
