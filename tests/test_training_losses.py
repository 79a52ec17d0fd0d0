from __future__ import annotations

import math
from collections.abc import Callable

import pytest
import torch
import torch.nn.functional as F

from mosegpipe.errors import InputError
from mosegpipe.training.losses import (
    LOSSES,
    MIMI_EPS,
    ce_affinity_loss,
    facility_location_loss,
    l2_affinity_loss,
    l2_balanced_affinity_loss,
    lifted_structured_loss,
    mimi_loss,
    mimi_mean_loss,
    mimi_point_loss,
    triplet_loss,
)


def _batch(points: list[list[float]], labels: list[int]) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """One clip: (N, E) points -> z (1, N, E), labels (1, N), mask (1, N)."""
    z = torch.tensor(points, dtype=torch.float64).unsqueeze(0)
    lab = torch.tensor([labels], dtype=torch.int64)
    return z, lab, torch.ones_like(lab, dtype=torch.bool)


# Four unit vectors: a=(1,0), b=(0,1) in group 0, c=(-1,0), d=(0,-1) in group 1.
CROSS = [[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]]


def test_mimi_hand_computed() -> None:
    # Group 0 = {(0,0), (2,0)}: mean (1,0), scatter 1 + 1 = 2. Group 1 = {(5,0), (5,2), (5,4)}:
    # mean (5,2), scatter 4 + 0 + 4 = 8. Intra = max(2, 8) = 8 (the worst single point is only 4 away).
    # Inter = |(1,0) - (5,2)|^2 = 16 + 4 = 20.
    z, lab, mask = _batch([[0, 0], [2, 0], [5, 0], [5, 2], [5, 4]], [0, 0, 1, 1, 1])
    expected = -0.3 * math.log(20.0 + MIMI_EPS) + 0.7 * math.log(8.0 + MIMI_EPS)
    assert mimi_loss(z, lab, mask, alpha=0.3).item() == pytest.approx(expected, abs=1e-6)
    # The per-point variant takes the farthest point instead: 4 (a point of group 1, 2 away from (5,2)).
    point = -0.3 * math.log(20.0 + MIMI_EPS) + 0.7 * math.log(4.0 + MIMI_EPS)
    assert mimi_point_loss(z, lab, mask, alpha=0.3).item() == pytest.approx(point, abs=1e-6)


def test_mimi_mean_takes_the_widest_mean_spread_and_scores_a_separated_embedding_below_a_collapse() -> None:
    # The groups of test_mimi_hand_computed: mean squared spreads 2 / 2 = 1 and 8 / 3; inter 20.
    z, lab, mask = _batch([[0, 0], [2, 0], [5, 0], [5, 2], [5, 4]], [0, 0, 1, 1, 1])
    expected = -0.3 * math.log(20.0 + MIMI_EPS) + 0.7 * math.log(8.0 / 3.0 + MIMI_EPS)
    assert mimi_mean_loss(z, lab, mask, alpha=0.3).item() == pytest.approx(expected, abs=1e-6)
    # Two groups of 50 points each, mean squared spread ~0.1 around means 1.0 apart (squared): the sum
    # form (scatter ~5 > inter 1) scores this above a total collapse (every point on one spot: loss 0
    # at alpha 0.5), the mean form (0.1 < 1) below it.
    gen = torch.Generator().manual_seed(0)
    pts = torch.randn(100, 3, generator=gen, dtype=torch.float64) * math.sqrt(0.1 / 3)
    pts[50:, 0] += 1.0
    z, lab, mask = pts.unsqueeze(0), torch.tensor([[0] * 50 + [1] * 50]), torch.ones(1, 100, dtype=torch.bool)
    collapsed = torch.zeros_like(z)
    assert mimi_loss(collapsed, lab, mask).item() == pytest.approx(0.0, abs=1e-9)
    assert mimi_mean_loss(collapsed, lab, mask).item() == pytest.approx(0.0, abs=1e-9)
    assert mimi_loss(z, lab, mask).item() > 0.0 > mimi_mean_loss(z, lab, mask).item()


