from __future__ import annotations

import dataclasses
import json
from collections.abc import Collection
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from mosegpipe.embed.model import ModelConfig
from mosegpipe.errors import ConfigError
from mosegpipe.studies import STUDIES, StudyRequest, get_study
from mosegpipe.studies import training as st
from mosegpipe.training import recipes
from mosegpipe.types import LabeledClip


def _clip(name: str, seed: int, per: int = 10) -> LabeledClip:
    """A two-view clip (N, 4) of two well separated blobs of trajectories."""
    rng = np.random.default_rng(seed)
    centres = np.array([[0, 0, 0, 0], [50, 0, 60, 5]], dtype=np.float64)
    traj = np.concatenate([c + rng.standard_normal((per, 4)) for c in centres]).astype(np.float32)
    return LabeledClip(name, traj, np.repeat(np.arange(2), per).astype(np.int64), "test")


def test_weak_labels_keep_a_fixed_share_per_clip_and_seed() -> None:
    clip = _clip("pairA", 0, per=25)
    clip = dataclasses.replace(clip, labels=np.where(np.arange(50) < 5, -1, clip.labels))  # 45 labelled
    weak = st.weak_labels(clip, 0.4, seed=0)
    assert int((weak.labels >= 0).sum()) == 18  # round(0.4 * 45)
    kept = weak.labels >= 0
    assert np.array_equal(weak.labels[kept], clip.labels[kept]) and not kept[:5].any()
    assert np.array_equal(weak.traj, clip.traj)
    assert np.array_equal(st.weak_labels(clip, 0.4, seed=0).labels, weak.labels)  # the same every draw
    assert not np.array_equal(st.weak_labels(clip, 0.4, seed=1).labels, weak.labels)  # another trial
    other = st.weak_labels(dataclasses.replace(clip, name="pairB"), 0.4, seed=0)
    assert not np.array_equal(other.labels, weak.labels)  # another clip
    assert st.weak_labels(clip, 1.0, seed=3) is clip
    assert int((st.weak_labels(clip, 0.001, seed=0).labels >= 0).sum()) == 1
    with pytest.raises(ConfigError, match="label_fraction"):
        st.Variant("none", label_fraction=0.0)


def test_folds_hold_out_every_clip_exactly_once() -> None:
    clips = [_clip(n, i) for i, n in enumerate("abcde")]
    data = st.StudyData("adelaidermf", 2, (("adelaide", 1.0),), ModelConfig(in_dim=4))
    two = st.make_folds(clips, data, st.TrainingBudget(steps=1))
    assert two == [("even", ["a", "c", "e"]), ("odd", ["b", "d"])]
    loo = st.make_folds(clips, data, st.TrainingBudget(steps=1, folds="loo"))
    assert loo == [(n, [n]) for n in "abcde"]
    split = dataclasses.replace(data, folds_by_name=False)
    assert st.make_folds(clips, split, st.TrainingBudget(steps=1)) == [("split", [])]


def test_summarize_variants_hand_computed() -> None:
    def rows(*errs: float) -> list[dict[str, Any]]:
        return [
            {"error": e, "error_true_k": e / 2, "k_pred": 2, "k_true": 2 if e < 0.3 else 3, "nmi": 0.5} for e in errs
        ]

    parts = [
        {"dataset": "d", "variant": "v", "trial": 0, "rows": rows(0.1, 0.3), "train_seconds": 10.0},
        {"dataset": "d", "variant": "v", "trial": 1, "rows": rows(0.5, 0.1), "train_seconds": 20.0},
    ]
    s = st.summarize_variants(parts)["d"]["v"]
    # Trial means 0.2 and 0.3: mean 25 %, population std 5 %; true K halves; correct K 1/2 in both trials.
    assert s == {
        "mean": 25.0,
        "std": 5.0,
        "true_k": 12.5,
        "correct_k": 50.0,
        "nmi": 0.5,
        "clips": 2,
        "trials": 2,
        "train_seconds": 15.0,
    }


def test_every_registered_variant_builds_on_its_datasets() -> None:
    datasets = st.load_datasets()
    for name, (_paper, _desc, spec) in st.TRAINING_STUDIES.items():
        assert name in STUDIES and set(spec.budgets) == {"cpu", "full"}
        for variant in spec.variants:
            for d in spec.datasets:
                cfg = dataclasses.replace(datasets[d].model, **dict(variant.model))
                assert cfg.in_dim == 2 * datasets[d].frames
    assert {v.model for v in st.NETWORK_STUDY.variants} == {
        (("arch", a),) for a in ("subspacenet", "pointnet", "corresnet")
    }
    assert [v.x for v in st.DIM_STUDY.variants] == [3, 4, 5, 6, 7]


