"""What segment_video yields (mosegpipe.pipeline.video): a window's result (WindowResult), each of its
frames (VideoFrame) and a frame's mask (frame_mask)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import numpy as np
import numpy.typing as npt

from mosegpipe.masks import (
    MaskConfig,
    labels_to_mask,
    moving_to_labels,
)
from mosegpipe.pipeline.resize import upscale_labels, upscale_mask, upscale_xy
from mosegpipe.types import FLOW_MASK_METHODS

AMBIGUOUS_K_NOTE = "the K choice is ambiguous"
"""How cluster_auto_k's note (and warning) for an ambiguous K choice starts."""

FrameTracks = tuple[int, npt.NDArray[np.uint8], npt.NDArray[np.int64], npt.NDArray[np.float32]]


@dataclass(frozen=True)
class VideoFrame:
    """One frame of a whole-video run with the labels of its tracks.

    Attributes:
        index: frame index in the source (0-based).
        image: (H, W, 3) uint8 RGB.
        track_ids: (N,) int64 ids of the tracks live in this frame.
        xy: (N, 2) float32 pixel positions of those tracks.
        labels: (N,) int64 global motion label of each track, -1 = unlabelled. A track that ends
            inside its window (lost before the window's last frame, so not clustered there) keeps
            the label the window before gave it.
        mask: (H, W) uint8, label = motion, 255 = unknown; None when segment_video was asked for
            no masks (see `frame_mask`).
        moving: (H, W) bool moving pixels from the window's dense flow (mask methods "motion", "learned"); None
            with the other methods and in windows of one frame.
    """

    index: int
    image: npt.NDArray[np.uint8]
    track_ids: npt.NDArray[np.int64]
    xy: npt.NDArray[np.float32]
    labels: npt.NDArray[np.int64]
    mask: npt.NDArray[np.uint8] | None
    moving: npt.NDArray[np.bool_] | None = None


def frame_mask(frame: VideoFrame, cfg: MaskConfig = MaskConfig()) -> npt.NDArray[np.uint8]:
    """The dense mask of one whole-video frame from its labelled tracks (what segment_video computes).

    Returns:
        (H, W) uint8, label = motion, 255 = unknown.
    """
    if frame.mask is not None:
        return frame.mask
    if cfg.method in FLOW_MASK_METHODS and frame.moving is not None:
        return moving_to_labels(frame.moving, frame.xy, frame.labels, image=frame.image, cfg=cfg)
    keep = frame.labels >= 0
    return labels_to_mask(frame.xy[keep], frame.labels[keep], frame.image.shape[:2], cfg, frame.image)


@dataclass(frozen=True)
class WindowResult:
    """One F-frame window of a whole video.

    Attributes:
        start: index of the window's first frame.
        num_frames: frames in the window (F, or fewer for the last one).
        num_tracks: tracks live through the whole window.
        k: motions found in it (0 = left unlabelled: too few tracks).
        track_ids: (N,) int64 ids of the labelled tracks (empty when unlabelled).
        labels: (N,) int64 their global labels.
        frames: the frames this window adds (its first frame belongs to the previous window, except
            for the first window), with labels and masks.
        num_motions: global labels handed out so far.
        num_labels_reused: labels handed out again so far (only after 255 labels).
        num_frames_read: frames of the source done so far (those of this window and the windows before).
        k_note: automatic K's note on this window (Clustering.note: e.g. the K choice was
            ambiguous); "" when none.
        k_scores: automatic K's score per candidate K in this window (Clustering.scores); empty
            when K was forced or the window was left unlabelled.
        shot_start: the window starts on a shot cut (PipelineConfig.video_cut_survival): its
            tracks were detected afresh there, and it shares no frame with the window before.
    """

    start: int
    num_frames: int
    num_tracks: int
    k: int
    track_ids: npt.NDArray[np.int64]
    labels: npt.NDArray[np.int64]
    frames: tuple[VideoFrame, ...]
    num_motions: int
    num_labels_reused: int
    num_frames_read: int
    k_note: str = ""
    k_scores: Mapping[int, float] = field(default_factory=dict)
    shot_start: bool = False

    @property
    def is_labelled(self) -> bool:
        """Whether the window had enough tracks to be segmented."""
        return self.k > 0

    @property
    def is_k_ambiguous(self) -> bool:
        """Whether automatic K found two K scoring within ClusterConfig.ambiguity_margin here."""
        return self.k_note.startswith(AMBIGUOUS_K_NOTE)

    def record(self) -> dict[str, int | bool]:
        """The window's row in summary.json."""
        return {
            "start": self.start,
            "frames": self.num_frames,
            "num_tracks": self.num_tracks,
            "k": self.k,
            "k_ambiguous": self.is_k_ambiguous,
            "shot_start": self.shot_start,
        }


def at_input_size(window: WindowResult, originals: dict[int, npt.NDArray[np.uint8]]) -> WindowResult:
    """A window segmented on shrunk frames (cfg.max_side) with its frames brought back to the input's: the
    input's image (taken out of `originals`), the tracks' positions scaled, the mask upsampled with its edges
    snapped to the image's (resize.upscale_mask), the moving pixels by nearest neighbour."""
    frames = []
    for fr in window.frames:
        image = originals.pop(fr.index, None)
        if image is None:  # not shrunk: already at the input's size
            frames.append(fr)
            continue
        size_hw = (int(image.shape[0]), int(image.shape[1]))
        scale = fr.image.shape[1] / size_hw[1]
        moving = None if fr.moving is None else upscale_labels(fr.moving.view(np.uint8), size_hw).view(np.bool_)
        mask = None if fr.mask is None else upscale_mask(fr.mask, image)
        frames.append(replace(fr, image=image, xy=upscale_xy(fr.xy, scale), mask=mask, moving=moving))
    return replace(window, frames=tuple(frames))
