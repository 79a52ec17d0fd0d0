"""K-means on embeddings, with the number of clusters K chosen automatically.

Two criteria pick K from a sweep of K-means fits:

- ``"residual"`` (default): an elbow of the K-means residual curve, scored by how much sharper the
  relative drop of the residual is at K than at K+1 (see :func:`cluster_auto_k`).
- ``"silhouette"``: the mean silhouette coefficient, K >= 2 plus a threshold rule
  for K = 1.

Cluster ids are ordered by cluster size (0 = largest, usually the background), ties broken by
first appearance, so results are deterministic for a seed and easy to colour consistently.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import replace

import numpy as np
import numpy.typing as npt

from mosegpipe.configs.grouping import ClusterConfig
from mosegpipe.errors import InputError
from mosegpipe.runtime import limited_threads
from mosegpipe.types import Clustering

logger = logging.getLogger(__name__)

# A residual at or below this fraction of r(1) counts as "nothing left to explain": float noise,
# not structure, so the relative drop after it is defined as 0 instead of 0/0.
_RESIDUAL_FLOOR = 1e-9

# Automatic K scores the candidates on a seeded random sample of this many points when N is larger,
# then gives every point the label of its nearest centre: the silhouette needs (S, S) distances, so
# without a sample 20 000 tracks took 3.3 GB and 100 000 asked for 74.5 GiB. 3000 points cost about
# 70 MB of distances and keep clips and video windows (< 1100 tracks) exactly as they were.
MAX_SCORED_POINTS = 3000


def _check_embeddings(emb: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Validate (N, E) embeddings; return them as float64 (residual ratios need the precision)."""
    try:
        arr = np.asarray(emb)
    except (TypeError, ValueError) as exc:  # ragged lists
        raise InputError(f"embeddings: not an array of numbers ({exc})") from exc
    if arr.ndim != 2 or arr.shape[0] == 0 or arr.shape[1] == 0:
        raise InputError(f"embeddings must have shape (N, E) with N, E >= 1, got {arr.shape}")
    if arr.dtype.kind not in "iuf":
        raise InputError(f"embeddings must be real numbers, got dtype {arr.dtype}")
    arr = arr.astype(np.float64, copy=False)
    if not np.all(np.isfinite(arr)):
        raise InputError(f"embeddings of shape {arr.shape} contain NaN or inf")
    return arr


def check_k(k: object, what: str) -> int:
    """`k` as an int, or an InputError naming it (1.5, "3", True and None are not a number of clusters)."""
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)):
        raise InputError(f"{what}={k!r}: the number of clusters must be an integer")
    return int(k)


def relabel_by_size(labels: npt.ArrayLike) -> npt.NDArray[np.int64]:
    """Renumber cluster ids 0..k-1 by decreasing size, ties broken by first appearance.

    Args:
        labels: (N,) integer cluster ids (any values).

    Returns:
        (N,) int64 ids; id 0 is the largest cluster.
    """
    labels = np.asarray(labels).ravel()
    values, first, inverse, counts = np.unique(labels, return_index=True, return_inverse=True, return_counts=True)
    # lexsort sorts by the last key first: size descending, then first appearance ascending.
    order = np.lexsort((first, -counts))
    new_id = np.empty(values.size, dtype=np.int64)
    new_id[order] = np.arange(values.size, dtype=np.int64)
    return new_id[inverse.ravel()]


# K-means stops when no centre's squared move in an iteration exceeds _TOL times the data's mean
# per-dimension variance (OpenCV compares the largest move with its epsilon), or after _MAX_ITER
# iterations: scikit-learn's defaults (tol 1e-4, max_iter 300), which the clustering was measured with.
_TOL = 1e-4
_MAX_ITER = 300


