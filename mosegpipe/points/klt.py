"""KLT point tracking (Shi-Tomasi corners + pyramidal Lucas-Kanade) with a forward-backward check.

`track_klt` tracks the corners of the first frame through a short clip and returns Tracks;
`KLTTracker` does the same one frame at a time and re-seeds corners where tracks were lost, for
long videos segmented in windows. Both share one implementation (the tracker).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import replace

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe.configs.tracking import TrackConfig
from mosegpipe.errors import InputError
from mosegpipe.types import Frames, Tracks

logger = logging.getLogger(__name__)


def _inside(xy: npt.NDArray[np.float32], size_hw: tuple[int, int], border_px: float) -> npt.NDArray[np.bool_]:
    """Which points lie at least border_px inside an image of size_hw (and are finite)."""
    height, width = size_hw
    return np.asarray(
        np.isfinite(xy).all(axis=1)
        & (xy[:, 0] >= border_px)
        & (xy[:, 1] >= border_px)
        & (xy[:, 0] <= width - 1 - border_px)
        & (xy[:, 1] <= height - 1 - border_px)
    )


def _away_from(shape: tuple[int, ...], xy: npt.NDArray[np.float32], distance_px: float) -> npt.NDArray[np.uint8] | None:
    """A detection mask that forbids the discs of radius distance_px around `xy` (None: no points)."""
    if not len(xy):
        return None
    mask = np.full(shape[:2], 255, dtype=np.uint8)
    radius = max(1, int(round(distance_px)))
    for x, y in np.round(xy).astype(int):
        cv2.circle(mask, (int(x), int(y)), radius, 0, -1)
    return mask


def _to_gray(frame: npt.NDArray[np.uint8]) -> npt.NDArray[np.uint8]:
    frame = np.asarray(frame)
    if frame.ndim == 2:
        gray = frame
    elif frame.ndim == 3 and frame.shape[2] == 3:
        gray = cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY)
    elif frame.ndim == 3 and frame.shape[2] == 1:
        gray = frame[:, :, 0]
    else:
        raise InputError(f"frame must be (H, W) gray or (H, W, 3) RGB, got shape {frame.shape}")
    if gray.dtype != np.uint8:
        raise InputError(f"frame must be uint8, got {gray.dtype}")
    return np.ascontiguousarray(gray)


class KLTTracker:
    """Streaming KLT tracker: feed frames one by one, get the live points with stable ids.

    Ids are assigned in detection order and never reused; a point that is lost (LK failure,
    forward-backward error, leaving the image) never comes back. With `cfg.reseed`, new corners
    are detected every `cfg.reseed_every` frames in areas farther than `cfg.min_distance_px`
    from every live point, up to `cfg.max_corners` live points.

    Example:
        >>> tracker = KLTTracker(TrackConfig(reseed=True))
        >>> for frame in frames:  # doctest: +SKIP
        ...     ids, xy = tracker.step(frame)
    """

    def __init__(self, cfg: TrackConfig = TrackConfig()) -> None:
        self.cfg = cfg
        self._criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, cfg.max_iter, cfg.epsilon_px)
        self.reset()

    def reset(self) -> None:
        """Forget all points and frames; the next step() starts afresh."""
        self._prev_gray: npt.NDArray[np.uint8] | None = None
        self._size_hw: tuple[int, int] | None = None
        self._ids = np.zeros(0, dtype=np.int64)
        self._xy = np.zeros((0, 2), dtype=np.float32)
        self._next_id = 0
        self._seeded_at = 0  # frame index the re-seeding period counts from
        self.frame_index = -1

    @property
    def gray(self) -> npt.NDArray[np.uint8] | None:
        """(H, W) uint8 grey of the last frame stepped (None before the first): whole videos hand it to the
        dense flow, which would convert the frame again (mosegpipe.points.flow.to_gray gives the same image)."""
        return self._prev_gray

    def restart(self, frame: npt.NDArray[np.uint8]) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float32]]:
        """Forgets the live points and detects corners afresh in `frame`, the frame of the last step.

        For a shot cut: the few points tracked across it landed on unrelated image content. Ids keep
        growing (an id is never reused), and re-seeding counts its period from this frame.

        Returns:
            ids, xy: the new points, as `step` returns them.
        """
        gray = _to_gray(frame)
        if self._prev_gray is None or gray.shape != self._prev_gray.shape:
            raise ValueError("restart() takes the frame of the last step")
        self._ids = np.zeros(0, dtype=np.int64)
        self._xy = np.zeros((0, 2), dtype=np.float32)
        self._prev_gray = gray
        self._seeded_at = self.frame_index
        self._seed(gray)
        return self._ids.copy(), self._xy.copy()

    def start(
        self, frame: npt.NDArray[np.uint8], xy: npt.NDArray[np.float32]
    ) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float32]]:
        """The first step with given points instead of detected corners (ids 0..N-1, in order).

        Raises:
            ValueError: the tracker has already stepped.
        """
        if self.frame_index >= 0:
            raise ValueError("start() must be the first call")
        gray = _to_gray(frame)
        self._size_hw = (int(gray.shape[0]), int(gray.shape[1]))
        self.frame_index = 0
        self._prev_gray = gray
        self._xy = np.asarray(xy, dtype=np.float32).reshape(-1, 2).copy()
        self._ids = np.arange(len(self._xy), dtype=np.int64)
        self._next_id = len(self._xy)
        return self._ids.copy(), self._xy.copy()

    def _seed(self, gray: npt.NDArray[np.uint8]) -> None:
        new_xy = self._detect(gray, self.cfg.max_corners - len(self._xy))
        if len(new_xy):
            new_ids = np.arange(self._next_id, self._next_id + len(new_xy), dtype=np.int64)
            self._next_id += len(new_xy)
            self._ids = np.concatenate([self._ids, new_ids])
            self._xy = np.concatenate([self._xy, new_xy])

    @property
    def num_ids(self) -> int:
        """Number of ids handed out so far (live or lost)."""
        return self._next_id

    def _lk(
        self,
        gray_from: npt.NDArray[np.uint8],
        gray_to: npt.NDArray[np.uint8],
        pts: npt.NDArray[np.float32],
    ) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.bool_]]:
        out, status, _ = cv2.calcOpticalFlowPyrLK(
            gray_from,
            gray_to,
            pts.reshape(-1, 1, 2),
            None,
            winSize=(self.cfg.win_size_px, self.cfg.win_size_px),
            maxLevel=self.cfg.max_level,
            criteria=self._criteria,
            minEigThreshold=self.cfg.min_eig,
        )
        return out.reshape(-1, 2), status.reshape(-1).astype(bool)

    def _inside(self, xy: npt.NDArray[np.float32]) -> npt.NDArray[np.bool_]:
        assert self._size_hw is not None
        return _inside(xy, self._size_hw, self.cfg.border_px)

    def _detect(self, gray: npt.NDArray[np.uint8], budget: int) -> npt.NDArray[np.float32]:
        if budget <= 0:
            return np.zeros((0, 2), dtype=np.float32)
        # Forbid detection within min_distance_px of a live point, so re-seeded corners fill
        # only the areas that lost their tracks.
        mask = _away_from(gray.shape, self._xy, self.cfg.min_distance_px)
        corners = cv2.goodFeaturesToTrack(
            gray,
            maxCorners=budget,
            qualityLevel=self.cfg.quality_level,
            minDistance=self.cfg.min_distance_px,
            mask=mask,
            blockSize=self.cfg.block_size,
        )
        if corners is None:
            return np.zeros((0, 2), dtype=np.float32)
        corners = corners.reshape(-1, 2).astype(np.float32)
        return corners[self._inside(corners)]

    def step(self, frame: npt.NDArray[np.uint8]) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float32]]:
        """Track the live points into `frame` (and detect/re-seed corners when due).

        Args:
            frame: (H, W) uint8 gray or (H, W, 3) uint8 RGB; the same size every call.

        Returns:
            ids: (M,) int64 ids of the points live in this frame, ascending.
            xy: (M, 2) float32 their pixel coordinates in this frame.

        Raises:
            InputError: wrong dtype/shape, or a frame size different from earlier frames.
        """
        gray = _to_gray(frame)
        if self._size_hw is None:
            self._size_hw = (int(gray.shape[0]), int(gray.shape[1]))
        elif gray.shape != self._size_hw:
            raise InputError(
                f"frame {self.frame_index + 1} is {gray.shape[1]}x{gray.shape[0]}, "
                f"earlier frames are {self._size_hw[1]}x{self._size_hw[0]}"
            )
        self.frame_index += 1
        if self._prev_gray is not None and len(self._xy):
            self._track(gray)
        self._prev_gray = gray
        since = self.frame_index - self._seeded_at
        if self.frame_index == 0 or (self.cfg.reseed and since % self.cfg.reseed_every == 0):
            self._seed(gray)
        return self._ids.copy(), self._xy.copy()

    def _track(self, gray: npt.NDArray[np.uint8]) -> None:
        # OpenCV's Python binding cannot take the pyramids of cv2.buildOpticalFlowPyramid
        # (opencv/opencv#4777), so each LK call rebuilds them; building one costs ~0.1-0.3 ms
        # at 640x480, against ~12 ms per LK pass over 1000 points.
        assert self._prev_gray is not None
        old = self._xy
        new, ok = self._lk(self._prev_gray, gray, old)
        ok &= self._inside(new)
        if self.cfg.fb_threshold_px is not None and ok.any():
            # Track back only the survivors, from scratch: seeding the backward search with the
            # old position could only pull it towards a pass.
            back, ok_back = self._lk(gray, self._prev_gray, new[ok])
            err = np.linalg.norm(back - old[ok], axis=1)
            keep = ok_back & (err <= self.cfg.fb_threshold_px)
            ok[np.flatnonzero(ok)[~keep]] = False
        self._ids = self._ids[ok]
        self._xy = new[ok].astype(np.float32)


def tracks_from_steps(
    steps: Sequence[tuple[npt.NDArray[np.int64], npt.NDArray[np.float32]]],
    size_hw: tuple[int, int],
) -> tuple[Tracks, npt.NDArray[np.int64]]:
    """Assemble the per-frame outputs of KLTTracker.step into Tracks (e.g. one window of a video).

    Args:
        steps: for each of T consecutive frames, (ids (M,) int64, xy (M, 2) float32) as
            returned by KLTTracker.step.
        size_hw: (H, W) of the frames.

    Returns:
        tracks: Tracks with one row per id seen in the T frames (ascending id), xy NaN and
            visible False where the id was not live.
        ids: (N,) int64 the tracker id of each row.
    """
    all_ids = [ids for ids, _ in steps]
    row_ids = np.unique(np.concatenate(all_ids)) if all_ids else np.zeros(0, np.int64)
    row_ids = row_ids.astype(np.int64)
    xy = np.full((len(row_ids), len(steps), 2), np.nan, dtype=np.float32)
    visible = np.zeros((len(row_ids), len(steps)), dtype=bool)
    for t, (ids, pts) in enumerate(steps):
        rows = np.searchsorted(row_ids, ids)
        xy[rows, t] = pts
        visible[rows, t] = True
    return Tracks(xy=xy, visible=visible, size_hw=(int(size_hw[0]), int(size_hw[1]))), row_ids


def spread_corners(
    image: npt.NDArray[np.uint8],
    budget: int,
    avoid_xy: npt.NDArray[np.float32] | None = None,
    cfg: TrackConfig = TrackConfig(),
    grid: int = 16,
) -> npt.NDArray[np.float32]:
    """Up to `budget` corners spread over the image: taken in turn from the cells of a grid x grid
    partition (the strongest corner of every cell, then the second, ...), away from `avoid_xy`.

    goodFeaturesToTrack alone hands its budget out strongest first, so a high-contrast background can
    take every corner and leave a weakly textured object without any; here every textured cell gets
    its share. Same quality level, spacing and border as the tracker's own detection.

    Args:
        image: (H, W) gray or (H, W, 3) RGB uint8.
        budget: the most corners returned.
        avoid_xy: (M, 2) points (e.g. tracks already there): no corner within cfg.min_distance_px.
        cfg: detection settings (quality_level, min_distance_px, block_size, border_px).
        grid: cells per side.

    Returns:
        (K, 2) float32 corner positions, K <= budget.
    """
    gray = _to_gray(image)
    if budget <= 0:
        return np.zeros((0, 2), dtype=np.float32)
    avoid = np.zeros((0, 2), np.float32) if avoid_xy is None else avoid_xy[np.isfinite(avoid_xy).all(axis=1)]
    found = cv2.goodFeaturesToTrack(
        gray, maxCorners=0, qualityLevel=cfg.quality_level, minDistance=cfg.min_distance_px,
        mask=_away_from(gray.shape, avoid, cfg.min_distance_px), blockSize=cfg.block_size,
    )  # fmt: skip
    if found is None:
        return np.zeros((0, 2), dtype=np.float32)
    corners = found.reshape(-1, 2).astype(np.float32)
    height, width = gray.shape
    corners = corners[_inside(corners, (height, width), cfg.border_px)]
    if len(corners) <= budget:
        return corners
    col = np.minimum((corners[:, 0] * grid / width).astype(np.int64), grid - 1)
    row = np.minimum((corners[:, 1] * grid / height).astype(np.int64), grid - 1)
    cell = row * grid + col
    order = np.argsort(cell, kind="stable")  # by cell, strongest first within a cell
    first = np.searchsorted(cell[order], cell[order], side="left")
    rank = np.empty(len(corners), dtype=np.int64)
    rank[order] = np.arange(len(corners)) - first  # 0 = the strongest of its cell
    keep = np.lexsort((np.arange(len(corners)), rank))[:budget]
    return corners[np.sort(keep)]


def track_points(
    images: npt.NDArray[np.uint8], xy: npt.NDArray[np.float32], cfg: TrackConfig = TrackConfig()
) -> Tracks:
    """Track given points of the first image through the others (as track_klt tracks its corners).

    Args:
        images: (T, H, W, 3) uint8 RGB (or (T, H, W) gray).
        xy: (N, 2) float32 positions in images[0].
        cfg: tracker settings (detection ones unused; no re-seeding).

    Returns:
        Tracks of the N points in the order given (visible until lost).
    """
    tracker = KLTTracker(replace(cfg, reseed=False))
    steps = [tracker.start(images[0], xy)] + [tracker.step(image) for image in images[1:]]
    tracks, _ = tracks_from_steps(steps, (int(images.shape[1]), int(images.shape[2])))
    return tracks  # every id is live in the first step, so row n is point n


def track_klt(frames: Frames, cfg: TrackConfig = TrackConfig()) -> Tracks:
    """Track Shi-Tomasi corners of the first frame through a clip with pyramidal Lucas-Kanade.

    A point is visible from its first frame until it is lost (LK failure, forward-backward error
    above `cfg.fb_threshold_px`, or leaving the image), and invisible from then on. With
    `cfg.reseed`, points detected later are invisible before their first frame. A blank clip
    (no corners) gives N = 0 tracks rather than an error; the caller decides what is too few.

    Args:
        frames: Frames with images (T, H, W, 3) uint8 RGB.
        cfg: tracker settings.

    Returns:
        Tracks with xy (N, T, 2) float32 pixels (NaN where not visible), visible (N, T) bool,
        size_hw = frames.size_hw. Row n is the n-th detected corner.

    Raises:
        ValueError: images that are not (T, H, W, 3) with H, W >= 1 (e.g. 0x0 frames).
    """
    shape = np.shape(frames.images)
    if len(shape) != 4 or shape[1] < 1 or shape[2] < 1 or shape[3] != 3:
        raise ValueError(f"track_klt: images must be (T, H, W, 3) with H, W >= 1, got {shape}")
    tracker = KLTTracker(cfg)
    steps = [tracker.step(image) for image in frames.images]
    tracks, _ = tracks_from_steps(steps, frames.size_hw)
    logger.debug(
        "KLT: %d tracks, %d visible in all %d frames",
        tracks.num_tracks,
        int(tracks.visible.all(axis=1).sum()),
        tracks.num_frames,
    )
    return tracks
