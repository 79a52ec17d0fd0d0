from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from mosegpipe.cli.main import app
from mosegpipe.errors import ConfigError
from mosegpipe.studies import registry
from mosegpipe.studies.registry import (
    STUDIES,
    StudyRequest,
    get_study,
    model_selection_rows,
    summarize_model_selection,
)
from mosegpipe.types import LabeledClip

from helpers import tiny_model

runner = CliRunner(env={"COLUMNS": "200"})


def _clip(name: str, centres: list[tuple[float, float, float, float]], per: int = 12, seed: int = 0) -> LabeledClip:
    """A 2-frame clip (N, 4) with one tight blob of trajectories per centre."""
    rng = np.random.default_rng(seed)
    traj = np.concatenate([np.asarray(c) + 0.05 * rng.standard_normal((per, 4)) for c in centres])
    labels = np.repeat(np.arange(len(centres)), per)
    return LabeledClip(name, traj.astype(np.float32), labels.astype(np.int64), "test")


def test_registry_records_are_complete() -> None:
    assert list(STUDIES) == [
        "model-selection",
        "tsne",
        "sampling-imbalance",
        "lce-curve",
        "losses",
        "weak-supervision",
        "embedding-dim",
        "networks",
        "depth",
    ]
    for study in STUDIES.values():
        assert set(study.budgets) == {"cpu", "full"} and study.paper and study.description
    with pytest.raises(ConfigError, match="model-selection"):
        get_study("losses-typo")


def test_model_selection_rows_on_separated_embeddings() -> None:
    clip = _clip("three", [(0, 0, 0, 0), (10, 0, 10, 0), (0, 10, 0, 10)])
    emb = np.repeat(np.eye(5)[:3], 12, axis=0) + 0.01 * np.random.default_rng(1).standard_normal((36, 5))
    rows = model_selection_rows(clip, emb, k_max=6)
    assert set(rows) == {"residual", "silhouette", "true K", "kmeans-raw", "spectral-raw", "ssc"}
    for rule in ("residual", "silhouette", "true K"):
        assert rows[rule] == {"k": 3, "error": 0.0}
    for name in ("kmeans-raw", "spectral-raw", "ssc"):
        assert 1 <= int(rows[name]["k"]) <= 8 and 0.0 <= float(rows[name]["error"]) <= 1.0
    # Embeddings all in one blob: both rules answer one motion -> 2/3 of the points misclassified.
    one = model_selection_rows(clip, np.tile([1.0, 0, 0, 0, 0], (36, 1)), k_max=6)
    assert one["residual"]["k"] == one["silhouette"]["k"] == 1
    assert one["residual"]["error"] == pytest.approx(2 / 3)


def test_summarize_model_selection_hand_computed() -> None:
    rows = [
        {"dataset": "a", "k_true": 2, "methods": {"r": {"k": 2, "error": 0.1}, "s": {"k": 3, "error": 0.4}}},
        {"dataset": "a", "k_true": 3, "methods": {"r": {"k": 3, "error": 0.0}, "s": {"k": 3, "error": 0.2}}},
        {"dataset": "a", "k_true": 4, "methods": {"r": {"k": 2, "error": 0.5}, "s": {"k": 4, "error": 0.0}}},
        {"dataset": "b", "k_true": 2, "methods": {"r": {"k": 1, "error": 0.5}}},
    ]
    summary = summarize_model_selection(rows)
    assert summary["a"]["r"] == {"mean": 20.0, "median": 10.0, "correct_k": 66.7, "clips": 3}
    assert summary["a"]["s"] == {"mean": 20.0, "median": 20.0, "correct_k": 66.7, "clips": 3}
    assert summary["b"] == {"r": {"mean": 50.0, "median": 50.0, "correct_k": 0.0, "clips": 1}}


@pytest.fixture
def fake_data(monkeypatch: pytest.MonkeyPatch) -> dict[str, list[LabeledClip]]:
    """Tiny two-view clips in place of the benchmarks and tiny random models in place of the shipped ones."""
    data = {
        "kt3dmoseg": [_clip("Seq001_Clip01/f1-5", [(0, 0, 0, 0), (10, 0, 10, 0)], seed=2)],
        "adelaidermf": [_clip("pairA", [(0, 0, 0, 0), (0, 9, 0, 9), (9, 9, 9, 9)], seed=3)],
    }
    monkeypatch.setattr(registry, "load_datasets", lambda root: data)
    monkeypatch.setattr(registry, "study_models", lambda req: (tiny_model(2, seed=0), tiny_model(2, seed=1)))
    return data


