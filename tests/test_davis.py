"""DAVIS reader, split, scores and protocol on a tiny fake DAVIS folder; one test on the real clips."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from mosegpipe.data.davis import (
    DAVIS2016_TRAIN,
    DAVIS_DEV,
    DAVIS_VAL,
    DavisClip,
    davis_split,
    list_davis_clips,
    read_davis_clip,
)
from mosegpipe.errors import ConfigError, DatasetError, TooFewTracksError
from mosegpipe.evaluation.davis import MethodOutput, flow_homography_labels, format_table, run_davis, score_clip
from mosegpipe.evaluation.davis_scores import (
    background_label,
    best_single_label,
    clip_statistics,
    foreground_from_labels,
    majority_foreground,
    per_frame_scores,
    world_off_share,
)

H, W, T = 48, 64, 6
SIDE = 20


def _scene(num_frames: int = T, step_px: int = 4, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A textured square moving right over a textured static background: images (T,H,W,3), gt (T,H,W)."""
    rng = np.random.default_rng(seed)
    background = cv2.GaussianBlur(rng.integers(0, 256, (H, W), dtype=np.uint8), (5, 5), 0)
    patch = cv2.GaussianBlur(rng.integers(0, 256, (SIDE, SIDE), dtype=np.uint8), (5, 5), 0)
    images = np.zeros((num_frames, H, W, 3), np.uint8)
    gt = np.zeros((num_frames, H, W), bool)
    for t in range(num_frames):
        img = background.copy()
        x, y = 8 + step_px * t, 14
        img[y : y + SIDE, x : x + SIDE] = patch
        images[t] = np.repeat(img[..., None], 3, axis=2)
        gt[t, y : y + SIDE, x : x + SIDE] = True
    return images, gt


@pytest.fixture()
def fake_davis(tmp_path: Path) -> Path:
    """Three clips, alpha / beta / gamma, of T 64x48 frames with masks."""
    root = tmp_path / "davis2016-train"
    for i, name in enumerate(("alpha", "beta", "gamma")):
        images, gt = _scene(seed=i)
        (root / name / "frames").mkdir(parents=True)
        (root / name / "masks").mkdir()
        for t in range(T):
            cv2.imwrite(
                str(root / name / "frames" / f"{t:05d}.jpg"), images[t][..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, 98]
            )
            cv2.imwrite(str(root / name / "masks" / f"{t:05d}.png"), gt[t].astype(np.uint8) * 255)
    return root


# ---------------------------------------------------------------------------------------------
# Reader and split


def test_reader_shapes(fake_davis: Path) -> None:
    assert list_davis_clips(fake_davis) == ["alpha", "beta", "gamma"]
    assert list_davis_clips(fake_davis.parent) == ["alpha", "beta", "gamma"]  # a data root holding it
    clip = read_davis_clip(fake_davis, "beta", start=1, max_frames=3)
    assert clip.images.shape == (3, H, W, 3) and clip.images.dtype == np.uint8
    assert clip.gt.shape == (3, H, W) and clip.gt.dtype == bool
    assert clip.start == 1 and clip.num_frames == 3 and clip.frames_dir == fake_davis / "beta" / "frames"
    assert np.array_equal(clip.gt, _scene(seed=1)[1][1:4])
    assert read_davis_clip(fake_davis, "alpha").num_frames == T


def test_reader_errors_name_the_path(fake_davis: Path) -> None:
    with pytest.raises(DatasetError, match="nowhere"):
        list_davis_clips(fake_davis / "nowhere")
    with pytest.raises(DatasetError, match="delta"):
        read_davis_clip(fake_davis, "delta")
    for f in (fake_davis / "alpha" / "masks").iterdir():
        f.unlink()
    (fake_davis / "alpha" / "masks").rmdir()
    with pytest.raises(DatasetError, match=r"alpha[/\\]masks"):
        read_davis_clip(fake_davis, "alpha")
    (fake_davis / "beta" / "masks" / "00003.png").unlink()
    with pytest.raises(DatasetError, match=rf"beta: {T} frames but {T - 1} masks"):
        read_davis_clip(fake_davis, "beta")
    with pytest.raises(DatasetError, match="start 9"):
        read_davis_clip(fake_davis, "gamma", start=9)


