"""Evaluation: per-clip scoring, summaries and tables, result files, leave-one-out resume, `moseg eval`."""

from __future__ import annotations

import csv
import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

import mosegpipe.training.run as training_run
from mosegpipe.cli.main import app
from mosegpipe.embed.model import SubspaceNet
from mosegpipe.evaluation.benchmark import EvalConfig, embed_clip, evaluate_clips, run_protocol
from mosegpipe.evaluation.metrics import misclassification_error
from mosegpipe.evaluation.protocols import PROTOCOLS, get_protocol
from mosegpipe.evaluation.report import format_table, summarize, write_results
from mosegpipe.group.cluster import ClusterConfig, cluster_auto_k
from mosegpipe.training.loop import TrainConfig
from mosegpipe.types import LabeledClip

from helpers import tiny_config, tiny_model

TINY = tiny_config(2)
MODEL_COLUMNS = {"k_pred", "error", "error_true_k", "nmi", "seconds"}


def separated_clip(
    rng: np.random.Generator, name: str, sizes: tuple[int, ...] = (15, 15), frames: int = 2
) -> LabeledClip:
    """Groups 300 px apart, each translated by its own velocity: K-means on raw coordinates solves it."""
    trajs, labels = [], []
    for g, n in enumerate(sizes):
        start = rng.uniform(0.0, 50.0, (n, 2)) + 300.0 * g
        velocity = rng.normal(0.0, 10.0, 2)
        xy = start[:, None, :] + velocity * np.arange(frames)[None, :, None]
        trajs.append(xy.reshape(n, 2 * frames))
        labels.append(np.full(n, g, dtype=np.int64))
    return LabeledClip(
        name, np.concatenate(trajs).astype(np.float32), np.concatenate(labels), "toy", {"sequence": name}
    )


def toy_sampler(rng: np.random.Generator) -> LabeledClip:
    return separated_clip(rng, "train", sizes=(12, 12))


# ---------------------------------------------------------------------------------------------
# evaluate_clips / embed_clip
# ---------------------------------------------------------------------------------------------


def test_evaluate_clips_fills_every_column() -> None:
    rng = np.random.default_rng(0)
    clips = [
        separated_clip(rng, "a"),
        separated_clip(rng, "b", sizes=(10, 12, 14)),
        separated_clip(rng, "c", sizes=(20,)),
    ]
    model = tiny_model()
    cfg = ClusterConfig(k_max=5)
    rows = evaluate_clips(model, clips, cfg, baselines=("kmeans-raw",))
    assert [r["name"] for r in rows] == ["a", "b", "c"]
    for clip, row in zip(clips, rows):
        assert set(row) == {"name", "num_points", "k_true", *MODEL_COLUMNS, "kmeans-raw@K", "kmeans-raw@auto"}
        assert row["num_points"] == clip.num_points and row["k_true"] == clip.k
        assert 1 <= row["k_pred"] <= 5
        for col in ("error", "error_true_k", "kmeans-raw@K", "kmeans-raw@auto"):
            assert 0.0 <= row[col] <= 1.0, (col, row[col])
        assert 0.0 <= row["nmi"] <= 1.0 + 1e-12
        assert row["seconds"] > 0.0
        # error_true_k is the error of clustering this clip's embedding into its true K.
        fixed = cluster_auto_k(model.embed(clip.traj), cfg, k=clip.k)
        assert row["error_true_k"] == misclassification_error(fixed.labels, clip.labels)
        assert row["kmeans-raw@K"] == 0.0  # 300 px apart: raw K-means with the true K is exact
    assert [r["k_true"] for r in rows] == [2, 3, 1]
    assert rows[2]["error_true_k"] == 0.0  # one group forced into one cluster cannot be wrong


def test_evaluate_clips_without_model_and_bad_baseline() -> None:
    clip = separated_clip(np.random.default_rng(1), "a")
    rows = evaluate_clips(None, [clip], baselines=("kmeans-raw",))
    assert set(rows[0]) == {"name", "num_points", "k_true", "kmeans-raw@K", "kmeans-raw@auto"}
    assert evaluate_clips(None, [clip]) == [{"name": "a", "num_points": 30, "k_true": 2}]
    with pytest.raises(ValueError, match=r"unknown baseline\(s\) \['nope'\]"):
        evaluate_clips(None, [clip], baselines=("nope",))


