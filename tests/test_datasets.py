from __future__ import annotations

import collections
import functools
from pathlib import Path

import cv2
import numpy as np
import pytest
import scipy.io

from mosegpipe.data.adelaidermf import list_adelaide, load_adelaide, read_adelaide_pair
from mosegpipe.data.fbms import (
    fbms_track_labels,
    fbms_windows,
    read_fbms_groundtruth,
    read_fbms_tracks,
)
from mosegpipe.data.hopkins155 import list_hopkins_sequences, load_hopkins, read_hopkins
from mosegpipe.data.kt3dmoseg import (
    kt3d_frame_paths,
    kt3d_test_clips,
    kt3d_windows,
    list_kt3d_sequences,
    read_kt3d_sequence,
)
from mosegpipe.data.labels import remap_labels
from mosegpipe.errors import DatasetError, InputError
from mosegpipe.points.trajectories import window_starts
from mosegpipe.types import LabeledClip


@functools.cache
def _kt3d_test_clips(root: Path) -> tuple[LabeledClip, ...]:
    return tuple(kt3d_test_clips(root))


@functools.cache
def _hopkins(root: Path) -> tuple[LabeledClip, ...]:
    return tuple(load_hopkins(root))


def _raw_kt3d(root: Path, name: str):  # noqa: ANN202 - a MATLAB struct
    path = root / "kt3dmoseg" / "tracks" / f"{name}_Tracks.mat"
    return scipy.io.loadmat(path, squeeze_me=True, struct_as_record=False)["Data"]


def _assert_contiguous(labels: np.ndarray) -> None:
    assert labels.dtype == np.int64
    assert np.array_equal(np.unique(labels), np.arange(labels.max() + 1))


# ---------------------------------------------------------------- shared helpers


def test_remap_labels_contiguous_in_original_order() -> None:
    labels, original = remap_labels(np.array([5, 2, 5, 9, 2]))
    assert labels.tolist() == [1, 0, 1, 2, 0]
    assert original == [2, 5, 9]


def test_window_starts() -> None:
    assert window_starts(10, 5, "first") == [0]
    assert window_starts(10, 5, "all") == [0, 1, 2, 3, 4, 5]
    assert window_starts(10, 5, "all", stride=2) == [0, 2, 4]
    assert window_starts(4, 5, "all") == []
    with pytest.raises(InputError, match="middle"):
        window_starts(10, 5, "middle")


# ---------------------------------------------------------------- KT3DMoSeg


def test_kt3d_lists_22_sequences(data_root: Path) -> None:
    names = list_kt3d_sequences(data_root)
    assert len(names) == 22
    assert names == sorted(names)
    assert "Seq028_clip03" in names and names[0] == "Seq005_Clip01"


def test_kt3d_test_clips_k_histogram(data_root: Path) -> None:
    clips = _kt3d_test_clips(data_root)
    assert len(clips) == 22
    # Counted on frames 1-5 with fully visible tracks; some objects appear only later, so this
    # differs from the whole-clip histogram {2: 12, 3: 4, 4: 5, 5: 1}.
    assert collections.Counter(c.k for c in clips) == {2: 12, 3: 8, 4: 1, 5: 1}
    sizes = {c.name: c.num_points for c in clips}
    assert min(sizes.values()) == 90 and max(sizes.values()) == 565
    assert sizes["Seq005_Clip01/f1-5"] == 424 and sizes["Seq038_Clip01/f1-5"] == 319
    for clip in clips:
        assert clip.traj.dtype == np.float32 and clip.traj.shape == (clip.num_points, 10)
        assert clip.dataset == "kt3dmoseg" and clip.meta["start"] == 0 and clip.meta["frames"] == 5
        _assert_contiguous(clip.labels)
        # GtLabel 1 (background) is present in every clip and becomes label 0.
        assert clip.meta["background_label"] == 0 and clip.meta["original_labels"][0] == 1


def test_kt3d_whole_clip_statistics_match_readme(data_root: Path) -> None:
    ks, sizes = collections.Counter(), []
    for name in list_kt3d_sequences(data_root):
        seq = read_kt3d_sequence(data_root, name)
        ks[int(seq.labels.max()) + 1] += 1
        sizes.append(seq.num_tracks)
        assert 10 <= seq.num_frames <= 20
    assert ks == {2: 12, 3: 4, 4: 5, 5: 1}
    assert (min(sizes), max(sizes)) == (158, 1018)