def test_training_study_trains_per_fold_without_its_test_clips_and_resumes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    test = [_clip(n, i) for i, n in enumerate(["pairA", "pairB", "pairC"])]
    pool = [*test, _clip("pairD", 7), _clip("pairE", 8)]
    excluded: list[set[str]] = []

    def fake_source_clips(source: str, root: Any, frames: int, exclude: Collection[str] = ()) -> list[LabeledClip]:
        assert source == "adelaide" and frames == 2
        excluded.append(set(exclude))
        return [c for c in pool if c.name not in set(exclude)]

    data = st.StudyData("adelaidermf", 2, (("adelaide", 1.0),), ModelConfig(in_dim=4, width=8, num_blocks=1))
    monkeypatch.setattr(recipes, "source_clips", fake_source_clips)
    monkeypatch.setattr(st, "load_datasets", lambda: {"adelaidermf": data})
    monkeypatch.setattr(st, "scored_clips", lambda data, root, budget: test)
    spec = st.TrainingStudy(
        "tiny",
        (st.Variant("L2", x=1), st.Variant("half labelled", label_fraction=0.5, x=2)),
        ("adelaidermf",),
        {"cpu": st.TrainingBudget(steps=3, trials=2), "full": st.TrainingBudget(steps=3, folds="loo")},
        x_label="x",
    )
    study = get_study("weak-supervision")
    req = StudyRequest(out_dir=tmp_path / "tiny", data_root=tmp_path)
    first = st.run_training_study(spec, study, req)
    # 2 variants x 2 folds x 2 trials, each fold trained without the clips it is scored on.
    assert len(first.results["parts"]) == 8 and len(list((tmp_path / "tiny" / "parts").iterdir())) == 8
    assert {frozenset(e) for e in excluded} == {frozenset({"pairA", "pairC"}), frozenset({"pairB"})}
    for part in first.results["parts"]:
        held_out = {"even": {"pairA", "pairC"}, "odd": {"pairB"}}[part["fold"]]
        assert {r["name"] for r in part["rows"]} == held_out
        assert all(0.0 <= r["error"] <= 1.0 for r in part["rows"])
    summary = first.results["summary"]["adelaidermf"]
    assert set(summary) == {"L2", "half labelled"} and summary["L2"]["clips"] == 3 and summary["L2"]["trials"] == 2
    assert "| L2 |" in first.table and "| half labelled |" in first.table and " ± " in first.table
    assert Image.open(tmp_path / "tiny" / "plot.png").format == "PNG"
    stored = json.loads((tmp_path / "tiny" / "results.json").read_text())
    assert stored["settings"]["steps"] == 3

    def boom(*args: Any, **kwargs: Any) -> None:
        raise AssertionError("retrained a finished part")

    monkeypatch.setattr(st, "train_and_score", boom)
    again = st.run_training_study(spec, study, req)
    assert again.results["summary"] == first.results["summary"]
    # Another number of steps is another model: its parts are trained again.
    longer = dataclasses.replace(spec, budgets={"cpu": st.TrainingBudget(steps=4)})
    with pytest.raises(AssertionError, match="retrained"):
        st.run_training_study(longer, study, req)


def test_a_redefined_loss_retrains_only_its_own_parts(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from mosegpipe.training import losses

    test = [_clip(n, i) for i, n in enumerate(["pairA", "pairB"])]
    data = st.StudyData("adelaidermf", 2, (("adelaide", 1.0),), ModelConfig(in_dim=4, width=8, num_blocks=1))
    monkeypatch.setattr(recipes, "source_clips", lambda source, root, frames, exclude=(): test)
    monkeypatch.setattr(st, "load_datasets", lambda: {"adelaidermf": data})
    monkeypatch.setattr(st, "scored_clips", lambda data, root, budget: test)
    spec = st.TrainingStudy(
        "tiny",
        (st.Variant("L2"), st.Variant("MIMI", loss="mimi")),
        ("adelaidermf",),
        {"cpu": st.TrainingBudget(steps=2), "full": st.TrainingBudget(steps=2, folds="loo")},
    )
    study = get_study("losses")
    req = StudyRequest(out_dir=tmp_path / "tiny", data_root=tmp_path)
    st.run_training_study(spec, study, req)
    trained: list[str] = []
    real = st.train_and_score

    def record(data: st.StudyData, variant: st.Variant, *args: Any, **kwargs: Any) -> dict[str, Any]:
        trained.append(variant.label)
        return real(data, variant, *args, **kwargs)

    monkeypatch.setattr(st, "train_and_score", record)
    st.run_training_study(spec, study, req)
    assert trained == []  # nothing changed: every part reused
    monkeypatch.setitem(losses.LOSS_REVISIONS, "mimi", losses.LOSS_REVISIONS["mimi"] + 1)
    st.run_training_study(spec, study, req)
    assert trained == ["MIMI", "MIMI"]  # both folds of the redefined loss, none of L2


def test_losses_study_compares_both_mimi_forms() -> None:
    assert {(v.label, v.loss) for v in st.LOSSES_STUDY.variants} >= {
        ("L2 regression", "l2"),
        ("MaxInterMinIntra", "mimi"),
        ("MaxInterMinIntra, worst point", "mimi-point"),
    }
