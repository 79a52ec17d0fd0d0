from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F

from mosegpipe.errors import InputError
from mosegpipe.training.losses import LOSSES, MIMI_EPS, ce_affinity_loss, l2_affinity_loss, mimi_loss


def _batch(points: list[list[float]], labels: list[int]) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """One clip: (N, E) points -> z (1, N, E), labels (1, N), mask (1, N)."""
    z = torch.tensor(points, dtype=torch.float64).unsqueeze(0)
    lab = torch.tensor([labels], dtype=torch.int64)
    return z, lab, torch.ones_like(lab, dtype=torch.bool)


# Four unit vectors: a=(1,0), b=(0,1) in group 0, c=(-1,0), d=(0,-1) in group 1.
CROSS = [[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]]


def test_mimi_hand_computed() -> None:
    # Group 0 = {(1,0), (1,0)}: mean (1,0), spread 0. Group 1 = {(-1,0), (0,-1)}: mean (-.5,-.5),
    # spread |(-.5,.5)|^2 = .5. Inter = |(1.5, .5)|^2 = 2.5.
    z, lab, mask = _batch([[1, 0], [1, 0], [-1, 0], [0, -1]], [0, 0, 1, 1])
    expected = -0.3 * math.log(2.5 + MIMI_EPS) + 0.7 * math.log(0.5 + MIMI_EPS)
    assert mimi_loss(z, lab, mask, alpha=0.3).item() == pytest.approx(expected, abs=1e-12)


def test_mimi_three_groups_uses_closest_pair_and_worst_spread() -> None:
    # Means (0,0), (3,0), (0,1) (labels need not be contiguous): closest pair distance^2 = 1.
    # Spreads: group 7 points at (0,+-0.2) -> 0.04; group 2 at (3,+-0.5) -> 0.25; group 5 single -> 0.
    z, lab, mask = _batch([[0, 0.2], [0, -0.2], [3, 0.5], [3, -0.5], [0, 1]], [7, 7, 2, 2, 5])
    expected = -0.5 * math.log(1.0 + MIMI_EPS) + 0.5 * math.log(0.25 + MIMI_EPS)
    assert mimi_loss(z, lab, mask).item() == pytest.approx(expected, abs=1e-12)


def test_mimi_single_cluster_drops_inter_term() -> None:
    # One group {(1,0), (0,1)}: mean (.5,.5), spread .5; no pair of means -> intra term only.
    z, lab, mask = _batch([[1, 0], [0, 1]], [3, 3])
    expected = 0.6 * math.log(0.5 + MIMI_EPS)
    assert mimi_loss(z, lab, mask, alpha=0.4).item() == pytest.approx(expected, abs=1e-12)
    assert torch.isfinite(mimi_loss(*_batch([[1, 0], [1, 0]], [0, 0])))


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
