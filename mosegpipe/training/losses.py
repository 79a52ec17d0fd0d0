"""Training losses for SubspaceNet embeddings, masked for padded batches.

Every loss takes
    z: (B, N, E) float embeddings (unit L2 norm per point, as SubspaceNet outputs them),
    labels: (B, N) int64 ground-truth group of each point, -1 on padding,
    mask: (B, N) bool, True on real points,
and returns a scalar: the mean over the batch's clips of a per-clip loss computed on that clip's real
points only (mask True and label >= 0). Clips without real points are left out of the mean; a batch
without any real point gives 0 (still attached to the graph). Labels need not be contiguous.
Tensors of the wrong shape are a bug in the caller (ValueError); bad settings are a ConfigError.

`LOSSES` names them for `--loss`: the paper's MaxInterMinIntra ("mimi"), the affinity losses "l2"
and "ce", the metric-learning baselines of the paper's Table 2: "triplet" (FaceNet, semi-hard
negatives), "lifted" (lifted structured embedding) and "facility" (the clustering-quality /
facility-location loss), "mimi-point" (MIMI with the worst point's spread as its intra term) and
"mimi-mean" (MIMI with the widest group's mean squared spread as its intra term).
"""

from __future__ import annotations

from collections.abc import Callable

import torch
import torch.nn.functional as F
from torch import Tensor

from mosegpipe.errors import ConfigError

# Added inside the logarithms of MIMI. Embeddings are unit vectors, so squared distances lie in
# [0, 4] (a group's scatter in [0, its size]); a perfectly collapsed group has intra spread 0 and log(0) = -inf. 1e-6 bounds the loss
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
    """MaxInterMinIntra loss as the paper defines it (Xu, Cheong, Li, ICCV 2019).

    Per clip, with mu_k the mean embedding of group k:
        inter = min over pairs m != n of ||mu_m - mu_n||^2            (closest pair of groups)
        s_l   = sum over points i in group l of ||z_i - mu_l||^2      (scatter of group l)
        intra = max over groups l of s_l                                (widest group)
        loss  = -alpha * log(inter + eps) + (1 - alpha) * log(intra + eps),   eps = MIMI_EPS.
    The intra gradient flows through every point of the widest group: d s_l / d z_i = 2 (z_i - mu_l)
    (the mean's own dependence on z_i cancels in the sum) and 0 for the other groups' points.
    A clip with a single group has no pair of means: its loss is the intra term alone,
    (1 - alpha) * log(intra + eps), which still pulls the group together.
    `mimi_point_loss` is the earlier variant whose intra term is the single worst point.

    Args:
        z: (B, N, E) embeddings.
        labels: (B, N) int64 groups, -1 on padding.
        mask: (B, N) bool, True on real points.
        alpha: weight of the inter term, in [0, 1].

    Returns:
        Scalar tensor, mean over clips.
    """
    return _mimi(z, labels, mask, alpha, "mimi_loss", intra="sum")


def mimi_point_loss(z: Tensor, labels: Tensor, mask: Tensor, alpha: float = 0.5) -> Tensor:
    """MaxInterMinIntra with a per-point intra term ("mimi-point"; our loss before it followed the paper).

    As `mimi_loss`, except intra = max over groups l, points i in l of ||z_i - mu_l||^2: the single
    point farthest from its group's mean, so the intra gradient reaches that one point only.
    The shipped two-view weights were trained with it (through the synthetic-f2 recipe).

    Args:
        z: (B, N, E) embeddings.
        labels: (B, N) int64 groups, -1 on padding.
        mask: (B, N) bool, True on real points.
        alpha: weight of the inter term, in [0, 1].

    Returns:
        Scalar tensor, mean over clips.
    """
    return _mimi(z, labels, mask, alpha, "mimi_point_loss", intra="point")


def mimi_mean_loss(z: Tensor, labels: Tensor, mask: Tensor, alpha: float = 0.5) -> Tensor:
    """MaxInterMinIntra with the mean squared spread of the widest group as its intra term ("mimi-mean").

    As `mimi_loss`, except intra = max over groups l of s_l / n_l (n_l = the group's points): the
    average squared distance of a group's points to their mean, on the same scale as `inter`. With
    the paper's sum s_l the ratio intra / inter that the loss weighs grows with the group's size, so
    an embedding whose groups are clearly apart still scores above a total collapse (every point on
    one spot: both terms at eps, loss 0 at alpha 0.5) unless its per-point spread is under
    inter / n_l; with the mean it scores below it as soon as the groups' spread is smaller than the
    distance between their means.

    Args:
        z: (B, N, E) embeddings.
        labels: (B, N) int64 groups, -1 on padding.
        mask: (B, N) bool, True on real points.
        alpha: weight of the inter term, in [0, 1].

    Returns:
        Scalar tensor, mean over clips.
    """
    return _mimi(z, labels, mask, alpha, "mimi_mean_loss", intra="mean")