def test_kt3d_window_against_raw_arrays(data_root: Path) -> None:
    name, start = "Seq005_Clip01", 3
    raw = _raw_kt3d(data_root, name)
    seq = read_kt3d_sequence(data_root, name)
    windows = kt3d_windows(seq, frames=5, mode="all")
    assert len(windows) == seq.num_frames - 5 + 1
    clip = next(c for c in windows if c.meta["start"] == start)
    assert clip.name == f"{name}/f4-8" and clip.meta["frame_range"] == [4, 8]
    ids = np.array(clip.meta["track_ids"])
    vis = raw.visibleSparse.astype(bool)
    expected = np.flatnonzero(vis[:, start : start + 5].all(axis=1))
    np.testing.assert_array_equal(ids, expected)
    for j in (0, len(ids) // 2, len(ids) - 1):
        for f in range(5):
            assert clip.traj[j, 2 * f] == np.float32(raw.ySparse[0, ids[j], start + f])
            assert clip.traj[j, 2 * f + 1] == np.float32(raw.ySparse[1, ids[j], start + f])
    gt_of_new = np.array(clip.meta["original_labels"])[clip.labels]
    np.testing.assert_array_equal(gt_of_new, raw.GtLabel[ids])
    # Invisible entries are zero in the file and stay zero in the sequence.
    assert (seq.xy[~seq.visible] == 0).all()
    np.testing.assert_array_equal(seq.visible, vis)


def test_kt3d_window_options(data_root: Path) -> None:
    seq = read_kt3d_sequence(data_root, "Seq059_Clip01")
    first = kt3d_windows(seq)[0]
    assert first.k == 3 and sorted(np.bincount(first.labels).tolist()) == [1, 62, 190]
    # min_group drops the one-track group before relabelling.
    pruned = kt3d_windows(seq, min_group=2)[0]
    assert pruned.k == 2 and pruned.num_points == 252
    _assert_contiguous(pruned.labels)
    strided = kt3d_windows(seq, mode="all", stride=4)
    assert [c.meta["start"] for c in strided] == [0, 4, 8, 12]
    assert kt3d_windows(seq, min_points=10_000) == []


def test_kt3d_names_and_frames(data_root: Path) -> None:
    seq = read_kt3d_sequence(data_root, "SEQ028_CLIP03")
    assert seq.name == "Seq028_clip03"
    assert seq.frames_dir.name == "Seq028_clip03" and seq.frames_dir.is_dir()
    paths = kt3d_frame_paths(data_root, "Seq028_Clip03")
    assert len(paths) == seq.num_frames == 10
    assert [p.name for p in paths[:2]] == ["000001.jpg", "000002.jpg"]
    assert seq.image_size_hw == (375, 1242)
    assert read_kt3d_sequence(data_root, "Seq037_Clip01").image_size_hw == (370, 1224)


def test_kt3d_errors(data_root: Path, tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="Seq999_Clip01"):
        read_kt3d_sequence(data_root, "Seq999_Clip01")
    with pytest.raises(DatasetError, match=str(tmp_path / "kt3dmoseg")):
        list_kt3d_sequences(tmp_path)


# ---------------------------------------------------------------- Hopkins155


def test_hopkins_counts(data_root: Path) -> None:
    clips = _hopkins(data_root)
    assert len(clips) == 155
    assert "dancing" not in {c.name for c in clips}
    assert collections.Counter(c.k for c in clips) == {2: 120, 3: 35}
    # The README's table: checkerboard 78 + 26, traffic 31 + 7, articulated 11 + 2.
    table = collections.Counter((c.meta["subset"], c.meta["num_motions"]) for c in clips)
    assert table == {
        ("checkerboard", 2): 78,
        ("checkerboard", 3): 26,
        ("traffic", 2): 31,
        ("traffic", 3): 7,
        ("articulated", 2): 11,
        ("articulated", 3): 2,
    }
    mean_points = np.mean([c.num_points for c in clips if c.k == 2])
    assert round(mean_points) == 266
    for clip in clips:
        _assert_contiguous(clip.labels)
        assert clip.traj.shape == (clip.num_points, 2 * clip.meta["frames"])
    extra = list_hopkins_sequences(data_root, include_extra=True)
    assert len(extra) == 156 and "dancing" in extra


def test_hopkins_against_raw(data_root: Path) -> None:
    mat = scipy.io.loadmat(data_root / "hopkins155" / "1R2RC" / "1R2RC_truth.mat")
    clip = read_hopkins(data_root, "1R2RC")
    y, s = mat["y"], mat["s"].ravel()
    assert clip.traj.shape == (y.shape[1], 2 * y.shape[2]) == (459, 58)
    np.testing.assert_allclose(clip.traj[:, 0::2], y[0], rtol=1e-6)
    np.testing.assert_allclose(clip.traj[:, 1::2], y[1], rtol=1e-6)
    np.testing.assert_array_equal(clip.labels, s.astype(np.int64) - 1)
    assert clip.meta["subset"] == "checkerboard" and clip.meta["image_size_hw"] == [480, 640]
    short = read_hopkins(data_root, "1R2RC", frames=5)
    np.testing.assert_array_equal(short.traj, clip.traj[:, :10])
    with pytest.raises(InputError, match="frames=99"):
        read_hopkins(data_root, "1R2RC", frames=99)
    dancing = read_hopkins(data_root, "dancing")
    assert dancing.k == 5 and "subset" not in dancing.meta


def test_hopkins_first_frames_and_errors(data_root: Path, tmp_path: Path) -> None:
    clips = load_hopkins(data_root, frames=5)
    assert len(clips) == 155 and all(c.traj.shape[1] == 10 for c in clips)
    assert read_hopkins(data_root, "cars2_07_g23").meta["subset"] == "traffic"
    with pytest.raises(DatasetError, match="nosuch"):
        read_hopkins(data_root, "nosuch")
    with pytest.raises(DatasetError, match=str(tmp_path / "hopkins155")):
        load_hopkins(tmp_path)


# ---------------------------------------------------------------- AdelaideRMF


def test_adelaide_counts_and_labels(data_root: Path) -> None:
    names = list_adelaide(data_root)
    assert len(names) == 19 and names == sorted(names)
    clips = load_adelaide(data_root)
    ratios = [c.meta["outlier_ratio"] for c in clips]
    assert 0.2 < min(ratios) and max(ratios) < 0.75
    assert collections.Counter(c.meta["num_motions"] for c in clips) == {1: 4, 2: 6, 3: 7, 4: 2}
    for clip in clips:
        _assert_contiguous(clip.labels)
        assert clip.traj.shape == (clip.num_points, 4) and clip.num_frames == 2
        assert clip.meta["outlier_label"] == 0
        assert clip.k == clip.meta["num_motions"] + 1
        assert np.mean(clip.labels == 0) == pytest.approx(clip.meta["outlier_ratio"])


def test_adelaide_against_raw(data_root: Path) -> None:
    mat = scipy.io.loadmat(data_root / "adelaidermf" / "F" / "biscuitbook.mat")
    clip = next(c for c in load_adelaide(data_root) if c.name == "biscuitbook")
    np.testing.assert_allclose(clip.traj, mat["data"][[0, 1, 3, 4]].T, rtol=1e-6)
    np.testing.assert_array_equal(clip.labels, mat["label"].ravel())
    pair = read_adelaide_pair(data_root, "biscuitbook")
    np.testing.assert_array_equal(pair.img1, mat["img1"])
    np.testing.assert_allclose(pair.xy2, mat["data"][3:5].T, rtol=1e-6)
    assert pair.labels.tolist() == mat["label"].ravel().tolist()


def test_adelaide_grayscale_becomes_rgb(data_root: Path, tmp_path: Path) -> None:
    pair = read_adelaide_pair(data_root, "boardgame")
    assert pair.img1.shape == (480, 640, 3) and pair.img1.dtype == np.uint8
    assert (pair.img1[..., 0] == pair.img1[..., 2]).all()
    assert pair.img2.shape == (480, 640, 3)
    with pytest.raises(DatasetError, match="nosuch"):
        read_adelaide_pair(data_root, "nosuch")
    with pytest.raises(DatasetError, match=str(tmp_path / "adelaidermf")):
        list_adelaide(tmp_path)


# ---------------------------------------------------------------- FBMS (files written here)


def test_fbms_tracks_round_trip(tmp_path: Path) -> None:
    # Label and length on one line for the first track and on two lines for the second: the
    # format is a whitespace-separated stream.
    text = "4\n3\n0 2\n10.5 20.25 0\n11.5 21.25 1\n1\n3\n5 6 1\n7 8 2\n9 10 3\n2 0\n"
    path = tmp_path / "shotTracks4.dat"
    path.write_text(text)
    xy, visible, labels = read_fbms_tracks(path)
    assert xy.shape == (3, 4, 2) and visible.shape == (3, 4)
    assert labels.tolist() == [0, 1, 2]
    assert visible.tolist() == [
        [True, True, False, False],
        [False, True, True, True],
        [False, False, False, False],
    ]
    np.testing.assert_array_equal(xy[0, :2], [[10.5, 20.25], [11.5, 21.25]])
    np.testing.assert_array_equal(xy[1, 3], [9, 10])
    assert (xy[~visible] == 0).all()


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("4\n2\n0 1\n1 2 0\n", "ends in track 1"),
        ("2\n1\n0 1\n1 2 5\n", "frame 5"),
        ("x", "non-numeric"),
    ],
)
def test_fbms_tracks_malformed(tmp_path: Path, text: str, match: str) -> None:
    path = tmp_path / "badTracks.dat"
    path.write_text(text)
    with pytest.raises(DatasetError, match=match):
        read_fbms_tracks(path)
    with pytest.raises(DatasetError, match="missing.dat"):
        read_fbms_tracks(tmp_path / "missing.dat")