def test_mimi_widest_group_is_the_largest_sum_not_the_worst_point() -> None:
    # Group 0: two points 1.5 apart from their mean (0,0): scatter 2.25 + 2.25 = 4.5, worst point 2.25.
    # Group 1: five points, mean (10,0), four of them 1 away: scatter 4, worst point 1.
    # The paper's intra is group 0's 4.5; with four more points 1.1 away group 1 would win instead.
    pts = [[-1.5, 0], [1.5, 0], [10, 0], [11, 0], [9, 0], [10, 1], [10, -1]]
    z, lab, mask = _batch(pts, [0, 0, 1, 1, 1, 1, 1])
    inter = 100.0
    expected = -0.5 * math.log(inter + MIMI_EPS) + 0.5 * math.log(4.5 + MIMI_EPS)
    assert mimi_loss(z, lab, mask).item() == pytest.approx(expected, abs=1e-6)
    wide = [[10, 0], [11.1, 0], [8.9, 0], [10, 1.1], [10, -1.1]]  # scatter 4 * 1.21 = 4.84 > 4.5
    z, lab, mask = _batch(pts[:2] + wide, [0, 0, 1, 1, 1, 1, 1])
    expected = -0.5 * math.log(inter + MIMI_EPS) + 0.5 * math.log(4.84 + MIMI_EPS)
    assert mimi_loss(z, lab, mask).item() == pytest.approx(expected, abs=1e-6)


def test_mimi_intra_gradient_flows_through_every_point_of_the_widest_group_only() -> None:
    # alpha = 0 leaves the intra term alone: loss = log(s + eps), so dloss/dz_i = 2 (z_i - mu_l) / (s + eps)
    # for the points of the widest group l and 0 for every other point.
    gen = torch.Generator().manual_seed(5)
    labels = torch.tensor([[2, 0, 2, 1, 0, 2, 1, 0, 2]])
    z = torch.randn(1, 9, 3, generator=gen, dtype=torch.float64)
    z[0, labels[0] == 2] *= 3.0  # group 2 the widest by far
    z.requires_grad_(True)
    mimi_loss(z, labels, labels >= 0, alpha=0.0).backward()
    assert z.grad is not None
    widest = labels[0] == 2
    pts = z.detach()[0, widest]
    centred = pts - pts.mean(0)
    scatter = float((centred**2).sum())
    others = [
        float(((z.detach()[0, labels[0] == k] - z.detach()[0, labels[0] == k].mean(0)) ** 2).sum()) for k in (0, 1)
    ]
    assert scatter > max(others)
    torch.testing.assert_close(z.grad[0, widest], 2 * centred / (scatter + MIMI_EPS), rtol=1e-10, atol=1e-12)
    assert (z.grad[0, ~widest] == 0).all()
    assert (z.grad[0, widest].abs().sum(1) > 0).all()  # every point of the widest group, not one


def test_mimi_point_gradient_follows_the_farthest_point() -> None:
    # Group 1 = {(5,0), (5,2), (5,5)}: mean (5, 7/3); the farthest point (5,5) is d = (0, 8/3) away.
    # With alpha = 0, loss = log(|d|^2 + eps): that point gets 2 d (1 - 1/3) / (|d|^2 + eps), the other two
    # (only through the mean) -2 d / 3 / (|d|^2 + eps), and group 0 nothing.
    z, lab, mask = _batch([[0, 0], [2, 0], [5, 0], [5, 2], [5, 5]], [0, 0, 1, 1, 1])
    z.requires_grad_(True)
    mimi_point_loss(z, lab, mask, alpha=0.0).backward()
    assert z.grad is not None
    d = torch.tensor([0.0, 8.0 / 3.0], dtype=torch.float64)
    norm = float((d**2).sum()) + MIMI_EPS
    expected = torch.stack([torch.zeros(2), torch.zeros(2), -2 * d / 3, -2 * d / 3, 2 * d * 2 / 3]).double() / norm
    torch.testing.assert_close(z.grad[0], expected, rtol=1e-10, atol=1e-12)


