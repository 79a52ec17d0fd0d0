"""The per-motion network (mosegpipe.masks.learned.which): its query channels, the choice it makes among a frame's moving
motions, its shipped weights, its recipe (seeded, learns) and the pipeline's use of it (`MaskConfig.which`)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from mosegpipe.errors import CheckpointError, ConfigError
from mosegpipe.masks import UNKNOWN, WORLD, MaskConfig, motion_masks
from mosegpipe.masks.learned import which as which_mod
from mosegpipe.masks.learned.features import NUM_CHANNELS
from mosegpipe.masks.learned.net import MaskNet, load_masknet, shipped_path
from mosegpipe.masks.learned.which import QUERY_CHANNELS, frame_queries, needs_choice, query_channels, which_motion
from mosegpipe.pipeline import PipelineConfig
from mosegpipe.points.klt import track_klt
from mosegpipe.synth.render import ObjectSpec, RenderConfig, RenderedClip, render_clip
from mosegpipe.training.masks import whichnet as which_train
from mosegpipe.training.masks.whichnet import SPLIT_LABEL, WhichFrames, WhichTrainConfig, spoiled, train_whichnet


def test_query_channels_mark_the_query_and_its_nearest_pixels() -> None:
    xy = np.array([[2.0, 2.0], [17.0, 2.0], [40.0, 40.0]], np.float32)  # the last outside a 10 x 20 input
    q = query_channels(xy, np.array([3, 5, 3]), 3, (10, 20))
    assert q.shape == (QUERY_CHANNELS, 10, 20)
    assert q[0, 2, 2] == 1 and q[0, 2, 17] == -1 and np.count_nonzero(q[0]) == 2
    assert (q[1][:, :9] == 1).all() and (q[1][:, 11:] == -1).all()  # the nearest track's sign, split midway
    assert not query_channels(xy[2:], np.array([3]), 3, (10, 20)).any()  # no track inside: no evidence


def test_frame_queries_take_moving_motions_with_enough_tracks() -> None:
    xy = np.random.default_rng(0).uniform(0, 100, (12, 2)).astype(np.float32)
    labels = np.array([0, 0, 0, 1, 1, 1, 2, 2, 2, 3, 3, -1])  # the world, two motions of 3, one of 2, unlabelled
    motions, queries = frame_queries(xy, labels, (100, 100), (25, 25))
    assert motions.tolist() == [1, 2] and queries.shape == (2, QUERY_CHANNELS, 25, 25)
    assert needs_choice(labels) and not needs_choice(np.where(labels == 2, 0, labels))


def _frame() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A 40 x 80 mask: the world on the left, motions 1 and 2 on the right with 255 at one corner; tracks of 1 at
    x 44..52, of 2 at x 68..76, of the world at x 4..12."""
    mask = np.zeros((40, 80), np.uint8)
    mask[:, 40:60], mask[:, 60:] = 1, 2
    mask[:4, 76:] = UNKNOWN
    ys = np.arange(4, 40, 8, dtype=np.float32)
    xy = np.concatenate([np.stack([np.full_like(ys, x), ys], 1) for x in (4.0, 12.0, 44.0, 52.0, 68.0, 76.0)])
    labels = np.repeat([0, 0, 1, 1, 2, 2], len(ys))
    return mask, xy, labels


def test_which_motion_relabels_only_the_motions_that_take_part(monkeypatch: pytest.MonkeyPatch) -> None:
    mask, xy, labels = _frame()
    seen: dict[str, int] = {}

    def predict(net: MaskNet, inputs: np.ndarray) -> np.ndarray:
        seen["channels"] = inputs.shape[1]
        # motion 2 (the second query) is the most likely everywhere but on the left half
        prob = np.full((len(inputs), *inputs.shape[2:]), 0.2, np.float32)
        prob[1, :, 5:] = 0.9
        return prob

    monkeypatch.setattr("mosegpipe.masks.learned.net.predict", predict)
    out = which_motion(mask, np.zeros((NUM_CHANNELS, 10, 20), np.float32), xy, labels)
    assert seen["channels"] == NUM_CHANNELS + QUERY_CHANNELS
    assert (out[:, :40] == WORLD).all() and (out[:4, 76:] == UNKNOWN).all()  # the world, unknown kept
    assert (out[:, 40:60][:, 4:] == 2).all() and (out[4:, 60:] == 2).all()
    assert which_motion(mask, np.zeros((NUM_CHANNELS, 10, 20), np.float32), xy, np.minimum(labels, 1)) is mask


def test_shipped_per_motion_weights_load_with_weights_only() -> None:
    path = shipped_path("which")
    assert path.is_file() and path.stat().st_size < 3 * 2**20
    ckpt = torch.load(path, weights_only=True, map_location="cpu")
    assert ckpt["output"] == "which" and ckpt["recipe"]["name"] == "whichnet"
    net = load_masknet("", output="which")
    assert not net.training and net.in_channels == NUM_CHANNELS + QUERY_CHANNELS
    with pytest.raises(CheckpointError, match="output 'which', not 'moving'"):
        MaskNet.from_checkpoint(path)
    with pytest.raises(CheckpointError, match="not 'which'"):
        MaskNet.from_checkpoint(shipped_path(), output="which")


