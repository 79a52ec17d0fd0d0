from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest
import torch
from scipy.optimize import linear_sum_assignment
from sklearn.cluster import KMeans

import mosegpipe
from mosegpipe.embed import architecture
from mosegpipe.embed.model import (
    CHECKPOINT_FORMAT,
    ModelConfig,
    SubspaceNet,
    available_default_frames,
    normalize_input,
    num_parameters,
    pad_batch,
)
from mosegpipe.errors import CheckpointError, InputError
from mosegpipe.runtime import limited_threads
from mosegpipe.training.losses import mimi_loss

SMALL = ModelConfig(in_dim=10, width=16, num_blocks=3, embed_dim=4)


def _net(cfg: ModelConfig = SMALL, seed: int = 0) -> SubspaceNet:
    torch.manual_seed(seed)
    return SubspaceNet(cfg)


def _traj(n: int, d: int = 10, seed: int = 0) -> npt.NDArray[np.float32]:
    return (np.random.default_rng(seed).uniform(0, 500, size=(n, d))).astype(np.float32)


def test_forward_shapes_unit_norm_and_zero_padding() -> None:
    net = _net(ModelConfig())  # the full 30 x 64 architecture
    x, labels, mask = pad_batch([_traj(40), _traj(25, seed=1)], [np.zeros(40, int), np.ones(25, int)])
    assert x.shape == (2, 40, 10) and labels is not None and labels.shape == (2, 40) and mask.shape == (2, 40)
    z = net(x, mask)
    assert z.shape == (2, 40, 5) and z.dtype == torch.float32
    norms = z.norm(dim=2)
    assert torch.allclose(norms[mask], torch.ones(65), atol=1e-6)
    assert (z[1, 25:] == 0).all()
    assert num_parameters(net) == 10 * 64 + 64 + 30 * 2 * (64 * 64 + 64) + 64 * 5 + 5


def test_padded_batch_equals_clips_alone() -> None:
    net = _net()
    a, b = _traj(37, seed=2), _traj(60, seed=3)
    x, _, mask = pad_batch([a, b])
    x[0, 37:] = float("nan")  # whatever the padding holds must not matter
    z = net(x, mask).detach()
    alone_a = net(torch.from_numpy(a.copy())[None]).detach()
    alone_b = net(torch.from_numpy(b.copy())[None]).detach()
    assert torch.allclose(z[0, :37], alone_a[0], atol=1e-5, rtol=0)
    assert torch.allclose(z[1], alone_b[0], atol=1e-5, rtol=0)
    assert np.allclose(net.embed(a), alone_a[0].numpy(), atol=1e-6)


@pytest.mark.parametrize("input_norm", ["shared", "channel", "motion"])
def test_invariant_to_translation_and_scale(input_norm: str) -> None:
    net = _net(ModelConfig(input_norm=input_norm))
    traj = _traj(80, seed=4)
    z = net.embed(traj)
    shift = np.random.default_rng(5).uniform(-300, 300, size=2).astype(np.float32)
    translated = traj + np.tile(shift, 5)  # the same 2-D shift in every frame
    assert np.abs(net.embed(translated) - z).max() < 1e-4
    assert np.abs(net.embed(traj * 3.5) - z).max() < 1e-4
    assert np.abs(net.embed(traj * 0.02) - z).max() < 1e-4


def test_shared_norm_keeps_relative_scale_channel_norm_does_not() -> None:
    traj = _traj(80, seed=6)
    stretched = traj.copy()
    stretched[:, 0::2] *= 4.0  # x coordinates only
    shared, channel = _net(ModelConfig(input_norm="shared")), _net(ModelConfig(input_norm="channel"))
    assert np.abs(channel.embed(stretched) - channel.embed(traj)).max() < 1e-4
    assert np.abs(shared.embed(stretched) - shared.embed(traj)).max() > 1e-2


def test_normalize_input_hand_computed() -> None:
    x = torch.tensor([[[0.0, 10.0], [2.0, 30.0]]])  # (B=1, N=2, D=2)
    w = torch.full((1, 1, 2), 0.5)
    # Centred: (-1, -10), (1, 10); channel stds 1 and 10; RMS point distance sqrt(101).
    channel = normalize_input(x, w, "channel")
    assert torch.allclose(channel, torch.tensor([[[-1.0, -1.0], [1.0, 1.0]]]))
    shared = normalize_input(x, w, "shared")
    assert torch.allclose(shared, torch.tensor([[[-1.0, -10.0], [1.0, 10.0]]]) / 101**0.5)


