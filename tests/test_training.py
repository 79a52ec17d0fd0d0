"""Training: augmentation, samplers, the training loop, recipes and `moseg train`."""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from mosegpipe.cli.main import app
from mosegpipe.embed.model import ModelConfig, SubspaceNet
from mosegpipe.errors import ConfigError
from mosegpipe.training.loop import (
    TrainConfig,
    augment,
    clip_sampler,
    mixture_sampler,
    recipe_of,
    resolve_device,
    train_model,
    with_overrides,
)
from mosegpipe.training.recipes import RECIPES, build_sampler, get_recipe
from mosegpipe.types import LabeledClip

from helpers import moseg, one_error_line, tiny_config

TINY = tiny_config(2)


def affine_clip(
    rng: np.random.Generator, frames: int = 2, sizes: tuple[int, ...] = (20, 20), name: str = "toy"
) -> LabeledClip:
    """A clip of len(sizes) groups, each moved by its own random affine map per frame.

    Group g's points start uniformly in [0, 100)^2 px; frame t > 0 is A_t x + b_t with A_t near the
    identity and b_t ~ 20 px, so groups differ in motion, not in where they start.
    """
    trajs, labels = [], []
    for g, n in enumerate(sizes):
        pts = rng.uniform(0.0, 100.0, (n, 2))
        xy = np.empty((n, frames, 2))
        xy[:, 0] = pts
        for t in range(1, frames):
            a = np.eye(2) + rng.normal(0.0, 0.2, (2, 2))
            xy[:, t] = pts @ a.T + rng.normal(0.0, 20.0, 2)
        trajs.append(xy.reshape(n, 2 * frames))
        labels.append(np.full(n, g, dtype=np.int64))
    return LabeledClip(name, np.concatenate(trajs).astype(np.float32), np.concatenate(labels), "toy")


def coded_clip(labels: list[int], frames: int = 3) -> LabeledClip:
    """A clip whose coordinates identify each point: x_t = i + 0.1 t (point index i), y_t = label."""
    lab = np.asarray(labels, dtype=np.int64)
    n = lab.size
    xy = np.empty((n, frames, 2), dtype=np.float64)  # float64 in: augment must return float32
    xy[:, :, 0] = np.arange(n)[:, None] + 0.1 * np.arange(frames)[None, :]
    xy[:, :, 1] = lab[:, None]
    return LabeledClip("coded", xy.reshape(n, 2 * frames), lab.astype(np.int32), "toy")


# ---------------------------------------------------------------------------------------------
# augment
# ---------------------------------------------------------------------------------------------


