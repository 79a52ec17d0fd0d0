from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import pytest
import torch
from PIL import Image

from mosegpipe.embed.model import ModelConfig
from mosegpipe.errors import ConfigError
from mosegpipe.studies import StudyRequest, get_study
from mosegpipe.studies import lce as study_lce
from mosegpipe.studies.lce import CurveBudget, CurveConfig, checkpoint_steps, run_lce_curve
from mosegpipe.synth.lce import lce_splits
from mosegpipe.training.loop import TrainConfig, TrainState, clip_sampler, train_model

TINY = ModelConfig(in_dim=2, width=8, num_blocks=1, embed_dim=5)
TINY_BUDGET = CurveBudget(num_checkpoints=2, val_clips=2, test_clips=3)


def _config(name: str, lr: float = 1e-2) -> CurveConfig:
    train = TrainConfig(frames=1, batch_size=2, lr=lr, warmup=1, lr_min_ratio=1.0, reverse=False)
    return CurveConfig(name, f"tiny {name}", TINY, train, cpu_steps=4)


CONFIGS = (_config("tiny-a"), _config("tiny-b", lr=3e-2))


def test_checkpoint_steps_double_up_to_the_budget() -> None:
    assert checkpoint_steps(3000, 6) == [94, 188, 375, 750, 1500, 3000]
    assert checkpoint_steps(4, 5) == [1, 2, 4]  # 4/8 and 4/16 round to 1 (kept once) and 0 (raised to 1)
    assert checkpoint_steps(7, 1) == [7]
    with pytest.raises(ConfigError, match="steps=0"):
        checkpoint_steps(0, 3)


def test_resumed_training_equals_one_run() -> None:
    """A run stopped at a checkpoint and resumed from its saved state ends with the same weights."""
    clips = [lce_splits()["train"][i] for i in range(5)]
    cfg = TrainConfig(frames=1, steps=6, batch_size=2, lr=1e-2, warmup=2, reverse=False)
    whole = train_model(clip_sampler(clips), cfg, TINY, log_every=2)
    saved: list[dict[str, Any]] = []

    def keep(state: TrainState, model: Any) -> None:
        assert not model.training  # eval mode during the callback
        buf = io.BytesIO()
        torch.save(state.to_dict(), buf)  # the state must survive a file (weights_only load)
        buf.seek(0)
        saved.append(torch.load(buf, weights_only=True))

    half = train_model(clip_sampler(clips), cfg, TINY, log_every=2, checkpoints=[3], on_checkpoint=keep, stop_after=3)
    assert half.steps_done == 3 and [s["step"] for s in saved] == [3]
    rest = train_model(clip_sampler(clips), cfg, TINY, log_every=2, resume=TrainState.from_dict(saved[0]))
    assert rest.steps_done == 6
    for name, value in whole.model.state_dict().items():
        assert torch.equal(value, rest.model.state_dict()[name]), name
    # The half run really stopped at step 3.
    assert not torch.equal(half.model.head.weight, whole.model.head.weight)
    with pytest.raises(ConfigError, match=r"checkpoint steps \[7\]"):
        train_model(clip_sampler(clips), cfg, TINY, checkpoints=[7])


