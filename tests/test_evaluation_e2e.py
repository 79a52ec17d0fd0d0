from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from mosegpipe.errors import ConfigError
from mosegpipe.evaluation import e2e, report
from mosegpipe.evaluation.label_transfer import nearest_within, transfer_labels
from mosegpipe.evaluation.protocols import PROTOCOLS, get_protocol
from mosegpipe.pipeline import PipelineConfig

from helpers import tiny_checkpoint, tiny_model

# ---------------------------------------------------------------- label transfer


def test_transfer_labels_nearest_within_radius() -> None:
    gt_xy = np.array([[0.0, 0.0], [10.0, 0.0], [50.0, 50.0]])
    gt_labels = np.array([2, 5, 7])
    ours = np.array(
        [
            [1.0, 0.0],  # 1 px from gt 0
            [8.0, 0.0],  # 2 px from gt 1, 8 px from gt 0
            [5.0, 0.0],  # 5 px from both: too far
            [10.0, 3.0],  # exactly at the radius: accepted
            [53.0, 50.1],  # just beyond the radius
        ]
    )
    out = transfer_labels(ours, gt_xy, gt_labels, max_dist_px=3.0)
    assert out.dtype == np.int64
    np.testing.assert_array_equal(out, [2, 5, -1, 5, -1])
    np.testing.assert_array_equal(nearest_within(ours, gt_xy, 3.0), [0, 1, -1, 1, -1])
    # A wider radius reaches the 5 px point (tie between equal distances: either neighbour).
    assert transfer_labels(ours[2:3], gt_xy, gt_labels, max_dist_px=5.0)[0] in (2, 5)


def test_transfer_labels_empty_and_bad_inputs() -> None:
    np.testing.assert_array_equal(transfer_labels(np.zeros((3, 2)), np.zeros((0, 2)), np.zeros(0, np.int64)), [-1] * 3)
    assert transfer_labels(np.zeros((0, 2)), np.zeros((2, 2)), np.array([0, 1])).shape == (0,)
    with pytest.raises(ValueError, match="non-negative"):
        transfer_labels(np.zeros((1, 2)), np.zeros((1, 2)), np.array([-1]))
    with pytest.raises(ValueError, match="shape"):
        transfer_labels(np.zeros((1, 3)), np.zeros((1, 2)), np.array([0]))
    with pytest.raises(ValueError, match=r"gt_labels has shape \(2,\)"):
        transfer_labels(np.zeros((1, 2)), np.zeros((1, 2)), np.array([0, 1]))


def test_outliers_become_one_more_group() -> None:
    out = e2e._with_outlier_group(np.array([0, -1, 1, -1, 0]))
    np.testing.assert_array_equal(out, [0, 2, 1, 2, 0])
    np.testing.assert_array_equal(e2e._with_outlier_group(np.array([-1, -1])), [0, 0])


# ---------------------------------------------------------------- rows and tables


def test_summary_and_table_leave_unscored_rows_out() -> None:
    rows = [
        {"name": "a", "num_scored": 10, "k_true": 2, "k_pred": 2, "error": 0.1, "seconds": 0.5},
        {"name": "b", "num_scored": 20, "k_true": 3, "k_pred": 2, "error": 0.3, "seconds": 0.25},
        {"name": "c", "num_scored": 0, "k_true": 0, "k_pred": 0, "error": float("nan"), "seconds": 0.0},
    ]
    s = report.summarize_rows(rows)
    assert s["num_rows"] == 3 and s["num_unscored"] == 1
    assert s["error"] == {"mean": pytest.approx(0.2), "median": pytest.approx(0.2)}
    assert s["correct_k"] == 0.5
    assert s["seconds_total"] == 0.75
    table = report.format_rows(rows)
    assert "| a | 10 | 2 | 2 | 10.00 | 500 |" in table
    assert "| c | 0 | 0 | 0 | – | 0 |" in table
    assert "| **mean** | 15.0 | 2.5 | 2.0 | 20.00 | 375 |" in table
    assert "1 not scored" in table
    assert report.format_rows([]) == "(no rows)\n"
    # kt3d-video's rows also count the motions that enough scored tracks carry
    seen = [{**r, "k_true_5": k} for r, k in zip(rows, (2, 2, 0))]
    assert report.summarize_rows(seen)["correct_k_5"] == 1.0 and "correct_k_5" not in s
    assert "against the motions of 5 scored tracks or more 100.0 %" in report.format_rows(seen)


def test_motions_seen_counts_the_motions_enough_scored_tracks_carry() -> None:
    from mosegpipe.evaluation.e2e import motions_seen

    gt = np.array([0] * 40 + [1] * 5 + [2] * 2 + [3] * 1)  # the last two: a far car, a stray transfer
    assert motions_seen(gt) == 2 and motions_seen(gt, least=1) == 4 and motions_seen(np.zeros(0, np.int64)) == 0