def test_spoiled_labels_stay_among_the_motions() -> None:
    cfg = replace(WhichTrainConfig(), flip_share=0.5, merge_share=1.0, split_share=0.0, keep_share=0.5)
    ids = np.repeat(np.array([0, 1, 2, 3], np.uint8), 50)
    out = spoiled(np.random.default_rng(1), ids, np.array([1, 2, 3]), cfg)
    assert set(np.unique(out)) <= {-1, 0, 1, 2, 3} and len(set(np.unique(out)) - {-1, 0}) == 2  # two merged
    assert (out == -1).mean() < 0.6 and (out[ids == 0] == 0).mean() > 0.5
    untouched = replace(cfg, flip_share=0.0, merge_share=0.0, keep_share=1.0)
    assert np.array_equal(spoiled(np.random.default_rng(1), ids, np.array([1, 2, 3]), untouched), ids)
    split = spoiled(np.random.default_rng(2), ids, np.array([1, 2, 3]), replace(cfg, merge_share=0.0, split_share=1.0))
    (obj,) = {v - SPLIT_LABEL for v in np.unique(split) if v > SPLIT_LABEL}  # one object split, the minority
    assert 0 < (split[ids == obj] == SPLIT_LABEL + obj).mean() < 0.5 < (split[ids == obj] == obj).mean() + 0.2


def _tiny_frames(num: int, seed: int) -> WhichFrames:
    """Two objects side by side whose flow (channel 4) differs: +1 and -1; corners on both and on the world."""
    rng = np.random.default_rng(seed)
    out = WhichFrames()
    for i in range(num):
        f = rng.normal(scale=0.3, size=(NUM_CHANNELS, 24, 32)).astype(np.float32)
        ids = np.zeros((24, 32), np.uint8)
        cut = int(rng.integers(10, 22))
        ids[4:20, 4:cut], ids[4:20, cut:28] = 1, 2
        f[4] += np.where(ids == 1, 1.0, np.where(ids == 2, -1.0, 0.0))
        xy = rng.uniform(0, [31, 23], (60, 2)).astype(np.float32)
        p = np.round(xy).astype(int)
        out.features.append(f.astype(np.float16))
        out.ids.append(ids)
        out.corners.append(xy)
        out.corner_ids.append(ids[p[:, 1], p[:, 0]])
        out.names.append(f"tiny/{i}")
    return out


def test_training_is_seeded_and_learns(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(which_train, "which_frames", lambda root, cfg: (_tiny_frames(12, 0), _tiny_frames(6, 1)))
    cfg = replace(
        WhichTrainConfig(),
        steps=60,
        batch_size=4,
        lr=0.01,
        crop_hw=(24, 32),
        eval_every=20,
        min_pixels=5,
        split_share=0,
    )
    first = train_whichnet(tmp_path / "a.pt", tmp_path, cfg)
    again = train_whichnet(tmp_path / "b.pt", tmp_path, cfg)
    a = MaskNet.from_checkpoint(tmp_path / "a.pt", output="which")
    b = MaskNet.from_checkpoint(tmp_path / "b.pt", output="which")
    assert all(torch.equal(x, y) for x, y in zip(a.state_dict().values(), b.state_dict().values()))
    assert first["held_out_table"] == again["held_out_table"]
    assert first["held_out_accuracy"] > max(0.9, first["nearest_track_accuracy"])  # the flow's sign, learnt


def _two_objects() -> RenderedClip:
    objects = (
        ObjectSpec(centre_m=(-0.5, 0.0, 3.0), size_m=(0.7, 0.7, 0.7), velocity_m=(0.06, 0.0, 0.0)),
        ObjectSpec(centre_m=(0.5, 0.0, 3.0), size_m=(0.7, 0.7, 0.7), velocity_m=(-0.06, 0.0, 0.0)),
    )
    return render_clip(RenderConfig(size_hw=(240, 320), frames=5, seed=4, camera_motion="static", objects=objects))


def test_the_pipeline_asks_the_network_and_keeps_the_moving_pixels(monkeypatch: pytest.MonkeyPatch) -> None:
    clip = _two_objects()
    frames, truth = clip.frames, clip.masks
    tracks = track_klt(clip.to_frames(), PipelineConfig().track)
    ids = np.arange(tracks.num_tracks)
    labels = np.array([truth[0][min(int(y), 239), min(int(x), 319)] for x, y in np.round(tracks.xy[:, 0])], np.int64)
    calls = []
    real = which_mod.which_motion
    monkeypatch.setattr("mosegpipe.masks.compose.which_motion", lambda *a: calls.append(1) or real(*a))
    by_tracks = motion_masks(frames, tracks, ids, labels, MaskConfig())
    learned = motion_masks(frames, tracks, ids, labels, MaskConfig(which="learned"))
    assert len(calls) == len(frames)  # every frame has both motions' tracks
    assert np.array_equal(by_tracks == WORLD, learned == WORLD)  # which pixels move is not its question
    for obj in (1, 2):
        on = truth == obj
        assert (learned[on] == obj).mean() > 0.8, obj


def test_the_setting_is_checked() -> None:
    with pytest.raises(ConfigError, match="which"):
        MaskConfig(which="nearest")