def test_motion_norm_hand_computed() -> None:
    # Two points over two frames: (0, 0) -> (1, 0) and (4, 0) -> (4, 0).
    x = torch.tensor([[[0.0, 0.0, 1.0, 0.0], [4.0, 0.0, 4.0, 0.0]]])
    w = torch.full((1, 1, 2), 0.5)
    # Positions centred: (-2, 0), (2, 0), RMS 2. Displacements (1, 0), (0, 0) centred: (0.5, 0),
    # (-0.5, 0), RMS 0.5.
    out = normalize_input(x, w, "motion")
    assert torch.allclose(out, torch.tensor([[[-1.0, 0.0, 1.0, 0.0], [1.0, 0.0, -1.0, 0.0]]]))


def test_coincident_points_give_finite_output() -> None:
    net = _net()
    z = net.embed(np.full((12, 10), 123.0, dtype=np.float32))
    assert z.shape == (12, 4) and np.isfinite(z).all()
    assert net.embed(np.zeros((0, 10), dtype=np.float32)).shape == (0, 4)


def test_wrong_dimension_raises_input_error() -> None:
    net = _net()
    with pytest.raises(InputError, match=r"\(30, 4\).*\(N, 10\)"):
        net.embed(np.zeros((30, 4), dtype=np.float32))
    with pytest.raises(InputError, match="NaN"):
        net.embed(np.full((3, 10), np.nan))
    with pytest.raises(ValueError, match="expected"):  # a tensor of the wrong shape is a caller's bug
        net(torch.zeros(1, 30, 4))
    with pytest.raises(ValueError, match="one D"):
        pad_batch([np.zeros((3, 10)), np.zeros((3, 4))])


def test_embed_restores_training_mode() -> None:
    net = _net().train()
    net.embed(_traj(5))
    assert net.training


def test_checkpoint_round_trip(tmp_path: Path) -> None:
    net = _net()
    recipe = {"loss": "mimi", "lr": np.float32(1e-3), "steps": np.int64(10), "sizes": (1, 2), "out": tmp_path}
    path = net.save(tmp_path / "m.pt", recipe=recipe, metrics={"hopkins_err": 0.0123})
    assert [p.name for p in tmp_path.iterdir()] == ["m.pt"]  # no temporary file left behind
    raw = torch.load(path, weights_only=True)  # plain data only
    assert raw["format"] == CHECKPOINT_FORMAT and raw["version"] == mosegpipe.__version__
    assert raw["model_config"] == SMALL.to_dict()
    loaded = SubspaceNet.from_checkpoint(path)
    assert not loaded.training and loaded.cfg == SMALL
    assert loaded.recipe == {
        "loss": "mimi",
        "lr": pytest.approx(1e-3),
        "steps": 10,
        "sizes": [1, 2],
        "out": str(tmp_path),
    }
    assert loaded.metrics == {"hopkins_err": 0.0123}
    traj = _traj(50, seed=7)
    assert np.array_equal(loaded.embed(traj), net.embed(traj))
    assert np.array_equal(SubspaceNet.from_checkpoint(net.checkpoint()).embed(traj), net.embed(traj))
    net.save(path)  # overwriting an existing file works
    assert SubspaceNet.from_checkpoint(path).recipe == {}


def test_checkpoint_rejects_unstorable_values() -> None:
    with pytest.raises(CheckpointError, match="recipe.fn"):
        _net().checkpoint(recipe={"fn": print})


def test_corrupt_missing_and_mismatched_checkpoints(tmp_path: Path) -> None:
    missing = tmp_path / "missing.pt"
    with pytest.raises(CheckpointError, match="missing.pt"):
        SubspaceNet.from_checkpoint(missing)
    corrupt = tmp_path / "corrupt.pt"
    corrupt.write_bytes(b"not a checkpoint at all")
    with pytest.raises(CheckpointError, match="corrupt.pt"):
        SubspaceNet.from_checkpoint(corrupt)
    good = _net().save(tmp_path / "good.pt")
    truncated = tmp_path / "truncated.pt"
    truncated.write_bytes(good.read_bytes()[:200])
    with pytest.raises(CheckpointError, match="truncated.pt"):
        SubspaceNet.from_checkpoint(truncated)
    foreign = tmp_path / "foreign.pt"
    with open(foreign, "wb") as f:
        pickle.dump({"format": CHECKPOINT_FORMAT, "obj": Path("x")}, f, protocol=2)  # not weights_only-loadable
    with pytest.raises(CheckpointError, match="foreign.pt"):
        SubspaceNet.from_checkpoint(foreign)
    other = tmp_path / "other.pt"
    torch.save({"format": "something/2", "state_dict": {}}, other)
    with pytest.raises(CheckpointError, match="other.pt.*something/2"):
        SubspaceNet.from_checkpoint(other)
    mismatched = tmp_path / "mismatched.pt"
    ckpt = _net().checkpoint()
    ckpt["model_config"]["width"] = 32
    torch.save(ckpt, mismatched)
    with pytest.raises(CheckpointError, match="mismatched.pt.*do not fit"):
        SubspaceNet.from_checkpoint(mismatched)
    ckpt["model_config"] = {"width": 16, "depth": 3}
    with pytest.raises(CheckpointError, match="depth"):
        SubspaceNet.from_checkpoint(ckpt)


