"""--mask-method on the command line, and the methods against each other on a rendered clip."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from mosegpipe.cli.main import app
from mosegpipe.evaluation.metrics import mask_scores
from mosegpipe.masks import UNKNOWN, MaskConfig, labels_to_masks
from mosegpipe.pipeline import PipelineConfig, clip_masks
from mosegpipe.points.klt import track_klt
from mosegpipe.points.trajectories import build_trajectories
from mosegpipe.types import Tracks

from helpers import render_scene, write_frames

runner = CliRunner(env={"COLUMNS": "200"})


def test_bad_mask_method_is_one_error_line(tmp_path: Path) -> None:
    clip = write_frames(tmp_path / "clip", render_scene(5).frames)
    result = runner.invoke(app, ["run", str(clip), "--mask-method", "grabcut", "--out", str(tmp_path / "o")])
    assert result.exit_code == 2  # a usage error: --mask-method is a choice (an Enum)
    assert "--mask-method grabcut: 'grabcut' is not one of 'motion', 'watershed', 'nearest', 'vote'" in result.output
    assert not (tmp_path / "o").exists()


def test_watershed_beats_nearest_on_boundaries_with_true_labels() -> None:
    scene = render_scene(5)
    tracks = track_klt(scene.to_frames())
    traj = build_trajectories(tracks)
    gt = scene.label_at(0, tracks.xy[traj.track_ids, 0])
    scores = {}
    for method in ("nearest", "watershed"):
        masks = labels_to_masks(tracks, traj.track_ids, gt, MaskConfig(method=method), scene.frames)
        assert set(np.unique(masks)) <= {0, 1, 2, UNKNOWN}
        scores[method] = mask_scores(masks, scene.masks, background=0, unknown=UNKNOWN)
    assert scores["watershed"].f > scores["nearest"].f + 0.05, {m: s.f for m, s in scores.items()}
    assert scores["watershed"].j >= scores["nearest"].j - 0.01


@pytest.mark.parametrize("method", ["nearest", "vote", "watershed"])
def test_every_method_writes_masks_from_the_cli(tmp_path: Path, method: str) -> None:
    clip = write_frames(tmp_path / "clip", render_scene(5).frames)
    out = tmp_path / method
    result = runner.invoke(app, ["run", str(clip), "--mask-method", method, "--out", str(out), "--no-rrd"])
    assert result.exit_code == 0, result.output
    assert '"method": "' + method + '"' in (out / "summary.json").read_text()


def test_watershed_with_one_label_fills_everything_near_a_track() -> None:
    import cv2

    from mosegpipe.masks import labels_to_mask

    rng = np.random.default_rng(1)
    image = cv2.GaussianBlur(rng.integers(0, 255, (120, 160, 3), dtype=np.uint8), (5, 5), 0)
    xy = rng.uniform((0, 0), (159, 119), size=(40, 2)).astype(np.float32)
    xy[:, 0] *= 0.5  # the right half of the image is far from every track
    mask = labels_to_mask(xy, np.full(40, 3), (120, 160), MaskConfig(method="watershed"), image)
    seeds = np.full((120, 160), 255, np.uint8)
    seeds[np.round(xy[:, 1]).astype(int), np.round(xy[:, 0]).astype(int)] = 0
    near = cv2.distanceTransform(seeds, cv2.DIST_L2, 5) <= 40
    assert np.array_equal(mask, np.where(near, 3, UNKNOWN)) and not near.all()


def test_extra_tracks_fill_in_an_object_with_few_tracks() -> None:
    scene = render_scene(5)
    tracks = track_klt(scene.to_frames())
    traj = build_trajectories(tracks)
    gt = scene.label_at(0, tracks.xy[traj.track_ids, 0])
    on_one = np.flatnonzero(gt == 1)
    keep = np.sort(np.r_[np.flatnonzero(gt != 1), on_one[:: max(1, len(on_one) // 12)][:12]])
    rows = traj.track_ids[keep]  # object 1 left with 12 tracks, as a weakly textured one would be
    few = Tracks(tracks.xy[rows], tracks.visible[rows], tracks.size_hw)
    ids, labels = np.arange(len(rows)), gt[keep]
    off = PipelineConfig(mask=MaskConfig(method="watershed", extra_tracks=0))
    without = clip_masks(scene.frames, few, ids, labels, off)
    assert np.array_equal(without, labels_to_masks(few, ids, labels, off.mask, scene.frames))
    with_extra = clip_masks(scene.frames, few, ids, labels, PipelineConfig(mask=MaskConfig(method="watershed")))
    assert set(np.unique(with_extra)) <= {0, 1, 2, UNKNOWN}
    j = {}
    for name, masks in (("without", without), ("with", with_extra)):
        hit = (masks == 1) & (scene.masks == 1)
        j[name] = hit.sum() / ((masks == 1) | (scene.masks == 1)).sum()
    assert j["with"] > j["without"] + 0.05, j
    scores = mask_scores(with_extra, scene.masks, background=0, unknown=UNKNOWN)
    assert scores.j >= mask_scores(without, scene.masks, background=0, unknown=UNKNOWN).j
    with pytest.raises(ValueError, match="^extra_tracks: -1 must be >= 0"):
        MaskConfig(extra_tracks=-1)


def test_a_summary_without_extra_tracks_replays_without_them() -> None:
    from dataclasses import asdict

    recorded = asdict(PipelineConfig())
    assert PipelineConfig.from_dict(recorded).mask.extra_tracks == 1000
    del recorded["mask"]["extra_tracks"]  # written before the extra mask tracks existed
    assert PipelineConfig.from_dict(recorded).mask.extra_tracks == 0
    assert PipelineConfig.from_dict(recorded).mask.unexplained_px == MaskConfig().unexplained_px > 0
    del recorded["mask"]["unexplained_px"]  # written before the unexplained regions got their own label
    assert PipelineConfig.from_dict(recorded).mask.unexplained_px == 0


def test_a_summary_from_before_the_spread_and_guided_filter_replays_without_them() -> None:
    from dataclasses import asdict

    recorded = asdict(PipelineConfig())
    assert PipelineConfig.from_dict(recorded) == PipelineConfig()
    del recorded["mask"]["motion"]["flow"]["camera_fit"]  # written before the camera's fit by RANSAC
    assert PipelineConfig.from_dict(recorded).mask.motion.flow.camera_fit == "magsac"
    del recorded["mask"]["motion"]["local_colour_weight"]  # written before the local colour contrast
    assert PipelineConfig.from_dict(recorded).mask.motion.local_colour_weight == 0
    assert PipelineConfig.from_dict(recorded).mask.motion.anchor_tracks == 3
    del recorded["mask"]["motion"]["anchor_tracks"]  # written before the regions kept by tracks
    assert PipelineConfig.from_dict(recorded).mask.motion.anchor_tracks == 0
    assert PipelineConfig.from_dict(recorded).mask.motion.spread_weight == 0.5
    for name in ("spread_weight", "guided_radius", "guided_eps", "colour_memory"):
        del recorded["mask"]["motion"][name]  # written before these steps existed
    recorded["mask"]["motion"]["colour_bins"] = 16
    motion = PipelineConfig.from_dict(recorded).mask.motion
    assert (motion.spread_weight, motion.guided_radius, motion.colour_memory, motion.colour_bins) == (0, 0, 0, 16)
    assert motion.anchor_tracks == 0


def test_settings_by_dotted_path_change_only_those_fields() -> None:
    cfg = PipelineConfig().with_settings(
        [
            "mask.motion.fb_weight=0.5",
            "mask.motion.flow.camera_fit=magsac",
            "mask.motion.flow.patch_stride=null",
            "frames=7",
        ]
    )
    motion = cfg.mask.motion
    assert (motion.fb_weight, motion.flow.camera_fit, motion.flow.patch_stride, cfg.frames) == (0.5, "magsac", None, 7)
    assert isinstance(motion.fb_weight, float)
    back = cfg.with_settings(["mask.motion.fb_weight=0.75", "mask.motion.flow.camera_fit=ransac"])
    back = back.with_settings(["mask.motion.flow.patch_stride=4", "frames=5"])
    assert back == PipelineConfig()
    assert PipelineConfig().with_settings([]) == PipelineConfig()


@pytest.mark.parametrize(
    ("setting", "message"),
    [
        ("mask.motion.fb_weight=high", "--set mask.motion.fb_weight: expected a number, got 'high'"),
        ("mask.motion.fb_weight=-1", "--set mask.motion.fb_weight: -1.0 must be >= 0"),
        ("mask.motion.nope=1", "--set mask.motion.nope: unknown setting"),
        ("mask.method.x=1", "--set mask.method: not a group of settings"),
        ("fb_weight", "expected dotted.field=value"),
        ("mask..fb_weight=1", "expected dotted.field=value"),
    ],
)
def test_a_bad_setting_is_named(setting: str, message: str) -> None:
    import re

    from mosegpipe.errors import InputError

    with pytest.raises(InputError, match=re.escape(message)):
        PipelineConfig().with_settings([setting])
