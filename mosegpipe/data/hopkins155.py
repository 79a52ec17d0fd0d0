"""Hopkins155 reader (Tron & Vidal, CVPR 2007): 155 affine-camera sequences, complete trajectories.

Layout under the data root: ``hopkins155/<seq>/<seq>_truth.mat`` with ``y`` (3, P, F) homogeneous
pixel coordinates, ``s`` (P, 1) labels 1..K, ``width``, ``height``. The official 155 are 35
three-motion sequences, their 105 two-motion subsets ``<seq>_g12/_g13/_g23``, and 15 two-motion
sequences (120 two-motion + 35 three-motion). Any other folder (the release's ``dancing``, 5
motions) is extra.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mosegpipe.data.labels import remap_labels
from mosegpipe.errors import DatasetError, InputError
from mosegpipe.types import LabeledClip

DATASET = "hopkins155"

# The release's README groups sequences into checkerboard (names starting with a digit, and
# three-cars), traffic and articulated; these two sets spell out the non-checkerboard names.
_TRAFFIC = frozenset(
    {
        "cars1",
        "cars2",
        "cars2B",
        "cars2_06",
        "cars2_07",
        "cars3",
        "cars4",
        "cars5",
        "cars6",
        "cars7",
        "cars8",
        "cars9",
        "cars10",
        "kanatani1",
        "kanatani2",
        "truck1",
        "truck2",
    }
)
_ARTICULATED = frozenset({"arm", "articulated", "head", "kanatani3", "people1", "people2", "two_cranes"})

_THREE_MOTION = (
    "1R2RC",
    "1R2RCR",
    "1R2RCT_A",
    "1R2RCT_B",
    "1R2TCR",
    "1R2TCRT",
    "1RT2RCR",
    "1RT2RCRT",
    "1RT2RTCRT_A",
    "1RT2RTCRT_B",
    "1RT2TC",
    "1RT2TCRT_A",
    "1RT2TCRT_B",
    "2R3RTC",
    "2R3RTCRT",
    "2RT3RC",
    "2RT3RCR",
    "2RT3RCT_A",
    "2RT3RCT_B",
    "2RT3RTCRT",
    "2T3RCR",
    "2T3RCRT",
    "2T3RCRTP",
    "2T3RCTP",
    "2T3RTCR",
    "articulated",
    "cars10",
    "cars2B",
    "cars2_06",
    "cars2_07",
    "cars3",
    "cars5",
    "cars9",
    "three-cars",
    "two_cranes",
)
_TWO_MOTION = (
    "arm",
    "cars1",
    "cars2",
    "cars4",
    "cars6",
    "cars7",
    "cars8",
    "head",
    "kanatani1",
    "kanatani2",
    "kanatani3",
    "people1",
    "people2",
    "truck1",
    "truck2",
)
_SUBSET_SUFFIXES = ("_g12", "_g13", "_g23")
OFFICIAL_SEQUENCES: frozenset[str] = frozenset(
    list(_THREE_MOTION) + list(_TWO_MOTION) + [base + suffix for base in _THREE_MOTION for suffix in _SUBSET_SUFFIXES]
)


def _dataset_dir(root: str | Path) -> Path:
    """The hopkins155 folder: ``root/hopkins155``, or root itself when it already is that folder."""
    root = Path(root)
    if (root / DATASET).is_dir():
        return root / DATASET
    if root.name.lower() == DATASET and root.is_dir():
        return root
    raise DatasetError(f"{root / DATASET}: Hopkins155 folder not found")


def hopkins_subset(name: str) -> str:
    """Scene type of a Hopkins155 sequence as grouped in the release's README.

    Args:
        name: sequence name, e.g. "1R2RC_g12", "cars3", "people1".

    Returns:
        "checkerboard", "traffic" or "articulated".
    """
    base = name
    for suffix in _SUBSET_SUFFIXES:
        if name.endswith(suffix):
            base = name[: -len(suffix)]
    if base in _TRAFFIC:
        return "traffic"
    if base in _ARTICULATED:
        return "articulated"
    if base[:1].isdigit() or base == "three-cars":
        return "checkerboard"
    raise InputError(f"{name!r} is not a Hopkins155 sequence name")


def list_hopkins_sequences(root: str | Path, include_extra: bool = False) -> list[str]:
    """Sequence names under root, sorted.

    Args:
        root: the data folder holding ``hopkins155/`` (or the ``hopkins155`` folder itself).
        include_extra: also list folders with a ``*_truth.mat`` outside the official 155
            (e.g. ``dancing``).

    Raises:
        DatasetError: the folder is missing, or one of the official 155 is missing.
    """
    folder = _dataset_dir(root)
    present = {d.name for d in folder.iterdir() if (d / f"{d.name}_truth.mat").is_file()}
    missing = sorted(OFFICIAL_SEQUENCES - present)
    if missing:
        raise DatasetError(f"{folder}: {len(missing)} official sequences missing, e.g. {folder / missing[0]}")
    names = present if include_extra else present & OFFICIAL_SEQUENCES
    return sorted(names)


def read_hopkins(root: str | Path, name: str, frames: int | None = None) -> LabeledClip:
    """Read one Hopkins155 sequence.

    Args:
        root: the data folder holding ``hopkins155/``.
        name: sequence folder name, e.g. "1R2RC_g12".
        frames: keep only the first `frames` frames; None keeps all.

    Returns:
        traj (P, 2F) float32 pixel coordinates (from ``y``), labels (P,) int64 0..K-1 (from ``s``),
        meta keys "file", "sequence", "num_motions", "frames", "total_frames", "frame_range"
        (1-based, inclusive), "image_size_hw", "original_labels", "outlier_label" (None),
        "subset" (official sequences only).

    Raises:
        DatasetError: the file is missing or malformed.
        InputError: `frames` is < 1 or longer than the sequence.
    """
    import scipy.io

    path = _dataset_dir(root) / name / f"{name}_truth.mat"
    if not path.is_file():
        raise DatasetError(f"{path}: Hopkins155 ground-truth file not found")
    try:
        mat = scipy.io.loadmat(path, variable_names=("y", "s", "width", "height"))
        y = np.asarray(mat["y"], dtype=np.float64)
        s = np.asarray(mat["s"]).reshape(-1)
        size_hw = [int(np.asarray(mat["height"]).item()), int(np.asarray(mat["width"]).item())]
    except (KeyError, ValueError, OSError) as exc:
        raise DatasetError(f"{path}: not a Hopkins155 ground-truth file ({exc})") from exc
    if y.ndim == 2:
        y = y[:, :, None]
    if y.ndim != 3 or y.shape[0] != 3 or y.shape[1] != s.size:
        raise DatasetError(f"{path}: y has shape {y.shape} for {s.size} labels")
    total = int(y.shape[2])
    if frames is None:
        frames = total
    if not 1 <= frames <= total:
        raise InputError(f"{path}: {total} frames, frames={frames} asked")
    # (3, P, F) -> (P, F, 2) with the homogeneous coordinate divided out.
    xy = np.transpose(y[:2, :, :frames] / y[2:3, :, :frames], (1, 2, 0))
    labels, original = remap_labels(s)
    meta: dict[str, object] = {
        "file": str(path),
        "sequence": name,
        "num_motions": len(original),
        "frames": frames,
        "total_frames": total,
        "frame_range": [1, frames],
        "image_size_hw": size_hw,
        "original_labels": original,
        "outlier_label": None,
    }
    if name in OFFICIAL_SEQUENCES:
        meta["subset"] = hopkins_subset(name)
    return LabeledClip(
        name=name,
        traj=np.ascontiguousarray(xy.reshape(xy.shape[0], -1), dtype=np.float32),
        labels=labels,
        dataset=DATASET,
        meta=meta,
    )


def load_hopkins(root: str | Path, frames: int | None = None, include_extra: bool = False) -> list[LabeledClip]:
    """Read every Hopkins155 sequence, in sorted name order.

    Args:
        root: the data folder holding ``hopkins155/``.
        frames: None for all frames of each sequence, F for the first F frames (sequences shorter
            than F raise InputError; the shortest official sequence has 15 frames).
        include_extra: also read sequences outside the official 155.

    Returns:
        155 clips (120 with two motions, 35 with three) unless include_extra.
    """
    return [
        read_hopkins(root, name, frames=frames) for name in list_hopkins_sequences(root, include_extra=include_extra)
    ]