def kmeans(
    emb: npt.ArrayLike,
    k: int,
    seed: int = 0,
    n_init: int = 10,
    num_threads: int = 1,
) -> tuple[npt.NDArray[np.int64], float]:
    """K-means with a fixed K: OpenCV's `cv2.kmeans`, k-means++ initialisation, best of n_init restarts.

    OpenCV instead of scikit-learn: importing scikit-learn cost ~1.2 s of CPU, most of `moseg run`'s
    start-up on 5 frames (docs/RESULTS.md, "Start-up"). The k-means++ seeding draws from OpenCV's
    random generator of the calling thread, seeded with ``seed`` before every call: the same seed gives
    the same result whatever ran before. The points are centred and scaled by one number first (K-means
    does not change under either) so that OpenCV's float32 keeps their precision; the inertia is
    computed in float64 from the labels.

    Args:
        emb: (N, E) float embeddings.
        k: number of clusters, 1 <= k <= N.
        seed: seed of the k-means++ seeding; same seed, same result.
        n_init: number of restarts; the one of least residual is kept.
        num_threads: thread limit of the BLAS/OpenMP pools during the call (OpenCV's own threads are
            the process's setting, runtime.set_threads).

    Returns:
        labels: (N,) int64 in 0..k-1, ordered by decreasing cluster size (see relabel_by_size).
            Fewer than k ids occur when the points have fewer than k distinct values.
        inertia: sum of squared distances of the points to the mean of their cluster (units of emb**2).

    Raises:
        InputError: bad shape, non-finite values, or k outside 1..N.
    """
    import cv2

    x = _check_embeddings(emb)
    n = x.shape[0]
    k = check_k(k, "k")
    if k < 1:
        raise InputError(f"k={k} must be at least 1")
    if k > n:
        raise InputError(f"k={k} is larger than the number of points ({n})")
    centred = x - x.mean(axis=0)
    if k == 1:  # exact: the best single centre is the mean (and OpenCV reads one row as many points)
        return np.zeros(n, dtype=np.int64), float(np.sum(centred * centred))
    spread = float(np.sqrt(np.mean(centred * centred)))  # the root of the mean per-dimension variance
    scale = spread if spread > 0 else 1.0
    data = np.ascontiguousarray(centred / scale, dtype=np.float32)
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, _MAX_ITER, float(np.sqrt(_TOL)))
    # Inside cluster_auto_k's sweep the pools are already limited: limited_threads enters nothing then.
    with limited_threads(num_threads):
        cv2.setRNGSeed(seed)  # the calling thread's generator, which the k-means++ seeding draws from
        _, raw, _ = cv2.kmeans(data, k, None, criteria, n_init, cv2.KMEANS_PP_CENTERS)
    labels = relabel_by_size(raw.ravel())
    sums = np.zeros((int(labels.max()) + 1, x.shape[1]))
    np.add.at(sums, labels, centred)
    means = sums / np.bincount(labels)[:, None]
    return labels, float(np.sum((centred - means[labels]) ** 2))


def pairwise_distances(x: npt.NDArray[np.floating]) -> npt.NDArray[np.float64]:
    """(N, N) Euclidean distances between the rows of x: symmetric, zero on the diagonal (SciPy's, imported on
    first use: `moseg run` imports scipy.spatial ahead)."""
    from scipy.spatial.distance import pdist, squareform

    out: npt.NDArray[np.float64] = squareform(pdist(np.asarray(x, dtype=np.float64)))
    return out


