"""KT3DMoSeg reader (Xu, Cheong, Li, CVPR 2018): 22 KITTI clips, 2-5 rigid motions, partial tracks.

Layout under the data root::

    kt3dmoseg/tracks/<Seq>_Tracks.mat   MATLAB struct ``Data`` (ySparse, visibleSparse, GtLabel)
    kt3dmoseg/frames/<Seq>/%06d.jpg     frames; column f of ySparse is file number f + 1

GtLabel 1 is the background (camera motion); there is no outlier label. The paper's protocol cuts
5-frame windows and keeps the trajectories visible in all 5 frames; a sequence's test clip is its
frames 1-5. Counted that way the test clips have K histogram {2: 12, 3: 8, 4: 1, 5: 1} and 90-565
trajectories; the {2: 12, 3: 4, 4: 5, 5: 1} and 158-1018 often quoted for the dataset count every
labelled trajectory of the whole clip (some objects only enter after frame 5).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from mosegpipe.data.labels import drop_small_groups, remap_labels
from mosegpipe.errors import DatasetError
from mosegpipe.points.trajectories import complete_in_window, window_starts, xy_to_traj
from mosegpipe.types import LabeledClip

logger = logging.getLogger(__name__)

DATASET = "kt3dmoseg"
_TRACKS_SUFFIX = "_Tracks.mat"
_IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png")


@dataclass(frozen=True)
class KT3DSequence:
    """One KT3DMoSeg clip: all labelled (sparse) trajectories over all its frames.

    Attributes:
        name: sequence name as in the tracks file, e.g. "Seq005_Clip01" (note "Seq028_clip03").
        xy: (N, T, 2) float32 pixel coordinates (x right, y down); 0 where not visible.
        visible: (N, T) bool, True where the trajectory is tracked in that frame.
        labels: (N,) int64 in 0..K-1; the file's GtLabel 1..K minus one, so 0 is the background.
        image_size_hw: (H, W) of the frames in pixels (KITTI sizes differ between drives).
        frames_dir: folder of the frames; frame t (0-based) is file number t + 1.
        tracks_path: the ``*_Tracks.mat`` file read.
        original_labels: the K GtLabel ids; label j was original_labels[j].
    """

    name: str
    xy: npt.NDArray[np.float32]
    visible: npt.NDArray[np.bool_]
    labels: npt.NDArray[np.int64]
    image_size_hw: tuple[int, int]
    frames_dir: Path
    tracks_path: Path
    original_labels: tuple[int, ...] = ()

    @property
    def num_tracks(self) -> int:
        return int(self.xy.shape[0])

    @property
    def num_frames(self) -> int:
        return int(self.xy.shape[1])


def _dataset_dir(root: str | Path) -> Path:
    """The kt3dmoseg folder: ``root/kt3dmoseg``, or root itself when it already is that folder."""
    root = Path(root)
    if (root / DATASET / "tracks").is_dir():
        return root / DATASET
    if root.name.lower() == DATASET and (root / "tracks").is_dir():
        return root
    raise DatasetError(f"{root / DATASET / 'tracks'}: KT3DMoSeg tracks folder not found")


def _tracks_files(root: str | Path) -> dict[str, Path]:
    tracks_dir = _dataset_dir(root) / "tracks"
    return {
        p.name[: -len(_TRACKS_SUFFIX)]: p
        for p in tracks_dir.iterdir()
        if p.is_file() and p.name.endswith(_TRACKS_SUFFIX)
    }


def list_kt3d_sequences(root: str | Path) -> list[str]:
    """Names of the KT3DMoSeg sequences found under root, sorted (22 in the release).

    Args:
        root: the data folder holding ``kt3dmoseg/`` (or the ``kt3dmoseg`` folder itself).

    Raises:
        DatasetError: the tracks folder is missing or holds no ``*_Tracks.mat`` file.
    """
    names = sorted(_tracks_files(root))
    if not names:
        raise DatasetError(f"{_dataset_dir(root) / 'tracks'}: no *{_TRACKS_SUFFIX} files")
    return names


def _resolve(root: str | Path, name: str) -> tuple[str, Path]:
    """Canonical sequence name and tracks file, matching the name case-insensitively."""
    files = _tracks_files(root)
    if name in files:
        return name, files[name]
    by_lower = {k.lower(): k for k in files}
    key = by_lower.get(name.lower())
    if key is None:
        raise DatasetError(f"{_dataset_dir(root) / 'tracks' / (name + _TRACKS_SUFFIX)}: no such KT3DMoSeg sequence")
    return key, files[key]


def _frames_dir(root: str | Path, name: str) -> Path:
    """Frame folder of a sequence; folder and track names differ in case in the release."""
    frames_root = _dataset_dir(root) / "frames"
    exact = frames_root / name
    if exact.is_dir():
        return exact
    if frames_root.is_dir():
        for d in frames_root.iterdir():
            if d.is_dir() and d.name.lower() == name.lower():
                return d
    raise DatasetError(f"{exact}: KT3DMoSeg frames folder not found")


def kt3d_frame_paths(root: str | Path, name: str) -> list[Path]:
    """Image files of a sequence in frame order; element t is frame t (column t of ySparse).

    Args:
        root: the data folder holding ``kt3dmoseg/``.
        name: sequence name (case-insensitive).

    Raises:
        DatasetError: the sequence or its frames folder is missing or empty.
    """
    canonical, _ = _resolve(root, name)
    folder = _frames_dir(root, canonical)
    files = [p for p in folder.iterdir() if p.suffix.lower() in _IMAGE_SUFFIXES]
    if not files:
        raise DatasetError(f"{folder}: no image files")
    # Files are numbered %06d from 1; a numeric sort survives names without zero padding.
    return sorted(files, key=lambda p: (int(p.stem) if p.stem.isdigit() else 1 << 62, p.name))


def _image_size_hw(path: Path) -> tuple[int, int]:
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise DatasetError(f"{path}: unreadable image")
    return int(image.shape[0]), int(image.shape[1])


def read_kt3d_sequence(root: str | Path, name: str) -> KT3DSequence:
    """Read one KT3DMoSeg sequence (labelled trajectories, visibility, labels, frame size).

    Args:
        root: the data folder holding ``kt3dmoseg/``.
        name: sequence name, e.g. "Seq005_Clip01"; matched case-insensitively.

    Returns:
        The sequence; xy is 0 wherever visible is False (as in the file).

    Raises:
        DatasetError: missing files or fields, or inconsistent array shapes.
    """
    import scipy.io

    canonical, path = _resolve(root, name)
    try:
        data = scipy.io.loadmat(path, squeeze_me=True, struct_as_record=False)["Data"]
        y_sparse = np.asarray(data.ySparse, dtype=np.float64)
        visible = np.asarray(data.visibleSparse).astype(bool)
        gt = np.asarray(data.GtLabel).reshape(-1)
    except (KeyError, AttributeError, ValueError, OSError) as exc:
        raise DatasetError(f"{path}: not a KT3DMoSeg tracks file ({exc})") from exc
    if y_sparse.ndim == 2:
        # squeeze_me collapses a single-frame or single-track clip; restore (3, N, T).
        y_sparse = y_sparse.reshape(3, gt.size, -1)
    visible = visible.reshape(gt.size, -1)
    if y_sparse.shape[0] != 3 or y_sparse.shape[1:] != visible.shape:
        raise DatasetError(f"{path}: ySparse {y_sparse.shape} does not match visibleSparse {visible.shape}")
    # Row 2 is the homogeneous 1 where visible and 0 elsewhere; visibility comes from visibleSparse
    # because a few visible points have x <= 0 (tracks leaving the image border).
    xy = np.transpose(y_sparse[:2], (1, 2, 0)).astype(np.float32)
    xy[~visible] = 0.0
    labels, original = remap_labels(gt)

    frames_dir = _frames_dir(root, canonical)
    frame_paths = kt3d_frame_paths(root, canonical)
    if len(frame_paths) < visible.shape[1]:
        logger.warning("%s: %d frames on disk, tracks span %d", frames_dir, len(frame_paths), visible.shape[1])
    return KT3DSequence(
        name=canonical,
        xy=xy,
        visible=visible,
        labels=labels,
        image_size_hw=_image_size_hw(frame_paths[0]),
        frames_dir=frames_dir,
        tracks_path=path,
        original_labels=tuple(original),
    )


def kt3d_windows(
    seq: KT3DSequence,
    frames: int = 5,
    mode: str = "first",
    stride: int = 1,
    min_points: int = 10,
    min_group: int = 1,
) -> list[LabeledClip]:
    """Cut F-frame windows of a sequence, keeping the trajectories visible in all F frames.

    Args:
        seq: a sequence from read_kt3d_sequence.
        frames: F, window length (the paper uses 5).
        mode: "first" for frames 1..F only (the test clip), "all" for every start (step `stride`).
        stride: step between window starts in "all" mode.
        min_points: windows with fewer kept trajectories are skipped.
        min_group: trajectories of groups with fewer members in the window are dropped first.

    Returns:
        One LabeledClip per kept window: traj (N, 2F) float32 pixels, labels (N,) int64 remapped to
        0..K-1 within the window (increasing original id, so the background is 0 when present);
        name f"{seq}/f{start+1}-{start+F}"; meta keys "sequence", "start" (0-based), "frames",
        "frame_range" (1-based file numbers), "file", "track_ids" (rows of ySparse),
        "original_labels" (GtLabel of each new label), "background_label", "outlier_label" (None),
        "image_size_hw".
    """
    clips = []
    for start in window_starts(seq.num_frames, frames, mode, stride):
        rows = complete_in_window(seq.visible, start, frames)
        rows = drop_small_groups(seq.labels, rows, min_group)
        if rows.size < max(min_points, 1):
            logger.debug("%s: window at %d has %d tracks, skipped", seq.name, start, rows.size)
            continue
        labels, seq_ids = remap_labels(seq.labels[rows])
        gt_ids = [seq.original_labels[i] for i in seq_ids] if seq.original_labels else seq_ids
        clips.append(
            LabeledClip(
                name=f"{seq.name}/f{start + 1}-{start + frames}",
                traj=xy_to_traj(seq.xy[rows, start : start + frames]),
                labels=labels,
                dataset=DATASET,
                meta={
                    "sequence": seq.name,
                    "start": start,
                    "frames": frames,
                    "frame_range": [start + 1, start + frames],
                    "file": str(seq.tracks_path),
                    "track_ids": [int(r) for r in rows],
                    "original_labels": [int(g) for g in gt_ids],
                    "background_label": gt_ids.index(1) if 1 in gt_ids else None,
                    "outlier_label": None,
                    "image_size_hw": [int(v) for v in seq.image_size_hw],
                },
            )
        )
    return clips


def kt3d_test_clips(root: str | Path, frames: int = 5) -> list[LabeledClip]:
    """The KT3DMoSeg test set: frames 1..F of every sequence, fully visible trajectories only.

    Args:
        root: the data folder holding ``kt3dmoseg/``.
        frames: F (the paper uses 5).

    Returns:
        One clip per sequence in sorted name order (22 for the release with F = 5).
    """
    clips = []
    for name in list_kt3d_sequences(root):
        found = kt3d_windows(read_kt3d_sequence(root, name), frames=frames, mode="first")
        if not found:
            logger.warning("%s: fewer than 10 trajectories visible in frames 1-%d", name, frames)
        clips.extend(found)
    return clips