def _mimi(z: Tensor, labels: Tensor, mask: Tensor, alpha: float, name: str, intra: str) -> Tensor:
    """The MIMI losses; intra: the widest group's summed ("sum") or mean ("mean") scatter, or the worst point."""
    z = _channels_first(z)
    if not 0.0 <= alpha <= 1.0:
        raise ConfigError(f"{name} alpha={alpha}: must lie in [0, 1]")
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
        spread = ((zb - means[group]) ** 2).sum(-1)  # (n,) squared distance of each point to its mean
        if intra == "point":
            widest = spread.max()
        else:
            scatter = onehot.transpose(0, 1) @ spread  # (K,) summed squared spread of each group
            widest = (scatter / onehot.sum(0) if intra == "mean" else scatter).max()
        loss = (1.0 - alpha) * torch.log(widest + MIMI_EPS)
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
    return _affinity_error(z, labels, mask, balanced=False)


def l2_balanced_affinity_loss(z: Tensor, labels: Tensor, mask: Tensor) -> Tensor:
    """Affinity regression with every pair of groups weighted equally: small objects count as much
    as the background.

    The plain L2 loss averages over the N^2 point pairs, so a group of n points weighs (n / N)^2: an
    object of 30 tracks among 600 moves the loss by 0.25 %. Here point i carries the weight
    w_i = 1 / n_g(i) (n_g points in its group), and per clip
        loss = sum_ij w_i w_j (A_ij - z_i . z_j)^2 / (sum_i w_i)^2,   A_ij = [g(i) = g(j)],
    i.e. the mean over the K^2 group blocks of each block's mean squared error. With D = diag(sqrt(w))
    this is ||(DY)^T (DY) - (DZ)^T (DZ)||_F^2 / K^2, computed with the traces of l2_affinity_loss.

    Args:
        z: (B, N, E) embeddings.
        labels: (B, N) int64 groups, -1 on padding.
        mask: (B, N) bool, True on real points.

    Returns:
        Scalar tensor, mean over clips.
    """
    return _affinity_error(z, labels, mask, balanced=True)


def _affinity_error(z: Tensor, labels: Tensor, mask: Tensor, balanced: bool) -> Tensor:
    """sum_ij w_i w_j (A_ij - z_i . z_j)^2 / (sum_i w_i)^2 per clip, averaged over clips, by traces.

    w_i = 1 (l2_affinity_loss) or 1 / n_g(i) (balanced, l2_balanced_affinity_loss). With D = diag(sqrt(w)),
    Y' = DY and Z' = DZ: ||Y'^T Y'||_F^2 (K x K), ||Z' Z'^T||_F^2 (E x E) and <Y' Y'^T, Z'^T Z'> =
    ||Z' Y'||_F^2 (E x K), so no N x N matrix is formed.
    """
    z = _channels_first(z)
    valid = _valid_points(z, labels, mask)
    dense, num_groups = _dense_labels(labels, valid)
    y = F.one_hot(dense, num_groups).to(z.dtype) * valid.unsqueeze(-1).to(z.dtype)  # (B, N, K)
    zm = torch.where(valid.unsqueeze(1), z, torch.zeros((), dtype=z.dtype, device=z.device))  # (B, E, N)
    if balanced:
        sizes = y.sum(1)  # (B, K) points per group per clip
        weight = (y / sizes.clamp_min(1.0).unsqueeze(1)).sum(-1)  # (B, N): 1 / n_g(i), 0 if invalid
        root = weight.sqrt()
        y, zm = y * root.unsqueeze(-1), zm * root.unsqueeze(1)
    else:
        weight = valid.to(z.dtype)
    total = weight.sum(-1)  # (B,): N, or the number of groups when balanced
    yy = (y.transpose(1, 2) @ y).pow(2).sum((1, 2))
    zz = (zm @ zm.transpose(1, 2)).pow(2).sum((1, 2))
    zy = (zm @ y).pow(2).sum((1, 2))
    # The three terms are each O(N^2) and nearly cancel at a good fit; clamp the float rounding.
    per_clip = (yy - 2.0 * zy + zz).clamp_min(0.0) / total.clamp_min(1.0) ** 2
    return _mean_over_clips(per_clip, total > 0, z)


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