def mean_silhouette(distances: npt.NDArray[np.float64], labels: npt.NDArray[np.int64]) -> float:
    """Mean silhouette coefficient from a precomputed (N, N) distance matrix: the value of scikit-learn's
    ``silhouette_score(distances, labels, metric="precomputed")`` (a point alone in its cluster scores 0),
    computed with one matrix product instead of scikit-learn's chunked loop, which cost ~10 ms per call
    at N = 1000 (half of whole-video mode's clustering time: every window scores K = 2..8).

    Args:
        distances: symmetric (N, N) distances with a zero diagonal.
        labels: (N,) cluster ids 0..K-1, at least two distinct.
    """
    ids, inverse, counts = np.unique(labels, return_inverse=True, return_counts=True)
    n = len(labels)
    onehot = np.zeros((n, len(ids)))
    onehot[np.arange(n), inverse] = 1.0
    sums = distances @ onehot  # (N, K): each point's summed distance to every cluster
    own = counts[inverse]
    a = sums[np.arange(n), inverse] / np.maximum(own - 1, 1)
    others = sums / counts
    others[np.arange(n), inverse] = np.inf
    b = others.min(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        s = (b - a) / np.maximum(a, b)
    s = np.where(own > 1, np.nan_to_num(s), 0.0)
    return float(s.mean())


def single_motion_residual_px(points: npt.ArrayLike) -> float:
    """How far the tracks are from moving as one: the residual flow after the best single affine motion.

    For every frame t >= 2, one affine map from the frame-1 positions to the frame-t positions is
    fitted to all points (least squares); each point's residual is its RMS distance to the map's
    prediction over the frames. Camera pans and zooms of a distant scene fit one affine map;
    independently moving objects leave residuals of about their motion relative to the rest.

    Args:
        points: (N, 2F) trajectory matrix, columns x_1, y_1, ..., x_F, y_F, pixels.

    Returns:
        The 99th percentile of the per-point residuals, pixels (inf for fewer than 10 points or
        fewer than 2 frames: no evidence).

    Raises:
        InputError: not an (N, 2F) matrix of finite real numbers.
    """
    arr = np.asarray(points)
    if arr.ndim != 2 or arr.shape[1] % 2 or arr.dtype.kind not in "iuf" or not np.all(np.isfinite(arr)):
        raise InputError(f"points must be a finite (N, 2F) trajectory matrix, got {arr.dtype} {arr.shape}")
    n, frames = arr.shape[0], arr.shape[1] // 2
    if n < 10 or frames < 2:
        return float("inf")
    xy = arr.reshape(n, frames, 2).astype(np.float64)
    design = np.c_[xy[:, 0], np.ones(n)]  # (N, 3): x_1, y_1, 1
    squared = np.zeros(n)
    for t in range(1, frames):
        affine, *_ = np.linalg.lstsq(design, xy[:, t], rcond=None)
        squared += np.sum((design @ affine - xy[:, t]) ** 2, axis=1)
    return float(np.percentile(np.sqrt(squared / (frames - 1)), 99))


def _elbow_scores(residuals: npt.NDArray[np.float64], candidates: range) -> dict[int, float]:
    """Elbow score per candidate K from residuals[K] = r(K), K = 0..K_max+1 (index 0 unused)."""
    r = np.minimum.accumulate(residuals[1:])  # r(K) is non-increasing for exact K-means
    r = np.concatenate(([np.inf], r))
    floor = _RESIDUAL_FLOOR * r[1]

    def drop(kk: int) -> float:
        # Relative drop d(K) = 1 - r(K) / r(K-1): the share of what K-1 clusters left unexplained
        # that the K-th cluster explains.
        if r[kk - 1] <= floor:
            return 0.0
        return float(1.0 - r[kk] / r[kk - 1])

    return {kk: drop(kk) - drop(kk + 1) for kk in candidates}


def cluster_auto_k(
    emb: npt.ArrayLike,
    cfg: ClusterConfig = ClusterConfig(),
    k: int | None = None,
    points: npt.ArrayLike | None = None,
    prefer_k: int | None = None,
) -> Clustering:
    """Cluster embeddings with K-means, choosing K automatically unless ``k`` is given.

    With ``k`` given this is plain K-means (method "fixed", empty scores). Otherwise K-means runs
    for every K in a sweep and one criterion picks K. Let r(K) be the K-means residual (inertia)
    and S = sum_i ||e_i||^2. The embeddings are expected L2-normalised, but both criteria are
    scale-free (multiplying all embeddings by a constant changes nothing).

    1. Small-spread rule (both methods, only when k_min == 1): if r(1) <= min_spread * S, i.e.
       all embeddings are one point up to noise, answer K = 1 without a sweep
       (scores = {1: 1.0}).
    2. "residual": r(K) is computed for K = 1 .. min(k_max + 1, N) and made non-increasing
       (running minimum, against K-means local minima). The relative drop
       d(K) = 1 - r(K) / r(K-1) is the share of the residual left by K-1 clusters that the K-th
       cluster removes (d(K) = 0 when r(K-1) <= 1e-9 r(1): nothing is left to explain).
       Candidates are K in [max(2, k_min), min(k_max, N - 1)] so that d(K + 1) exists, and
       score(K) = d(K) - d(K+1), a second-order difference on a relative scale: large when the
       residual collapses at K and flattens after it, as for well-separated groups. Relative
       drops make the score scale-free and little affected by unequal cluster sizes; it lies in
       [-1, 1]. When the spread r(1) is at most one_motion_spread * S, K = 1 is a candidate with
       the score min_elbow, so it wins exactly when no K >= 2 exceeds it (one Gaussian blob of
       N >= 100 points in E >= 3 dimensions scores at most 0.15); wider spreads never give K = 1.
    3. "silhouette": mean silhouette coefficient (Euclidean; scikit-learn's definition) of the K-means labels
       for K in [max(2, k_min), min(k_max, N - 1)]. K = 1 (under the same spread gate) gets the
       score min_silhouette, so it wins exactly when no K >= 2 exceeds it.

    0. No-motion rule (only with ``points``, k_min == 1 and cfg.static_residual_px set): when
       one affine motion explains the trajectories to within static_residual_px
       (single_motion_residual_px), the answer is K = 1 without a sweep (empty scores, a note):
       nothing moves more than the tracking noise, whatever the embedding looks like.

    Large N: with more than MAX_SCORED_POINTS points (3000), rules 1-3 run on a seeded random sample
    of that many points and every point takes the label of its nearest centre (the mean embedding of
    a sampled cluster), so memory and time stay linear in N; rule 0 and K given use all points.

    After a sweep, the choice is reported as ambiguous (Clustering.note, a logged warning) when
    the runner-up's score is within cfg.ambiguity_margin of the winner's. With ``prefer_k`` (e.g.
    the K of a video's previous window) a candidate K = prefer_k that scores within that margin of
    the winner wins instead: on a near tie the evidence does not justify a change of K.

    With k_min >= 2, K = 1 is never a candidate and the best K >= k_min wins. Ties go to the
    smaller K. When no candidate exists (N <= 2 or k_min > N - 1) the answer is
    K = min(k_min, N) with empty scores. For tiny N the choice means little: r(N) = 0 trivially,
    so the candidate K = N - 1 has d(K + 1) = 1 and a low "residual" score.

    Args:
        emb: (N, E) float embeddings, one row per point (L2-normalised rows expected).
        cfg: sweep range, criterion and K-means settings.
        k: force this many clusters (1 <= k <= N) instead of choosing.
        points: optional (N, 2F) trajectory matrix (pixels) of the same points, for the no-motion rule.
        prefer_k: the K that wins a near tie (within cfg.ambiguity_margin of the best score).

    Returns:
        Clustering with labels (N,) int64 ordered by decreasing cluster size (0 = largest, ties
        by first appearance), the chosen k, the score of every candidate K and the method
        ("residual", "silhouette" or "fixed").

    Raises:
        InputError: bad embeddings, or k outside 1..N.
    """
    with limited_threads(cfg.num_threads):
        return _cluster_auto_k(emb, cfg, k, points, prefer_k)


def nearest_centre(
    x: npt.NDArray[np.float64], centres: npt.NDArray[np.float64], chunk: int = 65536
) -> npt.NDArray[np.int64]:
    """(N,) index of each row's nearest centre (Euclidean), in chunks: memory O(chunk * K), not O(N * K)."""
    out = np.empty(len(x), dtype=np.int64)
    c2 = np.sum(centres * centres, axis=1)
    for lo in range(0, len(x), chunk):
        block = x[lo : lo + chunk]
        # ||x - c||^2 = ||x||^2 - 2 x.c + ||c||^2; ||x||^2 is the same for every centre of a row.
        out[lo : lo + chunk] = np.argmin(c2[None, :] - 2.0 * block @ centres.T, axis=1)
    return out


def _auto_k_on_sample(x: npt.NDArray[np.float64], cfg: ClusterConfig, prefer_k: int | None) -> Clustering:
    """Automatic K for N > MAX_SCORED_POINTS: the sweep on a seeded sample, then every point to its
    nearest centre of the chosen K (memory and time linear in N)."""
    n = x.shape[0]
    rng = np.random.default_rng(cfg.seed)
    idx = np.sort(rng.choice(n, size=MAX_SCORED_POINTS, replace=False))
    sample = _cluster_auto_k(x[idx], cfg, None, None, prefer_k)
    logger.info("automatic K scored on %d of %d points: K=%d", MAX_SCORED_POINTS, n, sample.k)
    if sample.k == 1:
        return replace(sample, labels=np.zeros(n, dtype=np.int64))
    centres = np.stack([x[idx][sample.labels == c].mean(axis=0) for c in range(int(sample.labels.max()) + 1)])
    return replace(sample, labels=relabel_by_size(nearest_centre(x, centres)))


def _cluster_auto_k(
    emb: npt.ArrayLike,
    cfg: ClusterConfig,
    k: int | None,
    points: npt.ArrayLike | None = None,
    prefer_k: int | None = None,
) -> Clustering:
    """cluster_auto_k inside one thread limit."""
    x = _check_embeddings(emb)
    n = x.shape[0]
    if points is not None and np.shape(points)[0] != n:
        raise InputError(f"points: {np.shape(points)[0]} rows for {n} embeddings")
    if k is not None:
        return fixed_k(x, cfg, k)

    def fit(kk: int) -> tuple[npt.NDArray[np.int64], float]:
        return kmeans(x, kk, seed=cfg.seed, n_init=cfg.n_init, num_threads=cfg.num_threads)

    if points is not None and cfg.k_min == 1 and cfg.static_residual_px is not None:
        residual = single_motion_residual_px(points)
        if residual <= cfg.static_residual_px:
            note = (
                f"K = 1: one motion explains every track to within {residual:.2f} px "
                f"(99th percentile; tracking noise is up to {cfg.static_residual_px:g} px): nothing moves"
            )
            logger.info(note)
            return Clustering(np.zeros(n, dtype=np.int64), 1, {}, cfg.method, note)

    if n > MAX_SCORED_POINTS:
        return _auto_k_on_sample(x, cfg, prefer_k)

    total = float(np.sum(x * x))
    spread = float(np.sum((x - x.mean(axis=0)) ** 2))
    if cfg.k_min == 1 and spread <= cfg.min_spread * total:
        logger.debug("spread %.3g of %.3g is below min_spread: K=1", spread, total)
        return Clustering(np.zeros(n, dtype=np.int64), 1, {1: 1.0}, cfg.method)

    k_hi = min(cfg.k_max, n - 1)
    candidates = range(max(2, cfg.k_min), k_hi + 1)
    if len(candidates) == 0:
        k_only = min(cfg.k_min, n)
        logger.debug("no candidate K for N=%d and k_min=%d: K=%d", n, cfg.k_min, k_only)
        return Clustering(fit(k_only)[0], k_only, {}, cfg.method)

    fits, scores, threshold = _scored_fits(x, cfg, candidates, k_hi, spread, fit)
    if cfg.k_min == 1 and spread <= cfg.one_motion_spread * total:
        scores = {1: float(threshold), **scores}
        fits[1] = np.zeros(n, dtype=np.int64)
    best = max(scores, key=lambda kk: (scores[kk], -kk))
    preferred = False
    if prefer_k is not None and prefer_k in scores and scores[best] - scores[prefer_k] <= cfg.ambiguity_margin:
        best, preferred = prefer_k, best != prefer_k
    logger.debug("%s scores %s: K=%d", cfg.method, scores, best)
    note = ""
    runner_up = max((kk for kk in scores if kk != best), key=lambda kk: (scores[kk], -kk), default=None)
    if runner_up is not None and scores[best] - scores[runner_up] <= cfg.ambiguity_margin:
        note = (
            f"the K choice is ambiguous: K = {best} scored {scores[best]:.3f}, K = {runner_up} {scores[runner_up]:.3f} "
            f"({cfg.method}, within {cfg.ambiguity_margin:g}){'; the preferred K kept' if preferred else ''}; "
            "pass --k to decide"
        )
        logger.warning(note)
    return Clustering(labels=fits[best], k=best, scores=scores, method=cfg.method, note=note)


def fixed_k(x: npt.NDArray[np.floating], cfg: ClusterConfig, k: int) -> Clustering:
    """K-means with the K given (--k); InputError for a K below 1 or above the number of tracks."""
    n = x.shape[0]
    k = check_k(k, "--k")
    if k < 1:
        raise InputError(f"--k {k} must be at least 1")
    if k > n:
        raise InputError(f"--k {k} is larger than the number of tracks ({n})")
    labels, _ = kmeans(x, k, seed=cfg.seed, n_init=cfg.n_init, num_threads=cfg.num_threads)
    return Clustering(labels=labels, k=k, scores={}, method="fixed")


def _scored_fits(
    x: npt.NDArray[np.floating],
    cfg: ClusterConfig,
    candidates: range,
    k_hi: int,
    spread: float,
    fit: Callable[[int], tuple[npt.NDArray[np.int64], float]],
) -> tuple[dict[int, npt.NDArray[np.int64]], dict[int, float], float]:
    """(the labels of each K fitted, the score of each candidate K, the score K = 1 stands for) by
    cfg.method: the elbow of the K-means residuals, or the mean silhouette."""
    n = x.shape[0]
    fits: dict[int, npt.NDArray[np.int64]] = {}
    if cfg.method == "residual":
        residuals = np.zeros(k_hi + 2, dtype=np.float64)
        residuals[1] = spread  # exact: the optimal single centroid is the mean
        fits[1] = np.zeros(n, dtype=np.int64)
        for kk in range(2, k_hi + 2):
            fits[kk], residuals[kk] = fit(kk)
        scores = _elbow_scores(residuals, candidates)
        threshold = cfg.min_elbow
    else:
        scores = {}
        # One distance matrix for every K: silhouette_score would recompute it per call.
        distances = pairwise_distances(x)
        for kk in candidates:
            fits[kk] = fit(kk)[0]
            if np.unique(fits[kk]).size < 2:
                scores[kk] = -1.0  # duplicate points gave one cluster: no evidence for K
                continue
            scores[kk] = mean_silhouette(distances, fits[kk])
        threshold = cfg.min_silhouette
    return fits, scores, threshold