def test_mimi_three_groups_uses_closest_pair_and_widest_scatter() -> None:
    # Means (0,0), (3,0), (0,1) (labels need not be contiguous): closest pair distance^2 = 1.
    # Scatters: group 7 points at (0,+-0.2) -> 0.08; group 2 at (3,+-0.5) -> 0.5; group 5 single -> 0.
    z, lab, mask = _batch([[0, 0.2], [0, -0.2], [3, 0.5], [3, -0.5], [0, 1]], [7, 7, 2, 2, 5])
    expected = -0.5 * math.log(1.0 + MIMI_EPS) + 0.5 * math.log(0.5 + MIMI_EPS)
    assert mimi_loss(z, lab, mask).item() == pytest.approx(expected, abs=1e-12)
    # Per point: the worst single spread, 0.25.
    point = -0.5 * math.log(1.0 + MIMI_EPS) + 0.5 * math.log(0.25 + MIMI_EPS)
    assert mimi_point_loss(z, lab, mask).item() == pytest.approx(point, abs=1e-12)


def test_mimi_single_cluster_drops_inter_term() -> None:
    # One group {(1,0), (0,1)}: mean (.5,.5), scatter .5 + .5 = 1 (worst point .5); no pair of means.
    z, lab, mask = _batch([[1, 0], [0, 1]], [3, 3])
    assert mimi_loss(z, lab, mask, alpha=0.4).item() == pytest.approx(0.6 * math.log(1.0 + MIMI_EPS), abs=1e-12)
    assert mimi_point_loss(z, lab, mask, alpha=0.4).item() == pytest.approx(0.6 * math.log(0.5 + MIMI_EPS), abs=1e-12)
    assert torch.isfinite(mimi_loss(*_batch([[1, 0], [1, 0]], [0, 0])))
    assert torch.isfinite(mimi_point_loss(*_batch([[1, 0], [1, 0]], [0, 0])))


def test_l2_hand_computed() -> None:
    # Y^TY - Z^TZ is 1 at (a,b), (b,a), (c,d), (d,c) (same group, orthogonal) and at (a,c), (c,a),
    # (b,d), (d,b) (different groups, affinity -1): 8 ones, 0 elsewhere -> 8 / 4^2.
    z, lab, mask = _batch(CROSS, [0, 0, 1, 1])
    assert l2_affinity_loss(z, lab, mask).item() == pytest.approx(0.5, abs=1e-12)
    # Perfect embedding: identical vectors inside a group, orthogonal across groups -> 0.
    z, lab, mask = _batch([[1, 0], [1, 0], [0, 1]], [0, 0, 1])
    assert l2_affinity_loss(z, lab, mask).item() == pytest.approx(0.0, abs=1e-12)