def test_model_selection_writes_outputs_and_resumes(
    tmp_path: Path, fake_data: dict[str, list[LabeledClip]], monkeypatch: pytest.MonkeyPatch
) -> None:
    study = get_study("model-selection")
    req = StudyRequest(out_dir=tmp_path / "ms", data_root=tmp_path, budget="full")
    first = study.run(study, req)
    assert "--budget cpu and full are the same" in first.table and "| residual |" in first.table
    results = json.loads((tmp_path / "ms" / "results.json").read_text())
    assert [r["name"] for r in results["rows"]] == ["Seq001_Clip01/f1-5", "pairA"]
    assert set(results["summary"]) == {"kt3dmoseg", "adelaidermf"}
    assert Image.open(tmp_path / "ms" / "plot.png").format == "PNG"
    assert len(list((tmp_path / "ms" / "parts").iterdir())) == 2

    # A re-run computes nothing (every part is stored) and writes the same table.
    def boom(*args: Any, **kwargs: Any) -> None:
        raise AssertionError("recomputed a finished part")

    monkeypatch.setattr(registry, "model_selection_rows", boom)
    assert study.run(study, req).table == first.table
    # Other settings make the stored parts stale: they are computed again.
    with pytest.raises(AssertionError, match="recomputed"):
        study.run(study, StudyRequest(out_dir=tmp_path / "ms", data_root=tmp_path, k_max=4))


def test_tsne_panels_resume_and_bad_clip(
    tmp_path: Path, fake_data: dict[str, list[LabeledClip]], monkeypatch: pytest.MonkeyPatch
) -> None:
    study = get_study("tsne")
    req = StudyRequest(out_dir=tmp_path / "ts", data_root=tmp_path, clips=("Seq001_Clip01", "pairA"))
    result = study.run(study, req)
    assert [c["name"] for c in result.results["clips"]] == ["Seq001_Clip01/f1-5", "pairA"]
    part = json.loads(next((tmp_path / "ts" / "parts").glob("adelaidermf__*")).read_text())["payload"]
    assert np.asarray(part["raw"]).shape == (36, 2) and np.asarray(part["embedding"]).shape == (36, 2)
    with Image.open(tmp_path / "ts" / "plot.png") as img:
        assert img.size == (560, 512)  # 80 dpi: two panels of 3.5 x 3.2 inches per clip, two clips
    monkeypatch.setattr(registry, "tsne_2d", lambda *a, **k: (_ for _ in ()).throw(AssertionError("recomputed")))
    study.run(study, req)  # both parts stored: no t-SNE runs
    with pytest.raises(ConfigError, match="--clips nope: no such"):
        study.run(study, StudyRequest(out_dir=tmp_path / "ts", data_root=tmp_path, clips=("nope",)))
    with pytest.raises(ConfigError, match="--budget"):
        study.run(study, StudyRequest(out_dir=tmp_path / "ts", data_root=tmp_path, budget="huge"))


def test_cli_study_errors_are_one_line(tmp_path: Path) -> None:
    result = runner.invoke(app, ["study", "nope", "--out", str(tmp_path / "x"), "--data-root", str(tmp_path)])
    assert result.exit_code == 2  # a usage error: NAME is a choice (an Enum) of the registry's names
    assert result.stderr.startswith("moseg: error:") and result.stderr.count("\n") == 1
    assert "model-selection" in result.stderr
    result = runner.invoke(
        app, ["study", "tsne", "--out", str(tmp_path / "x"), "--pair-model", str(tmp_path / "missing.pt")]
    )
    assert result.exit_code == 1 and "--pair-model" in result.stderr
    help_text = runner.invoke(app, ["study", "--help"]).stdout
    assert "Table 5" in help_text and "--budget" in help_text


def test_tsne_on_real_clip(tmp_path: Path, data_root: Path) -> None:
    study = get_study("tsne")
    out = tmp_path / "real"
    result = study.run(study, StudyRequest(out_dir=out, data_root=data_root, clips=("Seq070_Clip01",)))
    assert result.results["clips"][0]["num_points"] == 90 and result.results["clips"][0]["k_true"] == 2
    assert (out / "plot.png").stat().st_size < 200_000
