"""Training losses for SubspaceNet embeddings, masked for padded batches.

Every loss takes
    z: (B, N, E) float embeddings (unit L2 norm per point, as SubspaceNet outputs them),
    labels: (B, N) int64 ground-truth group of each point, -1 on padding,
    mask: (B, N) bool, True on real points,
and returns a scalar: the mean over the batch's clips of a per-clip loss computed on that clip's real
points only (mask True and label >= 0). Clips without real points are left out of the mean; a batch
without any real point gives 0 (still attached to the graph). Labels need not be contiguous.
Tensors of the wrong shape are a bug in the caller (ValueError); bad settings are a ConfigError.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
import torch.nn.functional as F
from torch import Tensor

from mosegpipe.errors import ConfigError

# Added inside the logarithms of MIMI. Embeddings are unit vectors, so squared distances lie in
# [0, 4]; a perfectly collapsed group has intra spread 0 and log(0) = -inf. 1e-6 bounds the loss
# below (log 1e-6 = -13.8) and its gradient 1/(s + eps) above, and it sits just above the float32
# rounding noise of squared distances between unit vectors (~1e-7), so the loss stops rewarding
# spreads that float32 cannot resolve anyway.
MIMI_EPS = 1e-6


def _channels_first(z: Tensor) -> Tensor:
    """(B, N, E) embeddings -> the (B, E, N) view the loss terms are written in (no copy)."""
    if z.ndim != 3:
        raise ValueError(f"embeddings shape {tuple(z.shape)}: expected (B, N, E)")
    return z.transpose(1, 2)


def _valid_points(z: Tensor, labels: Tensor, mask: Tensor) -> Tensor:
    """Check shapes and return the (B, N) bool of points that count (mask True and label >= 0)."""
    if z.ndim != 3:
        raise ValueError(f"embeddings shape {tuple(z.shape)}: expected (B, N, E)")
    expected = (z.shape[0], z.shape[2])
    if labels.shape != expected or mask.shape != expected:
        raise ValueError(
            f"labels shape {tuple(labels.shape)} / mask shape {tuple(mask.shape)}: "
            f"expected {expected} for embeddings {tuple(z.shape)}"
        )
    if mask.dtype != torch.bool:
        raise ValueError(f"mask dtype {mask.dtype}: expected torch.bool")
    return mask & (labels >= 0)


def _dense_labels(labels: Tensor, valid: Tensor) -> tuple[Tensor, int]:
    """Relabel the valid points' groups to 0..K-1 over the whole batch (invalid points get 0)."""
    if not bool(valid.any()):
        return torch.zeros_like(labels), 1
    uniq, inverse = torch.unique(labels[valid], return_inverse=True)
    dense = torch.zeros_like(labels)
    dense[valid] = inverse
    return dense, int(uniq.numel())


def _mean_over_clips(per_clip: Tensor, has_points: Tensor, z: Tensor) -> Tensor:
    if not bool(has_points.any()):
        return z.sum() * 0.0
    return per_clip[has_points].mean()


def mimi_loss(z: Tensor, labels: Tensor, mask: Tensor, alpha: float = 0.5) -> Tensor:
    """MaxInterMinIntra loss: push group means apart, pull every point towards its group's mean.

    Per clip, with mu_k the mean embedding of group k:
        inter = min over pairs m != n of ||mu_m - mu_n||^2      (closest pair of groups)
        intra = max over groups l, points i in l of ||z_i - mu_l||^2   (worst spread)
        loss  = -alpha * log(inter + eps) + (1 - alpha) * log(intra + eps),   eps = MIMI_EPS.
    A clip with a single group has no pair of means: its loss is the intra term alone,
    (1 - alpha) * log(intra + eps), which still pulls the group together.

    Args:
        z: (B, N, E) embeddings.
        labels: (B, N) int64 groups, -1 on padding.
        mask: (B, N) bool, True on real points.
        alpha: weight of the inter term, in [0, 1].

    Returns:
        Scalar tensor, mean over clips.
    """
    z = _channels_first(z)
    if not 0.0 <= alpha <= 1.0:
        raise ConfigError(f"mimi_loss alpha={alpha}: must lie in [0, 1]")
    valid = _valid_points(z, labels, mask)
    terms = []
    # A Python loop over clips: B is small (<= 8) and each clip has its own number of groups.
    for b in range(z.shape[0]):
        keep = valid[b]
        if not bool(keep.any()):
            continue
        zb = z[b][:, keep].transpose(0, 1)  # (n, E)
        _, group = torch.unique(labels[b][keep], return_inverse=True)
        onehot = F.one_hot(group).to(zb.dtype)  # (n, K)
        means = (onehot.transpose(0, 1) @ zb) / onehot.sum(0).unsqueeze(1)  # (K, E)
        intra = ((zb - means[group]) ** 2).sum(-1).max()
        loss = (1.0 - alpha) * torch.log(intra + MIMI_EPS)
        num_groups = means.shape[0]
        if num_groups > 1:
            dist = ((means.unsqueeze(1) - means.unsqueeze(0)) ** 2).sum(-1)  # (K, K)
            eye = torch.eye(num_groups, dtype=torch.bool, device=dist.device)
            inter = dist.masked_fill(eye, float("inf")).min()
            loss = loss - alpha * torch.log(inter + MIMI_EPS)
        terms.append(loss)
    if not terms:
        return z.sum() * 0.0
    return torch.stack(terms).mean()