def test_embed_clip_resamples_to_model_frames() -> None:
    rng = np.random.default_rng(2)
    n = 40
    x0 = rng.uniform(0.0, 100.0, (n, 1, 2))
    v = rng.normal(0.0, 3.0, (n, 1, 2))
    ten = (x0 + v * np.arange(10)[None, :, None]).reshape(n, 20).astype(np.float32)
    clip = LabeledClip("ten", ten, np.zeros(n, dtype=np.int64), "toy")
    model = tiny_model(5)
    emb = embed_clip(model, clip)
    assert emb.shape == (n, 5) and emb.dtype == np.float32
    # 5 frames spanning frames 1..10 sit at source times 0, 2.25, 4.5, 6.75, 9: linear motion is exact there.
    five = (x0 + v * (np.arange(5) * 9 / 4)[None, :, None]).reshape(n, 10)
    np.testing.assert_allclose(emb, model.embed(five), atol=1e-5)
    # The first five frames would be a different (slower) clip: resampling is not truncation.
    assert not np.allclose(emb, model.embed(ten[:, :10]), atol=1e-3)
    # A clip that already has the model's F is embedded as it is.
    same = LabeledClip("five", five.astype(np.float32), np.zeros(n, dtype=np.int64), "toy")
    np.testing.assert_array_equal(embed_clip(model, same), model.embed(same.traj))


# ---------------------------------------------------------------------------------------------
# summarize / format_table / write_results
# ---------------------------------------------------------------------------------------------


def hand_rows() -> list[dict[str, Any]]:
    cols = (
        "name",
        "num_points",
        "k_true",
        "k_pred",
        "error",
        "error_true_k",
        "nmi",
        "seconds",
        "kmeans-raw@K",
        "kmeans-raw@auto",
    )
    values = [
        ("a", 10, 2, 2, 0.1, 0.0, 0.9, 0.5, 0.2, 0.3),
        ("b", 20, 3, 2, 0.4, 0.2, 0.5, 0.25, 0.0, 0.6),
        ("c", 30, 1, 1, 0.0, 0.0, 1.0, 0.25, 0.1, 0.0),
        ("d", 40, 2, 3, 0.9, 0.1, 0.6, 1.0, 0.5, 0.1),
    ]
    return [dict(zip(cols, v)) for v in values]


def test_summarize_hand_computed() -> None:
    s = summarize(hand_rows())
    assert set(s) == {
        "num_clips",
        "error",
        "error_true_k",
        "kmeans-raw@K",
        "kmeans-raw@auto",
        "correct_k",
        "nmi",
        "seconds_total",
    }
    assert s["num_clips"] == 4
    # error: mean (.1 + .4 + 0 + .9) / 4 = .35, median of (0, .1, .4, .9) = .25.
    assert s["error"] == pytest.approx({"mean": 0.35, "median": 0.25})
    assert s["error_true_k"] == pytest.approx({"mean": 0.075, "median": 0.05})
    assert s["kmeans-raw@K"] == pytest.approx({"mean": 0.2, "median": 0.15})
    assert s["kmeans-raw@auto"] == pytest.approx({"mean": 0.25, "median": 0.2})
    assert s["correct_k"] == 0.5  # a and c
    assert s["nmi"] == pytest.approx(0.75)
    assert s["seconds_total"] == pytest.approx(2.0)
    assert summarize([]) == {}
    baseline_only = summarize([{"name": "x", "k_true": 2, "ssc@K": 0.5}, {"name": "y", "k_true": 2, "ssc@K": 0.0}])
    assert baseline_only == {"num_clips": 2, "ssc@K": {"mean": 0.25, "median": 0.25}}


