"""Augmentation that makes benchmark point sets look like what the tool's own front end produces.

Applied to the clips of a training source before the loop's own augmentation (subsampling to
`max_points`, mirroring, time reversal). Each operation is drawn independently per clip:

* point count drawn log-uniformly from `num_points` (KLT gives ~50 tracks on a blank wall and ~1000
  on a textured street; SIFT 100-400 matches per pair);
* spatially uneven density (a keep-probability ramp across the image) and a dropped region (a disc
  without points: sky, a textureless wall, an occluder);
* an object thinned to a few dozen points (distant cars, small objects);
* Gaussian tracker noise, drifting tracks (a constant velocity added: the tracker slid along an
  edge) and gross outliers (random walks); drifting and outlier points are labelled -1, so they
  take part in the context normalisation but not in the loss, as at inference, where they exist
  but have no right answer.

Labels -1 already present (points the label transfer could not label) are kept as context.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt


@dataclass(frozen=True)
class TrackAugmentConfig:
    """Probabilities and ranges of `augment_point_set` (ranges are (low, high), pixels where a unit).

    Attributes:
        num_points: range of the drawn point count (log-uniform), applied with prob_subsample.
        prob_subsample: probability of drawing a point count.
        prob_uneven: probability of a keep-probability ramp across the image.
        ramp_slope: range of the ramp's logistic slope (over half the image diagonal).
        prob_drop_region: probability of removing the points in a disc.
        drop_radius: range of that disc's radius as a fraction of the points' diagonal extent.
        prob_small_object: probability of thinning one non-background group.
        small_object_points: range of the points left to that group.
        noise_px: range of the Gaussian noise's standard deviation.
        prob_drift: probability of adding drifting tracks.
        drift_fraction: range of their share of the points.
        drift_px_per_frame: range of their speed.
        prob_outliers: probability of adding gross outliers.
        outlier_fraction: range of their share of the points.
        outlier_step_px: range of the random walk's step standard deviation.
    """

    num_points: tuple[int, int] = (50, 2000)
    prob_subsample: float = 0.5
    prob_uneven: float = 0.3
    ramp_slope: tuple[float, float] = (1.0, 4.0)
    prob_drop_region: float = 0.3
    drop_radius: tuple[float, float] = (0.05, 0.2)
    prob_small_object: float = 0.3
    small_object_points: tuple[int, int] = (8, 40)
    noise_px: tuple[float, float] = (0.0, 0.5)
    prob_drift: float = 0.5
    drift_fraction: tuple[float, float] = (0.0, 0.03)
    drift_px_per_frame: tuple[float, float] = (0.5, 2.0)
    prob_outliers: float = 0.5
    outlier_fraction: tuple[float, float] = (0.0, 0.03)
    outlier_step_px: tuple[float, float] = (1.0, 8.0)


def _keep_mask(
    xy0: npt.NDArray[np.float64], labels: npt.NDArray[np.int64], rng: np.random.Generator, cfg: TrackAugmentConfig
) -> npt.NDArray[np.bool_]:
    """Which points survive the density changes (positions in the first frame)."""
    n = xy0.shape[0]
    keep = np.ones(n, dtype=bool)
    lo, hi = xy0.min(axis=0), xy0.max(axis=0)
    half_diag = 0.5 * float(np.linalg.norm(hi - lo)) + 1e-6
    if rng.random() < cfg.prob_drop_region:
        centre = xy0[rng.integers(n)]
        keep &= np.linalg.norm(xy0 - centre, axis=1) > rng.uniform(*cfg.drop_radius) * 2 * half_diag
    if rng.random() < cfg.prob_uneven:
        direction = rng.normal(size=2)
        direction /= np.linalg.norm(direction) + 1e-12
        proj = (xy0 - 0.5 * (lo + hi)) @ direction / half_diag
        keep &= rng.random(n) < 1.0 / (1.0 + np.exp(-rng.uniform(*cfg.ramp_slope) * proj))
    if rng.random() < cfg.prob_subsample:
        target = int(np.exp(rng.uniform(np.log(cfg.num_points[0]), np.log(cfg.num_points[1]))))
        idx = np.flatnonzero(keep)
        if idx.size > target:
            keep[rng.choice(idx, idx.size - target, replace=False)] = False
    if rng.random() < cfg.prob_small_object:
        groups = [g for g in np.unique(labels[keep]) if g > 0]
        if groups:
            g = groups[int(rng.integers(len(groups)))]
            idx = np.flatnonzero(keep & (labels == g))
            target = int(rng.integers(cfg.small_object_points[0], cfg.small_object_points[1] + 1))
            if idx.size > target:
                keep[rng.choice(idx, idx.size - target, replace=False)] = False
    if not np.any(keep & (labels >= 0)):
        keep[:] = True  # never leave a clip without anything to learn from
    return keep


def augment_point_set(
    traj: npt.ArrayLike,
    labels: npt.ArrayLike,
    rng: np.random.Generator,
    cfg: TrackAugmentConfig = TrackAugmentConfig(),
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.int64]]:
    """An augmented copy of one clip's point set (see the module docstring).

    Args:
        traj: (N, 2F) trajectories, pixels, columns x_1, y_1, ..., x_F, y_F.
        labels: (N,) int64 group labels, -1 = context only.
        rng: random generator (the only source of randomness).
        cfg: probabilities and ranges.

    Returns:
        (traj (N', 2F) float32, labels (N',) int64); added drifting / outlier points have label -1.

    Raises:
        ValueError: traj is not (N, 2F) with N >= 1, or labels do not match.
    """
    arr = np.asarray(traj, dtype=np.float64)
    lab = np.asarray(labels, dtype=np.int64)
    if arr.ndim != 2 or arr.shape[0] < 1 or arr.shape[1] % 2 or lab.shape != (arr.shape[0],):
        raise ValueError(f"traj {arr.shape} / labels {lab.shape}: expected (N, 2F) and (N,), N >= 1")
    f = arr.shape[1] // 2
    xy = arr.reshape(-1, f, 2)
    keep = _keep_mask(xy[:, 0], lab, rng, cfg)
    xy, lab = xy[keep].copy(), lab[keep].copy()
    n = xy.shape[0]
    xy += rng.normal(scale=rng.uniform(*cfg.noise_px), size=xy.shape)
    if f > 1 and rng.random() < cfg.prob_drift:
        count = int(rng.uniform(*cfg.drift_fraction) * n)
        if count:
            sel = rng.choice(n, count, replace=False)
            velocity = rng.normal(size=(count, 2))
            velocity *= rng.uniform(*cfg.drift_px_per_frame, size=(count, 1)) / (
                np.linalg.norm(velocity, axis=1, keepdims=True) + 1e-12
            )
            xy[sel] += velocity[:, None, :] * np.arange(f)[None, :, None]
            lab[sel] = -1
    if rng.random() < cfg.prob_outliers:
        count = int(rng.uniform(*cfg.outlier_fraction) * n)
        if count:
            lo, hi = xy[:, 0].min(axis=0), xy[:, 0].max(axis=0)
            start = rng.uniform(lo, hi, size=(count, 1, 2))
            steps = rng.normal(scale=rng.uniform(*cfg.outlier_step_px), size=(count, f - 1, 2))
            walk = np.concatenate([start, start + np.cumsum(steps, axis=1)], axis=1)
            xy = np.concatenate([xy, walk])
            lab = np.concatenate([lab, np.full(count, -1, dtype=np.int64)])
    return np.ascontiguousarray(xy.reshape(-1, 2 * f), dtype=np.float32), lab


TRACK_AUGMENT = TrackAugmentConfig()
"""The augmentation of KLT-track sources (the defaults above)."""

PAIR_AUGMENT = TrackAugmentConfig(num_points=(40, 600), outlier_step_px=(10.0, 80.0))
"""The augmentation of two-view sources: SIFT gives 40-600 matches per pair, and a gross outlier
lands anywhere in image 2, not a few pixels from where it started."""