def _check_aligned(clip: LabeledClip, traj: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Asserts every output row is an original point (up to flip/reverse) with its own label; returns indices."""
    f = traj.shape[1] // 2
    xy = traj.reshape(-1, f, 2)
    # y never changes under flip or reverse and was set to the label at every frame.
    np.testing.assert_array_equal(xy[:, :, 1], np.repeat(labels[:, None].astype(np.float32), f, axis=1))
    idx = np.rint(np.abs(xy).min(axis=1)[:, 0]).astype(np.int64)  # |x| is smallest at frame 1: the index
    np.testing.assert_array_equal(clip.labels[idx], labels)
    assert np.unique(idx).size == idx.size, "a point was drawn twice"
    return idx


def test_augment_subsamples_and_keeps_every_group() -> None:
    # 200 + 150 points and a 1-point group: subsampling to 50 must still keep group 2's only point.
    labels = [0] * 200 + [1] * 150 + [2]
    clip = coded_clip(labels)
    cfg = TrainConfig(frames=3, max_points=50)
    for seed in range(20):
        traj, lab = augment(clip, np.random.default_rng(seed), cfg)
        assert traj.shape == (50, 6) and traj.dtype == np.float32
        assert lab.shape == (50,) and lab.dtype == np.int64
        assert set(lab.tolist()) == {0, 1, 2}
        idx = _check_aligned(clip, traj, lab)
        assert 350 in idx


def test_augment_keeps_every_group_when_several_are_small() -> None:
    # Groups 1, 2, 3 have one point each; max_points=4 leaves room for exactly one point per group.
    clip = coded_clip([0] * 7 + [1, 2, 3])
    cfg = TrainConfig(frames=3, max_points=4, flip=False, reverse=False)
    for seed in range(30):
        _, lab = augment(clip, np.random.default_rng(seed), cfg)
        assert set(lab.tolist()) == {0, 1, 2, 3}, f"seed {seed}: groups {sorted(set(lab.tolist()))}"


def test_augment_without_subsampling_keeps_all_points_and_input() -> None:
    clip = coded_clip([0, 0, 1, 1, 1])
    before = clip.traj.copy()
    traj, lab = augment(clip, np.random.default_rng(0), TrainConfig(frames=3, max_points=5))
    assert traj.shape == (5, 6) and traj.dtype == np.float32 and lab.dtype == np.int64
    np.testing.assert_array_equal(np.sort(_check_aligned(clip, traj, lab)), np.arange(5))
    np.testing.assert_array_equal(clip.traj, before)  # the clip itself is never modified


def _classify(clip: LabeledClip, traj: np.ndarray) -> str:
    """Which of the four flip/reverse combinations turned clip.traj (no subsampling) into traj."""
    xy = clip.traj.reshape(clip.num_points, -1, 2).astype(np.float32)
    candidates = {
        "none": xy,
        "flip": xy * np.array([-1.0, 1.0], dtype=np.float32),
        "reverse": xy[:, ::-1],
        "both": (xy * np.array([-1.0, 1.0], dtype=np.float32))[:, ::-1],
    }
    out = traj.reshape(clip.num_points, -1, 2)
    found = [k for k, v in candidates.items() if np.array_equal(out, v)]
    assert len(found) == 1, f"output matches {found}"
    return found[0]


def test_augment_flip_negates_x_and_reverse_reverses_frames() -> None:
    clip = coded_clip([0, 0, 1, 1], frames=4)
    seen = {_classify(clip, augment(clip, np.random.default_rng(s), TrainConfig(frames=4))[0]) for s in range(40)}
    assert seen == {"none", "flip", "reverse", "both"}
    # Flip alone: x negated, y and frame order unchanged (and some seeds leave the clip as it is).
    only_flip = TrainConfig(frames=4, reverse=False)
    seen = {_classify(clip, augment(clip, np.random.default_rng(s), only_flip)[0]) for s in range(40)}
    assert seen == {"none", "flip"}
    only_reverse = TrainConfig(frames=4, flip=False)
    seen = {_classify(clip, augment(clip, np.random.default_rng(s), only_reverse)[0]) for s in range(40)}
    assert seen == {"none", "reverse"}
    neither = TrainConfig(frames=4, flip=False, reverse=False)
    assert {_classify(clip, augment(clip, np.random.default_rng(s), neither)[0]) for s in range(10)} == {"none"}


def test_augment_reverse_example_by_hand() -> None:
    # One point, frames (1,2) (3,4) (5,6): reversed it reads (5,6) (3,4) (1,2); flipped too: x negated.
    clip = LabeledClip("p", np.array([[1, 2, 3, 4, 5, 6]], dtype=np.float32), np.array([0]), "toy")
    outs = {tuple(augment(clip, np.random.default_rng(s), TrainConfig(frames=3))[0][0].tolist()) for s in range(40)}
    assert outs == {
        (1, 2, 3, 4, 5, 6),
        (-1, 2, -3, 4, -5, 6),
        (5, 6, 3, 4, 1, 2),
        (-5, 6, -3, 4, -1, 2),
    }


# ---------------------------------------------------------------------------------------------
# Samplers
# ---------------------------------------------------------------------------------------------


def _const(name: str) -> LabeledClip:
    return LabeledClip(name, np.zeros((2, 4), dtype=np.float32), np.array([0, 1]), "toy")


def test_mixture_sampler_follows_weights() -> None:
    a, b, c = _const("a"), _const("b"), _const("c")
    draw = mixture_sampler([(1.0, lambda _r: a), (3.0, lambda _r: b), (0.0, lambda _r: c)])
    rng = np.random.default_rng(0)
    names = [draw(rng).name for _ in range(4000)]
    # Expected 1000 / 3000 / 0; binomial std of the count of "a" is ~27, so 150 is a loose bound.
    assert abs(names.count("a") - 1000) < 150
    assert abs(names.count("b") - 3000) < 150
    assert names.count("c") == 0


@pytest.mark.parametrize("weights", [[], [-1.0, 2.0], [0.0, 0.0]])
def test_mixture_sampler_rejects_bad_weights(weights: list[float]) -> None:
    with pytest.raises(ValueError, match="non-negative with a positive sum"):
        mixture_sampler([(w, lambda _r: _const("x")) for w in weights])


@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")
@pytest.mark.parametrize("bad", [math.nan, math.inf])
def test_mixture_sampler_rejects_non_finite_weights(bad: float) -> None:
    with pytest.raises(ValueError, match="mixture weights"):
        mixture_sampler([(bad, lambda _r: _const("x")), (1.0, lambda _r: _const("y"))])


def test_clip_sampler_draws_uniformly_and_rejects_empty() -> None:
    clips = [_const(n) for n in "abcd"]
    draw = clip_sampler(clips)
    rng = np.random.default_rng(1)
    names = [draw(rng).name for _ in range(2000)]
    assert {n: names.count(n) for n in "abcd"} == pytest.approx({n: 500 for n in "abcd"}, abs=100)
    with pytest.raises(ValueError, match="at least one clip"):
        clip_sampler([])


# ---------------------------------------------------------------------------------------------
# train_model
# ---------------------------------------------------------------------------------------------


def test_train_model_reduces_loss_on_two_affine_motions() -> None:
    cfg = TrainConfig(frames=2, steps=60, batch_size=4, lr=1e-2, warmup=0, seed=0)
    result = train_model(affine_clip, cfg, TINY, log_every=10)
    losses = [h["loss"] for h in result.history]
    assert len(losses) == 6
    # Measured (seeds 0-2, 40 steps): the last 10-step mean is 0.43-0.49 x the first.
    assert losses[-1] < 0.75 * losses[0], losses
    assert result.steps_done == 60
    assert not result.model.training
    assert result.model.cfg == TINY


def test_train_model_history_keys_and_schedule() -> None:
    cfg = TrainConfig(frames=2, steps=5, batch_size=2, lr=1e-3, warmup=2, lr_min_ratio=0.05)
    logged: list[dict[str, float]] = []
    result = train_model(affine_clip, cfg, TINY, log_every=2, on_log=logged.append)
    assert logged == result.history
    assert [h["step"] for h in result.history] == [2.0, 4.0, 5.0]  # every 2 steps, and the last one
    for h in result.history:
        assert set(h) == {"step", "loss", "lr", "seconds"}
        assert h["loss"] >= 0.0 and h["seconds"] >= 0.0
    # Warm-up: step 2 of 2 is at the peak; then cosine from 1e-3 to 5e-5 over 3 steps:
    # 5e-5 + 0.5 * 9.5e-4 * (1 + cos(pi k / 3)) for k = 1, 2.
    lrs = [h["lr"] for h in result.history]
    assert lrs == pytest.approx([1e-3, 7.625e-4, 2.875e-4], rel=1e-9)
    assert result.seconds >= result.history[-1]["seconds"]


def slow_clip(rng: np.random.Generator) -> LabeledClip:
    """A sampler slow enough (10 ms a clip) for a time budget to stop training."""
    time.sleep(0.01)
    return affine_clip(rng)


def test_train_model_time_budget_stops_early() -> None:
    cfg = TrainConfig(frames=2, steps=1000, batch_size=1, time_budget_s=0.05)
    result = train_model(slow_clip, cfg, TINY, log_every=1)
    assert 1 <= result.steps_done < 1000
    assert len(result.history) == result.steps_done
    assert not result.model.training


def test_time_budget_stop_keeps_the_losses_since_the_last_log_point() -> None:
    cfg = TrainConfig(frames=2, steps=1000, batch_size=1, time_budget_s=0.1)
    result = train_model(slow_clip, cfg, TINY, log_every=500)
    assert 1 <= result.steps_done < 500
    assert [e["step"] for e in result.history] == [float(result.steps_done)]
    assert np.isfinite(result.history[-1]["loss"])


def test_train_model_init_copies_and_leaves_argument_untouched() -> None:
    torch.manual_seed(3)
    init = SubspaceNet(TINY).eval()
    before = {k: v.clone() for k, v in init.state_dict().items()}
    # 0 steps: an exact copy in a new object; the model_cfg argument is ignored when init is given.
    copy = train_model(affine_clip, TrainConfig(frames=2, steps=0), ModelConfig(in_dim=4), init=init).model
    assert copy is not init and copy.cfg == TINY
    for k, v in copy.state_dict().items():
        assert torch.equal(v, before[k]), k
    trained = train_model(affine_clip, TrainConfig(frames=2, steps=3, batch_size=2, lr=1e-2, warmup=0), init=init).model
    assert trained is not init
    assert any(not torch.equal(v, before[k]) for k, v in trained.state_dict().items())
    for k, v in init.state_dict().items():
        assert torch.equal(v, before[k]), f"init's {k} changed"
    assert not init.training


def test_train_model_rejects_unknown_loss_and_wrong_in_dim() -> None:
    with pytest.raises(ValueError, match="unknown loss 'hinge'"):
        train_model(affine_clip, TrainConfig(frames=2, steps=1, loss="hinge"), TINY)
    with pytest.raises(ValueError, match="input dimension 4 does not fit 5 frames"):
        train_model(affine_clip, TrainConfig(frames=5, steps=1), TINY)
    with pytest.raises(ValueError, match="input dimension 4 does not fit 3 frames"):
        train_model(affine_clip, TrainConfig(frames=3, steps=1), init=SubspaceNet(TINY))


@pytest.mark.parametrize("loss", ["mimi", "ce"])
def test_train_model_other_losses_run(loss: str) -> None:
    result = train_model(affine_clip, TrainConfig(frames=2, steps=2, batch_size=2, loss=loss), TINY)
    assert result.steps_done == 2 and math.isfinite(result.history[-1]["loss"])


def test_recipe_of_and_with_overrides() -> None:
    cfg = with_overrides(TrainConfig(), steps=7, lr=None, loss="ce")
    assert cfg.steps == 7 and cfg.lr == TrainConfig().lr and cfg.loss == "ce"
    result = train_model(affine_clip, TrainConfig(frames=2, steps=2, batch_size=1), TINY)
    rec = recipe_of(TrainConfig(frames=2, steps=2), {"toy": {"weight": 1.0}}, result)
    assert rec["train_config"]["steps"] == 2 and rec["sources"] == {"toy": {"weight": 1.0}}
    assert rec["steps_done"] == 2 and rec["final_loss"] == result.history[-1]["loss"]
    assert set(recipe_of(cfg, {})) == {"train_config", "sources"}


# ---------------------------------------------------------------------------------------------
# Recipes
# ---------------------------------------------------------------------------------------------


def test_get_recipe_unknown_lists_names() -> None:
    assert get_recipe("clip-f5").name == "clip-f5"
    with pytest.raises(ValueError) as err:
        get_recipe("nope")
    message = str(err.value)
    assert "'nope'" in message
    for name in RECIPES:
        assert name in message


@pytest.mark.parametrize("name", sorted(RECIPES))
def test_recipe_model_fits_its_frames(name: str) -> None:
    recipe = RECIPES[name]
    assert recipe.name == name
    assert recipe.model.in_dim == 2 * recipe.train.frames
    assert recipe.sources and all(w > 0 for _, w in recipe.sources)


@pytest.mark.parametrize(("source", "frames", "width"), [("synthetic", 3, 6), ("synthetic-pair", 2, 4)])
def test_build_sampler_synthetic_needs_no_data(source: str, frames: int, width: int) -> None:
    sampler, described = build_sampler([(source, 1.0), ("kt3d", 0.0)], None, frames)
    assert described == {source: {"weight": 1.0, "generated": True}}  # zero weight: never loaded
    rng = np.random.default_rng(0)
    for _ in range(3):
        clip = sampler(rng)
        assert clip.traj.shape[1] == width and clip.labels.shape == (clip.num_points,)


def test_build_sampler_rejects_no_positive_source() -> None:
    with pytest.raises(ValueError, match="positive weight"):
        build_sampler([("synthetic", 0.0)], None, 5)


def test_build_sampler_unknown_source_named() -> None:
    with pytest.raises(ValueError, match="unknown source 'kt3dd'"):
        build_sampler([("kt3dd", 1.0)], None, 5)


def test_build_sampler_excludes_held_out_sequence(data_root: Path) -> None:
    sampler, described = build_sampler([("kt3d", 1.0)], data_root, 5, exclude=("Seq005_Clip01",))
    assert described["kt3d"]["excluded"] == ["Seq005_Clip01"]
    rng = np.random.default_rng(0)
    sequences = {sampler(rng).meta["sequence"] for _ in range(300)}
    assert "Seq005_Clip01" not in sequences
    assert len(sequences) > 5  # the draws do cover the other sequences


# ---------------------------------------------------------------------------------------------
# moseg train
# ---------------------------------------------------------------------------------------------

runner = CliRunner(env={"COLUMNS": "200"})


def test_cli_train_synthetic_f2(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    result = runner.invoke(
        app,
        [
            "train",
            "--preset",
            "synthetic-f2",
            "--steps",
            "2",
            "--batch-size",
            "2",
            "--threads",
            "1",
            "--out",
            "tmp/x.pt",
        ],
    )
    assert result.exit_code == 0, result.output
    model = SubspaceNet.from_checkpoint(tmp_path / "tmp" / "x.pt")
    assert model.recipe["name"] == "synthetic-f2"
    assert model.recipe["steps_done"] == 2
    assert model.recipe["train_config"]["steps"] == 2 and model.recipe["train_config"]["batch_size"] == 2
    assert model.cfg == RECIPES["synthetic-f2"].model
    assert "wrote tmp/x.pt (2 steps" in result.stdout


def test_cli_train_unknown_preset_one_line() -> None:
    result = runner.invoke(app, ["train", "--preset", "nope", "--threads", "1"])
    assert result.exit_code == 2  # a usage error: --preset is a choice (an Enum) of the recipe names
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1
    assert lines[0].startswith("moseg: error: --preset nope: 'nope' is not one of") and "synthetic-f2" in lines[0]


# ---------------------------------------------------------------------------------------------
# One training entry point: presets rebuild the shipped weights
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize(("frames", "name", "init"), [(5, "clip-f5", "base-f5"), (2, "pair-f2", "synthetic-f2")])
def test_presets_are_the_shipped_recipes(frames: int, name: str, init: str) -> None:
    from dataclasses import asdict

    shipped = SubspaceNet.default(frames=frames)
    recipe = get_recipe(name)
    assert shipped.recipe["name"] == name and recipe.init == init
    assert asdict(recipe.train) == shipped.recipe["train_config"]
    assert recipe.model == shipped.cfg
    assert {s: w for s, w in recipe.sources} == {s: d["weight"] for s, d in shipped.recipe["sources"].items()}


def test_train_recipe_trains_its_init_first_then_reuses_it(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from dataclasses import replace

    from mosegpipe.training import recipes
    from mosegpipe.training.run import TrainOverrides, needs_data, train_recipe

    tiny = TrainConfig(frames=2, steps=2, batch_size=2, warmup=0)
    base = recipes.Recipe("tiny-base", "t", tiny, TINY, (("synthetic-pair", 1.0),))
    fine = replace(base, name="tiny-fine", init="tiny-base")
    monkeypatch.setitem(recipes.RECIPES, "tiny-base", base)
    monkeypatch.setitem(recipes.RECIPES, "tiny-fine", fine)
    started: list[str] = []
    out = tmp_path / "runs" / "fine.pt"
    assert not needs_data("tiny-fine")
    train_recipe("tiny-fine", out, on_start=lambda r, cfg, described: started.append(r.name))
    assert started == ["tiny-base", "tiny-fine"]
    model = SubspaceNet.from_checkpoint(out)
    assert model.recipe["name"] == "tiny-fine" and model.recipe["init"] == str(tmp_path / "runs" / "tiny-base.pt")
    train_recipe("tiny-fine", out, overrides=TrainOverrides(steps=1), on_start=lambda r, c, d: started.append(r.name))
    assert started == ["tiny-base", "tiny-fine", "tiny-fine"]  # the base checkpoint is reused
    assert SubspaceNet.from_checkpoint(out).recipe["steps_done"] == 1


def test_device_names_are_checked_and_cpu_stays_the_default(monkeypatch: pytest.MonkeyPatch) -> None:
    assert resolve_device("cpu") == "cpu"
    assert resolve_device(" CPU ") == "cpu"
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert resolve_device("auto") == "cpu"  # a GPU only when there is one, and only when asked for
    for bad in ("gpu", "cuda:", "cuda:x", "mps0", ""):
        with pytest.raises(ConfigError, match="choose cpu, cuda, cuda:N, auto"):
            resolve_device(bad)
    with pytest.raises(ConfigError, match="no CUDA device"):
        resolve_device("cuda")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 1)
    assert resolve_device("auto") == "cuda"
    assert resolve_device("cuda:0") == "cuda:0"
    with pytest.raises(ConfigError, match="1 CUDA device"):
        resolve_device("cuda:1")


def test_training_on_the_cpu_device_is_the_default_run() -> None:
    """device="cpu" given explicitly trains exactly as the default does."""
    rng = np.random.default_rng(0)
    sampler = clip_sampler([affine_clip(rng, name=f"c{i}") for i in range(3)])
    cfg = TrainConfig(frames=2, steps=3, batch_size=2, warmup=1, seed=3)
    a = train_model(sampler, cfg, TINY)
    b = train_model(sampler, cfg, TINY, device=resolve_device("cpu"))
    assert next(b.model.parameters()).device.type == "cpu"
    for (name, x), (_, y) in zip(a.model.state_dict().items(), b.model.state_dict().items(), strict=True):
        assert torch.equal(x, y), name


@pytest.mark.parametrize("command", [["train", "--preset", "lce", "--steps", "1"], ["study", "lce-curve"]])
def test_a_bad_device_is_one_error_line(tmp_path: Path, command: list[str]) -> None:
    code, _, err = moseg(*command, "--out", tmp_path / "out", "--device", "gpu")
    assert code == 2  # a usage error: the name is none of the choices, whatever the machine has
    assert "--device gpu: choose cpu, cuda, cuda:N, auto" in one_error_line(err)
    assert not (tmp_path / "out").exists()  # nothing trained or written
