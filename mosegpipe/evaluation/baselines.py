"""Classical motion-segmentation baselines, run beside SubspaceNet by ``moseg eval``.

Every baseline has the signature ``(traj, k, seed=0) -> labels``: ``traj`` is an (N, D) trajectory
matrix (pixel columns x_1, y_1, ..., x_F, y_F, D = 2F), ``k`` the number of motions or None to
choose it, and the result (N,) int64 labels in 0..K-1 ordered by decreasing cluster size.

All baselines first z-score every column over the points (:func:`zscore_columns`). That is an
affine map of R^D, so points on a common affine motion subspace stay on one, and it puts
trajectories of any image size on one scale.

- ``kmeans-raw``: K-means on the z-scored matrix; K by :func:`mosegpipe.group.cluster.cluster_auto_k`
  with its default rule (``ClusterConfig().method``: the silhouette).
- ``spectral-raw``: spectral clustering with a self-tuning Gaussian affinity; K by the eigengap.
- ``ssc``: Sparse Subspace Clustering (Elhamifar & Vidal, PAMI 2013) with the affine constraint,
  solved by ADMM in O(D N^2) per iteration; spectral clustering of |C| + |C|^T, K by the eigengap.

Measured with one thread on the shared 2-core development machine, N = 500, D = 10 (three
synthetic affine motions), median of 5 runs: kmeans-raw 10-15 ms with K given, 95-150 ms with
the K sweep; spectral-raw 25-37 ms; ssc 210-340 ms (1.5 s at N = 1000).
"""

from __future__ import annotations

import logging
from typing import Protocol

import numpy as np
import numpy.typing as npt

from mosegpipe.errors import InputError
from mosegpipe.group.cluster import ClusterConfig, cluster_auto_k, kmeans

logger = logging.getLogger(__name__)


class Baseline(Protocol):
    """A baseline segmenter: trajectories (N, D) and K (or None) to labels (N,) int64."""

    def __call__(self, traj: npt.ArrayLike, k: int | None, seed: int = 0) -> npt.NDArray[np.int64]: ...


# Largest K that the automatic choices consider; the benchmarks have at most 5 motions.
MAX_AUTO_K = 8
# Self-tuning affinity scale (Zelnik-Manor & Perona 2004): distance to the 7th neighbour.
_LOCAL_SCALE_NEIGHBOUR = 7
# SSC regularisation: lambda = alpha / mu with mu the smallest "largest coherence" of a point
# with the others (Elhamifar & Vidal); alpha = 800 is their motion-segmentation setting.
_SSC_ALPHA = 800.0
_SSC_MAX_ITER = 200  # Elhamifar & Vidal's default; converges in 50-150 iterations here
_SSC_TOL = 2e-4  # max-abs change of the constraints, their default stopping threshold