def test_format_table_rows_percent_and_stats() -> None:
    rows = hand_rows()
    table = format_table(rows, summarize(rows))
    lines = table.splitlines()
    assert (
        lines[0]
        == "| name | num_points | k_true | k_pred | error | error_true_k | nmi | seconds | kmeans-raw@K | kmeans-raw@auto |"
    )
    assert lines[1] == "|" + "---|" * 10
    assert lines[2] == "| a | 10 | 2 | 2 | 10.00 | 0.00 | 0.900 | 500.0ms | 20.00 | 30.00 |"
    assert lines[5] == "| d | 40 | 2 | 3 | 90.00 | 10.00 | 0.600 | 1000.0ms | 50.00 | 10.00 |"
    assert lines[6] == "| **mean** |  |  |  | 35.00 | 7.50 |  |  | 20.00 | 25.00 |"
    assert lines[7] == "| **median** |  |  |  | 25.00 | 5.00 |  |  | 15.00 | 20.00 |"
    assert "correct K: 50.00 % · mean NMI 0.750 · embedding + automatic K for all 4 clips: 2.000 s" in table
    assert format_table([], {}) == "(no rows)\n"


def test_write_results_files_and_atomic_replace(tmp_path: Path) -> None:
    rows = hand_rows()
    rows[0]["train_seconds"] = 1.5  # a column only some rows have still reaches the CSV
    summary = summarize(rows)
    config = {"protocol": "kt3d-test", "frames": 5}
    out = tmp_path / "res"
    table = write_results(out, rows, summary, config)
    assert table == format_table(rows, summary)
    assert sorted(p.name for p in out.iterdir()) == ["results.csv", "results.json", "results.md"]
    data = json.loads((out / "results.json").read_text())
    assert data == {"config": config, "summary": summary, "rows": rows}
    with (out / "results.csv").open() as f:
        read = list(csv.DictReader(f))
    assert [r["name"] for r in read] == ["a", "b", "c", "d"]
    assert [float(r["error"]) for r in read] == [0.1, 0.4, 0.0, 0.9]
    assert read[0]["train_seconds"] == "1.5" and read[1]["train_seconds"] == ""
    md = (out / "results.md").read_text()
    assert md.startswith("# kt3d-test\n") and '"frames": 5' in md and md.endswith(table)
    # A write that fails half-way (a row json cannot store) leaves the earlier results whole, no temp files.
    with pytest.raises(TypeError):
        write_results(out, [{"name": "bad", "error": object()}], {}, config, table="x")
    assert json.loads((out / "results.json").read_text()) == data
    assert sorted(p.name for p in out.iterdir()) == ["results.csv", "results.json", "results.md"]
    # A custom table is written as given.
    write_results(out, rows, summary, {"protocol": "rendered"}, table="custom table\n")
    assert (out / "results.md").read_text().endswith("custom table\n")


# ---------------------------------------------------------------------------------------------
# run_protocol: test-only protocols and leave-one-out resume
# ---------------------------------------------------------------------------------------------


@pytest.fixture()
def fake_data(monkeypatch: pytest.MonkeyPatch) -> list[tuple[tuple[Any, ...], tuple[str, ...]]]:
    """Two tiny test clips and a synthetic training sampler instead of the benchmark data.

    Returns the list of (sources, exclude) that build_sampler was called with.
    """
    rng = np.random.default_rng(5)
    clips = [separated_clip(rng, "pairA"), separated_clip(rng, "pairB", sizes=(10, 10, 10))]
    for name in ("adelaide-loo", "adelaide-test"):
        monkeypatch.setitem(PROTOCOLS, name, replace(PROTOCOLS[name], load_clips=lambda root, frames: clips))
    calls: list[tuple[tuple[Any, ...], tuple[str, ...]]] = []

    def build_sampler(sources: Any, data_root: Any, frames: int, exclude: Any = (), seed: int = 0) -> Any:
        assert frames == 2
        calls.append((tuple(sources), tuple(exclude)))
        return toy_sampler, {"toy": {"weight": 1.0, "excluded": sorted(exclude)}}

    monkeypatch.setattr(training_run, "build_sampler", build_sampler)
    return calls


def run_named(cfg: EvalConfig, *args: Any, **kwargs: Any) -> Any:
    """run_protocol with the registry's record of cfg.protocol, as protocols.run_benchmark passes it."""
    return run_protocol(get_protocol(cfg.protocol), cfg, *args, **kwargs)