def _write_groundtruth(folder: Path) -> Path:
    """A 3-region shot with a PGM region image at frame 0 and a PPM one at frame 2."""
    gray = np.zeros((6, 8), dtype=np.uint8)
    gray[:, 4:] = 255
    gray[0, 0] = 77  # not a defined region
    cv2.imwrite(str(folder / "shot_01.pgm"), gray)
    colour_rgb = np.zeros((6, 8, 3), dtype=np.uint8)
    colour_rgb[:3] = (255, 0, 0)  # region 2: red = 255 * 65536
    colour_rgb[3:, 4:] = (255, 255, 255)  # region 1
    cv2.imwrite(str(folder / "shot_03.ppm"), colour_rgb[:, :, ::-1])
    definition = (
        "Ground truth definition file; do not change!\n\n"
        "Total number of regions:\n3\n"
        "Scale of region 0:\n0\nScale of region 1:\n255\nScale of region 2:\n16711680\n\n"
        "Confusion penality matrix:\n0 1 1\n1 0 1\n1 1 0\n\n"
        "Total number of frames in this shot:\n4\n"
        "Total number of labeled frames for this shot:\n2\n"
        "Frame number:\n0\nFile name:\nshot_01.pgm\nInput file name:\nshot_01.ppm\n"
        "Frame number:\n2\nFile name:\nshot_03.ppm\nInput file name:\nshot_03.ppm\n"
    )
    path = folder / "shotDef.dat"
    path.write_text(definition.replace("\n", "\r\n"))
    return path


