from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pytest

from mosegpipe.errors import InputError
from mosegpipe.evaluation.baselines import (
    BASELINES,
    Baseline,
    kmeans_raw,
    self_tuning_affinity,
    spectral_labels,
    spectral_raw,
    ssc,
    ssc_coefficients,
    zscore_columns,
)
from mosegpipe.evaluation.metrics import misclassification_error

Data = tuple[npt.NDArray[np.float32], npt.NDArray[np.int64]]


def affine_motions(n_per: tuple[int, ...] = (50, 50, 50), frames: int = 5, noise: float = 0.5, seed: int = 0) -> Data:
    """Independent affine motions of 3-D point clouds that overlap in the image.

    All clouds fill the same 200 px box around (320, 320) in frame 1, so positions alone do not
    separate them; from frame 2 on each cloud has its own random affine camera (identity plus
    0.2-scale perturbation, 20 px translation). Each motion's trajectories span a 3-D affine
    subspace of R^(2F).
    """
    rng = np.random.default_rng(seed)
    rows, labels = [], []
    for motion, n in enumerate(n_per):
        points = rng.uniform(-100, 100, size=(n, 3))
        cols = [points[:, :2] + 320]
        for _ in range(frames - 1):
            camera = np.eye(2, 3) + 0.2 * rng.normal(size=(2, 3))
            cols.append(points @ camera.T + 20 * rng.normal(size=2) + 320)
        rows.append(np.concatenate(cols, axis=1))
        labels += [motion] * n
    traj = np.concatenate(rows) + noise * rng.normal(size=(sum(n_per), 2 * frames))
    return traj.astype(np.float32), np.array(labels, dtype=np.int64)


def translating_groups(seed: int = 0) -> Data:
    """Three groups of points far apart, each translating as a whole: easy for any method."""
    rng = np.random.default_rng(seed)
    starts = np.array([[100.0, 100.0], [500.0, 120.0], [300.0, 400.0]])
    steps = np.array([[5.0, 0.0], [-4.0, 3.0], [0.0, -6.0]])
    labels = np.repeat(np.arange(3), 30)
    xy0 = starts[labels] + rng.normal(scale=15.0, size=(90, 2))
    traj = np.concatenate([xy0 + f * steps[labels] for f in range(5)], axis=1)
    return traj.astype(np.float32), labels


# --- building blocks ----------------------------------------------------------------------------


def test_zscore_columns() -> None:
    traj = np.array([[1.0, 5.0, 7.0], [3.0, 5.0, 9.0], [5.0, 5.0, 14.0]])
    z = zscore_columns(traj)
    np.testing.assert_allclose(z.mean(axis=0), 0.0, atol=1e-12)
    np.testing.assert_allclose(z.std(axis=0), [1.0, 0.0, 1.0])  # constant column stays 0
    np.testing.assert_allclose(z[:, 0], [-np.sqrt(1.5), 0.0, np.sqrt(1.5)])


def test_spectral_labels_on_block_affinity() -> None:
    # three cliques of sizes 5, 4, 3 joined by weak links
    labels = np.repeat([0, 1, 2], [5, 4, 3])
    affinity = np.where(labels[:, None] == labels[None, :], 1.0, 0.01)
    np.fill_diagonal(affinity, 0.0)
    np.testing.assert_array_equal(spectral_labels(affinity, None), labels)  # eigengap: K = 3
    np.testing.assert_array_equal(spectral_labels(affinity, 3), labels)


def test_self_tuning_affinity_properties() -> None:
    x = np.random.default_rng(0).normal(size=(20, 3))
    w = self_tuning_affinity(x)
    np.testing.assert_allclose(w, w.T)
    assert np.all(np.diag(w) == 0) and np.all((w >= 0) & (w <= 1))
    assert np.all(self_tuning_affinity(np.ones((4, 2)))[~np.eye(4, dtype=bool)] == 1.0)


def test_ssc_coefficients_are_affine_and_subspace_preserving() -> None:
    traj, labels = affine_motions(noise=0.0)
    c = ssc_coefficients(zscore_columns(traj), max_iter=400)
    assert np.all(np.diag(c) == 0)
    np.testing.assert_allclose(c.sum(axis=0), 1.0, atol=0.01)  # affine constraint 1^T C = 1^T
    same = labels[:, None] == labels[None, :]
    assert np.abs(c)[~same].sum() < 0.05 * np.abs(c).sum()  # almost no weight across motions


# --- the baselines ------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", [0, 1])
def test_ssc_segments_affine_motions(seed: int) -> None:
    traj, labels = affine_motions(seed=seed)
    assert misclassification_error(ssc(traj, 3), labels) < 0.05
    auto = ssc(traj, None)
    assert auto.max() + 1 == 3
    assert misclassification_error(auto, labels) < 0.05


@pytest.mark.parametrize("baseline", [kmeans_raw, spectral_raw])
def test_raw_baselines_segment_separated_groups(baseline: Baseline) -> None:
    traj, labels = translating_groups()
    assert misclassification_error(baseline(traj, 3), labels) == 0.0
    auto = baseline(traj, None)
    assert misclassification_error(auto, labels) == 0.0


@pytest.mark.parametrize("name", sorted(BASELINES))
@pytest.mark.parametrize("k", [2, None])
def test_baselines_return_valid_deterministic_labels(name: str, k: int | None) -> None:
    traj, _ = affine_motions(n_per=(30, 30), seed=3)
    labels = BASELINES[name](traj, k, seed=5)
    again = BASELINES[name](traj, k, seed=5)
    assert labels.dtype == np.int64 and labels.shape == (60,)
    np.testing.assert_array_equal(labels, again)
    num = labels.max() + 1
    assert labels.min() == 0 and set(labels.tolist()) == set(range(num))
    assert num == 2 if k == 2 else 1 <= num <= 8
    sizes = np.bincount(labels)
    assert np.all(sizes[:-1] >= sizes[1:])  # id 0 is the largest cluster


@pytest.mark.parametrize("name", sorted(BASELINES))
@pytest.mark.parametrize("n", [1, 2, 3])
def test_baselines_handle_tiny_inputs(name: str, n: int) -> None:
    traj = np.random.default_rng(0).normal(size=(n, 10)) * 100
    assert BASELINES[name](traj, None).shape == (n,)
    assert sorted(set(BASELINES[name](traj, n).tolist())) == list(range(n))


@pytest.mark.parametrize("name", sorted(BASELINES))
def test_baselines_reject_bad_input(name: str) -> None:
    traj = np.zeros((4, 10))
    msg = r"--k 5 must lie between 1 and the number of tracks \(4\)"
    with pytest.raises(InputError, match=msg):
        BASELINES[name](traj, 5)
    with pytest.raises(InputError, match=r"shape \(N, D\).*\(10,\)"):
        BASELINES[name](np.zeros(10), 2)
    with pytest.raises(InputError, match="NaN"):
        BASELINES[name](np.full((4, 10), np.nan), 2)
