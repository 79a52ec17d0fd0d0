from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from PIL import Image
from typer.testing import CliRunner

from mosegpipe.cli.main import app
from mosegpipe.embed.model import SubspaceNet
from mosegpipe.evaluation.metrics import misclassification_error
from mosegpipe.group.cluster import ClusterConfig, cluster_auto_k
from mosegpipe.studies import STUDIES, StudyRequest, get_study
from mosegpipe.studies import imbalance as study_imbalance
from mosegpipe.studies.imbalance import IMBALANCE_BUDGETS, ImbalanceBudget, summarize_imbalance
from mosegpipe.studies.ransac_curves import RansacConfig, sequential_ransac
from mosegpipe.synth.lce import SingleKindDataset

runner = CliRunner(env={"COLUMNS": "200"})

# Two test problems per (kind, K) and a one-block network trained for two steps: the numbers are poor, the
# bookkeeping is the point (every (kind, K) cell computed from the right samples and stored for a re-run).
TINY = ImbalanceBudget(num_train=40, num_test=2, steps=2, batch_size=2, num_blocks=1, width=8)


def _boom(what: str) -> Any:
    def fail(*args: Any, **kwargs: Any) -> None:
        raise AssertionError(f"{what} a finished part")

    return fail


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Any]:
    """The study run once on the TINY budget (three models, 15 test parts of two samples), K in 1..3."""
    out = tmp_path_factory.mktemp("imbalance") / "imb"
    with pytest.MonkeyPatch.context() as mp:
        mp.setitem(IMBALANCE_BUDGETS, "cpu", TINY)
        study = get_study("sampling-imbalance")
        return out, study.run(study, StudyRequest(out_dir=out, k_max=3))


def test_registry_and_budgets() -> None:
    study = STUDIES["sampling-imbalance"]
    assert study.paper == "Figure 4" and not study.needs_data
    assert set(study.budgets) == {"cpu", "full"}
    assert "8000 training samples" in study.budgets["full"] and "200 test samples per K" in study.budgets["full"]
    assert "50 test samples per K" in study.budgets["cpu"]


def test_summary_hand_computed() -> None:
    rows = [
        {
            "k_true": 2,
            "k_pred": 2,
            "subspacenet_true_k": 0.1,
            "subspacenet_auto_k": 0.2,
            "ransac": 0.0,
            "ransac_hypotheses": 10,
        },
        {
            "k_true": 2,
            "k_pred": 3,
            "subspacenet_true_k": 0.3,
            "subspacenet_auto_k": 0.4,
            "ransac": 0.5,
            "ransac_hypotheses": 30,
        },
    ]
    summary = summarize_imbalance([{"kind": "line", "k": 2, "rows": rows}])
    assert summary == {
        "line": {
            "2": {
                "subspacenet_true_k": 20.0,
                "subspacenet_auto_k": 30.0,
                "ransac": 25.0,
                "correct_k": 50.0,
                "samples": 2,
                "ransac_hypotheses": 20.0,
            }
        }
    }


def test_tiny_run_table_and_results(tiny_run: tuple[Path, Any]) -> None:
    out, first = tiny_run
    # One row per K = 2..6 with nine error cells (three kinds x three methods), all percentages.
    rows = [line for line in first.table.splitlines() if line.startswith("| ") and line[2].isdigit()]
    error_rows = [r for r in rows if r.count("|") == 11]
    assert [r.split("|")[1].strip() for r in error_rows] == ["2", "3", "4", "5", "6"]
    for r in error_rows:
        cells = [float(c) for c in r.split("|")[2:-1]]
        assert len(cells) == 9 and all(0.0 <= c <= 100.0 for c in cells)
    assert "Budget: cpu (per kind: 40 training samples" in first.table and "2 test samples per K" in first.table
    assert "threshold 2.5 sigma = 0.125" in first.table

    results = json.loads((out / "results.json").read_text())
    assert set(results["summary"]) == {"line", "circle", "ellipse"}
    assert all(set(results["summary"][kind]) == {"2", "3", "4", "5", "6"} for kind in results["summary"])
    assert len(results["parts"]) == 15
    for part in results["parts"]:
        assert len(part["rows"]) == 2 and {r["k_true"] for r in part["rows"]} == {part["k"]}
        for r in part["rows"]:
            assert all(0.0 <= r[m] <= 1.0 for m in ("subspacenet_true_k", "subspacenet_auto_k", "ransac"))
            assert 1 <= r["k_pred"] <= 3
    assert all(t["steps_done"] == 2 for t in results["training"].values())
    models = {p.name for p in (out / "parts").glob("model__*.pt")}
    assert models == {"model__line.pt", "model__circle.pt", "model__ellipse.pt"}
    with Image.open(out / "plot.png") as img:
        assert img.format == "PNG" and img.size == (768, 256)  # 80 dpi, three 3.2-inch panels


