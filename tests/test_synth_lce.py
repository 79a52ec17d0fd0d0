from __future__ import annotations

import numpy as np
import pytest

from mosegpipe.errors import InputError
from mosegpipe.synth.lce import (
    CURVE_KINDS,
    CURVE_TYPES,
    SINGLE_KIND_K,
    LCEConfig,
    LCEDataset,
    SingleKindDataset,
    lce_sample,
    lce_splits,
    make_lce,
    single_kind_sample,
    single_kind_splits,
)
from mosegpipe.types import LabeledClip


def _distance_to_curve(points: np.ndarray, curve: dict) -> np.ndarray:
    """Unsigned distance of (M, 2) points to a curve described by an LCE meta entry."""
    if curve["type"] == "line":
        p0, d = np.array(curve["point"]), np.array(curve["direction"])
        normal = np.array([-d[1], d[0]])
        return np.abs((points - p0) @ normal)
    if curve["type"] == "circle":
        return np.abs(np.linalg.norm(points - np.array(curve["centre"]), axis=1) - curve["radius"])
    # Ellipse: nearest of 4096 samples of the true curve (spacing < 1e-3, far below sigma).
    major, minor = curve["axes"]
    theta = np.linspace(0.0, 2 * np.pi, 4096, endpoint=False)
    c, s = np.cos(curve["angle"]), np.sin(curve["angle"])
    local = np.stack([major * np.cos(theta), minor * np.sin(theta)], axis=1)
    dense = np.array(curve["centre"]) + local @ np.array([[c, s], [-s, c]])
    return np.sqrt(((points[:, None, :] - dense[None]) ** 2).sum(-1)).min(axis=1)


def test_sample_has_four_groups_of_bounded_size() -> None:
    clips = make_lce(20, seed=1, points_per_curve=(7, 12))
    for clip in clips:
        assert isinstance(clip, LabeledClip)
        assert clip.dataset == "lce"
        assert clip.traj.dtype == np.float32 and clip.traj.shape == (clip.num_points, 2)
        assert clip.labels.dtype == np.int64
        counts = np.bincount(clip.labels, minlength=4)
        assert clip.k == 4 and counts.size == 4
        assert counts.min() >= 7 and counts.max() <= 12
        assert [c["type"] for c in clip.meta["curves"]] == list(CURVE_TYPES)
        assert clip.num_frames == 1


def test_fixed_points_per_curve() -> None:
    clip = make_lce(1, seed=0, points_per_curve=(5, 5))[0]
    assert clip.num_points == 20
    assert np.bincount(clip.labels).tolist() == [5, 5, 5, 5]


def test_deterministic_per_index_and_seed() -> None:
    a = LCEDataset(50, seed=7, split="train")
    b = LCEDataset(50, seed=7, split="train")
    # Item 42 must not depend on which items were generated before it.
    np.testing.assert_array_equal(a[42].traj, b[42].traj)
    _ = [b[i] for i in range(10)]
    np.testing.assert_array_equal(a[42].labels, b[42].labels)
    np.testing.assert_array_equal(a[-1].traj, a[49].traj)
    assert not np.array_equal(a[0].traj, a[1].traj)
    c = LCEDataset(50, seed=8, split="train")
    assert not np.array_equal(a[0].traj, c[0].traj)
    listed = make_lce(3, seed=7)
    lazy = LCEDataset(3, seed=7)
    for x, y in zip(listed, lazy, strict=True):
        np.testing.assert_array_equal(x.traj, y.traj)


def test_splits_sizes_and_distinct() -> None:
    splits = lce_splits(seed=0)
    assert {k: len(v) for k, v in splits.items()} == {"train": 8000, "val": 200, "test": 200}
    first = [splits[k][0].traj for k in ("train", "val", "test")]
    assert not np.array_equal(first[0][:5], first[1][:5])
    assert not np.array_equal(first[1][:5], first[2][:5])
    assert splits["test"][199].name == "lce/test/00199"
    with pytest.raises(IndexError):
        splits["val"][200]
    assert len(splits["train"][10:13]) == 3
    np.testing.assert_array_equal(lce_splits(seed=0)["val"][3].traj, splits["val"][3].traj)


def test_noise_free_points_lie_on_their_curves() -> None:
    rng = np.random.default_rng(0)
    clip = lce_sample(rng, LCEConfig(noise_sigma=0.0))
    for label, curve in enumerate(clip.meta["curves"]):
        d = _distance_to_curve(clip.traj[clip.labels == label].astype(np.float64), curve)
        assert d.max() < 2e-3, curve["type"]


