"""Synthetic lines / circles / ellipses (LCE) benchmark of the SubspaceNet paper.

Every sample is a 2-D point set with K = 4 groups: one line, one circle and two ellipses, each curve
sampled at a random number of points and perturbed by isotropic Gaussian noise (sigma = 0.05).
The points are "trajectories" of one frame: traj (N, 2) = (x, y), labels 0 = line, 1 = circle,
2 and 3 = ellipses, rows shuffled.

Curve parameters are not given in the paper; they are chosen at unit scale so that sigma = 0.05 is
small but visible against the curves (about 5-15 % of a radius):
centres and line anchors uniform in [-1, 1]^2, circle radius in [0.3, 1.0], ellipse semi-major axis
in [0.5, 1.0] with semi-minor axis 0.35-0.75 of it, orientations uniform, the line sampled over a
length-3 segment centred on its anchor. Circles and ellipses are sampled uniformly in angle.

Samples are generated lazily and deterministically per index, so a split of 8000 samples costs
nothing until read and sample i is the same whether or not samples 0..i-1 were read.

Single-kind problems (the paper's sampling-imbalance study, Figure 4): K curves of one kind (all lines,
all circles or all ellipses), with the same parameter ranges and noise; labels 0..K-1, one per curve
(`single_kind_sample`, `SingleKindDataset`, `single_kind_splits`).
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from mosegpipe.errors import InputError
from mosegpipe.synth.seeded import SeededClips
from mosegpipe.types import LabeledClip

DATASET = "lce"
CURVE_TYPES = ("line", "circle", "ellipse", "ellipse")
SPLIT_SIZES = {"train": 8000, "val": 200, "test": 200}
CURVE_KINDS = ("line", "circle", "ellipse")
"""The kinds of a single-kind problem."""
SINGLE_KIND_K = (2, 3, 4, 5, 6)
"""Numbers of curves of the sampling-imbalance study (the paper's Figure 4)."""


@dataclass(frozen=True)
class LCEConfig:
    """Parameters of the LCE generator (unit-scale defaults; see the module docstring).

    Attributes:
        points_per_curve: (lo, hi) inclusive range of the number of points on each curve.
        noise_sigma: standard deviation of the Gaussian noise added to x and y (paper: 0.05).
        centre_box: centres and line anchors are uniform in [-centre_box, centre_box]^2.
        circle_radius: (min, max) circle radius.
        ellipse_major: (min, max) semi-major axis.
        ellipse_ratio: (min, max) semi-minor / semi-major; below 1 so ellipses are not circles.
        line_half_length: points on the line lie within this distance of its anchor.
        shuffle: shuffle the rows so that groups are not in contiguous blocks.
    """

    points_per_curve: tuple[int, int] = (20, 60)
    noise_sigma: float = 0.05
    centre_box: float = 1.0
    circle_radius: tuple[float, float] = (0.3, 1.0)
    ellipse_major: tuple[float, float] = (0.5, 1.0)
    ellipse_ratio: tuple[float, float] = (0.35, 0.75)
    line_half_length: float = 1.5
    shuffle: bool = True

    def __post_init__(self) -> None:
        lo, hi = self.points_per_curve
        if not 1 <= lo <= hi:
            raise InputError(f"points_per_curve={self.points_per_curve} must satisfy 1 <= lo <= hi")
        if self.noise_sigma < 0:
            raise InputError(f"noise_sigma={self.noise_sigma} must be >= 0")


def _curve_points(
    rng: np.random.Generator, kind: str, count: int, cfg: LCEConfig
) -> tuple[npt.NDArray[np.float64], dict[str, object]]:
    """Noise-free points on one random curve, and its parameters as plain floats."""
    centre = rng.uniform(-cfg.centre_box, cfg.centre_box, size=2)
    if kind == "line":
        angle = rng.uniform(0.0, np.pi)
        direction = np.array([np.cos(angle), np.sin(angle)])
        t = rng.uniform(-cfg.line_half_length, cfg.line_half_length, size=count)
        points = centre + t[:, None] * direction
        params: dict[str, object] = {"point": centre.tolist(), "direction": direction.tolist()}
    elif kind == "circle":
        radius = rng.uniform(*cfg.circle_radius)
        theta = rng.uniform(0.0, 2 * np.pi, size=count)
        points = centre + radius * np.stack([np.cos(theta), np.sin(theta)], axis=1)
        params = {"centre": centre.tolist(), "radius": float(radius)}
    else:
        major = rng.uniform(*cfg.ellipse_major)
        minor = major * rng.uniform(*cfg.ellipse_ratio)
        angle = rng.uniform(0.0, np.pi)
        theta = rng.uniform(0.0, 2 * np.pi, size=count)
        local = np.stack([major * np.cos(theta), minor * np.sin(theta)], axis=1)
        c, s = np.cos(angle), np.sin(angle)
        points = centre + local @ np.array([[c, s], [-s, c]])
        params = {
            "centre": centre.tolist(),
            "axes": [float(major), float(minor)],
            "angle": float(angle),
        }
    return points, {"type": kind, **params}


def _noisy_curves(
    rng: np.random.Generator, kinds: tuple[str, ...], cfg: LCEConfig
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64], list[dict[str, object]]]:
    """Points on one curve per entry of `kinds` (label = its index), noise added, rows shuffled if asked.

    Returns:
        (xy (N, 2) noisy points, labels (N,), the curves' parameters per label).
    """
    lo, hi = cfg.points_per_curve
    chunks, labels, curves = [], [], []
    for label, kind in enumerate(kinds):
        count = int(rng.integers(lo, hi + 1))
        points, params = _curve_points(rng, kind, count, cfg)
        chunks.append(points)
        labels.append(np.full(count, label, dtype=np.int64))
        curves.append(params)
    xy = np.concatenate(chunks)
    xy = xy + rng.normal(0.0, cfg.noise_sigma, size=xy.shape)
    label_arr = np.concatenate(labels)
    if cfg.shuffle:
        perm = rng.permutation(label_arr.size)
        xy, label_arr = xy[perm], label_arr[perm]
    return xy, label_arr, curves