def test_tiny_run_numbers_are_those_of_the_stored_model_and_ransac(tiny_run: tuple[Path, Any]) -> None:
    out, first = tiny_run
    part = next(p for p in first.results["parts"] if p["kind"] == "ellipse" and p["k"] == 4)
    clips = list(SingleKindDataset("ellipse", 2, 4, seed=0, split="test/k4"))
    model = SubspaceNet.from_checkpoint(out / "parts" / "model__ellipse.pt")
    for i, (clip, row) in enumerate(zip(clips, part["rows"], strict=True)):
        assert row["name"] == clip.name and row["num_points"] == clip.num_points
        fit = sequential_ransac(clip.traj, "ellipse", 4, RansacConfig(seed=i))
        assert row["ransac"] == pytest.approx(misclassification_error(fit.labels, clip.labels))
        fixed = cluster_auto_k(model.embed(clip.traj), ClusterConfig(k_max=3), k=4)
        assert row["subspacenet_true_k"] == pytest.approx(misclassification_error(fixed.labels, clip.labels))
    cell = first.results["summary"]["ellipse"]["4"]
    assert cell["ransac"] == pytest.approx(round(50.0 * sum(r["ransac"] for r in part["rows"]), 2))


def test_resume_reuses_parts_and_redoes_stale_ones(tiny_run: tuple[Path, Any], monkeypatch: pytest.MonkeyPatch) -> None:
    out, first = tiny_run
    study = get_study("sampling-imbalance")
    monkeypatch.setitem(IMBALANCE_BUDGETS, "cpu", TINY)
    monkeypatch.setattr("mosegpipe.training.loop.train_model", _boom("retrained"))
    monkeypatch.setattr(study_imbalance, "imbalance_rows", _boom("recomputed"))
    # A re-run trains nothing and tests nothing: every part is stored.
    assert study.run(study, StudyRequest(out_dir=out, k_max=3)).table == first.table
    # Another K range for the automatic rule: the models are reused, the test parts are redone.
    with pytest.raises(AssertionError, match="recomputed"):
        study.run(study, StudyRequest(out_dir=out, k_max=2))
    # More training steps make the stored models stale: they are trained again.
    monkeypatch.setitem(IMBALANCE_BUDGETS, "cpu", ImbalanceBudget(40, 2, steps=3, batch_size=2, num_blocks=1, width=8))
    with pytest.raises(AssertionError, match="retrained"):
        study.run(study, StudyRequest(out_dir=out, k_max=3))


def test_cli_runs_without_data_root(tiny_run: tuple[Path, Any], monkeypatch: pytest.MonkeyPatch) -> None:
    out, first = tiny_run
    monkeypatch.setitem(IMBALANCE_BUDGETS, "cpu", TINY)
    monkeypatch.delenv("MOSEG_DATA", raising=False)
    monkeypatch.setattr(study_imbalance, "imbalance_rows", _boom("recomputed"))
    result = runner.invoke(app, ["study", "sampling-imbalance", "--out", str(out), "--k-max", "3"])
    assert result.exit_code == 0, result.output
    assert first.table in result.stdout and "plot.png" in result.stdout
