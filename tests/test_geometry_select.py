"""The joint grouping's model selection on hand-made tracks: merge, split, outliers left out."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from mosegpipe.errors import ConfigError
from mosegpipe.group.joint import (
    JointConfig,
    best_model,
    choose_partition,
    geometry_supported,
    select_models,
)
from mosegpipe.group.twoview import gric

FRAMES = 5
ROOT = Path(__file__).resolve().parents[1]


def _moving(
    rng: np.random.Generator,
    n: int,
    box: tuple[float, float, float, float],
    step: tuple[float, float],
    turn: float = 0.0,
) -> np.ndarray:
    """(n, 2F) tracks of points in box (x0, y0, x1, y1) moving by `step` px and turning by `turn` rad a frame."""
    x0, y0, x1, y1 = box
    p = np.c_[rng.uniform(x0, x1, n), rng.uniform(y0, y1, n)]
    centre = p.mean(axis=0)
    out = []
    for t in range(FRAMES):
        c, s = np.cos(turn * t), np.sin(turn * t)
        q = (p - centre) @ np.array([[c, s], [-s, c]]) + centre + np.array(step) * t
        out.append(q + rng.normal(0, 0.2, q.shape))
    return np.stack(out, axis=1).reshape(n, -1)


def test_two_motions_cut_in_three_are_merged() -> None:
    rng = np.random.default_rng(0)
    world = _moving(rng, 200, (0, 0, 640, 480), (0.0, 0.0))
    car = _moving(rng, 60, (300, 200, 400, 280), (6.0, 1.0))
    points = np.vstack([world, car])
    labels = np.r_[np.zeros(100, int), np.ones(100, int), np.full(60, 2)]  # K-means cut the world in two
    out, note = select_models(points, labels)
    assert "merged 1" in note
    assert len(np.unique(out[:200])) == 1 and len(np.unique(out[200:])) == 1 and out[0] != out[-1]


def test_a_piece_of_the_world_with_a_tracking_glitch_is_merged_back() -> None:
    rng = np.random.default_rng(6)
    world = _moving(rng, 200, (0, 0, 640, 480), (0.0, 0.0))
    piece = _moving(rng, 32, (500, 380, 600, 460), (0.0, 0.0))
    piece[:9, 8:10] += 5.0  # 9 of its 32 tracks slip in the last frame only: explained in most frame pairs
    car = _moving(rng, 60, (300, 200, 400, 280), (6.0, 1.0))
    labels = np.r_[np.zeros(200, int), np.ones(32, int), np.full(60, 2)]
    points = np.vstack([world, piece, car])
    out, note = select_models(points, labels)
    assert "merged 1" in note
    assert len(np.unique(out[:232])) == 1 and len(np.unique(out[232:])) == 1 and out[0] != out[-1]
    # counted in every frame pair, the union's model explains 23 / 32 < merge_share of the piece: kept apart
    out, note = select_models(points, labels, JointConfig(merge_most_pairs=False))
    assert "merged" not in note and len(np.unique(out)) == 3


def test_a_group_of_two_motions_is_split() -> None:
    rng = np.random.default_rng(1)
    world = _moving(rng, 300, (0, 0, 640, 480), (1.0, 0.0))
    one = _moving(rng, 60, (100, 100, 200, 180), (8.0, 0.0))
    two = _moving(rng, 50, (400, 300, 500, 380), (-2.0, 5.0), turn=0.03)
    points = np.vstack([world, one, two])
    labels = np.r_[np.zeros(300, int), np.ones(110, int)]
    out, note = select_models(points, labels)
    assert "split 1" in note
    assert len(np.unique(out[300:360])) == 1 and len(np.unique(out[360:])) == 1 and out[300] != out[-1]
    assert len(np.unique(out)) == 3


def test_tracks_no_model_explains_are_left_out() -> None:
    rng = np.random.default_rng(2)
    world = _moving(rng, 200, (0, 0, 640, 480), (0.0, 0.0))
    car = _moving(rng, 60, (300, 200, 400, 280), (6.0, 1.0))
    start = rng.uniform(0, 480, (8, 2))
    wild = np.cumsum(np.concatenate([start[:, None], rng.normal(0, 12, (8, FRAMES - 1, 2))], axis=1), axis=1)
    points = np.vstack([world, car, wild.reshape(8, -1)])
    labels = np.r_[np.zeros(200, int), np.ones(60, int), np.zeros(8, int)]
    out, note = select_models(points, labels, JointConfig(leave_out=True))
    assert np.all(out[260:] == -1) and "left out 8" in note
    assert np.all(out[:200] == 0) and np.all(out[200:260] == 1)
    kept, note = select_models(points, labels)  # the default: they keep their group
    assert np.all(kept == labels) and "left out" not in note


def test_a_track_of_another_groups_motion_moves_to_it() -> None:
    rng = np.random.default_rng(5)
    world = _moving(rng, 200, (0, 0, 640, 480), (0.0, 0.0))
    car = _moving(rng, 60, (300, 200, 400, 280), (6.0, 1.0))
    labels = np.r_[np.zeros(200, int), np.ones(60, int)]
    labels[200:205] = 0  # five of the car's tracks in the world's group
    out, note = select_models(np.vstack([world, car]), labels)
    assert np.all(out[200:] == 1) and np.all(out[:200] == 0) and "moved 5" in note


def test_a_group_no_rigid_model_explains_is_kept() -> None:
    rng = np.random.default_rng(3)
    world = _moving(rng, 200, (0, 0, 640, 480), (0.0, 0.0))
    start = rng.uniform(200, 300, (40, 2))
    limbs = np.cumsum(np.concatenate([start[:, None], rng.normal(0, 6, (40, FRAMES - 1, 2))], axis=1), axis=1)
    out, _ = select_models(np.vstack([world, limbs.reshape(40, -1)]), np.r_[np.zeros(200, int), np.ones(40, int)])
    assert np.all(out[200:] == 1) and np.all(out[:200] == 0)


def test_gric_prefers_the_plane_for_planar_points_and_the_matrix_for_depth() -> None:
    rng = np.random.default_rng(4)
    plane = _moving(rng, 100, (0, 0, 640, 480), (3.0, 0.0)).reshape(100, FRAMES, 2)
    model = best_model(plane)
    assert model is not None and model.kind != "fundamental" and model.share > 0.95
    # a camera moving sideways through points of many depths: displacement 1 / depth
    depth = rng.uniform(1, 10, 150)
    base = rng.uniform(0, 480, (150, 2))
    deep = np.stack(
        [base + np.c_[30.0 * t / depth, np.zeros(150)] + rng.normal(0, 0.2, (150, 2)) for t in range(FRAMES)], axis=1
    )
    model = best_model(deep)
    assert model is not None and model.kind == "fundamental"
    assert gric(np.zeros(10), 1.0, 2, 8) < gric(np.zeros(10), 1.0, 3, 7)


def test_config_is_checked() -> None:
    with pytest.raises(ConfigError, match="rigid_share"):
        JointConfig(rigid_share=0.0)
    with pytest.raises(ConfigError, match="outlier_px"):
        JointConfig(outlier_px=-1.0)


def test_joint_method_on_a_clip_and_a_whole_video(tmp_path: Path) -> None:
    from mosegpipe.apps.outputs import write_clip_outputs
    from mosegpipe.io.read import read_video
    from mosegpipe.pipeline import PipelineConfig, segment_frames, segment_video

    clip = ROOT / "samples" / "rendered" / "frames"
    frames = read_video(clip, max_frames=5)
    result = segment_frames(frames, PipelineConfig(frames=5, method="joint"))
    labels = result.clustering.labels
    assert result.clustering.k >= 2 and labels.max() == result.clustering.k - 1 and labels.min() >= -1
    assert "joint: models" in result.clustering.note
    # strict thresholds leave tracks out (-1): the outputs and whole videos take them
    strict = PipelineConfig(
        frames=5, method="joint", joint=JointConfig(outlier_px=0.05, residual_px=0.1, leave_out=True)
    )
    result = segment_frames(frames, strict)
    assert (result.clustering.labels == -1).any()
    summary = write_clip_outputs(result, tmp_path / "out", strict)
    assert sum(summary["tracks_per_motion"]) == (result.clustering.labels >= 0).sum()
    assert (tmp_path / "out" / "recording.rrd").is_file()
    windows = list(segment_video(clip, strict))
    assert windows and all(w.k >= 1 for w in windows)


def _movers_case(rng: np.random.Generator, second_step: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """(points, embeddings): a still world and two groups of movers, the second moving by `second_step`; the
    embedding puts the world at one place and the two movers near each other (two tight blobs)."""
    world = _moving(rng, 200, (0, 0, 640, 480), (0.0, 0.0))
    a = _moving(rng, 40, (100, 100, 200, 200), (5.0, 0.0))
    b = _moving(rng, 40, (400, 300, 500, 380), second_step)
    centres = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.1], [0.0, 1.0, -0.1]])
    emb = np.repeat(centres, [200, 40, 40], axis=0) + rng.normal(0, 0.01, (280, 3))
    return np.vstack([world, a, b]), emb / np.linalg.norm(emb, axis=1, keepdims=True)


def test_split_movers_separates_movers_the_clustering_joined() -> None:
    from mosegpipe.group.refine import split_movers
    from mosegpipe.pipeline import PipelineConfig
    from mosegpipe.types import Clustering

    rng = np.random.default_rng(3)
    points, emb = _movers_case(rng, (-4.0, 3.0))
    joined = Clustering(labels=np.repeat([0, 1], [200, 80]).astype(np.int64), k=2)
    off = split_movers(joined, emb, points, PipelineConfig())
    assert off is joined  # movers_k_max 1: off
    cfg = PipelineConfig().with_settings(["cluster.movers_k_max=4"])
    split = split_movers(joined, emb, points, cfg)
    assert split.k == 3 and (split.labels[:200] == 0).all()
    assert len(set(split.labels[200:240].tolist())) == 1 and len(set(split.labels[240:].tolist())) == 1
    assert split.labels[200] != split.labels[240] and "clustered again" in split.note
    # the same embedding, but both groups move as one: one rigid motion explains them, nothing is split
    points, emb = _movers_case(np.random.default_rng(3), (5.0, 0.0))
    assert split_movers(joined, emb, points, cfg) is joined
    assert split_movers(joined, emb, points, replace_k(cfg)) is joined  # K given: unchanged


def replace_k(cfg):  # type: ignore[no-untyped-def]
    return replace(cfg, k=2)


def _three_motions(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(points, embeddings) of a still world (200 tracks), a mover `a` (40) and a mover `b` (40, turning), on a poor
    embedding: `a` lies beside the world (0.15 apart, noise 0.03), `b` far from both."""
    world = _moving(rng, 200, (0, 0, 640, 480), (0.0, 0.0))
    a = _moving(rng, 40, (100, 100, 200, 200), (5.0, 0.0))
    b = _moving(rng, 40, (400, 300, 500, 380), (-3.0, 4.0), turn=0.02)
    centres = np.array([[1.0, 0.0, 0.0], [1.0, 0.15, 0.0], [0.0, 0.0, 1.0]])
    emb = np.repeat(centres, [200, 40, 40], axis=0) + rng.normal(0, 0.03, (280, 3))
    return np.vstack([world, a, b]), emb / np.linalg.norm(emb, axis=1, keepdims=True)