def loo_config(**kw: Any) -> EvalConfig:
    base = EvalConfig(
        protocol="adelaide-loo", frames=2, baselines=(), train=TrainConfig(frames=2, steps=3, batch_size=2, warmup=0)
    )
    return replace(base, **kw)


def _no_training(*_a: Any, **_k: Any) -> Any:
    raise AssertionError("train_model was called although the fold was stored")


def _errors(rows: list[dict[str, Any]]) -> list[tuple[Any, ...]]:
    return [(r["name"], r["k_pred"], r["error"], r["error_true_k"], r["nmi"], r["train_seconds"]) for r in rows]


@pytest.mark.slow
def test_run_protocol_loo_saves_folds_and_resumes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, fake_data: list[Any]
) -> None:
    out = tmp_path / "out"
    init = tiny_model()
    said: list[str] = []
    rows, summary, table = run_named(loo_config(), tmp_path, out, init=init, progress=said.append)
    assert [r["name"] for r in rows] == ["pairA", "pairB"]
    assert fake_data == [((("adelaide", 1.0),), ("pairA",)), ((("adelaide", 1.0),), ("pairB",))]
    assert (
        len(said) == 2 and said[0].startswith("pairA: trained 3 steps") and said[1].startswith("pairB: trained 3 steps")
    )
    for name in ("pairA", "pairB"):
        stored = json.loads((out / "folds" / f"{name}.json").read_text())
        assert set(stored) == {"config_hash", "recipe", "rows"}
        assert stored["recipe"]["steps_done"] == 3 and stored["rows"][0]["name"] == name
        fold_model = SubspaceNet.from_checkpoint(out / "folds" / f"{name}.pt")
        assert fold_model.recipe["name"] == f"adelaide-loo/{name}" and fold_model.cfg == TINY
    assert summary["num_clips"] == 2 and (out / "results.md").read_text().endswith(table)
    assert json.loads((out / "results.json").read_text())["config"]["init"] == "checkpoint"

    # Run again: nothing trains, both folds are re-scored from their checkpoints with identical results.
    monkeypatch.setattr(training_run, "train_model", _no_training)
    said.clear()
    rows2, _, _ = run_named(loo_config(), tmp_path, out, init=init, progress=said.append)
    assert said == ["pairA: trained earlier, re-scored", "pairB: trained earlier, re-scored"]
    assert _errors(rows2) == _errors(rows)
    assert len(fake_data) == 2

    # Other clustering settings and baselines do not invalidate the stored folds.
    said.clear()
    rows3, _, _ = run_named(
        loo_config(cluster=ClusterConfig(k_max=3), baselines=("kmeans-raw",)),
        tmp_path,
        out,
        init=init,
        progress=said.append,
    )
    assert all(m.endswith("re-scored") for m in said) and len(said) == 2
    assert all(r["k_pred"] <= 3 and "kmeans-raw@K" in r for r in rows3)


def test_run_protocol_loo_retrains_when_training_changes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, fake_data: list[Any]
) -> None:
    out = tmp_path / "out"
    init = tiny_model()
    run_named(loo_config(), tmp_path, out, init=init)
    trained: list[int] = []
    real = training_run.train_model

    def counting(sampler: Any, cfg: TrainConfig, *a: Any, **k: Any) -> Any:
        trained.append(cfg.steps)
        return real(sampler, cfg, *a, **k)

    monkeypatch.setattr(training_run, "train_model", counting)
    said: list[str] = []
    cfg = loo_config(train=TrainConfig(frames=2, steps=4, batch_size=2, warmup=0))
    run_named(cfg, tmp_path, out, init=init, progress=said.append)
    assert trained == [4, 4]
    assert len(said) == 2
    assert said[0].startswith("pairA: trained 4 steps") and said[1].startswith("pairB: trained 4 steps")
    assert json.loads((out / "folds" / "pairA.json").read_text())["recipe"]["steps_done"] == 4
    # A different starting point is a different training too.
    trained.clear()
    run_named(cfg, tmp_path, out, init=None)
    assert trained == [4, 4]