def test_fbms_groundtruth_round_trip(tmp_path: Path) -> None:
    gt = read_fbms_groundtruth(_write_groundtruth(tmp_path))
    assert sorted(gt) == [0, 2]
    assert gt[0].shape == (6, 8)
    assert gt[0][1, 1] == 0 and gt[0][1, 5] == 1 and gt[0][0, 0] == -1
    # Region 1 is white (255) in the PPM too, so its colour value is 16777215, not 255: undefined.
    assert gt[2][0, 0] == 2 and gt[2][4, 1] == 0 and gt[2][4, 6] == -1


def test_fbms_groundtruth_errors(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="nodef.dat"):
        read_fbms_groundtruth(tmp_path / "nodef.dat")
    bad = tmp_path / "badDef.dat"
    bad.write_text("Total number of regions:\n2\nScale of region 0:\n0\n")
    with pytest.raises(DatasetError, match="2 regions declared"):
        read_fbms_groundtruth(bad)
    lost = tmp_path / "lostDef.dat"
    lost.write_text("Total number of regions:\n1\nScale of region 0:\n0\nFrame number:\n0\nFile name:\nx.pgm\n")
    with pytest.raises(DatasetError, match="x.pgm"):
        read_fbms_groundtruth(lost)


def test_fbms_track_labels() -> None:
    region = np.zeros((6, 8), dtype=np.int32)
    region[:, 4:] = 1
    region[0, 0] = -1
    gt = {0: region, 2: region}
    xy = np.zeros((6, 4, 2), dtype=np.float32)
    visible = np.zeros((6, 4), dtype=bool)
    xy[0, [0, 2]] = [[5.2, 1.0], [6.0, 4.4]]  # region 1 in both annotated frames
    visible[0, [0, 2]] = True
    xy[1, [0, 2]] = [[1.0, 1.0], [5.0, 1.0]]  # region 0 then 1: ambiguous
    visible[1, [0, 2]] = True
    xy[2, [1, 3]] = [[5.0, 5.0], [5.0, 5.0]]  # never visible in an annotated frame
    visible[2, [1, 3]] = True
    xy[3, 0] = [20.0, 1.0]  # outside the image
    visible[3, 0] = True
    xy[4, 0] = [0.2, 0.3]  # undefined pixel
    visible[4, 0] = True
    xy[5, [0, 2]] = [[1.4, 2.0], [-5.0, 1.0]]  # region 0, then outside: region 0
    visible[5, [0, 2]] = True
    labels = fbms_track_labels(xy, visible, gt)
    assert labels.tolist() == [1, -1, -1, -1, -1, 0]


def test_fbms_windows() -> None:
    xy = np.arange(5 * 3 * 2, dtype=np.float32).reshape(5, 3, 2)
    visible = np.ones((5, 3), dtype=bool)
    visible[2, 1] = False
    labels = np.array([4, 7, 4, -1, 7])
    (clip,) = fbms_windows("shot", xy, visible, labels, frames=3, min_points=1)
    assert clip.name == "shot/f1-3"
    assert clip.meta["track_ids"] == [0, 1, 4]
    assert clip.labels.tolist() == [0, 1, 1] and clip.meta["original_labels"] == [4, 7]
    np.testing.assert_array_equal(clip.traj[2], xy[4].reshape(-1))
