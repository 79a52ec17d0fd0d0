"""The bad-input matrix of issue 12: faults, bad options and API misuse, each answered by one line.

Every case here failed before its fix (a box of usage text, a traceback, a hang, stray decoder bytes
on stderr or a `.partial` folder left behind). The promise under test (README): one line
`moseg: error: ...` on stderr, exit code 1 (2 for usage errors), nothing half-written left behind.
"""

from __future__ import annotations

import errno
import os
import shutil
import subprocess
import sys
import tempfile
import textwrap
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from mosegpipe import viz
from mosegpipe.embed.model import SubspaceNet
from mosegpipe.errors import CheckpointError, InputError
from mosegpipe.group.cluster import ClusterConfig, cluster_auto_k, kmeans, single_motion_residual_px
from mosegpipe.io.read import read_image, read_video, video_info
from mosegpipe.pipeline import PipelineConfig, segment_frames, segment_pair, segment_tracks
from mosegpipe.types import Frames

from helpers import (
    best_permutation_accuracy,
    moseg,
    motion_checkpoint,
    one_error_line,
    render_scene,
    tiny_model,
    write_avi,
)

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def clip_avi(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_avi(tmp_path_factory.mktemp("clip") / "scene.avi", render_scene(6).frames)


@pytest.fixture(scope="module")
def model5(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return motion_checkpoint(tmp_path_factory.mktemp("models") / "motion5.pt", 5)


def nothing_left(folder: Path) -> None:
    assert sorted(p.name for p in folder.iterdir()) == [], list(folder.iterdir())


def run_script(code: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    """Runs Python code in a fresh process (fd-level output, signals and hangs cannot touch pytest)."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(REPO / "tests")}
    # Outside the checkout, so that the installed package is imported, not the source folder (whose cli/
    # lives beside it, not inside it).
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=env,
        cwd=tempfile.gettempdir(),
    )


# ---------------------------------------------------------------------------------------------
# 5. Usage errors: one line naming the option and the value, exit code 2
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["run", "x.avi", "--frames", "0"], "--frames 0: "),
        (["run", "x.avi", "--k", "0"], "--k 0: "),
        (["run", "x.avi", "--k=0"], "--k 0: "),
        (["run", "x.avi", "--k-max", "0"], "--k-max 0: "),
        (["run", "x.avi", "--threads", "0"], "--threads 0: "),
        (["run", "x.avi", "--k-method", "elbow"], "--k-method elbow: "),
        (["batch", "d", "--out", "o", "--engine", "slurm"], "--engine slurm: "),
        (["train", "--steps", "0"], "--steps 0: "),
        (["run"], "Missing argument"),
        (["run", "x.avi", "--bogus"], "No such option: --bogus"),
        (["frobnicate"], "No such command 'frobnicate'"),
    ],
)
def test_usage_errors_are_one_line(args: list[str], expected: str) -> None:
    code, out, err = moseg(*args)
    line = one_error_line(err)
    assert code == 2 and expected in line and "--help" in line and out == ""


# ---------------------------------------------------------------------------------------------
# 1. Disk full while the recording is written
# ---------------------------------------------------------------------------------------------


class _FullDisk:
    """A file whose writes fail with ENOSPC, as on a full disk."""

    def __init__(self, path: object, mode: str = "r") -> None:
        self.path = path

    def __enter__(self) -> _FullDisk:
        return self

    def __exit__(self, *exc: object) -> None:
        pass

    def write(self, data: bytes) -> int:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


@pytest.mark.parametrize("whole", [False, True])
def test_disk_full_while_writing_the_recording(
    tmp_path: Path, clip_avi: Path, model5: Path, monkeypatch: pytest.MonkeyPatch, whole: bool
) -> None:
    monkeypatch.setattr(viz.blocks, "open", _FullDisk, raising=False)  # the recording's writer, nothing else
    parent = tmp_path / "parent"
    parent.mkdir()
    extra = ["--whole", "--frames", "3"] if whole else []
    code, _, err = moseg("run", clip_avi, "--out", parent / "out", "--model", model5, *extra)
    line = one_error_line(err)
    assert code == 1 and "No space left on device" in line and "out/recording.rrd" in line
    assert ".partial" not in line and ".tmp" not in line
    nothing_left(parent)


def test_disk_full_on_a_real_small_file_system(tmp_path: Path, clip_avi: Path, model5: Path) -> None:
    """A 200 kB tmpfs as --out's parent: masks and overlay.mp4 fit (70 kB), the recording (330 kB) does
    not. Before the fix Rerun's flush hung for ever (or raised a traceback)."""
    mount = tmp_path / "tiny"
    mount.mkdir()
    if (
        shutil.which("mount") is None
        or subprocess.run(
            ["mount", "-t", "tmpfs", "-o", "size=200k", "tmpfs", str(mount)], capture_output=True
        ).returncode
    ):
        pytest.skip("cannot mount a tmpfs here (needs root)")
    try:
        proc = subprocess.run(
            [sys.executable, "-m", "mosegpipe.cli.main", "run", str(clip_avi), "--out", str(mount / "out")]
            + ["--model", str(model5), "--whole", "--frames", "3"],
            capture_output=True,
            text=True,
            timeout=90,
            env={**os.environ, "OMP_NUM_THREADS": "1"},
            cwd=tmp_path,
        )
        assert proc.returncode == 1, proc.stderr
        assert "No space left on device" in one_error_line(proc.stderr)
        nothing_left(mount)
    finally:
        subprocess.run(["umount", str(mount)], check=False)


# ---------------------------------------------------------------------------------------------
# 2. Checkpoint configurations are bounded and checked before anything is built
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("width", 2**20, "width=1048576: must lie in 1..4096"),
        ("num_blocks", 10**7, "num_blocks=10000000: must lie in 0..1000"),
        ("in_dim", 0, "in_dim=0"),
        ("embed_dim", 1.5, "embed_dim=1.5: must be an int"),
        ("width", True, "width=True: must be an int"),
        ("input_norm", ["shared"], "input_norm="),
    ],
)
def test_checkpoint_config_is_validated_first(field: str, value: object, message: str) -> None:
    ckpt = tiny_model(5).checkpoint()
    ckpt["model_config"][field] = value
    with pytest.raises(CheckpointError, match=message.replace("[", r"\[").replace(".", r"\.")):
        SubspaceNet.from_checkpoint(ckpt)


def test_checkpoint_too_many_parameters_and_bad_weights() -> None:
    ckpt = tiny_model(5).checkpoint()
    ckpt["model_config"].update(width=4096, num_blocks=1000)
    with pytest.raises(CheckpointError, match="parameters, more than"):
        SubspaceNet.from_checkpoint(ckpt)
    ckpt = tiny_model(5).checkpoint()
    ckpt["state_dict"]["head.bias"] = torch.full_like(ckpt["state_dict"]["head.bias"], float("nan"))
    with pytest.raises(CheckpointError, match="'head.bias' holds NaN"):
        SubspaceNet.from_checkpoint(ckpt)
    ckpt = tiny_model(5).checkpoint()
    ckpt["state_dict"]["head.bias"] = torch.zeros(5, dtype=torch.int64)
    with pytest.raises(CheckpointError, match="'head.bias' must be a floating-point tensor"):
        SubspaceNet.from_checkpoint(ckpt)
    ckpt = tiny_model(5).checkpoint()
    ckpt["recipe"] = ["not", "a", "dict"]
    with pytest.raises(CheckpointError, match="'recipe' must be a dict"):
        SubspaceNet.from_checkpoint(ckpt)


def test_cli_names_the_bad_checkpoint_field(tmp_path: Path, clip_avi: Path) -> None:
    ckpt = tiny_model(5).checkpoint()
    ckpt["model_config"]["width"] = 2**20
    torch.save(ckpt, tmp_path / "huge.pt")
    code, _, err = moseg("run", clip_avi, "--out", tmp_path / "out", "--model", tmp_path / "huge.pt")
    assert code == 1 and "huge.pt: invalid model_config: ModelConfig.width=1048576" in one_error_line(err)


# ---------------------------------------------------------------------------------------------
# 6. SIGTERM is handled as Ctrl-C: no hidden .partial folder left
# ---------------------------------------------------------------------------------------------


def test_sigterm_leaves_nothing_behind(tmp_path: Path, clip_avi: Path, model5: Path) -> None:
    out = tmp_path / "parent" / "out"
    proc = run_script(
        f"""
        import os, signal, sys
        import mosegpipe.apps.outputs as outputs
        from mosegpipe.cli.main import app

        real = outputs.write_npz
        def write_npz(*args, **kwargs):  # the folder is half built: SIGTERM arrives now
            real(*args, **kwargs)
            os.kill(os.getpid(), signal.SIGTERM)
        outputs.write_npz = write_npz
        sys.argv = ["moseg", "run", {str(clip_avi)!r}, "--out", {str(out)!r}, "--model", {str(model5)!r}]
        app()
        """
    )
    assert proc.returncode == 143, proc.stderr  # 128 + SIGTERM, as shells report it
    assert one_error_line(proc.stderr) == "moseg: error: terminated (SIGTERM)"
    assert not out.parent.exists()  # made for the run's lock file and its outputs: removed with them


# ---------------------------------------------------------------------------------------------
# 7. Stray decoder output: stderr holds only the error line
# ---------------------------------------------------------------------------------------------


def test_avi_cut_inside_its_header(tmp_path: Path, clip_avi: Path, capfd: pytest.CaptureFixture[str]) -> None:
    cut = tmp_path / "cut.avi"
    cut.write_bytes(clip_avi.read_bytes()[:12])  # OpenCV's AVI parser prints "Unexpected element ..."
    capfd.readouterr()
    code, _, err = moseg("run", cut, "--out", tmp_path / "out")
    assert code == 1 and "cut.avi: not a readable video" in one_error_line(err)
    assert capfd.readouterr().err == ""  # nothing written to file descriptor 2 directly
    with pytest.raises(InputError):
        video_info(cut)
    assert capfd.readouterr().err == ""


def test_blank_video_in_whole_mode_prints_no_warnings(tmp_path: Path, model5: Path) -> None:
    blank = write_avi(tmp_path / "blank.avi", np.full((9, 64, 80, 3), 128, np.uint8))
    proc = run_script(
        f"""
        import sys
        from mosegpipe.cli.main import app
        sys.argv = ["moseg", "run", {str(blank)!r}, "--whole", "--frames", "3", "--model", {str(model5)!r},
                    "--out", {str(tmp_path / "out")!r}]
        app()
        """
    )
    assert proc.returncode == 1
    assert "no window had at least" in one_error_line(proc.stderr)


# ---------------------------------------------------------------------------------------------
# 8. API misuse raises the library's errors
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def net5() -> SubspaceNet:
    return tiny_model(5)


def _traj(scale: float = 1.0) -> np.ndarray:
    rng = np.random.default_rng(0)
    return rng.uniform(0, 300, size=(40, 10)) * scale


def test_embed_float64_beyond_float32_range(net5: SubspaceNet) -> None:
    """Coordinates in the 1e40s are far from pixels, but the embedding is scale-invariant: no NaN."""
    z_big = net5.embed(_traj(1e40))
    z = net5.embed(_traj())
    assert np.all(np.isfinite(z_big)) and np.allclose(z_big, z, atol=1e-4)
    with pytest.raises(InputError, match="too large to normalise"):
        net5.embed(_traj(1e300))


@pytest.mark.parametrize("dtype", [complex, str, object, bool])
def test_embed_rejects_what_is_not_coordinates(net5: SubspaceNet, dtype: type) -> None:
    with pytest.raises(InputError, match="expected real numbers"):
        net5.embed(_traj().astype(dtype))


@pytest.mark.parametrize("k", [1.5, "3", True])
def test_non_integer_k(k: object) -> None:
    emb = np.random.default_rng(0).normal(size=(20, 3))
    with pytest.raises(InputError, match="must be an integer"):
        cluster_auto_k(emb, k=k)  # type: ignore[arg-type]
    with pytest.raises(InputError, match="must be an integer"):
        kmeans(emb, k)  # type: ignore[arg-type]


def test_complex_embeddings_are_not_truncated() -> None:
    with pytest.raises(InputError, match="real numbers"):
        cluster_auto_k(np.ones((10, 3), dtype=complex))


def test_empty_images() -> None:
    image = np.zeros((50, 60, 3), np.uint8)
    with pytest.raises(InputError, match="image 1: empty image"):
        segment_pair(np.zeros((0, 0, 3), np.uint8), image, model=tiny_model(2))
    with pytest.raises(InputError, match="image 2: expected a"):
        segment_pair(image, np.zeros((50, 60), np.float32), model=tiny_model(2))
    with pytest.raises(InputError, match="empty image"):
        segment_frames(Frames(images=np.zeros((5, 0, 0, 3), np.uint8), fps=0.0, source="", start=0))


@pytest.mark.parametrize("path", [None, 3, b"clip.avi", ""])
def test_paths_that_are_not_paths(path: object) -> None:
    with pytest.raises(InputError, match="video: "):
        read_video(path)  # type: ignore[arg-type]
    with pytest.raises(InputError, match="image: "):
        read_image(path)  # type: ignore[arg-type]


def test_non_integer_frame_counts(clip_avi: Path) -> None:
    with pytest.raises(InputError, match="max_frames=2.5 must be an integer"):
        read_video(clip_avi, max_frames=2.5)  # type: ignore[arg-type]


# ---------------------------------------------------------------------------------------------
# 9. No motion, no motions; ambiguous K choices are said so
# ---------------------------------------------------------------------------------------------


def test_identical_images_are_one_motion(tmp_path: Path) -> None:
    """Two identical images gave K = 8 (the embedding of zero motion is noise); now K = 1 with a note."""
    rng = np.random.default_rng(0)
    image = cv2.GaussianBlur(rng.integers(0, 255, (240, 320, 3), dtype=np.uint8), (5, 5), 0)
    result = segment_pair(image, image.copy())
    assert result.clustering.k == 1 and "nothing moves" in result.clustering.note
    assert result.clustering.scores == {}


def test_no_motion_rule_needs_the_residual_below_the_noise() -> None:
    rng = np.random.default_rng(0)
    xy1 = rng.uniform(0, 300, size=(200, 2))
    static = np.concatenate([xy1, xy1 + rng.normal(0, 0.2, size=xy1.shape)], axis=1)  # noise only
    assert single_motion_residual_px(static) < 1.0
    moving = static.copy()
    moving[:20, 2:] += 6.0  # 10 % of the points move 6 px against the rest
    assert single_motion_residual_px(moving) > 3.0
    emb = rng.normal(size=(200, 5))
    emb[:100] += 4.0  # two clear groups in the embedding
    assert cluster_auto_k(emb, points=static).k == 1
    assert cluster_auto_k(emb, points=moving).k == 2
    assert cluster_auto_k(emb).k == 2  # without points the embedding decides, as before


def test_ambiguous_k_choice_is_reported(caplog: pytest.LogCaptureFixture) -> None:
    rng = np.random.default_rng(1)
    emb = rng.normal(size=(300, 5))  # one wide blob: every K scores about the same
    cfg = ClusterConfig(one_motion_spread=0.0, ambiguity_margin=1.0)
    result = cluster_auto_k(emb, cfg)
    assert "the K choice is ambiguous" in result.note and "pass --k" in result.note
    assert any("ambiguous" in r.getMessage() for r in caplog.records)
    clear = rng.normal(size=(300, 5)) * 0.05
    clear[:150] += 3.0
    assert cluster_auto_k(clear).note == ""


# ---------------------------------------------------------------------------------------------
# 16. External tracks: segment_tracks / moseg tracks
# ---------------------------------------------------------------------------------------------


def _two_motions(n: int = 200, frames: int = 8) -> np.ndarray:
    rng = np.random.default_rng(0)
    velocity = np.where(np.arange(n)[:, None] < n // 2, [[2.0, 0.0]], [[0.0, -3.0]])
    return rng.uniform(0, 300, (n, 1, 2)) + np.arange(frames)[None, :, None] * velocity[:, None, :]


def test_segment_tracks_of_another_tracker() -> None:
    xy = _two_motions()
    visible = np.ones(xy.shape[:2], dtype=bool)
    visible[:10, 3] = False  # occluded once: not segmented, label -1
    xy[:10, 3] = np.nan  # what a tracker may hold where a point is hidden
    result = segment_tracks(xy, visible)
    assert result.clustering.k == 2 and np.all(result.labels[:10] == -1)
    assert best_permutation_accuracy(result.labels[10:], (np.arange(10, 200) >= 100).astype(np.int64)) == 1.0
    for bad, message in [
        (xy[..., 0], "must be an \\(N, T, 2\\) array"),
        (xy.astype(complex), "must be an \\(N, T, 2\\) array"),
    ]:
        with pytest.raises(InputError, match=message):
            segment_tracks(bad)
    with pytest.raises(InputError, match="NaN or inf where the tracks are visible"):
        segment_tracks(xy)
    with pytest.raises(InputError, match="visible must be an \\(200, 8\\) bool array"):
        segment_tracks(xy, visible[:, :3])
    with pytest.raises(InputError, match="the window must hold 2 or more"):
        segment_tracks(xy, visible, start=5, frames=4)
    with pytest.raises(InputError, match=r"start=7: must lie in 0..6 \(the tracks span 8 frames\)"):
        segment_tracks(xy, visible, start=7)


def test_moseg_tracks_reads_our_and_cotracker_layouts(tmp_path: Path) -> None:
    xy = _two_motions().astype(np.float32)
    np.savez(tmp_path / "ours.npz", xy=xy)
    np.savez(tmp_path / "cotracker.npz", tracks=np.swapaxes(xy, 0, 1)[None], visibility=np.ones((1, 8, 200), bool))
    for name in ("ours", "cotracker"):
        code, out, err = moseg("tracks", tmp_path / f"{name}.npz", "--frames", "5", "--out", tmp_path / name)
        assert code == 0 and "K = 2" in out and err == "", err
        labels = np.load(tmp_path / name / "labels.npz")["labels"]
        assert labels.shape == (200,) and set(labels.tolist()) == {0, 1}
    np.savez(tmp_path / "other.npz", points=xy)
    code, _, err = moseg("tracks", tmp_path / "other.npz", "--out", tmp_path / "x")
    assert code == 1 and "holds ['points']; expected 'xy'" in one_error_line(err)
    nothing_left_but = sorted(p.name for p in tmp_path.iterdir())
    assert "x" not in nothing_left_but and ".x.partial" not in nothing_left_but


# ---------------------------------------------------------------------------------------------
# 24. Issue 24: moseg tracks at scale and its damaged files
# ---------------------------------------------------------------------------------------------


def _blobs(n: int, k: int = 3, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    truth = rng.integers(0, k, n)
    centres = np.eye(5)[:k] * 3.0
    return centres[truth] + rng.normal(0, 0.1, (n, 5)), truth


@pytest.mark.parametrize("rule", ["silhouette", "residual"])
def test_automatic_k_scores_a_sample_of_many_points(monkeypatch: pytest.MonkeyPatch, rule: str) -> None:
    """N x N distances for 100 000 tracks asked for 74.5 GiB: beyond MAX_SCORED_POINTS K is chosen on
    a seeded sample and the others go to the nearest centre; nothing quadratic sees more than the sample."""
    import mosegpipe.group.cluster as cluster

    monkeypatch.setattr(cluster, "MAX_SCORED_POINTS", 300)
    real_distances, real_kmeans = cluster.pairwise_distances, cluster.kmeans
    seen: list[int] = []

    def distances(x: np.ndarray) -> np.ndarray:
        seen.append(len(x))
        return real_distances(x)

    def kmeans(x: np.ndarray, *args: object, **kwargs: object) -> tuple[np.ndarray, float]:
        seen.append(len(x))
        return real_kmeans(x, *args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(cluster, "pairwise_distances", distances)
    monkeypatch.setattr(cluster, "kmeans", kmeans)
    emb, truth = _blobs(5000)
    result = cluster_auto_k(emb, ClusterConfig(method=rule))  # type: ignore[arg-type]
    assert seen and max(seen) == 300
    assert result.k == 3 and result.labels.shape == (5000,)
    assert best_permutation_accuracy(result.labels, truth) == 1.0
    again = cluster_auto_k(emb, ClusterConfig(method=rule))  # type: ignore[arg-type]
    assert np.array_equal(again.labels, result.labels)  # seeded


def test_automatic_k_is_unchanged_up_to_the_sample_size() -> None:
    import mosegpipe.group.cluster as cluster

    emb, _ = _blobs(cluster.MAX_SCORED_POINTS)
    cfg = ClusterConfig()
    distances = cluster.pairwise_distances(emb)
    fits = {k: cluster.kmeans(emb, k, seed=cfg.seed, n_init=cfg.n_init) for k in range(2, 9)}
    expected = max(fits, key=lambda k: (cluster.mean_silhouette(distances, fits[k][0]), -k))
    result = cluster_auto_k(emb, cfg)
    assert result.k == expected and np.array_equal(result.labels, fits[expected][0])


def _rigid_scene(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(N, 2F) tracks over 5 frames of a 400x300 view: a static background and a 100x100 square
    moving 4 px per frame (about 8 % of the points), all in one cluster."""
    rng = np.random.default_rng(seed)
    start = rng.uniform((0, 0), (400, 300), (n, 2))
    inside = np.all((start > (150, 100)) & (start < (250, 200)), axis=1)
    t = np.arange(5)[None, :, None]
    xy = start[:, None] + t * np.where(inside[:, None], 4.0, 0.0)[:, None] + rng.normal(0, 0.2, (n, 5, 2))
    return xy.reshape(n, 10), inside


def test_rigid_check_of_many_points_links_a_sample(monkeypatch: pytest.MonkeyPatch) -> None:
    """Linking candidates within a radius was quadratic in the density; beyond MAX_CHECKED_POINTS the
    check runs on a sample and the other points follow the groups split off."""
    import mosegpipe.group.rigid as rigid

    monkeypatch.setattr(rigid, "MAX_CHECKED_POINTS", 400)
    real = rigid._coherent_groups
    seen: list[int] = []

    def groups(xy: np.ndarray, *args: object) -> np.ndarray:
        seen.append(len(xy))
        return real(xy, *args)  # type: ignore[arg-type]

    monkeypatch.setattr(rigid, "_coherent_groups", groups)
    points, inside = _rigid_scene(6000)
    labels, split = rigid.split_by_rigid_motion(points, np.zeros(len(points), np.int64), (300, 400))
    assert split == 1 and seen and max(seen) <= 400
    assert best_permutation_accuracy(labels, inside.astype(np.int64)) > 0.99


def test_rigid_check_is_unchanged_up_to_the_sample_size(monkeypatch: pytest.MonkeyPatch) -> None:
    import mosegpipe.group.rigid as rigid

    points, inside = _rigid_scene(1000)
    labels, split = rigid.split_by_rigid_motion(points, np.zeros(1000, np.int64), (300, 400))
    monkeypatch.setattr(rigid, "MAX_CHECKED_POINTS", 10**9)
    assert np.array_equal(rigid.split_by_rigid_motion(points, np.zeros(1000, np.int64), (300, 400))[0], labels)
    assert split == 1 and best_permutation_accuracy(labels, inside.astype(np.int64)) > 0.95


@pytest.mark.parametrize(
    ("fault", "message"),
    [
        ("truncated", "truncated.npz: not a readable .npz file"),
        ("npy", "npy.npz: a single .npy array, not a .npz archive"),
        ("huge", "huge.npz: xy holds coordinates up to 1e+300"),
    ],
)
def test_moseg_tracks_names_a_damaged_file(tmp_path: Path, fault: str, message: str) -> None:
    xy = _two_motions()
    path = tmp_path / f"{fault}.npz"
    if fault == "truncated":
        np.savez(tmp_path / "whole.npz", xy=xy)
        path.write_bytes((tmp_path / "whole.npz").read_bytes()[:300])  # cut inside the first array
    elif fault == "npy":
        with open(path, "wb") as fh:
            np.save(fh, xy)
    else:
        xy[0, 0] = 1e300  # became inf in float32, then an OverflowError traceback
        np.savez(path, xy=xy)
    code, out, err = moseg("tracks", path, "--out", tmp_path / "out")
    assert code == 1 and message in one_error_line(err) and out == ""
    assert not (tmp_path / "out").exists() and not (tmp_path / ".out.partial").exists()


@pytest.mark.parametrize("damage", ["truncated", "nan"])
def test_damaged_inference_copy_is_rewritten(
    tmp_path: Path, model5: Path, monkeypatch: pytest.MonkeyPatch, damage: str
) -> None:
    """A cut-short copy gave a BadZipFile traceback on every run, one with NaN weights an error blaming
    the input; either is now ignored and written again from the checkpoint."""
    from mosegpipe.embed.numpy_net import NumpySubspaceNet, load_embedder

    cache = tmp_path / "cache"
    monkeypatch.setenv("MOSEG_CACHE", str(cache))
    load_embedder(5, model5)
    (copy,) = (cache / "inference").glob("*.npz")
    if damage == "truncated":
        copy.write_bytes(copy.read_bytes()[:200])
    else:
        net = NumpySubspaceNet.load_npz(copy)
        net.weights["head.bias"][:] = np.nan
        net.save_npz(copy)
    np.savez(tmp_path / "tracks.npz", xy=_two_motions())
    code, out, err = moseg("tracks", tmp_path / "tracks.npz", "--model", model5, "--out", tmp_path / "out")
    assert code == 0 and "K = 2" in out, err
    assert "error" not in err and "Traceback" not in err
    assert np.all(np.isfinite(NumpySubspaceNet.load_npz(copy).weights["head.bias"]))  # rewritten


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["run", "x.avi", "--min-distance", "1e308"], "--min-distance 1e308: "),  # was SIGSEGV in OpenCV
        (["run", "x.avi", "--min-distance", "1e30"], "--min-distance 1e30: "),
        (["run", "x.avi", "--max-corners", "3000000000"], "--max-corners 3000000000: "),  # was a traceback
        (["run", "x.avi", "--win-size", "100001"], "--win-size 100001: "),  # was a traceback
        (["run", "x.avi", "--mask-median", "100001"], "--mask-median 100001: "),  # ran for minutes
        (["run", "x.avi", "--mask-max-distance", "1e9"], "--mask-max-distance 1e9: "),
        (["run", "x.avi", "--mask-extra-tracks", "1000001"], "--mask-extra-tracks 1000001: "),
        (["run", "x.avi", "--k-max", "65"], "--k-max 65: "),
        (["run", "x.avi", "--k", "1000000"], "--k 1000000: "),
        (["run", "x.avi", "--frames", "100000"], "--frames 100000: "),
        (["run", "x.avi", "--start", "99999999999"], "--start 99999999999: "),
        (["run", "x.avi", "--threads", "100000"], "--threads 100000: "),
        (["pair", "a.png", "b.png", "--mask-median", "100001"], "--mask-median 100001: "),
        (["tracks", "t.npz", "--frames", "100000"], "--frames 100000: "),
        (["tracks", "t.npz", "--k-max", "1000"], "--k-max 1000: "),
        (["batch", "d", "--out", "o", "--max-corners", "3000000000"], "--max-corners 3000000000: "),
        (["batch", "d", "--out", "o", "--jobs", "100000"], "--jobs 100000: "),
        (["batch", "d", "--out", "o", "--clip-timeout", "1e300"], "--clip-timeout 1e300: "),
    ],
)
def test_numeric_options_have_upper_bounds(args: list[str], expected: str) -> None:
    code, out, err = moseg(*args)
    line = one_error_line(err)
    assert code == 2 and expected in line and "less than or equal to" in line and out == ""


def test_the_library_refuses_what_the_option_bounds_refuse() -> None:
    """The options' bounds are mosegpipe.settings' (imported by both); the config classes refuse the same
    values, naming the field."""
    from mosegpipe.points.klt import TrackConfig
    from mosegpipe.settings import SettingError

    for bad in ({"max_corners": 3_000_000_000}, {"win_size_px": 100_001}, {"min_distance_px": 1e308}):
        with pytest.raises(SettingError, match=f"^{next(iter(bad))}: .* must lie in"):
            TrackConfig(**bad)  # type: ignore[arg-type]
    with pytest.raises(SettingError, match=r"^quality_level: 0.0 must lie in \(0, 1\]"):
        TrackConfig(quality_level=0.0)
    with pytest.raises(InputError, match="^k_max: 65 must be at most 64"):
        ClusterConfig(k_max=65)


@pytest.mark.parametrize(
    ("toml", "message"),
    [
        ("max-corners = 3000000000\n", "max-corners = 3000000000: Input should be less than or equal to 100000"),
        ("min-distance = 1e308\n", "min-distance = 1e+308: Input should be less than or equal to 10000"),
        ("[run]\nmask-median = 100001\n", "run.mask-median = 100001: Input should be less than or equal to 255"),
        ("k-method = 'residual'\nk_method = 'silhouette'\n", "'k-method' and 'k_method' set the same option"),
        ("[run]\nk_max = 3\nk-max = 4\n", "'run.k_max' and 'run.k-max' set the same option"),
    ],
)
def test_config_files_hold_the_option_bounds(tmp_path: Path, toml: str, message: str) -> None:
    (tmp_path / "c.toml").write_text(toml)
    code, out, err = moseg("run", tmp_path / "x.avi", "--config", tmp_path / "c.toml")
    assert code == 1 and message in one_error_line(err) and out == ""


def test_top_level_and_table_may_set_one_option(tmp_path: Path) -> None:
    (tmp_path / "c.toml").write_text("k-method = 'residual'\n[run]\nk_method = 'silhouette'\n")
    code, _, err = moseg("run", tmp_path / "x.avi", "--config", tmp_path / "c.toml")
    assert code == 1 and "x.avi: no such file or folder" in one_error_line(err)  # the config was accepted


def test_api_misuse_of_issue_24() -> None:
    from mosegpipe.points.klt import track_klt
    from mosegpipe.points.trajectories import build_trajectories
    from mosegpipe.types import Tracks

    one = Frames(images=render_scene(2).frames[:1], fps=0.0, source="", start=0)
    for model in (tiny_model(1), tiny_model(5)):  # was an IndexError in the rigid-motion check
        result = segment_frames(one, model=model)
        assert result.clustering.k == 1 and not result.clustering.labels.any() and "one frame" in result.clustering.note
        assert result.masks.shape == (1, *one.images.shape[1:3]) and set(np.unique(result.masks)) <= {0, 255}
        assert result.embeddings.shape[0] == result.trajectories.num_points > 0
    assert segment_frames(one, replace(PipelineConfig(), k=2), model=tiny_model(1)).clustering.k == 2  # K as given
    tracks = Tracks(xy=np.zeros((5, 4, 2), np.float32), visible=np.ones((5, 3), bool), size_hw=(10, 10))
    with pytest.raises(ValueError, match=r"xy \(5, 4, 2\) and visible \(5, 3\)"):
        build_trajectories(tracks)
    with pytest.raises(ValueError, match=r"H, W >= 1, got \(3, 0, 0, 3\)"):  # was an OpenCV assertion
        track_klt(Frames(images=np.zeros((3, 0, 0, 3), np.uint8), fps=0.0, source="", start=0))