def test_run_protocol_folds_filter(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, fake_data: list[Any]) -> None:
    rows, _, _ = run_named(loo_config(folds=("pairB",)), tmp_path, tmp_path / "out", init=tiny_model())
    assert [r["name"] for r in rows] == ["pairB"] and [c[1] for c in fake_data] == [("pairB",)]
    with pytest.raises(ValueError, match="no test clip matches --folds"):
        run_named(loo_config(folds=("nope",)), tmp_path, tmp_path / "out")


def test_run_protocol_full_run_reuses_folds_of_a_partial_run(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, fake_data: list[Any]
) -> None:
    out = tmp_path / "out"
    init = tiny_model()
    run_named(loo_config(folds=("pairA",)), tmp_path, out, init=init)
    said: list[str] = []
    run_named(loo_config(), tmp_path, out, init=init, progress=said.append)
    assert said[0] == "pairA: trained earlier, re-scored"


def test_run_protocol_fold_recipe_records_trained_frames(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, fake_data: list[Any]
) -> None:
    cfg = loo_config(train=TrainConfig(steps=2, batch_size=2), folds=("pairA",))  # TrainConfig.frames defaults to 5
    run_named(cfg, tmp_path, tmp_path / "out", init=tiny_model())
    model = SubspaceNet.from_checkpoint(tmp_path / "out" / "folds" / "pairA.pt")
    assert model.recipe["train_config"]["frames"] == model.cfg.in_dim // 2 == 2


def test_run_protocol_test_protocol(tmp_path: Path, fake_data: list[Any]) -> None:
    cfg = EvalConfig(protocol="adelaide-test", frames=2, baselines=("kmeans-raw",))
    rows, summary, _ = run_named(cfg, tmp_path, tmp_path / "out", model=tiny_model())
    assert [r["name"] for r in rows] == ["pairA", "pairB"] and fake_data == []  # no training
    assert not (tmp_path / "out" / "folds").exists()
    assert summary["kmeans-raw@K"] == {"mean": 0.0, "median": 0.0}
    with pytest.raises(ValueError, match="needs a model"):
        run_named(cfg, tmp_path, tmp_path / "out")
    with pytest.raises(ValueError, match="unknown protocol 'nope'"):
        run_named(EvalConfig(protocol="nope"), tmp_path, tmp_path / "out")
    with pytest.raises(ValueError, match="record of 'adelaide-loo' given for protocol 'adelaide-test'"):
        run_protocol(get_protocol("adelaide-loo"), cfg, tmp_path, tmp_path / "out", model=tiny_model())


# ---------------------------------------------------------------------------------------------
# moseg eval
# ---------------------------------------------------------------------------------------------


def test_cli_eval_unknown_protocol_one_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    result = CliRunner(env={"COLUMNS": "200"}).invoke(app, ["eval", "nope", "--out", "d"])
    assert result.exit_code == 2  # a usage error: PROTOCOL is a choice (an Enum) of the registry's names
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("moseg: error: PROTOCOL: 'nope' is not one of 'kt3d-test'")
    assert "kt3d-loo" in lines[0]
    assert not (tmp_path / "d").exists()


def test_run_protocol_loo_retrains_folds_of_a_redefined_loss(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, fake_data: list[Any]
) -> None:
    from mosegpipe.training import losses

    out = tmp_path / "out"
    cfg = loo_config(train=TrainConfig(frames=2, steps=2, batch_size=2, warmup=0, loss="mimi"))
    run_named(cfg, tmp_path, out, init=None)
    said: list[str] = []
    run_named(cfg, tmp_path, out, init=None, progress=said.append)
    assert all(m.endswith("re-scored") for m in said) and len(said) == 2
    # Fold models trained under an earlier definition of the loss are trained again.
    monkeypatch.setitem(losses.LOSS_REVISIONS, "mimi", losses.LOSS_REVISIONS["mimi"] + 1)
    said.clear()
    run_named(cfg, tmp_path, out, init=None, progress=said.append)
    assert len(said) == 2 and all(" trained 2 steps" in m for m in said)