def test_lce_curve_tiny_budget_writes_curves_and_resumes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    study = get_study("lce-curve")
    assert not study.needs_data
    req = StudyRequest(out_dir=tmp_path / "curve", budget="cpu", k_max=5)
    first = run_lce_curve(study, req, configs=CONFIGS, budget=TINY_BUDGET)

    rows = first.results["rows"]
    assert [(r["config"], r["step"], r["samples"]) for r in rows] == [
        ("tiny-a", 2, 4),
        ("tiny-a", 4, 8),
        ("tiny-b", 2, 4),
        ("tiny-b", 4, 8),
    ]
    for r in rows:
        assert r["val"]["clips"] == 2 and r["test"]["clips"] == 3
        for split in ("val", "test"):
            for key in ("error", "error_true_k", "nmi", "correct_k"):
                assert 0.0 <= r[split][key] <= 1.0, (split, key)
    assert 0.0 <= first.results["kmeans_raw_true_k"] <= 1.0
    for cc in CONFIGS:  # every configuration named, with its settings, in the table
        assert f"| {cc.name} | 1 blocks x 8 |" in first.table and cc.why in first.table
    assert (tmp_path / "curve" / "models" / "tiny-a.pt").is_file()
    assert not list((tmp_path / "curve" / "parts").glob("*__state.pt"))  # finished runs keep no state
    with Image.open(tmp_path / "curve" / "plot.png") as img:
        assert img.format == "PNG" and img.size == (800, 320)  # 10 x 4 inches at 80 dpi

    # A re-run trains and scores nothing: every checkpoint is a stored part.
    def boom(*args: Any, **kwargs: Any) -> None:
        raise AssertionError("recomputed a stored part")

    monkeypatch.setattr("mosegpipe.training.loop.train_model", boom)
    monkeypatch.setattr(study_lce, "score_clips", boom)
    again = run_lce_curve(study, req, configs=CONFIGS, budget=TINY_BUDGET)
    assert again.results["rows"] == rows
    # Other settings (k_max) make the parts stale: they are computed again.
    with pytest.raises(AssertionError, match="recomputed"):
        run_lce_curve(study, StudyRequest(out_dir=req.out_dir, k_max=4), configs=CONFIGS, budget=TINY_BUDGET)


def test_lce_curve_interrupted_run_continues_from_its_last_checkpoint(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    study = get_study("lce-curve")
    config = CONFIGS[:1]
    reference = run_lce_curve(study, StudyRequest(out_dir=tmp_path / "ref"), configs=config, budget=TINY_BUDGET)

    real = study_lce.score_clips
    calls = {"n": 0}

    def fail_at_the_second_checkpoint(*args: Any, **kwargs: Any) -> dict[str, float]:
        calls["n"] += 1
        if calls["n"] > 2:  # val and test of checkpoint 1 pass, checkpoint 2 dies
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    req = StudyRequest(out_dir=tmp_path / "cut")
    monkeypatch.setattr(study_lce, "score_clips", fail_at_the_second_checkpoint)
    with pytest.raises(KeyboardInterrupt):
        run_lce_curve(study, req, configs=config, budget=TINY_BUDGET)
    parts = tmp_path / "cut" / "parts"
    assert (parts / "tiny-a__state.pt").is_file() and (parts / "tiny-a__step0000002.json").is_file()
    assert not (parts / "tiny-a__step0000004.json").exists()

    monkeypatch.setattr(study_lce, "score_clips", real)
    said: list[str] = []
    resumed = run_lce_curve(
        study, StudyRequest(out_dir=req.out_dir, progress=said.append), configs=config, budget=TINY_BUDGET
    )
    assert "tiny-a: resuming from step 2" in said

    def scores(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
        return [{k: v for k, v in r.items() if k != "train_seconds"} for r in rows]

    assert scores(resumed.results["rows"]) == scores(reference.results["rows"])
    stored = json.loads((parts / "tiny-a__step0000004.json").read_text())
    assert stored["payload"]["step"] == 4


def test_lce_curve_budget_can_run_the_first_configuration_with_its_own_batch(tmp_path: Path) -> None:
    study = get_study("lce-curve")
    budget = CurveBudget(num_checkpoints=2, val_clips=2, test_clips=2, full_steps=2, batch_size=3, num_configs=1)
    result = run_lce_curve(study, StudyRequest(out_dir=tmp_path / "full"), configs=CONFIGS, budget=budget)
    assert [(r["config"], r["step"], r["samples"]) for r in result.results["rows"]] == [
        ("tiny-a", 1, 3),
        ("tiny-a", 2, 6),
    ]
    assert [c["train"]["batch_size"] for c in result.results["configs"]] == [3]
    assert "| tiny-a |" in result.table and "tiny-b" not in result.table


def test_full_budget_is_the_recipe_at_about_half_the_papers_samples() -> None:
    full = study_lce.BUDGETS["full"]
    assert full.num_configs == 1 and study_lce.CURVE_CONFIGS[0].name == "recipe"
    samples = (full.full_steps or 0) * (full.batch_size or 0)
    assert study_lce.PAPER_SAMPLES // 2 <= samples <= study_lce.PAPER_SAMPLES
