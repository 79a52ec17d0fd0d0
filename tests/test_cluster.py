from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pytest

from mosegpipe.errors import InputError
from mosegpipe.evaluation.metrics import misclassification_error
from mosegpipe.group.cluster import (
    ClusterConfig,
    cluster_auto_k,
    kmeans,
    mean_silhouette,
    pairwise_distances,
    relabel_by_size,
)

RESIDUAL = ClusterConfig(method="residual")


def sphere_blobs(
    k: int, n: int = 200, e: int = 8, noise: float = 0.05, seed: int = 0
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]:
    """k Gaussian blobs around well-separated random centres, rows L2-normalised."""
    rng = np.random.default_rng(seed)
    centres = np.linalg.qr(rng.normal(size=(e, e)))[0][:k]  # orthonormal: 90 degrees apart
    labels = np.arange(n) % k
    rng.shuffle(labels)
    x = centres[labels] + noise * rng.normal(size=(n, e))
    return x / np.linalg.norm(x, axis=1, keepdims=True), labels.astype(np.int64)


# --- config -------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"method": "gap"}, "'gap'"),
        ({"k_min": 0}, "^k_min: 0 must"),
        ({"k_min": 4, "k_max": 3}, "^k_max: 3 must"),
        ({"n_init": 0}, "^n_init: 0 must"),
        ({"num_threads": 0}, "num_threads: 0 must lie in 1..256"),
        ({"num_threads": 100_000}, "num_threads: 100000 must lie in 1..256"),
        ({"min_elbow": 2.0}, "^min_elbow: 2.0 must"),
        ({"min_spread": -1.0}, "^min_spread: -1.0 must"),
        ({"one_motion_spread": 1.5}, "^one_motion_spread: 1.5 must"),
    ],
)
def test_config_rejects_bad_values(kwargs: dict, message: str) -> None:
    with pytest.raises(InputError, match=message):
        ClusterConfig(**kwargs)


# --- kmeans -------------------------------------------------------------------------------------


def test_relabel_by_size_orders_by_size_then_first_appearance() -> None:
    assert relabel_by_size([7, 3, 3, 5, 5, 3]).tolist() == [2, 0, 0, 1, 1, 0]
    # equal sizes: the cluster seen first gets the smaller id
    assert relabel_by_size([9, 9, 4, 4]).tolist() == [0, 0, 1, 1]


def test_kmeans_recovers_blobs_and_inertia() -> None:
    x, gt = sphere_blobs(3, n=90)
    labels, inertia = kmeans(x, 3)
    assert labels.dtype == np.int64 and labels.shape == (90,)
    assert misclassification_error(labels, gt) == 0.0
    expected = sum(((x[labels == c] - x[labels == c].mean(0)) ** 2).sum() for c in range(3))
    assert inertia == pytest.approx(expected, rel=1e-6)


def test_kmeans_is_deterministic_for_a_seed() -> None:
    rng = np.random.default_rng(1)
    x = rng.normal(size=(120, 4))  # no structure: the result depends on the seed
    a = kmeans(x, 5, seed=3)
    b = kmeans(x, 5, seed=3)
    np.testing.assert_array_equal(a[0], b[0])
    assert a[1] == b[1]


def test_kmeans_does_not_depend_on_what_ran_before_or_on_the_thread() -> None:
    import threading

    import cv2

    x = np.random.default_rng(2).normal(size=(150, 3))  # no structure: the seeding decides
    first = kmeans(x, 6, seed=4, n_init=1)
    assert len({kmeans(x, 6, seed=s, n_init=1)[1] for s in range(6)}) > 1  # the seed matters
    cv2.setRNGSeed(99)
    cv2.randu(np.zeros(100, np.float32), 0, 1)  # OpenCV's generator moved on
    again = kmeans(x, 6, seed=4, n_init=1)
    on_thread: list[tuple[npt.NDArray[np.int64], float]] = []
    worker = threading.Thread(target=lambda: on_thread.append(kmeans(x, 6, seed=4, n_init=1)))
    worker.start()
    worker.join()
    for other in (again, on_thread[0]):
        np.testing.assert_array_equal(first[0], other[0])
        assert first[1] == other[1]


def test_kmeans_keeps_the_best_restart_and_is_translation_and_scale_free() -> None:
    x, _ = sphere_blobs(4, n=160, e=5, noise=0.3, seed=7)
    # The first restart of a seed is the single run of that seed: more restarts never end worse.
    one = np.array([kmeans(x, 6, seed=s, n_init=1)[1] for s in range(6)])
    eight = np.array([kmeans(x, 6, seed=s, n_init=8)[1] for s in range(6)])
    assert np.all(eight <= one * (1 + 1e-9)) and np.any(eight < one * (1 - 1e-6))
    labels, inertia = kmeans(x, 4)
    moved, moved_inertia = kmeans(1000.0 * x + 5e4, 4)  # far from the origin: float32 would lose it
    np.testing.assert_array_equal(labels, moved)
    assert moved_inertia == pytest.approx(1e6 * inertia, rel=1e-6)


