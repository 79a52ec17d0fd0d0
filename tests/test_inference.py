from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from mosegpipe.embed.model import ModelConfig, SubspaceNet
from mosegpipe.embed.numpy_net import NumpySubspaceNet, load_embedder, shipped_path
from mosegpipe.errors import CheckpointError, InputError
from mosegpipe.types import Trajectories

SAMPLE_FRAMES = Path(__file__).resolve().parents[1] / "samples" / "rendered" / "frames"


def _traj(n: int, d: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    base = rng.uniform(0, 640, size=(n, 2))
    motion = np.cumsum(rng.normal(0, 3, size=(n, d // 2 - 1, 2)), axis=1).reshape(n, -1) if d > 2 else np.zeros((n, 0))
    return np.concatenate([base, np.tile(base, (1, d // 2 - 1)) + motion], axis=1).astype(np.float32)


@pytest.mark.parametrize("norm", ["shared", "channel", "motion"])
@pytest.mark.parametrize("l2", [True, False])
def test_numpy_embedding_equals_torch(norm: str, l2: bool) -> None:
    torch.manual_seed(3)
    net = SubspaceNet(ModelConfig(in_dim=10, width=32, num_blocks=4, embed_dim=5, input_norm=norm, l2_normalize=l2))
    with torch.no_grad():  # biases away from their zero initialisation, so that every term counts
        for param in net.parameters():
            param.add_(0.05 * torch.randn_like(param))
    net.eval()
    fast = NumpySubspaceNet.from_torch(net)
    for seed, n in ((0, 300), (5, 7)):
        traj = _traj(n, 10, seed)
        np.testing.assert_allclose(fast.embed(traj), net.embed(traj), atol=2e-5, rtol=1e-5)
    # Trajectories of another length are resampled in time like the torch model's.
    tr = Trajectories(_traj(40, 14, seed=2), np.arange(40))
    np.testing.assert_allclose(fast.embed(tr), net.embed(tr), atol=2e-5, rtol=1e-5)
    assert fast.embed(np.zeros((0, 10))).shape == (0, 5)
    for bad in (np.full((3, 10), np.nan), np.zeros((3, 8)), np.array([["a"] * 10])):
        with pytest.raises(InputError) as fast_err:
            fast.embed(bad)
        with pytest.raises(InputError) as torch_err:
            net.embed(bad)
        assert str(fast_err.value) == str(torch_err.value)


def test_numpy_inference_refuses_other_architectures_and_misfit_weights() -> None:
    net = SubspaceNet(ModelConfig(in_dim=4, width=8, num_blocks=1, arch="pointnet"))
    with pytest.raises(CheckpointError, match="pointnet"):
        NumpySubspaceNet.from_torch(net)
    good = NumpySubspaceNet.from_torch(SubspaceNet(ModelConfig(in_dim=4, width=8, num_blocks=1)))
    weights = dict(good.weights)
    weights["head.bias"] = np.zeros(3, dtype=np.float32)
    with pytest.raises(CheckpointError, match="head.bias"):
        NumpySubspaceNet(good.cfg, weights)


def test_load_embedder_keeps_a_copy_and_serves_it(tmp_path: Path) -> None:
    torch.manual_seed(0)
    ckpt = SubspaceNet(ModelConfig(in_dim=10, width=16, num_blocks=2, input_norm="motion")).save(tmp_path / "m.pt")
    cache = tmp_path / "cache"
    first = load_embedder(5, ckpt, cache_dir=cache)
    assert isinstance(first, SubspaceNet)  # a cache miss: the torch model, and a copy written
    (copy,) = cache.glob("m-*.npz")
    second = load_embedder(5, ckpt, cache_dir=cache)
    assert isinstance(second, NumpySubspaceNet)
    assert second.checkpoint_path == str(ckpt.resolve())  # type: ignore[attr-defined]
    assert second.cfg == first.cfg and second.recipe == first.recipe
    traj = _traj(80, 10)
    np.testing.assert_allclose(second.embed(traj), first.embed(traj), atol=2e-5, rtol=0)

    # Other weights in the same file: another digest, so the old copy is not used.
    torch.manual_seed(1)
    SubspaceNet(first.cfg).save(ckpt)
    assert isinstance(load_embedder(5, ckpt, cache_dir=cache), SubspaceNet)
    assert len(list(cache.glob("m-*.npz"))) == 2
    # A damaged copy is ignored (the checkpoint is loaded with torch) and written again.
    newest = max(cache.glob("m-*.npz"), key=lambda p: p.stat().st_mtime_ns)
    newest.write_bytes(b"not an npz")
    assert isinstance(load_embedder(5, ckpt, cache_dir=cache), SubspaceNet)
    assert isinstance(load_embedder(5, ckpt, cache_dir=cache), NumpySubspaceNet)
    assert copy.exists()


def test_load_embedder_without_a_writable_cache_and_for_other_architectures(tmp_path: Path) -> None:
    blocked = tmp_path / "file"
    blocked.write_text("x")  # a file where the cache folder would be: nothing can be written under it
    ckpt = SubspaceNet(ModelConfig(in_dim=4, width=8, num_blocks=1)).save(tmp_path / "a.pt")
    assert isinstance(load_embedder(2, ckpt, cache_dir=blocked / "cache"), SubspaceNet)
    other = SubspaceNet(ModelConfig(in_dim=4, width=8, num_blocks=1, arch="corresnet")).save(tmp_path / "c.pt")
    assert isinstance(load_embedder(2, other, cache_dir=tmp_path / "c2"), SubspaceNet)
    assert not (tmp_path / "c2").exists() or not list((tmp_path / "c2").iterdir())
    with pytest.raises(CheckpointError, match="not found"):
        load_embedder(2, tmp_path / "missing.pt", cache_dir=tmp_path / "c3")


def test_shipped_weights_through_numpy_match_torch(tmp_path: Path) -> None:
    for frames, expected in ((5, 5), (2, 2), (7, 5)):
        assert shipped_path(frames).name == f"subspacenet_f{expected}.pt"
        load_embedder(frames, cache_dir=tmp_path)
        fast = load_embedder(frames, cache_dir=tmp_path)
        assert isinstance(fast, NumpySubspaceNet)
        reference = SubspaceNet.default(expected)
        traj = _traj(500, 2 * expected, seed=frames)
        # float32 sums in another order, through 12-30 context normalisations: ~1e-5 apart on unit vectors.
        np.testing.assert_allclose(fast.embed(traj), reference.embed(traj), atol=1e-4, rtol=0)
        assert fast.recipe == reference.recipe and dataclasses.asdict(fast.cfg) == dataclasses.asdict(reference.cfg)


@pytest.mark.slow
def test_moseg_run_with_a_kept_copy_does_not_import_torch(tmp_path: Path) -> None:
    load_embedder(5, cache_dir=tmp_path / "cache" / "inference")  # the copy a first run would keep
    code = (
        "import atexit, sys\n"
        "atexit.register(lambda: print('TORCH', 'torch' in sys.modules, file=sys.stderr))\n"
        "from mosegpipe.cli.main import app\nsys.argv[0] = 'moseg'\napp()\n"
    )
    args = ["run", str(SAMPLE_FRAMES), "--frames", "5", "--no-rrd", "--out", str(tmp_path / "o")]
    env = {**__import__("os").environ, "MOSEG_CACHE": str(tmp_path / "cache")}
    proc = subprocess.run(
        [sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=300, cwd=tmp_path, env=env
    )
    assert proc.returncode == 0, proc.stderr
    assert "TORCH False" in proc.stderr and (tmp_path / "o" / "labels.npz").is_file()