def test_k_by_gric_finds_the_three_motions_kmeans_joins_in_two() -> None:
    from mosegpipe.group.cluster import cluster_auto_k
    from mosegpipe.pipeline import PipelineConfig, check_rigid

    points, emb = _three_motions(np.random.default_rng(7))
    auto = cluster_auto_k(emb)
    assert auto.k == 2 and len(set(auto.labels[:240].tolist())) == 1  # the world and `a` in one group
    cfg = PipelineConfig(method="joint", joint=JointConfig(rigid_first=False, k_search=0))
    plain = check_rigid(auto, points.astype(np.float32), (480, 640), cfg, emb)
    assert plain.k == 2  # the model selection alone does not split the largest group (the world's)
    search = PipelineConfig(method="joint", joint=JointConfig(rigid_first=False, k_search=1))
    found = check_rigid(auto, points.astype(np.float32), (480, 640), search, emb)
    assert found.k == 3 and "K by GRIC: K-means with K = 3" in found.note
    assert [len(set(found.labels[s].tolist())) for s in (slice(0, 200), slice(200, 240), slice(240, 280))] == [1] * 3
    assert len({found.labels[0], found.labels[200], found.labels[240]}) == 3
    # a group must pay for itself: at a high enough cost per group automatic K stands (K is never lowered)
    dear = PipelineConfig(method="joint", joint=JointConfig(rigid_first=False, k_search=1, group_cost=1e5))
    assert check_rigid(auto, points.astype(np.float32), (480, 640), dear, emb).k == 2
    # K given: no search
    assert check_rigid(auto, points.astype(np.float32), (480, 640), replace_k(search), emb) is auto