def lce_sample(rng: np.random.Generator, cfg: LCEConfig = LCEConfig(), name: str = "lce") -> LabeledClip:
    """Draw one LCE sample.

    Args:
        rng: random generator (consumed).
        cfg: generator parameters.
        name: clip name.

    Returns:
        traj (N, 2) float32 noisy points, labels (N,) int64 in 0..3 (0 line, 1 circle, 2-3
        ellipses); meta "curves" (per label: type and parameters), "noise_sigma", "frames" (1).
    """
    xy, label_arr, curves = _noisy_curves(rng, CURVE_TYPES, cfg)
    return LabeledClip(
        name=name,
        traj=xy.astype(np.float32),
        labels=label_arr,
        dataset=DATASET,
        meta={"curves": curves, "noise_sigma": cfg.noise_sigma, "frames": 1},
    )


class LCEDataset(SeededClips):
    """A fixed-size, lazily generated LCE split; item i depends only on (seed, split, i).

    Args:
        num_samples: length of the split.
        seed: base seed.
        split: split name mixed into the per-item seed, so that splits of one seed differ.
        cfg: generator parameters.
    """

    def __init__(self, num_samples: int, seed: int = 0, split: str = "", cfg: LCEConfig = LCEConfig()) -> None:
        if num_samples < 0:
            raise InputError(f"num_samples={num_samples} must be >= 0")
        self.num_samples = int(num_samples)
        self.length = self.num_samples
        self.seed = int(seed)
        self.split = split
        self.cfg = cfg
        self._split_key = zlib.crc32(split.encode())

    def _make(self, i: int) -> LabeledClip:
        rng = np.random.default_rng([self.seed, self._split_key, i])
        prefix = f"{self.split}/" if self.split else ""
        clip = lce_sample(rng, self.cfg, name=f"lce/{prefix}{i:05d}")
        clip.meta.update({"seed": self.seed, "split": self.split, "index": i})
        return clip

    def __repr__(self) -> str:
        return f"LCEDataset(num_samples={self.num_samples}, seed={self.seed}, split={self.split!r})"


def make_lce(
    num_samples: int,
    seed: int = 0,
    points_per_curve: tuple[int, int] | None = None,
    cfg: LCEConfig = LCEConfig(),
) -> list[LabeledClip]:
    """Generate `num_samples` LCE samples in memory (same items as LCEDataset(num_samples, seed)).

    Args:
        num_samples: number of samples.
        seed: base seed.
        points_per_curve: (lo, hi) inclusive; overrides cfg.points_per_curve when given.
        cfg: generator parameters.
    """
    if points_per_curve is not None:
        cfg = replace(cfg, points_per_curve=tuple(points_per_curve))  # type: ignore[arg-type]
    return list(LCEDataset(num_samples, seed=seed, cfg=cfg))


def lce_splits(seed: int = 0, cfg: LCEConfig = LCEConfig()) -> dict[str, LCEDataset]:
    """The LCE train / val / test splits (8000 / 200 / 200 samples), generated lazily.

    Args:
        seed: base seed; each split mixes its name into the per-item seed.
        cfg: generator parameters.

    Returns:
        {"train": ..., "val": ..., "test": ...}, each a Sequence[LabeledClip].
    """
    return {split: LCEDataset(size, seed=seed, split=split, cfg=cfg) for split, size in SPLIT_SIZES.items()}