def test_noise_level_matches_sigma() -> None:
    residuals: dict[str, list[np.ndarray]] = {"line": [], "circle": [], "ellipse": []}
    for clip in LCEDataset(40, seed=3, split="noise"):
        for label, curve in enumerate(clip.meta["curves"]):
            pts = clip.traj[clip.labels == label].astype(np.float64)
            residuals[curve["type"]].append(_distance_to_curve(pts, curve))
    for kind, parts in residuals.items():
        rms = float(np.sqrt(np.mean(np.concatenate(parts) ** 2)))
        # The normal component of isotropic 2-D noise has std sigma; curvature lowers it slightly.
        assert 0.044 < rms < 0.056, (kind, rms)


def test_points_in_unit_scale_box() -> None:
    cfg = LCEConfig()
    for clip in LCEDataset(30, seed=0):
        # Largest reach: centre 1 + line half-length 1.5 (plus a few sigma of noise).
        assert np.abs(clip.traj).max() < cfg.centre_box + cfg.line_half_length + 0.3


def test_invalid_config() -> None:
    with pytest.raises(InputError, match="points_per_curve"):
        LCEConfig(points_per_curve=(10, 5))
    with pytest.raises(InputError, match="noise_sigma"):
        LCEConfig(noise_sigma=-1.0)
    with pytest.raises(InputError, match="num_samples"):
        LCEDataset(-1)


# --- single-kind problems (the sampling-imbalance study)


@pytest.mark.parametrize("kind", CURVE_KINDS)
def test_single_kind_sample_has_k_curves_of_its_kind(kind: str) -> None:
    clip = single_kind_sample(np.random.default_rng(4), kind, 5, LCEConfig(points_per_curve=(8, 12)))
    assert clip.dataset == f"lce-{kind}" and clip.k == 5 and clip.meta["num_models"] == 5
    assert clip.traj.dtype == np.float32 and clip.traj.shape == (clip.num_points, 2)
    assert clip.labels.dtype == np.int64 and sorted(np.unique(clip.labels)) == [0, 1, 2, 3, 4]
    counts = np.bincount(clip.labels)
    assert counts.min() >= 8 and counts.max() <= 12
    assert [c["type"] for c in clip.meta["curves"]] == [kind] * 5
    # Noise-free points lie on their own curve.
    exact = single_kind_sample(np.random.default_rng(4), kind, 5, LCEConfig(noise_sigma=0.0))
    for label, curve in enumerate(exact.meta["curves"]):
        assert _distance_to_curve(exact.traj[exact.labels == label].astype(np.float64), curve).max() < 2e-3


def test_single_kind_dataset_is_deterministic_per_index() -> None:
    a = SingleKindDataset("circle", 30, (2, 3, 4, 5, 6), seed=2, split="train")
    b = SingleKindDataset("circle", 30, (2, 3, 4, 5, 6), seed=2, split="train")
    _ = [b[i] for i in range(5)]
    np.testing.assert_array_equal(a[17].traj, b[17].traj)
    np.testing.assert_array_equal(a[17].labels, b[17].labels)
    assert not np.array_equal(a[0].traj, SingleKindDataset("circle", 30, (2, 3, 4, 5, 6), seed=3)[0].traj)
    # Another kind with the same seed and split is another problem, not the same points.
    assert not np.array_equal(
        a[0].traj[:4], SingleKindDataset("line", 30, (2, 3, 4, 5, 6), seed=2, split="train")[0].traj[:4]
    )
    ks = {clip.k for clip in a}
    assert ks <= {2, 3, 4, 5, 6} and len(ks) >= 4  # K drawn per sample from the given numbers
    assert a[3].name == "lce-circle/train/00003"


def test_single_kind_splits_sizes_and_fixed_k() -> None:
    splits = single_kind_splits("ellipse", num_train=100, num_test=7)
    assert list(splits) == ["train", "test/k2", "test/k3", "test/k4", "test/k5", "test/k6"]
    assert len(splits["train"]) == 100 and all(len(splits[f"test/k{k}"]) == 7 for k in SINGLE_KIND_K)
    for k in SINGLE_KIND_K:
        assert {c.k for c in splits[f"test/k{k}"]} == {k}
    assert not np.array_equal(splits["test/k2"][0].traj[:4], splits["train"][0].traj[:4])
    assert len(single_kind_splits("line")["train"]) == 8000


def test_single_kind_bad_arguments() -> None:
    with pytest.raises(InputError, match="curve kind 'hyperbola'"):
        single_kind_sample(np.random.default_rng(0), "hyperbola", 2)
    with pytest.raises(InputError, match="k=0"):
        single_kind_sample(np.random.default_rng(0), "line", 0)
    with pytest.raises(InputError, match="k=\\(2, 0\\)"):
        SingleKindDataset("line", 3, (2, 0))
    with pytest.raises(InputError, match="num_samples"):
        SingleKindDataset("line", -1, 2)
