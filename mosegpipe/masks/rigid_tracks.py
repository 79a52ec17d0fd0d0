"""Tracks of the static world whatever its depth: one camera's 3D motion explains them over a long span.

Near static structure in front of a translating camera (a wall, rocks, foliage) moves against the camera's
homography as much as a mover does, and over a 5-frame window a mover the camera follows also lies on the
epipolar lines of everything else and keeps one projective depth (its speed is steady over so few frames). Over
a longer span it does not: a walker's or a rider's speed changes, and its depth along the epipolar lines stops
being one. Here, in whole videos, the tracks of the newest frame `r` are followed back through the frames
before (the window's and the earlier windows', `TrackHistory`), and per partner frame u (`r - gap` for each of
`RigidTracksConfig.gaps`):

1. the camera's motion from r to u is fitted to **all** the tracks seen in both (MAGSAC++, `group.twoview`): a
   fundamental matrix and a homography, and the plane + parallax form of the two (the compatible homography,
   the epipole);
2. the world's own depth gates it: the share of the tracks labelled the world that the fundamental matrix holds
   and the homography does not must reach `world_depth` at the longest gap; a world without depth (a distant
   or planar scene, a rotating camera) leaves F free to take in a mover along its epipolar lines, and nothing
   is judged;
3. each track gets one projective depth g for all its partner frames (least squares, one scale per frame,
   `twoview.depth_scale`); it is the static world's when its parallax stays within `residual_px` (per 4
   frames of gap) of g in every partner frame and g is not beyond the world's farthest depth (a depth no
   static point can have).

Only tracks seen at the longest gap count as known: over short spans the test cannot tell a followed mover.
`static_held` then keeps with the world every moving region that such tracks hold. Measured in
docs/RESULTS.md ("Which pixels move: the camera's 3D motion").
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from mosegpipe.colours import WORLD
from mosegpipe.configs.masks import RigidTracksConfig
from mosegpipe.group import twoview
from mosegpipe.masks.labels import without_held_regions

Seen = tuple[npt.NDArray[np.int64], npt.NDArray[np.float32]]
"""One frame's tracks: (M,) int64 ids and (M, 2) float32 positions, pixels."""


class TrackHistory:
    """The tracks of a video's last frames (ids and positions per frame index), for spans longer than a window."""

    def __init__(self, frames: int) -> None:
        self.frames: deque[tuple[int, Seen]] = deque(maxlen=max(1, frames))

    def reset(self) -> None:
        self.frames.clear()

    def add(self, index: int, seen: Seen) -> None:
        """Frame `index`'s tracks (a frame already held is not added twice)."""
        if self.frames and index <= self.frames[-1][0]:
            return
        self.frames.append((index, seen))

    def at(self, index: int) -> Seen | None:
        for i, seen in self.frames:
            if i == index:
                return seen
        return None


@dataclass(frozen=True)
class WindowTracks:
    """A whole video's window as the long-span test takes it: its frames' indices in the video, per frame its
    tracks (ids, positions), the last frame's tracks' labels, and the ids of the labelled tracks of the window
    (those of the clustering, in its order)."""

    indices: Sequence[int]
    seen: Sequence[Seen]
    last_labels: npt.NDArray[np.int64]
    clustered: npt.NDArray[np.int64]


@dataclass(frozen=True)
class RigidTracks:
    """The verdict on one frame's tracks: ids (M,) int64, known (M,) bool (seen at the longest gap and judged),
    static (M,) bool (known and explained by the camera's 3D motion)."""

    ids: npt.NDArray[np.int64]
    known: npt.NDArray[np.bool_]
    static: npt.NDArray[np.bool_]

    def of(self, ids: npt.NDArray[np.int64]) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.bool_]]:
        """(known, static) of the tracks `ids` (unknown where this verdict has no such track)."""
        known, static = np.zeros(ids.shape, bool), np.zeros(ids.shape, bool)
        _, here, there = np.intersect1d(ids, self.ids, assume_unique=True, return_indices=True)
        known[here], static[here] = self.known[there], self.static[there]
        return known, static


def _positions(ids: npt.NDArray[np.int64], seen: Seen) -> npt.NDArray[np.float64]:
    """(N, 2) positions of `ids` in one frame, NaN where the frame has no such track."""
    out = np.full((ids.size, 2), np.nan)
    _, here, there = np.intersect1d(ids, seen[0], assume_unique=True, return_indices=True)
    out[here] = seen[1][there]
    return out


