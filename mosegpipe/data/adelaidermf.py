"""AdelaideRMF two-view motion segmentation reader (Wong, Chin, Yu, Suter, ICCV 2011).

Layout under the data root: ``adelaidermf/F/<name>.mat`` with ``data`` (6, N) = [x1 y1 1 x2 y2 1]
SIFT correspondences in pixels, ``label`` (1, N) with 0 = gross outlier and 1..K = motion,
``img1``/``img2`` (480, 640, 3) uint8 RGB (two pairs are grayscale) and ``score`` (1, N).
The SubspaceNet paper counts the outliers as one more group; here they become group 0 and the
motions 1..K, so the contiguous labels equal the file's labels for every pair of the release.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from mosegpipe.data.labels import remap_labels
from mosegpipe.errors import DatasetError
from mosegpipe.types import LabeledClip

DATASET = "adelaidermf"
OUTLIER_ID = 0


@dataclass(frozen=True)
class AdelaidePair:
    """One AdelaideRMF image pair with its labelled correspondences.

    Attributes:
        name: pair name, e.g. "biscuitbook".
        xy1: (N, 2) float32 pixel coordinates in image 1.
        xy2: (N, 2) float32 pixel coordinates in image 2.
        labels: (N,) int64 raw file labels: 0 = gross outlier, 1..K = motion.
        img1: (H, W, 3) uint8 RGB (grayscale pairs are repeated over 3 channels).
        img2: (H, W, 3) uint8 RGB.
        score: (N,) float32 SIFT matching score from the file.
    """

    name: str
    xy1: npt.NDArray[np.float32]
    xy2: npt.NDArray[np.float32]
    labels: npt.NDArray[np.int64]
    img1: npt.NDArray[np.uint8]
    img2: npt.NDArray[np.uint8]
    score: npt.NDArray[np.float32]

    @property
    def num_points(self) -> int:
        return int(self.xy1.shape[0])


def _dataset_dir(root: str | Path) -> Path:
    """The .mat folder ``root/adelaidermf/F``; root may also be ``adelaidermf`` or ``F`` itself."""
    root = Path(root)
    for candidate in (root / DATASET / "F", root / "F"):
        if candidate.is_dir():
            return candidate
    if root.name == "F" and root.is_dir():
        return root
    raise DatasetError(f"{root / DATASET / 'F'}: AdelaideRMF folder not found")


def list_adelaide(root: str | Path) -> list[str]:
    """Names of the AdelaideRMF pairs, sorted (19 in the release).

    Args:
        root: the data folder holding ``adelaidermf/``.

    Raises:
        DatasetError: the folder is missing or empty.
    """
    folder = _dataset_dir(root)
    names = sorted(p.stem for p in folder.glob("*.mat"))
    if not names:
        raise DatasetError(f"{folder}: no .mat files")
    return names


def _path(root: str | Path, name: str) -> Path:
    path = _dataset_dir(root) / f"{name}.mat"
    if not path.is_file():
        raise DatasetError(f"{path}: AdelaideRMF pair not found")
    return path


def _correspondences(
    path: Path, mat: dict[str, npt.NDArray[np.generic]]
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.int64]]:
    try:
        data = np.asarray(mat["data"], dtype=np.float64)
        labels = np.asarray(mat["label"]).reshape(-1).astype(np.int64)
    except KeyError as exc:
        raise DatasetError(f"{path}: field {exc} missing") from exc
    if data.ndim != 2 or data.shape[0] != 6 or data.shape[1] != labels.size:
        raise DatasetError(f"{path}: data has shape {data.shape} for {labels.size} labels")
    # Rows 2 and 5 are the homogeneous 1s; divide them out rather than trust them.
    xy1 = (data[0:2] / data[2:3]).T
    xy2 = (data[3:5] / data[5:6]).T
    return xy1, xy2, labels


def _rgb(path: Path, image: npt.NDArray[np.generic], key: str) -> npt.NDArray[np.uint8]:
    arr = np.asarray(image)
    if arr.ndim == 2:
        arr = np.repeat(arr[:, :, None], 3, axis=2)
    if arr.ndim != 3 or arr.shape[2] != 3:
        raise DatasetError(f"{path}: {key} has shape {arr.shape}, expected (H, W) or (H, W, 3)")
    return np.ascontiguousarray(arr, dtype=np.uint8)


def read_adelaide_pair(root: str | Path, name: str) -> AdelaidePair:
    """Read one AdelaideRMF pair with its images.

    Args:
        root: the data folder holding ``adelaidermf/``.
        name: pair name, e.g. "biscuitbook".

    Raises:
        DatasetError: the file is missing or malformed.
    """
    import scipy.io

    path = _path(root, name)
    mat = scipy.io.loadmat(path)
    xy1, xy2, labels = _correspondences(path, mat)
    if "img1" not in mat or "img2" not in mat:
        raise DatasetError(f"{path}: img1/img2 missing")
    score = np.asarray(mat.get("score", np.zeros(labels.size)), dtype=np.float32).reshape(-1)
    return AdelaidePair(
        name=name,
        xy1=xy1.astype(np.float32),
        xy2=xy2.astype(np.float32),
        labels=labels,
        img1=_rgb(path, mat["img1"], "img1"),
        img2=_rgb(path, mat["img2"], "img2"),
        score=score,
    )


def read_adelaide(root: str | Path, name: str) -> LabeledClip:
    """One AdelaideRMF pair as a two-frame labelled clip (images not loaded).

    Args:
        root: the data folder holding ``adelaidermf/``.
        name: pair name.

    Returns:
        traj (N, 4) float32 pixels [x1, y1, x2, y2]; labels (N,) int64 with outliers as group 0
        ("outlier_label" 0) and motions 1..K in increasing file-label order (when a pair has no
        outliers, motions are 0..K-1 and "outlier_label" is None); meta keys "file",
        "num_motions" (K, outliers excluded), "outlier_ratio", "outlier_label",
        "original_labels" (file label of each new label), "frames" (2), "image_size_hw".
    """
    import scipy.io

    path = _path(root, name)
    mat = scipy.io.loadmat(path, variable_names=("data", "label"))
    xy1, xy2, raw = _correspondences(path, mat)
    # Outlier id 0 is the smallest file label, so the increasing remap sends it to group 0.
    labels, original = remap_labels(raw)
    has_outliers = OUTLIER_ID in original
    image_shape = [shape for var, shape, _ in scipy.io.whosmat(path) if var == "img1"]
    traj = np.stack([xy1[:, 0], xy1[:, 1], xy2[:, 0], xy2[:, 1]], axis=1).astype(np.float32)
    return LabeledClip(
        name=name,
        traj=traj,
        labels=labels,
        dataset=DATASET,
        meta={
            "file": str(path),
            "frames": 2,
            "num_motions": len(original) - int(has_outliers),
            "outlier_ratio": float(np.mean(raw == OUTLIER_ID)) if raw.size else 0.0,
            "outlier_label": 0 if has_outliers else None,
            "original_labels": original,
            "image_size_hw": [int(v) for v in image_shape[0][:2]] if image_shape else None,
        },
    )


def load_adelaide(root: str | Path) -> list[LabeledClip]:
    """Every AdelaideRMF pair as a two-frame clip (see read_adelaide), in sorted name order."""
    return [read_adelaide(root, name) for name in list_adelaide(root)]
