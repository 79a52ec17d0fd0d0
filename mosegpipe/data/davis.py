"""DAVIS-2016 reader (Perazzi et al., CVPR 2016): real videos with a human mask of the main moving object.

Layout under the root (the ``davis2016-train`` folder itself, or a data root that holds it)::

    <clip>/frames/00000.jpg ...   RGB frames (854x480 in the 480p release)
    <clip>/masks/00000.png ...    8-bit masks of the same size, 255 = the object, 0 = everything else

Frame file f (0-based, in name order) goes with mask file f. The masks mark one main moving object
(which may be several linked parts, rider + bike); other moving things are background in them, so
they are a foreground/background truth, not a full motion segmentation.

A fixed development / validation split of the 30 DAVIS-2016 train clips, decided by a rule before
any result was seen: in alphabetical order, every third clip from index 2 (2, 5, 8, ..., 29) is
validation (`DAVIS_VAL`, 10 clips), the other 20 are development (`DAVIS_DEV`). Tune on dev only;
report val once.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe.errors import DatasetError, InputError, check_choice
from mosegpipe.io.read import read_video

logger = logging.getLogger(__name__)

DATASET = "davis2016-train"
"""The folder name of the DAVIS-2016 train clips under a data root."""

DAVIS2016_TRAIN = (
    "bear", "bmx-bumps", "boat", "breakdance-flare", "bus", "car-turn", "dance-jump", "dog-agility",
    "drift-turn", "elephant", "flamingo", "hike", "hockey", "horsejump-low", "kite-walk", "lucia",
    "mallard-fly", "mallard-water", "motocross-bumps", "motorbike", "paragliding", "rhino", "rollerblade",
    "scooter-gray", "soccerball", "stroller", "surf", "swing", "tennis", "train",
)  # fmt: skip
"""The 30 clips of the official DAVIS-2016 train split (ImageSets/480p/train.txt), alphabetical."""

DAVIS_VAL = (
    "boat", "car-turn", "drift-turn", "hike", "kite-walk",
    "mallard-water", "paragliding", "scooter-gray", "surf", "train",
)  # fmt: skip
"""Validation clips: DAVIS2016_TRAIN[2::3], every third clip in alphabetical order (rule fixed in advance)."""

DAVIS_DEV = tuple(name for name in DAVIS2016_TRAIN if name not in DAVIS_VAL)
"""Development clips: the other 20; every setting is chosen on these."""

SPLIT_PARTS = ("dev", "val", "all")

_FRAME_SUFFIXES = (".jpg", ".jpeg", ".png")


@dataclass(frozen=True)
class DavisClip:
    """Frames and ground-truth masks of one DAVIS clip (or a stretch of it).

    Attributes:
        name: the clip folder's name, e.g. "bear".
        frames_dir: the folder of its frames (a path the pipeline can read as a video).
        images: (T, H, W, 3) uint8 RGB frames.
        gt: (T, H, W) bool, True on the annotated object.
        start: index of images[0] among the clip's frames (0-based).
    """

    name: str
    frames_dir: Path
    images: npt.NDArray[np.uint8]
    gt: npt.NDArray[np.bool_]
    start: int = 0

    @property
    def num_frames(self) -> int:
        return int(self.images.shape[0])


def davis_root(root: str | Path) -> Path:
    """The folder holding the clip folders: `root` itself, or `root`/davis2016-train when it exists.

    Raises:
        DatasetError: neither is a folder.
    """
    p = Path(root)
    if (p / DATASET).is_dir():
        return p / DATASET
    if not p.is_dir():
        raise DatasetError(f"{p}: DAVIS folder not found")
    return p


def list_davis_clips(root: str | Path) -> list[str]:
    """Names of the clips under `root` (folders with a ``frames`` subfolder), sorted.

    Args:
        root: the ``davis2016-train`` folder, or a data root holding it.

    Raises:
        DatasetError: the folder is missing or holds no clip.
    """
    folder = davis_root(root)
    names = sorted(p.name for p in folder.iterdir() if (p / "frames").is_dir())
    if not names:
        raise DatasetError(f"{folder}: no DAVIS clip folders (<clip>/frames/) found")
    return names


def davis_part(name: str) -> str:
    """The part of the fixed split a clip belongs to: "val" for DAVIS_VAL, else "dev" (unknown clips too)."""
    return "val" if name in DAVIS_VAL else "dev"


def davis_split(names: Iterable[str], part: str) -> list[str]:
    """The clips of `names` in one part of the fixed split, in the given order.

    Args:
        names: clip names (e.g. from list_davis_clips).
        part: "dev", "val" or "all".

    Raises:
        ConfigError: `part` is none of those.
    """
    check_choice("part", part, SPLIT_PARTS)
    return [n for n in names if part == "all" or davis_part(n) == part]


def _files(folder: Path, suffixes: tuple[str, ...]) -> list[Path]:
    if not folder.is_dir():
        raise DatasetError(f"{folder}: folder not found")
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in suffixes)


def read_davis_clip(root: str | Path, name: str, start: int = 0, max_frames: int | None = None) -> DavisClip:
    """Reads frames `start` .. `start + max_frames - 1` of one clip and their masks.

    Args:
        root: the ``davis2016-train`` folder, or a data root holding it.
        name: the clip folder's name.
        start: first frame to read (0-based).
        max_frames: read at most this many frames (None = to the end).

    Returns:
        DavisClip with images (T, H, W, 3) uint8 RGB and gt (T, H, W) bool.

    Raises:
        DatasetError: the clip, its frames or masks folder is missing, the two hold different numbers
            of files or differently named ones, a file is unreadable, a mask's size differs from its
            frame's, or `start` is past the end. The message names the path.
    """
    clip_dir = davis_root(root) / name
    frames_dir, masks_dir = clip_dir / "frames", clip_dir / "masks"
    frame_files = _files(frames_dir, _FRAME_SUFFIXES)
    mask_files = _files(masks_dir, (".png",))
    if not frame_files:
        raise DatasetError(f"{frames_dir}: no frames")
    if len(frame_files) != len(mask_files):
        raise DatasetError(f"{clip_dir}: {len(frame_files)} frames but {len(mask_files)} masks")
    if [p.stem for p in frame_files] != [p.stem for p in mask_files]:
        raise DatasetError(f"{clip_dir}: frame and mask file names do not pair up")
    if not 0 <= start < len(frame_files):
        raise DatasetError(f"{frames_dir}: start {start} is outside its {len(frame_files)} frames")
    if max_frames is not None and max_frames < 1:
        raise ValueError(f"max_frames={max_frames} must be >= 1")
    try:
        images = read_video(frames_dir, max_frames=max_frames, start=start).images
    except InputError as exc:
        raise DatasetError(f"{frames_dir}: {exc}") from exc
    gt = np.zeros(images.shape[:3], dtype=bool)
    for t, path in enumerate(mask_files[start : start + images.shape[0]]):
        mask = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if mask is None:
            raise DatasetError(f"{path}: cannot read the mask")
        if mask.shape != images.shape[1:3]:
            raise DatasetError(
                f"{path}: mask is {mask.shape[1]}x{mask.shape[0]}, frame is {images.shape[2]}x{images.shape[1]}"
            )
        gt[t] = mask > 127
    return DavisClip(name=name, frames_dir=frames_dir, images=images, gt=gt, start=start)