def test_protocol_registry() -> None:
    shipped = ["kt3d-test", "kt3d-loo", "adelaide-test", "adelaide-loo", "hopkins-test", "lce"]
    end_to_end = ["kt3d-video", "adelaide-pairs", "rendered"]
    names = list(PROTOCOLS)
    assert [n for n in names if n in shipped + end_to_end] == shipped + end_to_end  # more may follow
    assert {n for n in end_to_end} <= {p.name for p in PROTOCOLS.values() if p.kind == "end-to-end"}
    for p in PROTOCOLS.values():
        assert callable(p.run) and p.description and p.default_frames >= 1
        assert (p.load_clips is not None) == (p.kind == "benchmark")
        # an end-to-end protocol scores rows of its end_to_end function, or has a runner of its own (davis, composite)
        assert p.end_to_end is None or p.kind == "end-to-end"
        assert p.end_to_end is not None or p.kind == "benchmark" or p.name.startswith(("davis", "composite"))
    assert {"kt3d-loo", "adelaide-loo", "lce"} <= {p.name for p in PROTOCOLS.values() if not p.is_test_only}
    with pytest.raises(ConfigError, match="unknown protocol 'kitti'; choose from kt3d-test, kt3d-loo"):
        get_protocol("kitti")


def test_rendered_rows_tiny_run() -> None:
    rows = e2e.rendered_rows(tiny_model(5), PipelineConfig(), seeds=[0], size_hw=(240, 320), warmup=False)
    assert len(rows) == 1
    row = rows[0]
    assert list(row) == [
        "seed",
        "camera",
        "num_tracks",
        "k_true",
        "k_pred",
        "track_error",
        "J",
        "F",
        "J_oracle",
        "F_oracle",
        "seconds",
    ]
    assert row["seed"] == 0 and row["camera"] == "static"
    assert row["num_tracks"] >= 50
    assert row["k_true"] == 2  # seed 0: one object and the background
    assert 1 <= row["k_pred"] <= 8
    for key in ("track_error", "J", "F", "J_oracle", "F_oracle"):
        assert 0.0 <= row[key] <= 1.0
    # Ground-truth labels on the same tracks beat an untrained model's clusters.
    assert row["J_oracle"] > 0.5 and row["J_oracle"] >= row["J"]
    assert row["seconds"] > 0
    assert e2e.rendered_config(5).num_objects == 3 and e2e.rendered_config(5).camera_motion == "pan"


# ---------------------------------------------------------------- real data (skipped without it)


def test_kt3d_video_one_sequence(data_root: Path) -> None:
    rows = e2e.kt3d_video_rows(data_root, tiny_model(5), PipelineConfig(), names=["Seq009_Clip01"], warmup=False)
    (row,) = rows
    assert row["name"] == "Seq009_Clip01"
    assert 0 < row["num_scored"] < row["num_tracks"]
    assert 1 <= row["k_true"] <= 5 and 0.0 <= row["error"] <= 1.0
    # The ground truth lies on integer pixels and our corners are sub-pixel: nothing within 0 px.
    (none,) = e2e.kt3d_video_rows(data_root, tiny_model(5), names=["Seq009_Clip01"], max_dist_px=0.0, warmup=False)
    assert none["num_scored"] == 0 and math.isnan(none["error"])


def test_adelaide_one_pair(data_root: Path) -> None:
    (row,) = e2e.adelaide_pair_rows(data_root, tiny_model(2), names=["breadcube"], warmup=False)
    assert row["name"] == "breadcube"
    assert 0 < row["num_scored"] < row["num_matches"]
    assert row["k_true"] >= 1 and 0.0 <= row["error"] <= 1.0


def test_end_to_end_loo_excludes_the_held_out_sequence_and_resumes(
    data_root: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from mosegpipe.evaluation.protocols import EvalRequest
    from mosegpipe.training import run
    from mosegpipe.training.loop import TrainResult

    calls: list[tuple[tuple[str, float], ...]] = []
    excluded: list[tuple[str, ...]] = []

    def fake_train(sources, data_root, cfg, model_cfg=None, init=None, exclude=(), **kw):  # type: ignore[no-untyped-def]
        calls.append(tuple(sources))
        excluded.append(tuple(exclude))
        return TrainResult(model=tiny_model(5), seconds=0.1, steps_done=cfg.steps), {"steps": cfg.steps}

    monkeypatch.setattr(run, "train_sources", fake_train)
    proto = get_protocol("kt3d-video-loo")
    init = tiny_checkpoint(tmp_path / "init.pt", 5)
    req = EvalRequest(
        out_dir=tmp_path / "out",
        data_root=data_root,
        init=init,
        steps=3,
        baselines=("kmeans-raw",),
        folds=("Seq009_Clip01",),
    )
    first = proto.run(proto, req)
    assert excluded == [("Seq009_Clip01",)] and dict(calls[0])["kt3d-own"] > 0
    (row,) = first.rows
    assert row["name"] == "Seq009_Clip01" and row["num_scored"] > 0 and "kmeans-raw@K" in row and "error_true_k" in row
    assert (tmp_path / "out" / "folds" / "Seq009_Clip01.pt").is_file() and (tmp_path / "out" / "results.json").is_file()
    # Other clustering settings re-score the stored fold; other training settings train again.
    from dataclasses import replace

    proto.run(proto, replace(req, k_method="residual"))
    assert len(calls) == 1
    proto.run(proto, replace(req, steps=4))
    assert len(calls) == 2
    with pytest.raises(ConfigError, match="not in kt3d-video-loo"):
        proto.run(proto, replace(req, folds=("NoSuchSequence",)))
    # Another recipe: its sources train (and the stored folds of the shipped recipe are not reused).
    proto.run(proto, replace(req, recipe="clip-f5-rendered"))
    assert len(calls) == 3 and dict(calls[-1])["rendered-own"] > 0
    with pytest.raises(ConfigError, match="needs 5 frames"):
        proto.run(proto, replace(req, recipe="pair-f2"))