def test_kmeans_on_fewer_distinct_points_than_k() -> None:
    x = np.repeat(np.eye(3), [5, 3, 2], axis=0)
    labels, inertia = kmeans(x, 3)
    assert labels.tolist() == [0] * 5 + [1] * 3 + [2] * 2
    assert inertia == pytest.approx(0.0, abs=1e-12)
    labels, inertia = kmeans(np.ones((6, 2)), 2)  # one distinct point
    assert inertia == 0.0 and set(labels.tolist()) <= {0, 1}


def test_kmeans_of_one_cluster_and_of_one_point() -> None:
    x = np.arange(12.0).reshape(2, 6)  # two points of 6 dimensions: not 12 points of one
    assert kmeans(x, 2)[0].tolist() == [0, 1]
    labels, inertia = kmeans(x, 1)
    assert labels.tolist() == [0, 0] and inertia == pytest.approx(6 * 2 * 3.0**2)
    labels, inertia = kmeans(x[:1], 1)
    assert labels.tolist() == [0] and inertia == 0.0


def test_pairwise_distances_equal_scikit_learn() -> None:
    from sklearn.metrics import pairwise_distances as reference

    x = np.random.default_rng(3).normal(size=(70, 5)) + 40.0
    d = pairwise_distances(x)
    np.testing.assert_allclose(d, reference(x), atol=1e-9)
    assert np.array_equal(d, d.T) and not d.diagonal().any()


@pytest.mark.parametrize("bad", [np.zeros((0, 3)), np.zeros(5), np.full((4, 2), np.nan)])
def test_kmeans_rejects_bad_embeddings(bad: npt.NDArray[np.float64]) -> None:
    with pytest.raises(InputError, match="embeddings"):
        kmeans(bad, 1)


def test_kmeans_rejects_k_above_n() -> None:
    with pytest.raises(InputError, match="k=4 is larger than the number of points \\(3\\)"):
        kmeans(np.eye(3), 4)


# --- automatic K --------------------------------------------------------------------------------


@pytest.mark.parametrize("method", ["residual", "silhouette"])
@pytest.mark.parametrize("k", [2, 3, 4, 5, 6])
def test_auto_k_finds_separated_blobs(method: str, k: int) -> None:
    x, gt = sphere_blobs(k, seed=k)
    result = cluster_auto_k(x, ClusterConfig(method=method, n_init=4))
    assert result.k == k
    assert result.method == method
    assert misclassification_error(result.labels, gt) == 0.0
    assert sorted(result.scores) == list(range(2, 9))  # wide spread: K = 1 is no candidate
    assert max(result.scores, key=result.scores.__getitem__) == k


def test_residual_scores_match_hand_computed_elbow() -> None:
    # Four collinear groups of two points at 0, 10, 20, 30 (spread 0.1 inside each group):
    # r(K) is known in closed form, so score(K) = d(K) - d(K+1) with d(K) = 1 - r(K)/r(K-1).
    centres = np.repeat([0.0, 10.0, 20.0, 30.0], 2)
    x = (centres + np.tile([-0.05, 0.05], 4))[:, None]
    result = cluster_auto_k(x, ClusterConfig(method="residual", k_max=4, n_init=10))
    r1 = float(((x - x.mean()) ** 2).sum())  # 1000.02
    r2 = 2 * (2 * 25.0 + 2 * 25.0) + 8 * 0.0025  # groups {0,10} and {20,30}: 200.02
    r3 = 2 * 25.0 * 2 + 8 * 0.0025  # one merged pair: 100.02
    r4 = 8 * 0.0025  # 0.02
    r5 = 6 * 0.0025  # one group split: 0.015
    d = {2: 1 - r2 / r1, 3: 1 - r3 / r2, 4: 1 - r4 / r3, 5: 1 - r5 / r4}
    assert result.k == 4
    for kk in (2, 3, 4):
        assert result.scores[kk] == pytest.approx(d[kk] - d[kk + 1], abs=1e-9)
    assert 1 not in result.scores


def test_residual_picks_one_cluster_for_a_single_blob() -> None:
    x, _ = sphere_blobs(1, n=300, noise=0.1)
    result = cluster_auto_k(x, RESIDUAL)
    assert result.k == 1
    assert np.all(result.labels == 0)
    assert max(v for kk, v in result.scores.items() if kk > 1) < ClusterConfig().min_elbow


def test_silhouette_picks_one_cluster_for_a_single_blob() -> None:
    x, _ = sphere_blobs(1, n=200, noise=0.1)
    assert cluster_auto_k(x, ClusterConfig(method="silhouette", n_init=4)).k == 1


def test_identical_embeddings_give_one_cluster_without_sweep() -> None:
    x = np.tile([[0.6, 0.8]], (50, 1)) + 1e-7 * np.random.default_rng(0).normal(size=(50, 2))
    result = cluster_auto_k(x, RESIDUAL)
    assert (result.k, result.scores) == (1, {1: 1.0})


