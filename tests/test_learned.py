"""The learned masks (mosegpipe.learned): the network's size, its shipped weights, what its masks find on
rendered clips, the CLI end to end, and the training recipe (its data never a validation clip; seeded)."""

from __future__ import annotations

import json
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
import pytest
import torch

from mosegpipe.data.davis import DAVIS_DEV, DAVIS_VAL
from mosegpipe.errors import CheckpointError, ConfigError
from mosegpipe.learned import data as learned_data
from mosegpipe.learned.data import HELD_OUT, TRAIN_DAVIS, Frames4Net, source_clips, stacks
from mosegpipe.learned.features import NUM_CHANNELS, LearnedMaskConfig, clip_features, net_size
from mosegpipe.learned.moving import learned_moving
from mosegpipe.learned.net import MaskNet, load_masknet, shipped_path
from mosegpipe.learned.train import MaskTrainConfig, train_masknet
from mosegpipe.masks import MaskConfig
from mosegpipe.motion import MotionMaskConfig, stack_motion
from mosegpipe.pipeline import PipelineConfig
from mosegpipe.synth.render import ObjectSpec, RenderConfig, render_clip

from helpers import moseg, write_avi


def test_network_shapes_and_size() -> None:
    net = MaskNet().eval()
    assert 50_000 < net.num_params() < 400_000  # a few hundred thousand parameters at most: under 2 MB
    with torch.inference_mode():
        for h, w in ((30, 41), (120, 160), (8, 8)):
            assert net(torch.zeros(2, NUM_CHANNELS, h, w)).shape == (2, 1, h, w)


def test_shipped_weights_load_with_weights_only() -> None:
    path = shipped_path()
    assert path.is_file() and path.stat().st_size < 3 * 2**20
    ckpt = torch.load(path, weights_only=True, map_location="cpu")
    assert ckpt["kind"] == "masknet" and ckpt["recipe"]["name"] == "masknet"
    net = load_masknet()
    assert not net.training and net.in_channels == NUM_CHANNELS
    # the threshold the recipe chose on the held-out development clips is the default
    assert LearnedMaskConfig().threshold == ckpt["recipe"]["threshold"]


def test_a_broken_checkpoint_is_one_error(tmp_path: Path) -> None:
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a checkpoint")
    with pytest.raises(CheckpointError, match="not a readable checkpoint"):
        MaskNet.from_checkpoint(bad)
    torch.save({"kind": "other"}, bad)
    with pytest.raises(CheckpointError, match="not a mask network checkpoint"):
        MaskNet.from_checkpoint(bad)


def _moving(cfg: RenderConfig) -> tuple[np.ndarray, np.ndarray]:
    clip = render_clip(cfg)
    motion = stack_motion(clip.frames, MotionMaskConfig())
    return learned_moving(clip.frames, motion), clip.masks > 0


def test_learned_masks_find_a_moving_square() -> None:
    square = ObjectSpec(centre_m=(0.0, 0.0, 3.0), size_m=(0.8, 0.8, 0.8), velocity_m=(0.05, 0.01, 0.0))
    cfg = RenderConfig(size_hw=(240, 320), frames=5, seed=3, camera_motion="pan", objects=(square,))
    moving, truth = _moving(cfg)
    inter, union = (moving & truth).sum(), (moving | truth).sum()
    assert inter / union > 0.6, inter / union


def test_a_static_scene_under_a_panning_camera_stays_world() -> None:
    cfg = RenderConfig(size_hw=(240, 320), frames=5, seed=5, num_objects=0, camera_motion="pan", ground=True)
    moving, truth = _moving(cfg)
    assert not truth.any()
    assert moving.mean() < 0.03, moving.mean()


def test_features_shapes_and_first() -> None:
    clip = render_clip(RenderConfig(size_hw=(96, 128), frames=4, seed=1))
    motion = stack_motion(clip.frames, MotionMaskConfig())
    feats = clip_features(clip.frames, motion, 0.25)
    assert feats.shape == (4, NUM_CHANNELS, *net_size((96, 128), 0.25)) and np.isfinite(feats).all()
    assert np.array_equal(clip_features(clip.frames, motion, 0.25, first=2), feats[2:])


def test_settings() -> None:
    cfg = PipelineConfig(mask=MaskConfig(method="learned"))
    assert PipelineConfig.from_dict(json.loads(json.dumps(asdict(cfg)))) == cfg
    for bad in (dict(threshold=1.0), dict(scale=0.0)):
        with pytest.raises(ConfigError):
            LearnedMaskConfig(**bad)  # type: ignore[arg-type]


def test_cli_runs_learned_masks_end_to_end(tmp_path: Path) -> None:
    objects = (ObjectSpec(centre_m=(-0.2, 0.0, 3.0), size_m=(1.0, 1.0, 1.0), velocity_m=(0.05, 0.0, 0.0)),)
    clip = render_clip(RenderConfig(size_hw=(240, 320), frames=6, seed=2, camera_motion="pan", objects=objects))
    video = write_avi(tmp_path / "clip.avi", clip.frames)
    out = tmp_path / "out"
    code, stdout, stderr = moseg("run", video, "--frames", 5, "--mask-method", "learned", "-o", out, "--no-rrd")
    assert code == 0, stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["config"]["mask"]["method"] == "learned"
    assert len(list((out / "masks").glob("*.png"))) == 5


def test_recipe_never_reads_a_validation_clip() -> None:
    clips = source_clips()
    assert all(not set(names) & set(DAVIS_VAL) for names in clips.values())
    assert set(TRAIN_DAVIS) | set(HELD_OUT) == set(DAVIS_DEV) and not set(TRAIN_DAVIS) & set(HELD_OUT)
    with pytest.raises(ValueError, match="validation clips never train"):
        learned_data.davis_frames("unused", ("bear", DAVIS_VAL[0]), 0.25)
    assert stacks(12) == [(0, 5), (5, 10), (10, 12)] and stacks(11) == [(0, 5), (5, 11)]


def _tiny_source(seed: int, frames: int = 6) -> Frames4Net:
    rng = np.random.default_rng(seed)
    feats, truth = [], []
    for _ in range(frames):
        f = rng.normal(size=(NUM_CHANNELS, 20, 24)).astype(np.float16)
        t = (f[1] > 0.3).astype(np.float16)  # "not the world" where channel 1 (the relative residual) is high
        feats.append(f)
        truth.append(t)
    return Frames4Net(feats, truth, [f"tiny/{i}" for i in range(frames)])


def test_training_is_seeded_and_learns(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr("mosegpipe.learned.train.load_source", lambda name, *a, **k: _tiny_source(len(name)))
    cfg = replace(
        MaskTrainConfig(),
        steps=40,
        batch_size=4,
        lr=0.02,
        crop_hw=(16, 16),
        eval_every=10,
        sources=(("davis", 1.0),),
    )
    first = train_masknet(tmp_path / "a.pt", tmp_path, cfg)
    again = train_masknet(tmp_path / "b.pt", tmp_path, cfg)
    a, b = MaskNet.from_checkpoint(tmp_path / "a.pt"), MaskNet.from_checkpoint(tmp_path / "b.pt")
    assert all(torch.equal(x, y) for x, y in zip(a.state_dict().values(), b.state_dict().values()))
    assert first["held_out_table"] == again["held_out_table"]
    scores = [max(e["j"]) for e in first["held_out_table"]]
    assert scores[-1] > scores[0] + 0.2 and first["held_out_j"] > 0.7  # a threshold of channel 1, learnt in 40 steps