def judge(
    ref: Seen,
    partners: Sequence[npt.NDArray[np.float64]],
    gaps: Sequence[int],
    world: npt.NDArray[np.bool_],
    cfg: RigidTracksConfig,
) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.bool_]]:
    """(known, static) per track of the reference frame (steps 1-3 of the module docstring).

    Args:
        ref: the reference frame's tracks (ids, (N, 2) positions).
        partners: per partner frame, (N, 2) float64 positions of the same tracks there (NaN where absent),
            the longest gap last.
        gaps: the partners' frame gaps.
        world: (N,) bool the tracks labelled the world.
        cfg: the test's settings.
    """
    n = ref[0].size
    known, static = np.zeros(n, bool), np.zeros(n, bool)
    p = np.asarray(ref[1], np.float64)
    fits = []
    for q, gap in zip(partners, gaps):
        both = ~np.isnan(q[:, 0])
        if both.sum() < max(cfg.min_tracks, twoview.MIN_FUNDAMENTAL):
            return known, static
        px = cfg.residual_px * max(1.0, gap / 4.0) ** 0.5
        fun, f_in = twoview.fit_with_inliers("fundamental", p[both], q[both], px)
        if fun is None:
            return known, static
        f_all = np.zeros(n, bool)
        f_all[both] = f_in
        fits.append((q, both, px, fun, f_all))
    # the reference plane: the longest gap's homography, the same tracks for every partner (one plane, one depth)
    q, both, px, fun, inliers_far = fits[-1]
    hom, h_in = twoview.fit_with_inliers("homography", p[both], q[both], 2.0 * px)
    if hom is None:
        return known, static
    on_plane = np.zeros(n, bool)
    on_plane[both] = h_in
    depth_share = float((inliers_far & ~on_plane)[world & both].mean()) if (world & both).any() else 0.0
    if depth_share < cfg.world_depth:
        return known, static
    par, bas, seen, tol = [], [], [], []
    for q, both, px, fun, f_all in fits:
        use = on_plane & f_all & both
        if use.sum() < 4:
            return known, static
        plane = twoview.compatible_homography(fun, hom, p[use], q[use])
        mapped, basis = twoview.parallax_basis(plane, twoview.epipole(fun), p)
        # a track absent from a partner frame: no parallax and no direction there, so that frame says nothing
        par.append(np.where(both[:, None], np.nan_to_num(q) - mapped, 0.0))
        bas.append(np.where(both[:, None], basis, 0.0))
        seen.append(both)
        tol.append(px)
    # one scale per frame against the longest gap's depths (its F's inliers)
    far = len(par) - 1
    v2 = np.maximum(np.sum(bas[far] ** 2, axis=1), 1e-12)
    g_far = np.sum(par[far] * bas[far], axis=1) / v2
    scales = []
    for u in range(len(par)):
        use = inliers_far & seen[u]
        scales.append(1.0 if u == far else twoview.depth_scale(par[u][use], bas[u][use], g_far[use]))
    g, _ = twoview.shared_depth_residual(par, bas, scales)
    within = np.ones(n, bool)
    for c, r, v, px in zip(scales, par, bas, tol):
        within &= np.linalg.norm(r - (g * c)[:, None] * v, axis=1) <= px
    # not beyond the world's farthest depth
    sign = twoview.near_sign(g[inliers_far])
    farthest = twoview.farthest_depth(sign * g[world & inliers_far & within])
    known = seen[far].copy()
    static = known & within & (sign * g >= farthest)
    return known, static


def rigid_tracks(
    history: TrackHistory, ref_index: int, labels: npt.NDArray[np.int64], cfg: RigidTracksConfig
) -> RigidTracks | None:
    """The verdict on frame `ref_index`'s tracks (in `history`, as are the partner frames), or None where the
    history is too short or the test could not be made; `labels` (the frame's tracks' labels, WORLD = the
    world) say which are the world's."""
    ref = history.at(ref_index)
    gaps = list(cfg.gaps)
    if ref is None or ref[0].size == 0:
        return None
    partners = []
    for gap in gaps:
        seen = history.at(ref_index - gap)
        if seen is None:
            return None
        partners.append(_positions(ref[0], seen))
    known, static = judge(ref, partners, gaps, labels == WORLD, cfg)
    if not known.any():
        return None
    return RigidTracks(ref[0], known, static)


def static_held(
    moving: npt.NDArray[np.bool_],
    xy: npt.NDArray[np.float32],
    known: npt.NDArray[np.bool_],
    static: npt.NDArray[np.bool_],
    share: float,
    min_tracks: int,
) -> npt.NDArray[np.bool_]:
    """`moving` without its connected regions in which at least `min_tracks` known tracks lie and `share` of
    them are the static world's (`judge`)."""
    h, w = moving.shape
    ij = np.round(np.asarray(xy, np.float64)).astype(np.int64)
    ok = known & (ij[:, 0] >= 0) & (ij[:, 0] < w) & (ij[:, 1] >= 0) & (ij[:, 1] < h)
    if ok.sum() < min_tracks or not moving.any():
        return moving
    ij = ij[ok]
    on = moving[ij[:, 1], ij[:, 0]]
    if on.sum() < min_tracks:
        return moving
    return without_held_regions(moving, ij[on], static[ok][on], share, min_tracks)