def test_wide_spread_never_gives_one_cluster() -> None:
    # Two loose groups whose elbow scores stay below min_elbow: without the spread gate K = 1 won.
    x, gt = sphere_blobs(2, n=200, noise=0.6, seed=3)
    spread = float(((x - x.mean(axis=0)) ** 2).sum() / (x**2).sum())
    assert spread > ClusterConfig().one_motion_spread
    result = cluster_auto_k(x, RESIDUAL)
    assert result.k >= 2
    assert 1 not in result.scores
    gated = cluster_auto_k(x, ClusterConfig(method="residual", one_motion_spread=1.0))
    assert 1 in gated.scores


def test_k_min_two_excludes_one_cluster() -> None:
    x, _ = sphere_blobs(1, n=100, noise=0.1)
    result = cluster_auto_k(x, ClusterConfig(k_min=2, k_max=4, n_init=4))
    assert 2 <= result.k <= 4
    assert 1 not in result.scores


def test_scale_does_not_change_the_choice() -> None:
    x, _ = sphere_blobs(3, n=120, seed=7)
    a = cluster_auto_k(x, ClusterConfig(n_init=4))
    b = cluster_auto_k(1000.0 * x, ClusterConfig(n_init=4))
    assert a.k == b.k == 3
    assert a.scores == pytest.approx(b.scores, abs=1e-9)
    np.testing.assert_array_equal(a.labels, b.labels)


def test_forced_k() -> None:
    x, gt = sphere_blobs(3, n=60)
    result = cluster_auto_k(x, k=2)
    assert (result.k, result.method, result.scores) == (2, "fixed", {})
    assert set(result.labels.tolist()) == {0, 1}
    # size order: cluster 0 is the largest
    assert np.sum(result.labels == 0) >= np.sum(result.labels == 1)


def test_forced_k_larger_than_n_is_an_input_error() -> None:
    with pytest.raises(InputError, match=r"--k 7 is larger than the number of tracks \(5\)"):
        cluster_auto_k(np.eye(5), k=7)


@pytest.mark.parametrize("method", ["residual", "silhouette"])
def test_auto_k_is_deterministic(method: str) -> None:
    rng = np.random.default_rng(5)
    x = rng.normal(size=(80, 5))
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    cfg = ClusterConfig(method=method, seed=11, n_init=3)
    a, b = cluster_auto_k(x, cfg), cluster_auto_k(x, cfg)
    assert a.k == b.k and a.scores == b.scores
    np.testing.assert_array_equal(a.labels, b.labels)


@pytest.mark.parametrize("method", ["residual", "silhouette"])
@pytest.mark.parametrize("n", [1, 2, 3])
def test_tiny_inputs_do_not_crash(method: str, n: int) -> None:
    x = np.eye(4)[:n]
    result = cluster_auto_k(x, ClusterConfig(method=method))
    assert result.labels.shape == (n,)
    assert 1 <= result.k <= n
    assert result.labels.max() < result.k


@pytest.mark.parametrize("seed", range(4))
def test_mean_silhouette_equals_scikit_learn(seed: int) -> None:
    from sklearn.metrics import pairwise_distances, silhouette_score

    rng = np.random.default_rng(seed)
    x = rng.normal(size=(120, 5))
    labels = rng.integers(0, 2 + seed, size=120)
    labels[7] = labels.max() + 1  # a cluster of one point scores 0
    d = pairwise_distances(x)
    assert mean_silhouette(d, labels) == pytest.approx(silhouette_score(d, labels, metric="precomputed"), abs=1e-12)
    x[:5] = x[0]  # duplicate points: zero distances
    d = pairwise_distances(x)
    assert mean_silhouette(d, labels) == pytest.approx(silhouette_score(d, labels, metric="precomputed"), abs=1e-12)


def test_prefer_k_wins_only_a_near_tie() -> None:
    x, _ = sphere_blobs(3, n=240, noise=0.2, seed=3)
    cfg = ClusterConfig(method="silhouette")
    free = cluster_auto_k(x, cfg)
    others = sorted((k for k in free.scores if k != free.k), key=lambda k: free.scores[free.k] - free.scores[k])
    near, far = others[0], others[-1]
    gap = free.scores[free.k] - free.scores[near]
    tie = ClusterConfig(method="silhouette", ambiguity_margin=gap + 1e-9)
    assert cluster_auto_k(x, tie, prefer_k=near).k == near
    assert cluster_auto_k(x, ClusterConfig(method="silhouette", ambiguity_margin=gap / 2), prefer_k=near).k == free.k
    assert free.scores[free.k] - free.scores[far] > gap and cluster_auto_k(x, tie, prefer_k=far).k == free.k
    assert cluster_auto_k(x, tie, prefer_k=99).k == free.k  # not a candidate: ignored
    kept = cluster_auto_k(x, tie, prefer_k=near)
    assert kept.note.startswith("the K choice is ambiguous") and "the preferred K kept" in kept.note