def test_the_partition_score_charges_what_a_group_does_not_explain() -> None:
    points, _ = _three_motions(np.random.default_rng(8))
    truth = np.repeat([0, 1, 2], [200, 40, 40])
    joined = np.repeat([0, 0, 1], [200, 40, 40])
    best, labels, _, scores = choose_partition(points, [joined, truth])
    assert best == 1 and scores[1] < scores[0] and len(np.unique(labels)) == 3
    # the same candidate twice: the first is kept
    assert choose_partition(points, [truth, truth])[0] == 0
    with pytest.raises(ValueError):
        choose_partition(points, [])


def test_a_small_rigid_group_is_supported_and_a_loose_or_explained_one_is_not() -> None:
    rng = np.random.default_rng(9)
    world = _moving(rng, 600, (0, 0, 640, 480), (1.0, 0.0))
    small = _moving(rng, 12, (100, 100, 130, 130), (6.0, 2.0))
    still = _moving(rng, 12, (300, 300, 330, 330), (1.0, 0.0))  # moves with the world: its model explains it
    start = rng.uniform(400, 440, (12, 2))
    loose = np.cumsum(np.concatenate([start[:, None], rng.normal(0, 6, (12, FRAMES - 1, 2))], axis=1), axis=1)
    points = np.vstack([world, small, still, loose.reshape(12, -1)])
    labels = np.repeat([0, 1, 2, 3], [600, 12, 12, 12])
    assert geometry_supported(points, labels, [1, 2, 3]) == [1]