def test_split_fixed_disjoint_and_deterministic() -> None:
    assert DAVIS_VAL == DAVIS2016_TRAIN[2::3] and len(DAVIS_VAL) == 10 and len(DAVIS_DEV) == 20
    dev, val = davis_split(DAVIS2016_TRAIN, "dev"), davis_split(DAVIS2016_TRAIN, "val")
    assert not set(dev) & set(val) and sorted(dev + val) == sorted(DAVIS2016_TRAIN)
    assert davis_split(reversed(DAVIS2016_TRAIN), "val") == list(reversed(DAVIS_VAL))  # order kept, same set
    assert davis_split(["bear", "boat", "mine"], "all") == ["bear", "boat", "mine"]
    assert davis_split(["bear", "boat", "mine"], "dev") == ["bear", "mine"]  # unknown clips are dev
    with pytest.raises(ConfigError, match="test"):
        davis_split(DAVIS2016_TRAIN, "test")


# ---------------------------------------------------------------------------------------------
# Scores


def test_clip_statistics_hand_computed() -> None:
    mean, recall, decay = clip_statistics([1.0, 1.0, 0.0, 0.0, 0.0])
    assert (mean, recall, decay) == pytest.approx((0.4, 0.4, 1.0))  # bins 0 = frames 0-1, 3 = frames 3-4
    assert clip_statistics([0.5, 0.6])[1] == 0.5  # recall counts scores strictly above 0.5
    x = np.zeros(25)
    x[6] = 0.7  # frame 6 ends bin 0 (frames 0-6); bin 3 is frames 18-24
    x[18] = 0.35
    assert clip_statistics(x)[2] == pytest.approx(0.1 - 0.05)
    assert clip_statistics([0.3]) == pytest.approx((0.3, 0.0, 0.0))
    with pytest.raises(ValueError):
        clip_statistics([])


def test_per_frame_scores_j_and_f() -> None:
    gt = np.zeros((2, 20, 20), bool)
    gt[:, 5:15, 5:15] = True
    pred = gt.copy()
    pred[1] = False
    pred[1, 5:15, 5:10] = True  # half the square
    j, f = per_frame_scores(pred, gt)
    assert j == pytest.approx([1.0, 0.5])
    assert f[0] == 1.0 and 0 < f[1] < 1
    j, f = per_frame_scores(np.zeros((1, 4, 4), bool), np.zeros((1, 4, 4), bool))
    assert (j[0], f[0]) == (1.0, 1.0)  # both empty


def test_foreground_is_the_masks_as_written_and_the_majority_reading_is_kept_beside() -> None:
    labels = np.full((2, 3, 3), 255, np.uint8)  # 255 covers the most pixels but is never background
    labels[0, 0, :] = 3  # label 3 covers the most known pixels: the after-the-fact reading's background
    labels[1, 0, :] = 3
    labels[0, 1, :2] = 0  # label 0: the world as written
    labels[1, 1, :2] = 1
    labels[1, 2, 2] = 4
    assert np.array_equal(foreground_from_labels(labels), (labels != 0) & (labels != 255))
    assert background_label(labels) == 3
    assert np.array_equal(majority_foreground(labels), (labels == 0) | (labels == 1) | (labels == 4))
    assert not majority_foreground(np.full((1, 2, 2), 255, np.uint8)).any()
    assert background_label(np.full((1, 2, 2), 255, np.uint8)) is None


def test_false_positive_and_miss_shares_and_background_tracks_labelled_moving(fake_davis: Path) -> None:
    gt = np.zeros((2, 4, 4), bool)
    gt[:, :2, :2] = True  # 4 object pixels a frame
    labels = np.zeros((2, 4, 4), np.uint8)
    labels[0, :2, :1] = 1  # frame 0: half the object found, nothing else
    labels[1, :2, :2] = 2
    labels[1, 3, :] = 2  # frame 1: the object and 4 background pixels
    points = [
        (np.array([[3.0, 3.0], [0.0, 0.0], [3.2, 2.9]], np.float32), np.array([1, 1, 0])),  # 1 of 2 bg moving
        (np.array([[2.0, 3.0]], np.float32), np.array([-1])),  # unlabelled: not counted
    ]
    scores = score_clip(labels, gt, points)
    assert scores["fp_share"] == pytest.approx((0.0 + 4 / 8) / 2)
    assert scores["miss_share"] == pytest.approx((2 / 4 + 0.0) / 2)
    assert scores["j_mean"] + scores["fp_share"] + scores["miss_share"] == pytest.approx(1.0)
    assert scores["bg_tracks_moving"] == pytest.approx(0.5)
    assert np.isnan(score_clip(labels, gt)["bg_tracks_moving"])

    def with_points(clip: DavisClip, mode: str) -> MethodOutput:
        xy = np.array([[0.0, 0.0], [W - 1.0, H - 1.0]], np.float32)  # both corners are background
        return MethodOutput(_oracle(clip, mode), [(xy, np.array([0, 2]))] * clip.num_frames)

    report = run_davis(fake_davis, mode="clip5", method=with_points, clips=["alpha"], threads=None)
    assert report.rows[0].fp_share == 0.0 and report.rows[0].bg_tracks_moving == 0.5  # label 2 of the two
    assert report.means["all"]["bg_tracks_moving"] == 0.5 and "bg trk mov" in format_table(report)