def zscore_columns(traj: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Z-score each column of a trajectory matrix over the points.

    Args:
        traj: (N, D) trajectory matrix, pixels.

    Returns:
        (N, D) float64 with zero-mean, unit-variance columns (constant columns become 0).

    Raises:
        InputError: not 2-D, empty, or not finite.
    """
    x = np.asarray(traj)
    if x.ndim != 2 or x.shape[0] == 0 or x.shape[1] == 0:
        raise InputError(f"trajectory matrix must have shape (N, D) with N, D >= 1, got {x.shape}")
    x = x.astype(np.float64, copy=False)
    if not np.all(np.isfinite(x)):
        raise InputError(f"trajectory matrix of shape {x.shape} contains NaN or inf")
    std = x.std(axis=0)
    return (x - x.mean(axis=0)) / np.where(std > 0, std, 1.0)


def check_k(k: int | None, n: int) -> None:
    if k is not None and not 1 <= k <= n:
        raise InputError(f"--k {k} must lie between 1 and the number of tracks ({n})")


def spectral_labels(affinity: npt.NDArray[np.float64], k: int | None, seed: int = 0) -> npt.NDArray[np.int64]:
    """Normalised spectral clustering (Ng, Jordan & Weiss 2001) of a symmetric affinity.

    K, when not given, is chosen by the eigengap: with 0 = l_1 <= l_2 <= ... the eigenvalues of
    the normalised Laplacian I - D^-1/2 W D^-1/2, K = argmax_{1 <= K <= K_max} (l_{K+1} - l_K),
    K_max = min(MAX_AUTO_K, N - 1). The K smallest eigenvectors, rows scaled to unit length, are
    clustered by K-means with the given seed.

    Args:
        affinity: (N, N) symmetric non-negative affinity.
        k: number of clusters, or None for the eigengap choice.
        seed: K-means seed.

    Returns:
        (N,) int64 labels ordered by decreasing cluster size.
    """
    from scipy.linalg import eigh

    n = affinity.shape[0]
    if n == 1 or k == 1:
        return np.zeros(n, dtype=np.int64)
    degree = affinity.sum(axis=1)
    # Isolated points (zero degree) would divide by zero; a tiny degree keeps them as their own
    # components, which is what they are.
    inv_sqrt = 1.0 / np.sqrt(np.maximum(degree, 1e-12 * max(degree.max(), 1e-300)))
    normalised = inv_sqrt[:, None] * affinity * inv_sqrt[None, :]
    k_max = min(MAX_AUTO_K, n - 1) if k is None else k
    # Largest eigenpairs of D^-1/2 W D^-1/2 are the smallest of the Laplacian.
    n_eig = min(k_max + 1, n)
    values, vectors = eigh(normalised, subset_by_index=[n - n_eig, n - 1])
    values, vectors = values[::-1], vectors[:, ::-1]
    if k is None:
        gaps = values[:k_max] - values[1 : k_max + 1]  # l_{K+1} - l_K of the Laplacian
        k = int(np.argmax(gaps)) + 1
        logger.debug("eigengap choice K=%d from eigenvalues %s", k, 1 - values)
        if k == 1:
            return np.zeros(n, dtype=np.int64)
    embedding = vectors[:, :k]
    embedding = embedding / np.maximum(np.linalg.norm(embedding, axis=1, keepdims=True), 1e-12)
    return kmeans(embedding, k, seed=seed)[0]


def kmeans_raw(traj: npt.ArrayLike, k: int | None, seed: int = 0) -> npt.NDArray[np.int64]:
    """K-means on the column-z-scored trajectory matrix.

    Args:
        traj: (N, D) trajectory matrix, pixels.
        k: number of motions, or None for the choice of :func:`mosegpipe.group.cluster.cluster_auto_k`
            with its default rule (``ClusterConfig().method``: the silhouette; K in 1..8).
        seed: K-means seed.

    Returns:
        (N,) int64 labels ordered by decreasing cluster size.
    """
    z = zscore_columns(traj)
    check_k(k, z.shape[0])
    cfg = ClusterConfig(k_max=MAX_AUTO_K, seed=seed)
    return cluster_auto_k(z, cfg, k=k).labels


def self_tuning_affinity(x: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Gaussian affinity with a local scale per point (Zelnik-Manor & Perona 2004).

    W_ij = exp(-||x_i - x_j||^2 / (s_i s_j)), s_i = distance from x_i to its 7th nearest
    neighbour (fewer for tiny N), W_ii = 0.

    Args:
        x: (N, D) points.

    Returns:
        (N, N) float64 symmetric affinity in [0, 1].
    """
    sq = np.sum(x * x, axis=1)
    dist2 = np.maximum(sq[:, None] + sq[None, :] - 2.0 * x @ x.T, 0.0)
    n = x.shape[0]
    if n == 1:
        return np.zeros((1, 1))
    neighbour = min(_LOCAL_SCALE_NEIGHBOUR, n - 1)
    scale = np.sqrt(np.partition(dist2, neighbour, axis=1)[:, neighbour])
    # Duplicated points have a zero local scale; a floor keeps them finite (all-identical input
    # gives an all-ones affinity).
    top = float(scale.max())
    scale = np.maximum(scale, 1e-6 * top if top > 0 else 1.0)
    affinity = np.exp(-dist2 / (scale[:, None] * scale[None, :]))
    np.fill_diagonal(affinity, 0.0)
    return affinity


def spectral_raw(traj: npt.ArrayLike, k: int | None, seed: int = 0) -> npt.NDArray[np.int64]:
    """Spectral clustering of the column-z-scored trajectory matrix.

    Args:
        traj: (N, D) trajectory matrix, pixels.
        k: number of motions, or None for the eigengap choice (K in 1..8).
        seed: seed of the K-means step.

    Returns:
        (N,) int64 labels ordered by decreasing cluster size.
    """
    z = zscore_columns(traj)
    check_k(k, z.shape[0])
    return spectral_labels(self_tuning_affinity(z), k, seed=seed)


def ssc_coefficients(
    x: npt.NDArray[np.float64],
    alpha: float = _SSC_ALPHA,
    max_iter: int = _SSC_MAX_ITER,
    tol: float = _SSC_TOL,
) -> npt.NDArray[np.float64]:
    """Sparse self-expression of points in affine subspaces (affine SSC), by ADMM.

    Solves  min_C ||C||_1 + lambda/2 ||X - X C||_F^2  s.t.  1^T C = 1^T, diag(C) = 0,
    with X = x^T (D, N) holding one point per column and lambda = alpha / mu,
    mu = min_i max_{j != i} |x_i . x_j|. ADMM splits C into a dense A (least-squares and affine
    constraint) and the sparse C (soft threshold, zero diagonal), with penalty rho = alpha and
    dual variables for A = C and 1^T A = 1^T. The A-step matrix
    lambda X^T X + rho I + rho 1 1^T = rho I + Y^T Y, Y = [sqrt(lambda) X; sqrt(rho) 1^T], is
    inverted through the Woodbury identity with a (D+1) x (D+1) solve, so one iteration costs
    O(D N^2) instead of O(N^3).

    Args:
        x: (N, D) points, one per row.
        alpha: regularisation multiplier (larger = denser, more exact self-expression).
        max_iter: ADMM iterations at most.
        tol: stop when max |A - C| and max |1^T A - 1| are both below this.

    Returns:
        (N, N) float64 coefficients C; column j expresses point j by the other points.
    """
    n, d = x.shape
    gram = x @ x.T  # X^T X, (N, N)
    off = np.abs(gram - np.diag(np.diag(gram)))
    mu = float(off.max(axis=1).min()) if n > 1 else 0.0
    lam = alpha / mu if mu > 0 else alpha
    rho = alpha  # C is dimensionless, so its penalty (threshold 1/rho) must not scale with x
    ones = np.ones(n)
    # lambda X^T X + rho 1 1^T = Y^T Y, so the A-step solves (rho I + Y^T Y) A = Y^T Y + rho (...)
    # and Woodbury gives rho (rho I + Y^T Y)^-1 = I - Y^T S^-1 Y with S = rho I + Y Y^T.
    y = np.vstack([np.sqrt(lam) * x.T, np.sqrt(rho) * ones[None, :]])  # (D+1, N)
    s_inv = np.linalg.inv(rho * np.eye(d + 1) + y @ y.T)  # (D+1, D+1)
    m = ones - y.T @ (s_inv @ (y @ ones))  # rho (rho I + Y^T Y)^-1 1, (N,)
    left = np.hstack([y.T, -m[:, None]])  # (N, D+2)
    right = np.empty((d + 2, n))

    # Scaled duals: u_c for A = C, u_aff for 1^T A = 1^T. With B = C - u_c the A-step is
    # A = B + Y^T S^-1 (Y - Y B) - m u_aff^T, one (D+2)-inner-dimension product per iteration.
    c = np.zeros((n, n))
    u_c = np.zeros((n, n))
    u_aff = np.zeros(n)
    b = np.empty((n, n))
    a = np.empty((n, n))
    v = np.empty((n, n))
    thresh = 1.0 / rho
    for it in range(max_iter):
        np.subtract(c, u_c, out=b)
        right[: d + 1] = s_inv @ (y - y @ b)
        right[d + 1] = u_aff
        np.matmul(left, right, out=a)
        a += b
        np.add(a, u_c, out=v)
        np.clip(v, -thresh, thresh, out=c)
        np.subtract(v, c, out=c)  # soft threshold: v - clip(v) = sign(v) max(|v| - t, 0)
        np.fill_diagonal(c, 0.0)
        col_gap = a.sum(axis=0) - 1.0
        u_aff += col_gap
        if it % 5 == 4 or it == max_iter - 1:
            np.subtract(a, c, out=b)
            if max(np.abs(b).max(), np.abs(col_gap).max()) < tol:
                np.subtract(v, c, out=u_c)
                logger.debug("SSC ADMM converged after %d iterations", it + 1)
                break
        np.subtract(v, c, out=u_c)  # u_c + A - C
    else:
        logger.debug("SSC ADMM stopped at max_iter=%d", max_iter)
    return c


def ssc(traj: npt.ArrayLike, k: int | None, seed: int = 0) -> npt.NDArray[np.int64]:
    """Sparse Subspace Clustering (Elhamifar & Vidal, PAMI 2013) with the affine constraint.

    Trajectories of one affine motion span an affine subspace of dimension <= 3 in R^D, hence
    the affine constraint 1^T C = 1^T (see :func:`ssc_coefficients`). Each column of C is scaled
    to a maximum absolute value of 1, the affinity is W = |C| + |C|^T, and
    :func:`spectral_labels` splits it (eigengap when k is None).

    Args:
        traj: (N, D) trajectory matrix, pixels.
        k: number of motions, or None for the eigengap choice (K in 1..8).
        seed: seed of the K-means step of spectral clustering.

    Returns:
        (N,) int64 labels ordered by decreasing cluster size.
    """
    z = zscore_columns(traj)
    n = z.shape[0]
    check_k(k, n)
    if n == 1:
        return np.zeros(1, dtype=np.int64)
    c = np.abs(ssc_coefficients(z))
    c /= np.maximum(c.max(axis=0, keepdims=True), 1e-12)
    return spectral_labels(c + c.T, k, seed=seed)


BASELINES: dict[str, Baseline] = {
    "kmeans-raw": kmeans_raw,
    "spectral-raw": spectral_raw,
    "ssc": ssc,
}
"""The baselines by the name ``moseg eval`` shows them under."""