def _check_kind(kind: str) -> str:
    if kind not in CURVE_KINDS:
        raise InputError(f"curve kind {kind!r}: choose from {', '.join(CURVE_KINDS)}")
    return kind


def single_kind_sample(
    rng: np.random.Generator, kind: str, k: int, cfg: LCEConfig = LCEConfig(), name: str = ""
) -> LabeledClip:
    """Draw one problem of K curves of a single kind.

    Curves are drawn like the LCE curves (same parameter ranges, points per curve and noise), so a
    K-line problem differs from an LCE sample only in the mix of kinds.

    Args:
        rng: random generator (consumed).
        kind: "line", "circle" or "ellipse".
        k: number of curves K >= 1.
        cfg: generator parameters.
        name: clip name (default "lce-<kind>").

    Returns:
        traj (N, 2) float32 noisy points (unit scale), labels (N,) int64 in 0..K-1 (one per curve);
        dataset "lce-<kind>"; meta "curves" (per label: type and parameters), "noise_sigma", "frames"
        (1), "kind", "num_models" (K).

    Raises:
        InputError: unknown kind or K < 1.
    """
    _check_kind(kind)
    if k < 1:
        raise InputError(f"k={k}: a problem needs at least one curve")
    xy, label_arr, curves = _noisy_curves(rng, (kind,) * k, cfg)
    return LabeledClip(
        name=name or f"{DATASET}-{kind}",
        traj=xy.astype(np.float32),
        labels=label_arr,
        dataset=f"{DATASET}-{kind}",
        meta={"curves": curves, "noise_sigma": cfg.noise_sigma, "frames": 1, "kind": kind, "num_models": k},
    )


class SingleKindDataset(SeededClips):
    """A fixed-size, lazily generated split of single-kind problems; item i depends only on (seed, kind, split, i).

    Args:
        kind: "line", "circle" or "ellipse".
        num_samples: length of the split.
        k: the number of curves of every item, or a tuple of numbers from which each item draws its K
            uniformly (from its own seed).
        seed: base seed.
        split: split name mixed into the per-item seed (with the kind), so that splits differ.
        cfg: generator parameters.
    """

    def __init__(
        self,
        kind: str,
        num_samples: int,
        k: int | tuple[int, ...],
        seed: int = 0,
        split: str = "",
        cfg: LCEConfig = LCEConfig(),
    ) -> None:
        self.kind = _check_kind(kind)
        if num_samples < 0:
            raise InputError(f"num_samples={num_samples} must be >= 0")
        self.ks = (int(k),) if isinstance(k, int | np.integer) else tuple(int(v) for v in k)
        if not self.ks or min(self.ks) < 1:
            raise InputError(f"k={k}: every number of curves must be >= 1")
        self.num_samples = int(num_samples)
        self.length = self.num_samples
        self.seed = int(seed)
        self.split = split
        self.cfg = cfg
        self._key = zlib.crc32(f"{kind}/{split}".encode())

    def _make(self, i: int) -> LabeledClip:
        rng = np.random.default_rng([self.seed, self._key, i])
        k = self.ks[0] if len(self.ks) == 1 else self.ks[int(rng.integers(len(self.ks)))]
        prefix = f"{self.split}/" if self.split else ""
        clip = single_kind_sample(rng, self.kind, k, self.cfg, name=f"{DATASET}-{self.kind}/{prefix}{i:05d}")
        clip.meta.update({"seed": self.seed, "split": self.split, "index": i})
        return clip

    def __repr__(self) -> str:
        return (
            f"SingleKindDataset(kind={self.kind!r}, num_samples={self.num_samples}, k={self.ks}, "
            f"seed={self.seed}, split={self.split!r})"
        )


def single_kind_splits(
    kind: str,
    num_train: int = 8000,
    num_test: int = 200,
    ks: tuple[int, ...] = SINGLE_KIND_K,
    seed: int = 0,
    cfg: LCEConfig = LCEConfig(),
) -> dict[str, SingleKindDataset]:
    """The splits of the sampling-imbalance study for one kind, generated lazily.

    Args:
        kind: "line", "circle" or "ellipse".
        num_train: training samples; each draws its K uniformly from `ks`.
        num_test: test samples per K.
        ks: the numbers of curves.
        seed: base seed.
        cfg: generator parameters.

    Returns:
        {"train": ..., "test/k2": ..., ..., "test/k6": ...}: every test split has exactly K curves
        per sample.
    """
    splits = {"train": SingleKindDataset(kind, num_train, tuple(ks), seed=seed, split="train", cfg=cfg)}
    for k in ks:
        splits[f"test/k{k}"] = SingleKindDataset(kind, num_test, k, seed=seed, split=f"test/k{k}", cfg=cfg)
    return splits
