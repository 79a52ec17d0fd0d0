"""Geometric grouping (mosegpipe.group.geometric): planar motions, one motion, outliers, parallax, the config,
the pipeline option and its record in summary.json."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest

from mosegpipe.errors import InputError
from mosegpipe.evaluation.metrics import misclassification_error
from mosegpipe.group.geometric import GeometricConfig, group_geometric
from mosegpipe.pipeline import PipelineConfig

from helpers import moseg

ROOT = Path(__file__).resolve().parents[1]
SIZE_HW = (480, 640)
FRAMES = 5


def _homography(rng: np.random.Generator, step: float) -> npt.NDArray[np.float64]:
    """A random small projective motion per frame: shift of about `step` px, slight rotation and scale."""
    angle = rng.uniform(-0.01, 0.01)
    scale = 1 + rng.uniform(-0.01, 0.01)
    c, s = scale * np.cos(angle), scale * np.sin(angle)
    shift = rng.normal(size=2)
    shift *= step / np.linalg.norm(shift)
    return np.array([[c, -s, shift[0]], [s, c, shift[1]], [rng.uniform(-1e-5, 1e-5), rng.uniform(-1e-5, 1e-5), 1]])


def _planar(
    rng: np.random.Generator, n: int, box: tuple[float, float, float, float], step: float
) -> npt.NDArray[np.float64]:
    """(n, 2F) tracks of points in `box` (x0, y0, x1, y1) moving under one homography per frame, 0.3 px noise."""
    h = _homography(rng, step)
    pts = np.c_[rng.uniform(box[0], box[2], n), rng.uniform(box[1], box[3], n)]
    out = [pts]
    for _ in range(FRAMES - 1):
        p = np.c_[out[-1], np.ones(n)] @ h.T
        out.append(p[:, :2] / p[:, 2:])
    xy = np.stack(out, axis=1) + rng.normal(0, 0.3, (n, FRAMES, 2))
    return xy.reshape(n, -1)


def _scenes(motions: int, seed: int = 0) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.int64]]:
    """A background (600 tracks over the image) and motions - 1 objects (120 tracks each) in boxes of their own."""
    rng = np.random.default_rng(seed)
    parts = [_planar(rng, 600, (0, 0, 640, 480), 3.0)]
    boxes = [(50, 50, 250, 200), (350, 250, 600, 450), (400, 40, 600, 200)]
    parts += [_planar(rng, 120, boxes[i], 8.0) for i in range(motions - 1)]
    labels = np.concatenate([np.full(len(p), i) for i, p in enumerate(parts)])
    return np.concatenate(parts).astype(np.float32), labels


@pytest.mark.parametrize("motions", [2, 3])
def test_planar_motions_are_recovered_with_automatic_and_given_k(motions: int) -> None:
    traj, truth = _scenes(motions)
    auto = group_geometric(traj, SIZE_HW)
    assert auto.method == "geometric"
    assert auto.k == motions
    assert misclassification_error(auto.labels, truth) < 0.02
    assert np.bincount(auto.labels).argmax() == 0  # label 0: the background, the largest group
    given = group_geometric(traj, SIZE_HW, k=motions)
    assert given.k == motions
    assert misclassification_error(given.labels, truth) < 0.02
    assert all(0 < share <= 1 for share in auto.scores.values())


def test_a_single_motion_is_one_group_and_k_given_still_splits() -> None:
    traj, _ = _scenes(1)
    assert group_geometric(traj, SIZE_HW).k == 1
    assert group_geometric(traj, SIZE_HW, k=2).k == 2  # exactly k, even when the data has one motion


def test_outlier_tracks_make_no_group() -> None:
    traj, truth = _scenes(2, seed=1)
    rng = np.random.default_rng(5)
    n_out = 15  # 2 % of the tracks: each jumps at random
    start = rng.uniform(0, 480, (n_out, 1, 2))
    wild = (start + np.cumsum(rng.normal(0, 6, (n_out, FRAMES, 2)), axis=1)).reshape(n_out, -1)
    result = group_geometric(np.r_[traj, wild.astype(np.float32)], SIZE_HW)
    assert result.k == 2
    assert misclassification_error(result.labels[: len(truth)], truth) < 0.02
    assert set(np.unique(result.labels)) == {0, 1}  # the outliers joined a group: every track is labelled


def test_a_static_3d_scene_under_camera_translation_is_one_group() -> None:
    """Random depths seen by a translating camera: parallax that no homography explains, one rigid motion."""
    rng = np.random.default_rng(2)
    n, focal = 800, 500.0
    world = np.c_[rng.uniform(-4, 4, n), rng.uniform(-3, 3, n), rng.uniform(4, 20, n)]
    xy = []
    for t in range(FRAMES):
        cam = world - np.array([0.08 * t, 0.02 * t, 0.1 * t])  # sideways, up and forwards
        xy.append(focal * cam[:, :2] / cam[:, 2:] + np.array([320.0, 240.0]))
    traj = (np.stack(xy, axis=1) + rng.normal(0, 0.3, (n, FRAMES, 2))).reshape(n, -1)
    keep = np.all((traj >= 0) & (traj < 640), axis=1)
    result = group_geometric(traj[keep], SIZE_HW)
    assert result.k == 1, result
    assert result.note == "models: fundamental"


@pytest.mark.parametrize(
    "bad",
    [
        {"residual_px": 0.0},
        {"min_group": 0},
        {"min_share": 1.0},
        {"k_max": 0},
        {"homography_ratio": 1.5},
        {"planar_share": 0.0},
        {"ransac_iters": 0},
        {"confidence": 1.0},
    ],
)
def test_config_refuses_bad_values_naming_them(bad: dict[str, float]) -> None:
    name = next(iter(bad))
    with pytest.raises(InputError, match=name):
        GeometricConfig(**bad)  # type: ignore[arg-type]


def test_bad_inputs_are_named() -> None:
    traj, _ = _scenes(2)
    with pytest.raises(InputError, match="2F"):
        group_geometric(traj[:, :3], SIZE_HW)
    with pytest.raises(InputError, match="k=0"):
        group_geometric(traj, SIZE_HW, k=0)
    with pytest.raises(InputError, match="NaN"):
        group_geometric(np.full((10, 10), np.nan), SIZE_HW)


def test_pipeline_config_method_and_older_summaries() -> None:
    from dataclasses import asdict

    assert PipelineConfig().method == "joint"
    assert PipelineConfig.from_dict(asdict(PipelineConfig())).method == "joint"
    old = asdict(PipelineConfig())
    del old["method"]  # a summary written before the methods existed: the embedding alone, as it ran
    assert PipelineConfig.from_dict(old) == PipelineConfig(method="subspacenet")
    assert PipelineConfig.from_dict({}).method == "subspacenet"
    del old["joint"]["merge_most_pairs"]  # a joint run before merges counted a track in most frame pairs
    assert not PipelineConfig.from_dict(old).joint.merge_most_pairs
    assert PipelineConfig().joint.merge_most_pairs
    assert PipelineConfig.from_dict({"method": "geometric"}).method == "geometric"
    cfg = PipelineConfig.from_dict({"method": "geometric", "geometric": {"residual_px": 2.0}})
    assert cfg.geometric.residual_px == 2.0
    with pytest.raises(InputError, match="method"):
        PipelineConfig(method="ransac")


def test_run_records_the_method_in_summary(tmp_path: Path) -> None:
    out = tmp_path / "geo"
    clip = ROOT / "samples" / "rendered" / "frames"
    code, stdout, stderr = moseg("run", clip, "--frames", "5", "--method", "geometric", "--no-rrd", "-o", out)
    assert code == 0, stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["config"]["method"] == "geometric"
    assert summary["k_method"] == "geometric"
    assert summary["k"] >= 2
    assert PipelineConfig.from_dict(summary["config"]).method == "geometric"


def test_a_default_run_records_joint_and_an_older_summary_replays_as_subspacenet(tmp_path: Path) -> None:
    out = tmp_path / "run"
    clip = ROOT / "samples" / "rendered" / "frames"
    code, _, stderr = moseg("run", clip, "--frames", "5", "--no-rrd", "-o", out)
    assert code == 0, stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["config"]["method"] == "joint"
    del summary["config"]["method"]  # as a summary written before the key was
    older = tmp_path / "older.json"
    older.write_text(json.dumps(summary))
    code, _, stderr = moseg("replay", older, "--no-rrd", "-o", tmp_path / "again")
    assert code == 0, stderr
    assert json.loads((tmp_path / "again" / "summary.json").read_text())["config"]["method"] == "subspacenet"


def test_geometric_segment_frames_gives_displacements_for_embeddings() -> None:
    from mosegpipe.io.read import read_video
    from mosegpipe.pipeline import segment_frames

    frames = read_video(ROOT / "samples" / "rendered" / "frames", max_frames=3)
    result = segment_frames(frames, PipelineConfig(frames=3, method="geometric"))
    n = result.trajectories.num_points
    assert result.embeddings.shape == (n, 4)
    assert result.clustering.method == "geometric"
    assert "embed" not in result.timings