def test_world_off_counts_frames_whose_true_background_is_mostly_not_0() -> None:
    gt = np.zeros((4, 4, 4), bool)
    gt[:, :2, :2] = True  # the object; the other 12 pixels of each frame are the true background
    labels = np.zeros((4, 4, 4), np.uint8)
    labels[:, :2, :2] = 1
    labels[1, 2:, :] = 1  # frame 1: 8 of the 12 background pixels painted with the mover's label
    labels[2, 2:, :] = 255  # frame 2: 8 unknown, the other 4 are 0: not off
    labels[3] = 255  # frame 3: nothing known: not off
    assert world_off_share(labels, gt) == pytest.approx(1 / 4)
    scores = score_clip(labels, gt)
    assert scores["world_off"] == pytest.approx(1 / 4)


def test_best_single_label_oracle() -> None:
    gt = np.zeros((2, 4, 4), bool)
    gt[:, :2, :2] = True
    labels = np.zeros((2, 4, 4), np.uint8)
    labels[0, :2, :] = 1  # frame 0: twice the object, J 1/2
    labels[1, :3, :] = 1  # frame 1: three times the object, J 1/3
    labels[1, 3, :3] = 2  # beside the object: J 0
    labels[:, 3, 3] = 255
    assert best_single_label(labels, gt) == (1, pytest.approx((1 / 2 + 1 / 3) / 2))
    labels[:, :2, :2] = 2
    assert best_single_label(labels, gt) == (2, pytest.approx((1 + 4 / 7) / 2))  # row 3 stays label 2 in frame 1
    assert best_single_label(np.full((2, 4, 4), 255, np.uint8), gt) == (None, 0.0)
    scores = score_clip(labels, gt)
    assert scores["k"] == 3 and scores["best_label_j"] == pytest.approx((1 + 4 / 7) / 2)


def test_labels_and_switches_on_the_object() -> None:
    gt = np.zeros((4, 4, 4), bool)
    gt[:, :2, :2] = True
    labels = np.zeros((4, 4, 4), np.uint8)
    labels[0, :2, :2] = 3
    labels[1, :2, :2] = 0  # taken for the world: no identity, no switch
    labels[2, :2, :2] = 5
    labels[3, :2, :2] = 3
    labels[3, 0, 0] = 7  # a quarter of the object: not its identity
    scores = score_clip(labels, gt)
    assert scores["labels"] == 2 and scores["switches"] == 2


# ---------------------------------------------------------------------------------------------
# Baseline and protocol


def test_flow_homography_finds_a_moving_square() -> None:
    images, gt = _scene(num_frames=4)
    labels = flow_homography_labels(images)
    assert labels.shape == gt.shape and labels.dtype == np.uint8
    j, _ = per_frame_scores(foreground_from_labels(labels), gt)
    assert j.mean() > 0.5, j
    assert not flow_homography_labels(images[:1]).any()  # one frame: no flow, no foreground


def _oracle(clip: DavisClip, mode: str) -> np.ndarray:
    return clip.gt.astype(np.uint8) * 3


def _fails(clip: DavisClip, mode: str) -> np.ndarray:
    raise TooFewTracksError(f"{clip.frames_dir}: only 2 tracks\nsecond line")