def _naive_l2(z: torch.Tensor, labels: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    per_clip = []
    for b in range(z.shape[0]):
        keep = mask[b] & (labels[b] >= 0)
        zb, lb = z[b][:, keep], labels[b][keep]
        same = (lb[:, None] == lb[None, :]).to(z.dtype)
        per_clip.append(((same - zb.T @ zb) ** 2).sum() / keep.sum() ** 2)
    return torch.stack(per_clip).mean()


def test_l2_matches_naive_formula() -> None:
    gen = torch.Generator().manual_seed(0)
    for _ in range(5):
        z = F.normalize(torch.randn(3, 4, 9, generator=gen, dtype=torch.float64), dim=1)
        labels = torch.randint(0, 4, (3, 9), generator=gen) * 5  # sparse label values
        mask = torch.ones(3, 9, dtype=torch.bool)
        mask[1, 6:] = False
        mask[2, 4:] = False
        labels[~mask] = -1
        loss = l2_affinity_loss(z.transpose(1, 2), labels, mask)  # z is (B, E, N) here; losses take (B, N, E)
        assert loss.item() == pytest.approx(_naive_l2(z, labels, mask).item(), abs=1e-12)


def test_l2_balanced_weighs_every_pair_of_groups_alike() -> None:
    # Groups {a, a', a''} = (1, 0) three times and {b} = (1, 0): the three same-group blocks fit (0 error),
    # the two cross blocks have affinity 0 but z.z = 1: each block's mean squared error is 1 -> 2 / 2^2.
    z, lab, mask = _batch([[1, 0], [1, 0], [1, 0], [1, 0]], [0, 0, 0, 1])
    assert l2_balanced_affinity_loss(z, lab, mask).item() == pytest.approx(0.5, abs=1e-12)
    # The plain loss sees 6 wrong pairs of 16: the small group barely counts.
    assert l2_affinity_loss(z, lab, mask).item() == pytest.approx(6 / 16, abs=1e-12)
    # Equal group sizes: the same as the plain loss.
    z, lab, mask = _batch(CROSS, [0, 0, 1, 1])
    assert l2_balanced_affinity_loss(z, lab, mask).item() == pytest.approx(0.5, abs=1e-12)


def test_l2_balanced_matches_naive_formula() -> None:
    gen = torch.Generator().manual_seed(2)
    for _ in range(5):
        z = F.normalize(torch.randn(3, 4, 9, generator=gen, dtype=torch.float64), dim=1)
        labels = torch.randint(0, 3, (3, 9), generator=gen) * 7
        mask = torch.ones(3, 9, dtype=torch.bool)
        mask[1, 5:] = False
        labels[~mask] = -1
        labels[2, 0] = -1  # unlabelled context point
        expected = []
        for b in range(3):
            keep = mask[b] & (labels[b] >= 0)
            zb, lb = z[b][:, keep], labels[b][keep]
            same = (lb[:, None] == lb[None, :]).to(z.dtype)
            w = 1.0 / same.sum(1)
            err = (same - zb.T @ zb) ** 2
            expected.append((w[:, None] * w[None, :] * err).sum() / w.sum() ** 2)
        loss = l2_balanced_affinity_loss(z.transpose(1, 2), labels, mask)
        assert loss.item() == pytest.approx(torch.stack(expected).mean().item(), abs=1e-12)


def test_ce_hand_computed() -> None:
    # Logits = Gram matrix. Diagonal (4 pairs): x=1, t=1 -> log(1+e^-1). Same group, orthogonal
    # (4): x=0, t=1 -> log 2. Opposite (4): x=-1, t=0 -> log(1+e^-1). Other cross pairs (4): log 2.
    z, lab, mask = _batch(CROSS, [0, 0, 1, 1])
    expected = (math.log(1 + math.exp(-1)) + math.log(2)) / 2
    assert ce_affinity_loss(z, lab, mask).item() == pytest.approx(expected, abs=1e-12)
    # scale=3 multiplies the logits: the +-1 pairs become log(1+e^-3).
    expected3 = (math.log(1 + math.exp(-3)) + math.log(2)) / 2
    assert ce_affinity_loss(z, lab, mask, scale=3.0).item() == pytest.approx(expected3, abs=1e-12)


@pytest.mark.parametrize("name", sorted(LOSSES))
def test_gradients_match_finite_differences(name: str) -> None:
    gen = torch.Generator().manual_seed(1)
    z = torch.randn(2, 3, 7, generator=gen, dtype=torch.float64, requires_grad=True)
    labels = torch.tensor([[0, 0, 0, 1, 1, 2, 2], [4, 4, 1, 1, 1, -1, -1]])
    mask = labels >= 0
    assert torch.autograd.gradcheck(lambda t: LOSSES[name](t.transpose(1, 2), labels, mask), (z,), eps=1e-6, atol=1e-6)


@pytest.mark.parametrize("name", sorted(LOSSES))
def test_padding_does_not_change_loss(name: str) -> None:
    gen = torch.Generator().manual_seed(2)
    fn = LOSSES[name]
    za = F.normalize(torch.randn(1, 4, 6, generator=gen, dtype=torch.float64), dim=1)
    la = torch.tensor([[0, 0, 1, 1, 2, 2]])
    zb = F.normalize(torch.randn(1, 4, 9, generator=gen, dtype=torch.float64), dim=1)
    lb = torch.tensor([[1, 0, 1, 0, 1, 0, 1, 0, 0]])
    # Built channels-first (E before N) as (1, E, N); the losses take (B, N, E).
    alone_a = fn(za.transpose(1, 2), la, torch.ones_like(la, dtype=torch.bool))
    alone_b = fn(zb.transpose(1, 2), lb, torch.ones_like(lb, dtype=torch.bool))
    # Pad clip a to 9 points with garbage (NaN embeddings, real-looking labels) that the mask removes.
    z = torch.cat([torch.cat([za, torch.full((1, 4, 3), float("nan"), dtype=za.dtype)], dim=2), zb])
    labels = torch.cat([torch.cat([la, torch.tensor([[0, 1, 2]])], dim=1), lb])
    mask = torch.ones(2, 9, dtype=torch.bool)
    mask[0, 6:] = False
    z.requires_grad_(True)
    batch = fn(z.transpose(1, 2), labels, mask)
    assert batch.item() == pytest.approx(((alone_a + alone_b) / 2).item(), abs=1e-12)
    batch.backward()
    assert torch.isfinite(z.grad).all()
    assert (z.grad[0, :, 6:] == 0).all()


def test_empty_batch_gives_zero() -> None:
    z = torch.randn(1, 4, 3, requires_grad=True)
    labels = torch.full((1, 4), -1)
    for fn in LOSSES.values():
        loss = fn(z, labels, labels >= 0)
        assert loss.item() == 0.0
        loss.backward()


def test_bad_shapes_and_arguments_raise() -> None:
    z, lab, mask = _batch(CROSS, [0, 0, 1, 1])
    with pytest.raises(ValueError, match="expected"):
        mimi_loss(z, lab[:, :3], mask[:, :3])
    with pytest.raises(InputError, match="alpha=1.5"):
        mimi_loss(z, lab, mask, alpha=1.5)
    with pytest.raises(InputError, match="mimi_point_loss alpha=-0.1"):
        mimi_point_loss(z, lab, mask, alpha=-0.1)
    with pytest.raises(InputError, match="scale=0"):
        ce_affinity_loss(z, lab, mask, scale=0.0)


def test_minimising_mimi_separates_two_clusters() -> None:
    torch.manual_seed(0)
    labels = torch.tensor([[0] * 10 + [1] * 10])
    mask = torch.ones_like(labels, dtype=torch.bool)
    raw = torch.randn(1, 3, 20, requires_grad=True)
    opt = torch.optim.Adam([raw], lr=0.05)

    def stats(z: torch.Tensor) -> tuple[float, float]:
        m0, m1 = z[0, :, :10].mean(1), z[0, :, 10:].mean(1)
        inter = float(((m0 - m1) ** 2).sum())
        spread = float(
            max(((z[0, :, :10] - m0[:, None]) ** 2).sum(0).max(), ((z[0, :, 10:] - m1[:, None]) ** 2).sum(0).max())
        )
        return inter, spread

    inter0, spread0 = stats(F.normalize(raw.detach(), dim=1))
    for _ in range(300):
        loss = mimi_loss(F.normalize(raw, dim=1).transpose(1, 2), labels, mask)
        opt.zero_grad()
        loss.backward()
        opt.step()
    inter, spread = stats(F.normalize(raw.detach(), dim=1))
    assert inter0 < 1.0 and spread0 > 0.5  # random start: overlapping groups
    assert inter > 3.0  # means nearly antipodal (max 4 on the unit sphere)
    assert spread < 0.01  # every point within 0.1 of its group's mean


# Metric-learning baselines (Table 2 of the paper). Points on a line (E = 1): a=0, b=1 in group 0,
# c=1.4, e=3 in group 1.
LINE = [[0.0], [1.0], [1.4], [3.0]]


def test_triplet_semihard_hand_computed() -> None:
    # Squared distances: ab 1, ac 1.96, ae 9, bc .16, be 4, ce 2.56. Margin 1, ordered positive pairs:
    # (a,b): a's negatives c 1.96, e 9; first beyond 1 is c -> 1 - 1.96 + 1 = .04.
    # (b,a): b's negatives .16, 4 -> e: 1 - 4 + 1 < 0 -> 0.
    # (c,e): c's negatives a 1.96, b .16, none beyond 2.56 -> the farthest, a: 2.56 - 1.96 + 1 = 1.6.
    # (e,c): e's negatives 9, 4 -> b: 2.56 - 4 + 1 < 0 -> 0.        Mean over 4 pairs: 1.64 / 4.
    z, lab, mask = _batch(LINE, [0, 0, 1, 1])
    assert triplet_loss(z, lab, mask, margin=1.0).item() == pytest.approx(0.41, abs=1e-12)
    # Margin 0.2 (the default): (a,b) -> 0, (c,e) -> .8: .2.
    assert triplet_loss(z, lab, mask).item() == pytest.approx(0.2, abs=1e-12)


def test_triplet_batch_all_hand_computed() -> None:
    # Every (anchor, positive, negative) with margin 1: a,b: c .04, e 0; b,a: c 1.84, e 0;
    # c,e: a 1.6, b 3.4; e,c: a 0, b 0. Mean over the 8 triplets: 6.88 / 8.
    z, lab, mask = _batch(LINE, [0, 0, 1, 1])
    assert triplet_loss(z, lab, mask, margin=1.0, mining="all").item() == pytest.approx(0.86, abs=1e-12)


def test_lifted_hand_computed() -> None:
    # Distances: ab 1, ac 1.4, ae 3, bc .4, be 2, ce 1.6. Positive pairs (a,b) and (c,e); both pairs'
    # negatives give the same sum s = e^(1-1.4) + e^(1-3) + e^(1-.4) + e^(1-2) (a: c, e; b: c, e;
    # c: a, b; e: a, b). J_ab = log s + 1, J_ce = log s + 1.6; loss = (J_ab^2 + J_ce^2) / (2 * 2).
    z, lab, mask = _batch(LINE, [0, 0, 1, 1])
    s = math.exp(-0.4) + math.exp(-2) + math.exp(0.6) + math.exp(-1)
    expected = ((math.log(s) + 1) ** 2 + (math.log(s) + 1.6) ** 2) / 4
    assert lifted_structured_loss(z, lab, mask).item() == pytest.approx(expected, abs=1e-12)
    # Far-apart groups: every J_ij < 0 -> 0.
    z, lab, mask = _batch([[0.0], [0.1], [50.0], [50.1]], [0, 0, 1, 1])
    assert lifted_structured_loss(z, lab, mask).item() == 0.0


def test_facility_location_hand_computed() -> None:
    # x = 0, 2 (group 0) and .9, 3.5 (group 1), gamma 1, n = 4, K = 2. Ground truth: best own medoids
    # cost 2 (group 0) and 2.6 (group 1): F~ = -4.6 / 4 = -1.15. Loss-augmented greedy: step 1, every
    # single medoid has NMI 0; mean distances 1.6, 1.15, 1.15, 1.9 -> x=2 or x=.9. Step 2 from either:
    # {0, 2} assigns (0, .9 | 2, 3.5): F = -(.9 + 1.5) / 4 = -.6, NMI 0 -> -.6 + 1 = .4, the best
    # bracket (the exact maximum over all pairs too). Loss = .4 - (-1.15) = 1.55.
    z, lab, mask = _batch([[0.0], [2.0], [0.9], [3.5]], [0, 0, 1, 1])
    assert facility_location_loss(z, lab, mask).item() == pytest.approx(1.55, abs=1e-12)
    # Tight, far-apart groups: the true medoids win with NMI 1 -> bracket = F~ -> 0.
    z, lab, mask = _batch([[0.0], [0.1], [50.0], [50.1], [50.2]], [0, 0, 1, 1, 1])
    assert facility_location_loss(z, lab, mask).item() == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize(
    "fn",
    [
        lambda z, y, m: triplet_loss(z, y, m, mining="all"),
        lambda z, y, m: facility_location_loss(z, y, m, gamma=0.3),
        lambda z, y, m: lifted_structured_loss(z, y, m, margin=0.5),
    ],
    ids=["triplet-all", "facility-gamma", "lifted-margin"],
)
def test_metric_loss_options_match_finite_differences(fn: Callable[..., torch.Tensor]) -> None:
    gen = torch.Generator().manual_seed(3)
    z = torch.randn(2, 8, 3, generator=gen, dtype=torch.float64, requires_grad=True)
    labels = torch.tensor([[0, 0, 0, 1, 1, 2, 2, 2], [4, 4, 1, 1, 1, 7, -1, -1]])
    assert torch.autograd.gradcheck(lambda t: fn(t, labels, labels >= 0), (z,), eps=1e-6, atol=1e-6)


@pytest.mark.parametrize("name", ["triplet", "lifted", "facility"])
def test_metric_losses_ignore_unlabelled_points(name: str) -> None:
    # Label -1 inside the mask (a point without ground truth) counts as little as padding.
    gen = torch.Generator().manual_seed(4)
    z = F.normalize(torch.randn(1, 7, 3, generator=gen, dtype=torch.float64), dim=2)
    labels = torch.tensor([[0, 0, 1, -1, 1, 2, -1]])
    keep = labels[0] >= 0
    alone = LOSSES[name](z[:, keep], labels[:, keep], torch.ones(1, 5, dtype=torch.bool))
    z.requires_grad_(True)
    full = LOSSES[name](z, labels, torch.ones(1, 7, dtype=torch.bool))
    assert full.item() == pytest.approx(alone.item(), abs=1e-12)
    full.backward()
    assert (z.grad[0, ~keep] == 0).all()


@pytest.mark.parametrize("name", ["triplet", "lifted", "facility"])
def test_metric_losses_single_group_clip_gives_zero(name: str) -> None:
    z, lab, mask = _batch([[1.0, 0.0], [0.0, 1.0], [0.6, 0.8]], [5, 5, 5])
    assert LOSSES[name](z, lab, mask).item() == pytest.approx(0.0, abs=1e-12)


def test_metric_loss_bad_arguments_raise() -> None:
    z, lab, mask = _batch(LINE, [0, 0, 1, 1])
    with pytest.raises(InputError, match="margin=-1"):
        triplet_loss(z, lab, mask, margin=-1.0)
    with pytest.raises(InputError, match="mining='hardest'"):
        triplet_loss(z, lab, mask, mining="hardest")
    with pytest.raises(InputError, match="margin=-0.5"):
        lifted_structured_loss(z, lab, mask, margin=-0.5)
    with pytest.raises(InputError, match="gamma=-1"):
        facility_location_loss(z, lab, mask, gamma=-1.0)


@pytest.mark.parametrize("name", ["triplet", "lifted", "facility"])
def test_minimising_metric_losses_separates_two_groups(name: str) -> None:
    torch.manual_seed(0)
    labels = torch.tensor([[0] * 8 + [1] * 8])
    mask = torch.ones_like(labels, dtype=torch.bool)
    raw = torch.randn(1, 16, 3, requires_grad=True)
    opt = torch.optim.Adam([raw], lr=0.05)

    def gap(z: torch.Tensor) -> float:
        """Smallest between-group distance minus the largest within-group distance (> 0: separable)."""
        d = torch.cdist(z[0], z[0])
        same = labels[0][:, None] == labels[0][None, :]
        return float(d[~same].min() - d[same].max())

    first = LOSSES[name](F.normalize(raw, dim=2), labels, mask).item()
    gap0 = gap(F.normalize(raw.detach(), dim=2))
    for _ in range(60):
        loss = LOSSES[name](F.normalize(raw, dim=2), labels, mask)
        opt.zero_grad()
        loss.backward()
        opt.step()
    last = LOSSES[name](F.normalize(raw, dim=2), labels, mask).item()
    assert gap0 < 0  # random start: groups overlap
    assert last < 0.5 * first
    assert gap(F.normalize(raw.detach(), dim=2)) > 0  # every pair of one group closer than any pair across