def test_a_new_small_rigid_cluster_is_labelled_under_joint_only() -> None:
    from mosegpipe.pipeline import LabelBook, PipelineConfig, match_labels
    from mosegpipe.pipeline.video import small_rigid

    rng = np.random.default_rng(10)
    world = _moving(rng, 600, (0, 0, 640, 480), (1.0, 0.0))
    small = _moving(rng, 12, (100, 100, 130, 130), (6.0, 2.0))
    points = np.vstack([world, small]).astype(np.float32)
    clusters = np.repeat([0, 1], [600, 12]).astype(np.int64)
    ids = np.arange(612, dtype=np.int64)
    joint = PipelineConfig(method="joint", joint=JointConfig(new_rigid_tracks=8))
    assert small_rigid(clusters, points, PipelineConfig(method="subspacenet")) == []  # the size guard alone
    assert small_rigid(clusters, points, PipelineConfig(method="joint", joint=JointConfig(new_rigid_tracks=None))) == []
    assert small_rigid(clusters, points, PipelineConfig(method="joint")) == [1]  # joint's default: 8 tracks
    assert small_rigid(clusters, points, joint) == [1]
    assert small_rigid(clusters, points, replace(joint, joint=JointConfig(new_rigid_tracks=13))) == []
    # 12 new tracks beside 600: under the guard (15 tracks, 5 %) unlabelled, labelled when supported
    xy = points.reshape(612, FRAMES, 2)
    plain = match_labels({}, ids, clusters, 2, LabelBook(), world=True, xy=xy)
    assert (plain[600:] == -1).all()
    trusted = match_labels({}, ids, clusters, 2, LabelBook(), world=True, xy=xy, supported=[1])
    assert (trusted[600:] == 1).all() and (trusted[:600] == 0).all()