def test_run_davis_scores_rows_and_isolates_failures(fake_davis: Path) -> None:
    report = run_davis(fake_davis, mode="clip5", method=_oracle, threads=None)
    assert [r.clip for r in report.rows] == ["alpha", "beta", "gamma"]
    assert all(r.frames == 5 and r.j_mean == 1.0 and r.f_mean == 1.0 and r.k == 2 for r in report.rows)
    assert set(report.means) == {"dev", "all"} and report.means["all"]["clips"] == 3
    report = run_davis(fake_davis, mode="whole", method=_fails, clips=["beta"], threads=None)
    row = report.rows[0]
    assert row.frames == T and row.j_mean == 0.0 and row.f_mean == 0.0 and row.k == 0
    assert row.error.endswith("only 2 tracks") and report.means["all"]["failed"] == 1
    table = format_table(report)
    assert "beta" in table and "mean all (1; world off 0)" in table and "failed: beta" in table
    assert report.to_dict()["rows"][0]["error"] == row.error
    with pytest.raises(ConfigError):
        run_davis(fake_davis, mode="clip7", method=_oracle)
    with pytest.raises(ConfigError):
        run_davis(fake_davis, method="nothing")


def test_run_davis_baseline_by_name(fake_davis: Path) -> None:
    report = run_davis(fake_davis, mode="clip5", method="flow-homography", clips=["alpha"], threads=None)
    assert report.method == "flow-homography" and report.rows[0].j_mean > 0.5


def test_baseline_on_a_real_clip(data_root: Path) -> None:
    root = data_root / "davis2016-train"
    if not root.is_dir():
        pytest.skip(f"DAVIS-2016 clips not found at {root}")
    report = run_davis(root, mode="clip5", method="flow-homography", clips=["bear"])
    row = report.rows[0]
    assert row.frames == 5 and not row.error
    assert row.j_mean > 0.3, row


def test_moseg_eval_davis_writes_both_methods(fake_davis: Path, tmp_path: Path) -> None:
    from helpers import moseg

    out = tmp_path / "out"
    code, stdout, stderr = moseg(
        "eval", "davis-clip5", "--data-root", fake_davis.parent, "--out", out, "--folds", "alpha,beta",
        "--set", "mask.unexplained_px=0",
    )  # fmt: skip
    assert code == 0, stderr
    result = json.loads((out / "results.json").read_text())
    assert result["config"]["mode"] == "clip5"
    assert result["config"]["settings"] == ["mask.unexplained_px=0"]
    methods = [(r["method"], r["clip"]) for r in result["rows"]]
    assert methods == [
        ("pipeline", "alpha"),
        ("pipeline", "beta"),
        ("flow-homography", "alpha"),
        ("flow-homography", "beta"),
    ]
    assert result["summary"]["flow-homography"]["all"]["j_mean"] > 0.5
    assert "DAVIS-2016 clip5, method pipeline" in stdout and "method flow-homography" in stdout


def test_davis_dev_tracks_for_training_never_read_the_validation_clips(tmp_path: Path) -> None:
    from mosegpipe.training.own_tracks import davis_dev_own_clips

    rng = np.random.default_rng(0)
    root = tmp_path / "davis2016-train"
    for name in ("alpha", "boat"):  # boat is in DAVIS_VAL: held out, so never tracked for training
        background = cv2.GaussianBlur(rng.integers(0, 256, (120, 160), dtype=np.uint8), (3, 3), 0)
        patch = cv2.GaussianBlur(rng.integers(0, 256, (48, 48), dtype=np.uint8), (3, 3), 0)
        (root / name / "frames").mkdir(parents=True)
        (root / name / "masks").mkdir()
        for t in range(6):
            img = background.copy()
            img[36 : 36 + 48, 20 + 3 * t : 68 + 3 * t] = patch
            gt = np.zeros((120, 160), np.uint8)
            gt[36 : 36 + 48, 20 + 3 * t : 68 + 3 * t] = 255
            cv2.imwrite(str(root / name / "frames" / f"{t:05d}.png"), np.repeat(img[..., None], 3, axis=2))
            cv2.imwrite(str(root / name / "masks" / f"{t:05d}.png"), gt)
    clips = davis_dev_own_clips(tmp_path, frames=5, cache_dir=tmp_path / "cache")
    assert [c.name for c in clips] == ["alpha/f1-5", "alpha/f2-6"]
    for clip in clips:
        xy = clip.traj.reshape(-1, 5, 2)
        inside = (xy[..., 0] >= 20 + 5) & (xy[..., 0] < 20 + 48 + 12 - 5) & (xy[..., 1] >= 41) & (xy[..., 1] < 79)
        assert (clip.labels == 1).sum() >= 10 and (clip.labels == 0).sum() >= 10
        assert not (clip.labels[~inside.any(axis=1)] == 1).any()  # a track labelled 1 is on the square
        assert set(np.unique(clip.labels)) <= {-1, 0, 1}
    assert sorted(p.name for p in (tmp_path / "cache").rglob("*.npz")) == ["alpha.npz"]