# ---------------------------------------------------------------------------------------------
# Metric-learning baselines of the paper's Table 2: triplet, lifted structure, facility location.
# Each works on one clip at a time (its real points only) with the distances between them.


def _per_clip(z: Tensor, labels: Tensor, mask: Tensor) -> list[tuple[Tensor, Tensor]]:
    """The real points of every clip that has some: [(points (n, E), dense groups (n,) int64)].

    Padded points and label -1 are dropped by indexing, so they can reach neither the loss nor the
    gradient (NaN padding included).
    """
    valid = _valid_points(_channels_first(z), labels, mask)
    clips = []
    for b in range(z.shape[0]):
        keep = valid[b]
        if bool(keep.any()):
            _, group = torch.unique(labels[b][keep], return_inverse=True)
            clips.append((z[b][keep], group))
    return clips


def _squared_distances(x: Tensor) -> Tensor:
    """(n, E) points -> (n, n) squared Euclidean distances from differences (exact 0 on the diagonal,
    smooth everywhere, unlike the |a|^2 + |b|^2 - 2ab form that needs a clamp)."""
    return ((x.unsqueeze(1) - x.unsqueeze(0)) ** 2).sum(-1)


def _distances(x: Tensor) -> Tensor:
    """(n, n) Euclidean distances with a finite gradient where two points coincide (the sqrt's
    derivative is infinite at 0; the double `where` keeps the NaN out of the backward pass)."""
    d2 = _squared_distances(x)
    positive = d2 > 0
    return torch.where(positive, torch.sqrt(torch.where(positive, d2, torch.ones_like(d2))), torch.zeros_like(d2))


def _mean_of_terms(terms: list[Tensor], z: Tensor) -> Tensor:
    if not terms:
        return z.sum() * 0.0
    return torch.stack(terms).mean()


# Anchors per chunk of the batch-all triplet tensor (chunk x n x n): ~4e6 elements at n = 1000.
_TRIPLET_CHUNK_ELEMENTS = 4_000_000