def l2_affinity_loss(z: Tensor, labels: Tensor, mask: Tensor) -> Tensor:
    """Affinity regression: ||Y^T Y - Z^T Z||_F^2 / N^2 per clip, without forming N x N matrices.

    Y is the (K, N) one-hot label matrix and Z the (E, N) embeddings of the clip's N real points.
    Expanding the square with traces:
        ||Y^T Y||_F^2 = sum_k n_k^2                 (n_k points in group k)
        ||Z^T Z||_F^2 = ||Z Z^T||_F^2               (E x E)
        <Y^T Y, Z^T Z> = tr(Z Y^T Y Z^T) = ||Z Y^T||_F^2   (E x K)
    so the cost is O(N (E + K) E) instead of O(N^2 E).

    Args:
        z: (B, N, E) embeddings.
        labels: (B, N) int64 groups, -1 on padding.
        mask: (B, N) bool, True on real points.

    Returns:
        Scalar tensor, mean over clips.
    """
    z = _channels_first(z)
    valid = _valid_points(z, labels, mask)
    dense, num_groups = _dense_labels(labels, valid)
    zm = torch.where(valid.unsqueeze(1), z, torch.zeros((), dtype=z.dtype, device=z.device))
    y = F.one_hot(dense, num_groups).to(z.dtype) * valid.unsqueeze(-1).to(z.dtype)  # (B, N, K)
    counts = valid.sum(-1).to(z.dtype)  # (B,)
    yy = (y.sum(1) ** 2).sum(-1)
    zz = (zm @ zm.transpose(1, 2)).pow(2).sum((1, 2))
    zy = (zm @ y).pow(2).sum((1, 2))
    # The three terms are each O(N^2) and nearly cancel at a good fit; clamp the float rounding.
    per_clip = (yy - 2.0 * zy + zz).clamp_min(0.0) / counts.clamp_min(1.0) ** 2
    return _mean_over_clips(per_clip, counts > 0, z)


def ce_affinity_loss(z: Tensor, labels: Tensor, mask: Tensor, scale: float = 1.0) -> Tensor:
    """Binary cross-entropy between same-group indicators and sigmoid(scale * cosine affinity).

    For every ordered pair (i, j) of real points of a clip (the diagonal included), the target is
    1 if i and j share a group, else 0, and the logit is scale * <z_i, z_j>. Since unit embeddings
    give affinities in [-1, 1], scale = 1 caps the probabilities at sigmoid(1) = 0.73; larger scales
    let the loss approach 0. Uses binary_cross_entropy_with_logits (stable log-sum-exp form).
    Forms a (B, N, N) tensor: fine up to N ~ 2000.

    Args:
        z: (B, N, E) embeddings.
        labels: (B, N) int64 groups, -1 on padding.
        mask: (B, N) bool, True on real points.
        scale: multiplier of the affinities before the sigmoid, > 0.

    Returns:
        Scalar tensor: per clip the mean over its real pairs, then the mean over clips.
    """
    z = _channels_first(z)
    if not scale > 0.0:
        raise ConfigError(f"ce_affinity_loss scale={scale}: must be > 0")
    valid = _valid_points(z, labels, mask)
    # Zero the padding first: NaN there would otherwise leak into the gradient through the BCE.
    zm = torch.where(valid.unsqueeze(1), z, torch.zeros((), dtype=z.dtype, device=z.device))
    logits = scale * (zm.transpose(1, 2) @ zm)  # (B, N, N)
    target = (labels.unsqueeze(2) == labels.unsqueeze(1)).to(z.dtype)
    pairs = valid.unsqueeze(2) & valid.unsqueeze(1)
    bce = F.binary_cross_entropy_with_logits(logits, target, reduction="none")
    bce = torch.where(pairs, bce, torch.zeros((), dtype=bce.dtype, device=bce.device))
    num_pairs = pairs.sum((1, 2)).to(z.dtype)
    per_clip = bce.sum((1, 2)) / num_pairs.clamp_min(1.0)
    return _mean_over_clips(per_clip, num_pairs > 0, z)


LOSSES: dict[str, Callable[..., Tensor]] = {
    "mimi": mimi_loss,
    "l2": l2_affinity_loss,
    "ce": ce_affinity_loss,
}