def test_default_weights_lookup(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(architecture, "weights_dir", lambda: tmp_path)
    assert available_default_frames() == []
    with pytest.raises(CheckpointError, match="no shipped weights for 5 frames; available: none"):
        SubspaceNet.default(frames=5)
    pair = _net(ModelConfig(in_dim=4, width=8, num_blocks=1))
    pair.save(tmp_path / "subspacenet_f2.pt")
    (tmp_path / "notes.md").write_text("x")
    assert available_default_frames() == [2]
    loaded = SubspaceNet.default(frames=2)
    assert loaded.cfg.in_dim == 4 and not loaded.training
    with pytest.raises(CheckpointError, match="available: 2"):
        SubspaceNet.default(frames=5)
    _net().save(tmp_path / "subspacenet_f3.pt")  # a 10-d model filed under 3 frames
    with pytest.raises(CheckpointError, match="in_dim=10"):
        SubspaceNet.default(frames=3)


def test_pad_batch_values_and_errors() -> None:
    a = np.arange(6, dtype=np.float64).reshape(3, 2)
    b = np.ones((1, 2))
    x, labels, mask = pad_batch([a, b], [np.array([2, 0, 1]), np.array([5])])
    assert x.dtype == torch.float32 and x.shape == (2, 3, 2)
    assert torch.equal(x[0], torch.tensor(a, dtype=torch.float32))
    assert torch.equal(x[1], torch.tensor([[1.0, 1.0], [0, 0], [0, 0]]))
    assert labels is not None and torch.equal(labels, torch.tensor([[2, 0, 1], [5, -1, -1]]))
    assert torch.equal(mask, torch.tensor([[True, True, True], [True, False, False]]))
    assert pad_batch([a])[1] is None
    with pytest.raises(ValueError, match="no trajectory"):
        pad_batch([])
    with pytest.raises(ValueError, match=r"clip 1 labels shape \(2,\)"):
        pad_batch([a, b], [np.zeros(3), np.zeros(2)])


def test_model_config_round_trip_and_validation() -> None:
    cfg = ModelConfig(in_dim=4, width=8, num_blocks=2, embed_dim=3, input_norm="channel")
    assert ModelConfig.from_dict(cfg.to_dict()) == cfg
    with pytest.raises(InputError, match="'zscore'"):
        ModelConfig(input_norm="zscore")
    with pytest.raises(InputError, match="width=0"):
        ModelConfig(width=0)
    with pytest.raises(InputError, match="unknown fields"):
        ModelConfig.from_dict({"in_dim": 4, "dropout": 0.1})


Clip = tuple[npt.NDArray[np.float32], npt.NDArray[np.int64]]


def _toy_clip(rng: np.random.Generator, k: int = 2, n: int = 60) -> Clip:
    """k groups of 2-frame trajectories; each group moves by its own random affine map."""
    labels = rng.permutation(np.arange(n) % k)
    xy1 = rng.uniform([0, 0], [640, 480], size=(n, 2))
    xy2 = np.empty_like(xy1)
    for g in range(k):
        a = np.eye(2) + 0.15 * rng.standard_normal((2, 2))
        t = 40.0 * rng.standard_normal(2)
        xy2[labels == g] = xy1[labels == g] @ a.T + t
    return np.concatenate([xy1, xy2], axis=1).astype(np.float32), labels.astype(np.int64)


def _misclassification(labels: npt.NDArray[np.int64], pred: npt.NDArray[np.int64], k: int) -> float:
    """Error of the best one-to-one matching of predicted to true groups (Hungarian)."""
    counts = np.zeros((k, k))
    np.add.at(counts, (labels, pred), 1)
    rows, cols = linear_sum_assignment(-counts)
    return 1.0 - counts[rows, cols].sum() / labels.size


def _mean_error(net: SubspaceNet, clips: list[Clip]) -> float:
    with limited_threads(1):
        return float(
            np.mean(
                [
                    _misclassification(lab, KMeans(2, n_init=5, random_state=0).fit_predict(net.embed(traj)), 2)
                    for traj, lab in clips
                ]
            )
        )


@pytest.mark.slow
def test_training_smoke_mimi_separates_affine_motions() -> None:
    net = _net(ModelConfig(in_dim=4, width=32, num_blocks=4))
    test_clips = [_toy_clip(np.random.default_rng(1000 + i)) for i in range(10)]
    untrained = _mean_error(net, test_clips)
    rng = np.random.default_rng(0)
    opt = torch.optim.Adam(net.parameters(), lr=3e-3)
    for _ in range(200):  # about 1.5 s on one thread
        batch = [_toy_clip(rng) for _ in range(8)]
        x, labels, mask = pad_batch([c[0] for c in batch], [c[1] for c in batch])
        assert labels is not None
        loss = mimi_loss(net(x, mask), labels, mask)
        opt.zero_grad()
        loss.backward()
        opt.step()
    trained = _mean_error(net, test_clips)
    assert untrained > 0.3  # near chance (0.5) before training
    assert trained < 0.12


@pytest.mark.parametrize("arch", ["pointnet", "corresnet"])
def test_baseline_networks_count_pad_and_round_trip(arch: str, tmp_path: Path) -> None:
    cfg = ModelConfig(in_dim=10, width=16, num_blocks=3, embed_dim=4, arch=arch)
    net = _net(cfg)
    assert num_parameters(net) == cfg.num_parameters
    # One training step moves the batch-norm statistics (corresnet), so that the round trip checks them.
    x, labels, mask = pad_batch([_traj(30), _traj(18, seed=1)], [np.arange(30) % 2, np.arange(18) % 3])
    assert labels is not None
    mimi_loss(net(x, mask), labels, mask).backward()
    net.eval()
    x[1, 18:] = float("nan")
    z = net(x, mask).detach()
    alone = net(x[1:, :18]).detach()
    assert torch.allclose(z[1, :18], alone[0], atol=1e-5, rtol=0)
    assert torch.allclose(z.norm(dim=2)[mask], torch.ones(48), atol=1e-5)
    path = net.save(tmp_path / "net.pt")
    back = SubspaceNet.from_checkpoint(path)
    assert back.cfg == cfg
    assert torch.equal(back(x, mask).detach(), z)


def test_pointnet_global_feature_reaches_every_point() -> None:
    # Moving one point changes the others' embeddings only through the pooled feature.
    net = _net(ModelConfig(in_dim=10, width=16, num_blocks=2, embed_dim=4, arch="pointnet", input_norm="channel"))
    a = torch.from_numpy(_traj(20))[None]
    b = a.clone()
    b[0, 0] += 300.0
    za, zb = net(a).detach(), net(b).detach()
    assert not torch.allclose(za[0, 1:], zb[0, 1:], atol=1e-4)


def test_without_l2_normalisation_the_embedding_is_not_unit() -> None:
    cfg = ModelConfig(in_dim=10, width=16, num_blocks=2, embed_dim=4, l2_normalize=False)
    z = _net(cfg)(torch.from_numpy(_traj(40))[None]).detach()
    norms = z.norm(dim=2)
    assert not torch.allclose(norms, torch.ones_like(norms), atol=1e-3)
    unit = _net(replace_cfg(cfg, l2_normalize=True))(torch.from_numpy(_traj(40))[None]).detach()
    assert torch.allclose(unit, torch.nn.functional.normalize(z, dim=-1), atol=1e-5)


def replace_cfg(cfg: ModelConfig, **changes: object) -> ModelConfig:
    import dataclasses

    return dataclasses.replace(cfg, **changes)  # type: ignore[arg-type]


@pytest.mark.parametrize(("field", "value"), [("arch", "resnet"), ("l2_normalize", 1)])
def test_bad_architecture_fields_are_config_errors(field: str, value: object) -> None:
    from mosegpipe.errors import ConfigError

    with pytest.raises(ConfigError, match=field):
        ModelConfig(**{field: value})  # type: ignore[arg-type]