def triplet_loss(z: Tensor, labels: Tensor, mask: Tensor, margin: float = 0.2, mining: str = "semihard") -> Tensor:
    """Triplet loss (Schroff, Kalenichenko, Philbin, FaceNet, CVPR 2015) with mining inside each clip.

    With d the squared Euclidean distance (FaceNet's), every ordered anchor-positive pair (a, p),
    a != p of one group, is scored against negatives n (another group):
        hinge(a, p, n) = max(d(a, p) - d(a, n) + margin, 0).
    mining="semihard" (FaceNet's semi-hard negatives, one per pair): n is the negative of a with the
    smallest d(a, n) > d(a, p); when a has none that far, its farthest negative (the easiest one, so
    that hard negatives never collapse the embedding early, as FaceNet warns). The clip's loss is the
    mean hinge over its anchor-positive pairs. mining="all": the mean hinge over every valid triplet
    (a, p, n) of the clip. A clip with a single group or without any positive pair has no triplet
    and contributes 0 (it still counts in the mean over clips). The mining is a selection, not
    differentiated; the gradient flows through the selected distances.

    Args:
        z: (B, N, E) embeddings (unit norm; margin 0.2 is FaceNet's for unit embeddings).
        labels: (B, N) int64 groups, -1 on padding.
        mask: (B, N) bool, True on real points.
        margin: alpha of FaceNet, in squared-distance units (on the unit sphere d lies in [0, 4]), >= 0.
        mining: "semihard" or "all".

    Returns:
        Scalar tensor, mean over clips with real points.
    """
    if not margin >= 0.0:
        raise ConfigError(f"triplet_loss margin={margin}: must be >= 0")
    if mining not in ("semihard", "all"):
        raise ConfigError(f"triplet_loss mining={mining!r}: choose from semihard, all")
    terms = []
    for x, group in _per_clip(z, labels, mask):
        n = x.shape[0]
        d = _squared_distances(x)
        same = group.unsqueeze(1) == group.unsqueeze(0)
        pos = same & ~torch.eye(n, dtype=torch.bool, device=x.device)
        neg = ~same
        if not bool(pos.any()) or not bool(neg.any()):
            terms.append(x.sum() * 0.0)
            continue
        if mining == "all":
            total = x.new_zeros(())
            count = 0
            chunk = max(1, _TRIPLET_CHUNK_ELEMENTS // (n * n))
            for lo in range(0, n, chunk):
                hi = min(n, lo + chunk)
                # (a, p, n) for anchors lo..hi: d(a, p) - d(a, n) + margin where p is a positive
                # and n a negative of a.
                h = F.relu(d[lo:hi].unsqueeze(2) - d[lo:hi].unsqueeze(1) + margin)
                valid = pos[lo:hi].unsqueeze(2) & neg[lo:hi].unsqueeze(1)
                total = total + torch.where(valid, h, torch.zeros_like(h)).sum()
                count += int(valid.sum())
            terms.append(total / count)
            continue
        # Semi-hard negative per pair: sort each anchor's negative distances (non-negatives at +inf)
        # and find the first one beyond d(a, p).
        with torch.no_grad():
            neg_d = torch.where(neg, d, torch.full_like(d, float("inf")))
            sorted_d, order = torch.sort(neg_d, dim=1)
            num_neg = neg.sum(1)  # (n,) >= 1 for every anchor: the clip has two groups
            first = torch.searchsorted(sorted_d, d.contiguous(), right=True)  # (n, n) first d(a, n) > d(a, p)
            farthest = (num_neg - 1).unsqueeze(1).expand_as(first)
            slot = torch.where(first < num_neg.unsqueeze(1), first, farthest)
            chosen = torch.gather(order, 1, slot)  # (n, n) index of the negative of pair (a, p)
        d_an = torch.gather(d, 1, chosen)
        h = F.relu(d - d_an + margin)
        terms.append(torch.where(pos, h, torch.zeros_like(h)).sum() / pos.sum())
    return _mean_of_terms(terms, z)


def lifted_structured_loss(z: Tensor, labels: Tensor, mask: Tensor, margin: float = 1.0) -> Tensor:
    """Lifted structured embedding loss (Oh Song, Xiang, Jegelka, Savarese, CVPR 2016), eq. 4.

    With D the Euclidean distance, over the clip's positive pairs P (unordered, i != j, one group)
        J_ij = log( sum_{k: neg of i} exp(margin - D_ik) + sum_{l: neg of j} exp(margin - D_jl) ) + D_ij
        loss = 1 / (2 |P|) * sum_{(i,j) in P} max(J_ij, 0)^2,
    the paper's smooth upper bound of the hardest-negative hinge, over every negative of both ends
    of each pair (computed with log-sum-exp). A clip with a single group or without positive pairs
    contributes 0 (and still counts in the mean over clips).

    Args:
        z: (B, N, E) embeddings.
        labels: (B, N) int64 groups, -1 on padding.
        mask: (B, N) bool, True on real points.
        margin: alpha of the paper (they use 1), distance units, >= 0.

    Returns:
        Scalar tensor, mean over clips with real points.
    """
    if not margin >= 0.0:
        raise ConfigError(f"lifted_structured_loss margin={margin}: must be >= 0")
    terms = []
    for x, group in _per_clip(z, labels, mask):
        same = group.unsqueeze(1) == group.unsqueeze(0)
        pos = torch.triu(same, diagonal=1)
        if bool(same.all()) or not bool(pos.any()):
            terms.append(x.sum() * 0.0)
            continue
        d = _distances(x)
        # log sum_{k neg of i} exp(margin - D_ik): every point has a negative in a clip of >= 2 groups.
        lse = torch.logsumexp(torch.where(same, torch.full_like(d, float("-inf")), margin - d), dim=1)  # (n,)
        j = torch.logaddexp(lse.unsqueeze(1), lse.unsqueeze(0)) + d
        h = F.relu(j) ** 2
        terms.append(torch.where(pos, h, torch.zeros_like(h)).sum() / (2.0 * pos.sum()))
    return _mean_of_terms(terms, z)


def _nmi_rows(assign: Tensor, group: Tensor, num_assign: int, num_groups: int) -> Tensor:
    """NMI (arithmetic normalisation, 2 I / (H(a) + H(g))) of each row of assign (c, n) against group (n,).

    Two one-cluster labellings have NMI 1 (both entropies 0).
    """
    c, n = assign.shape
    codes = (torch.arange(c, device=assign.device).unsqueeze(1) * num_assign + assign) * num_groups + group
    joint = torch.bincount(codes.reshape(-1), minlength=c * num_assign * num_groups)
    joint = joint.reshape(c, num_assign, num_groups).to(torch.float64) / n
    pa, pg = joint.sum(2), joint.sum(1)

    def entropy(p: Tensor) -> Tensor:
        return -(torch.where(p > 0, p * torch.log(p.clamp_min(1e-300)), torch.zeros_like(p))).sum(-1)

    ha, hg = entropy(pa), entropy(pg)
    outer = pa.unsqueeze(2) * pg.unsqueeze(1)
    ratio = torch.where(joint > 0, joint / outer.clamp_min(1e-300), torch.ones_like(joint))
    mutual = (joint * torch.log(ratio)).sum((1, 2))
    denom = ha + hg
    return torch.where(denom > 0, 2.0 * mutual / denom.clamp_min(1e-300), torch.ones_like(denom))


def facility_location_loss(z: Tensor, labels: Tensor, mask: Tensor, gamma: float = 1.0) -> Tensor:
    """Clustering-quality loss of Oh Song, Jegelka, Rathod, Murphy, "Deep metric learning via facility
    location" (CVPR 2017), eq. 6, per clip, with the facility-location score divided by n.

    With D the Euclidean distance, a set S of medoids scores F(S) = -(1/n) sum_i min_{j in S} D_ij,
    and g(S) assigns every point to its nearest medoid. The ground truth scores
    F~ = -(1/n) sum_k min_{j in C_k} sum_{i in C_k} D_ij (each true group C_k with its best own medoid).
    The loss is the structured hinge
        loss = max( max_{|S| = K} [ F(S) + gamma * (1 - NMI(g(S), y)) ] - F~, 0 ),
    K the number of true groups. As in the paper, the inner maximisation (loss-augmented inference)
    is greedy: medoids are added one at a time, each time the point that maximises the bracket (the
    paper proves a (1 - 1/e) bound for the F part); the chosen S and medoids of F~ are selections,
    and the gradient flows through the distances they select (the paper's subgradient). The
    differences to the paper: the score is averaged over the points (the paper sums; dividing by n
    makes gamma mean the same for clips of any size), NMI is the arithmetic-normalised one, and the
    greedy step does not re-run the paper's optional local refinement of S. A single-group clip
    scores 0: its best S has NMI 1 and reaches F~.

    Args:
        z: (B, N, E) embeddings.
        labels: (B, N) int64 groups, -1 on padding.
        mask: (B, N) bool, True on real points.
        gamma: weight of the structured margin 1 - NMI (distance units), >= 0.

    Returns:
        Scalar tensor, mean over clips with real points.
    """
    if not gamma >= 0.0:
        raise ConfigError(f"facility_location_loss gamma={gamma}: must be >= 0")
    terms = []
    for x, group in _per_clip(z, labels, mask):
        n = x.shape[0]
        num_groups = int(group.max()) + 1
        d = _distances(x)
        with torch.no_grad():
            dd = d.detach()
            chosen: list[int] = []
            nearest = torch.full((n,), float("inf"), dtype=dd.dtype, device=dd.device)
            assign = torch.zeros(n, dtype=torch.int64, device=dd.device)
            for step in range(num_groups):
                cand_nearest = torch.minimum(nearest.unsqueeze(0), dd)  # (n candidates, n points)
                cand_assign = torch.where(dd < nearest.unsqueeze(0), step, assign.unsqueeze(0))
                nmi = _nmi_rows(cand_assign, group, step + 1, num_groups).to(dd.dtype)
                score = -cand_nearest.mean(1) + gamma * (1.0 - nmi)
                if chosen:
                    score[chosen] = float("-inf")
                best = int(torch.argmax(score))
                chosen.append(best)
                nearest, assign = cand_nearest[best], cand_assign[best]
            delta = 1.0 - float(_nmi_rows(assign.unsqueeze(0), group, num_groups, num_groups)[0])
            onehot = F.one_hot(group, num_groups).to(dd.dtype)  # (n, K)
            cost = dd @ onehot  # (n candidates, K): sum of distances from group k's points to j
            cost = torch.where(onehot.bool(), cost, torch.full_like(cost, float("inf")))
            medoid = cost.argmin(0)  # (K,) best own medoid of every group
        augmented = -d[:, chosen].min(1).values.mean() + gamma * delta
        truth = -(d[medoid] @ onehot.to(d.dtype)).diagonal().sum() / n
        terms.append(F.relu(augmented - truth))
    return _mean_of_terms(terms, z)


LOSSES: dict[str, Callable[..., Tensor]] = {
    "mimi": mimi_loss,
    "l2": l2_affinity_loss,
    "l2-balanced": l2_balanced_affinity_loss,
    "ce": ce_affinity_loss,
    "triplet": triplet_loss,
    "lifted": lifted_structured_loss,
    "facility": facility_location_loss,
    "mimi-point": mimi_point_loss,
    "mimi-mean": mimi_mean_loss,
}

LOSS_REVISIONS: dict[str, int] = {"mimi": 2}
"""Losses whose definition changed after results were stored: cached study parts key on the revision.
mimi 2: the paper's sum-scatter intra term (1 was today's "mimi-point")."""
