"""Which motion is the world: the camera's motion, the static scene of any depth, written as label 0.

A clustering numbers its motions by size (0 = most tracks), but tracks crowd on textured objects: a
close-up rider can carry more corners than the whole street behind him. Counting tracks then hands the
world a moving label and the rider the world's, and the masks paint the background. The world is told
here by where its tracks are, not how many there are:

- **area**: the frame is cut into a grid of cells; in each of the window's frames each cell goes to the
  motion of the track nearest its centre, and a motion scores the cells it holds. The world spans the
  frame, its weakly textured parts included (they go to the world's tracks around them); an object,
  however textured, holds about the cells it covers.
- **border**: a cell on the frame's border counts `WorldConfig.border_weight` more: the world meets the
  image border all round, an object at most on a side or two.
- **the camera** (where the dense flow is known): the share of a motion's tracks, over the window's
  frames, that lie where the camera's motion (the homography fitted to the whole flow field,
  `flow.fit_camera`) explains the flow: near 1 for the world, near 0 for a mover. A motion's area
  is weighted by `static_floor` + that share.
- **continuity** (whole videos): a motion whose tracks were the world in the window before keeps that
  role unless the area says clearly otherwise (its score is multiplied by `1 + continuity` times the
  share of its shared tracks that were the world), so an object that fills the frame for a while does
  not take the world's label.

`world_first` then renumbers the motions so that the world is 0, the others keeping their order.
"""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe.colours import WORLD
from mosegpipe.configs.grouping import WorldConfig
from mosegpipe.group.twoview import gric, robust_fit, sampson_sq, transfer_sq
from mosegpipe.points.flow import FrameMotion


def world_scores(
    xy: npt.NDArray[np.float32],
    labels: npt.NDArray[np.int64],
    k: int,
    size_hw: tuple[int, int],
    was_world: npt.NDArray[np.bool_] | None = None,
    known: npt.NDArray[np.bool_] | None = None,
    cfg: WorldConfig = WorldConfig(),
    static: npt.NDArray[np.float64] | None = None,
) -> npt.NDArray[np.float64]:
    """Each motion's evidence of being the world (see the module's docstring).

    Args:
        xy: (N, T, 2) float32 positions of the labelled tracks over the window's frames, pixels
            (or (N, 2) for one frame).
        labels: (N,) int64 their motions in 0..k-1 (-1 = none, ignored).
        k: number of motions.
        size_hw: (H, W) of the frames, pixels.
        was_world: (N,) bool, whole videos: the tracks that were the world in the window before.
        known: (N,) bool, whole videos: the tracks that had any label in the window before
            (None = as `was_world` is not None, every track).
        cfg: grid, border weight, continuity, static floor.
        static: (N,) float in [0, 1], each track's share of the window's frames on pixels whose flow the
            camera's motion explains (`static_share`; None = no flow evidence).

    Returns:
        (k,) float64 scores, larger = more likely the world.
    """
    labels = np.asarray(labels, np.int64).reshape(-1)
    pts = np.asarray(xy, np.float32).reshape(labels.size, -1, 2)
    height, width = size_hw
    g = cfg.grid
    # cell centres, and the weight of each: border cells count more
    cy, cx = np.mgrid[0:g, 0:g]
    centres = np.stack([(cx.ravel() + 0.5) * width / g, (cy.ravel() + 0.5) * height / g], axis=1)
    border = (cy == 0) | (cy == g - 1) | (cx == 0) | (cx == g - 1)
    weight = np.where(border.ravel(), 1.0 + cfg.border_weight, 1.0)
    use = labels >= 0
    scores = np.zeros(k, np.float64)
    if use.any() and k > 0:
        from scipy.spatial import cKDTree  # on first use: see runtime.import_ahead

        for t in range(pts.shape[1]):  # each frame's cells go to the motion of their nearest track
            _, nearest = cKDTree(pts[use, t]).query(centres)
            scores += np.bincount(labels[use][nearest], weights=weight, minlength=k)[:k]
    if static is not None and use.any():
        sizes = np.bincount(labels[use], minlength=k)[:k]
        on = np.bincount(labels[use], weights=np.asarray(static, np.float64).reshape(-1)[use], minlength=k)[:k]
        scores = scores * (cfg.static_floor + np.divide(on, sizes, out=np.zeros(k), where=sizes > 0))
    if was_world is not None and cfg.continuity > 0:
        was = np.asarray(was_world, bool).reshape(-1)
        had = np.ones_like(was) if known is None else np.asarray(known, bool).reshape(-1)
        shared = np.bincount(labels[use & had], minlength=k)[:k]
        world = np.bincount(labels[use & had & was], minlength=k)[:k]
        if shared.sum() > 0:
            share = np.divide(world, shared, out=np.zeros(k), where=shared > 0)
            scores = scores * (1.0 + cfg.continuity * share)
    return scores


def world_cluster(scores: npt.NDArray[np.float64], cfg: WorldConfig = WorldConfig()) -> int:
    """The motion that is the world: the best of `world_scores` (ties go to the lower id, the larger motion);
    0 when there is one motion or cfg.enabled is False."""
    if scores.size <= 1 or not cfg.enabled:
        return 0
    return int(np.argmax(scores))


def static_share(
    xy: npt.NDArray[np.float32], residual: npt.NDArray[np.float32], scale: float, static_px: float
) -> npt.NDArray[np.float64]:
    """Each track's share of frames in which it lies where the camera's motion explains the flow.

    Args:
        xy: (N, T, 2) float32 track positions, pixels of the frame.
        residual: (T, h, w) float32 camera residual at the flow's scale (`flow.FrameMotion.residual`).
        scale: the flow's scale (h / H).
        static_px: the largest residual that counts as explained, pixels of the frame.

    Returns:
        (N,) float64 in [0, 1].
    """
    pts = np.asarray(xy, np.float32)
    num_frames, h, w = residual.shape
    x = np.clip(np.round(pts[:, :num_frames, 0] * scale).astype(np.int64), 0, w - 1)
    y = np.clip(np.round(pts[:, :num_frames, 1] * scale).astype(np.int64), 0, h - 1)
    miss = residual[np.arange(x.shape[1])[None, :], y, x]  # (N, T)
    return np.mean(miss <= static_px * scale, axis=1).astype(np.float64)


def world_first(labels: npt.NDArray[np.int64], world: int) -> npt.NDArray[np.int64]:
    """`labels` renumbered so that motion `world` is 0 and the motions before it move up one (-1 stays).

    Args:
        labels: (N,) int64 motions (-1 = none).
        world: the world's motion.

    Returns:
        (N,) int64: a new array (the input itself when `world` is already 0).
    """
    labels = np.asarray(labels, np.int64)
    if world == 0:
        return labels
    out = labels.copy()
    out[(labels >= 0) & (labels < world)] += 1
    out[labels == world] = 0
    return out


def world_epipolar(
    p: npt.NDArray[np.float32], q: npt.NDArray[np.float32], cfg: WorldConfig = WorldConfig()
) -> npt.NDArray[np.float64] | None:
    """The fundamental matrix of the world's correspondences p -> q when the scene needs one (parallax).

    A homography and a fundamental matrix are fitted by RANSAC and compared by GRIC (`twoview.gric`): a planar or
    distant scene, or a camera that only rotates, keeps the homography (None); a scene whose depth makes the
    world's points move differently (near walls, rocks, poles) takes the fundamental matrix.

    Args:
        p, q: (n, 2) float32 the world's track positions in two frames, pixels.
        cfg: parallax_sigma_px (the tracks' noise) and parallax_min_points.

    Returns:
        (3, 3) float64 fundamental matrix (q^T F p = 0), or None.
    """
    if len(p) < max(cfg.parallax_min_points, 8):
        return None
    a, b = np.asarray(p, np.float64), np.asarray(q, np.float64)
    hom, _ = robust_fit("homography", a, b, "ransac", 3.0 * cfg.parallax_sigma_px)
    fm, _ = robust_fit("fundamental", a, b, "ransac", 1.5 * cfg.parallax_sigma_px, confidence=0.999)
    if fm is None:
        return None
    if hom is None:
        return fm
    h_err = transfer_sq(hom, a, b)
    if gric(sampson_sq(fm, a, b), cfg.parallax_sigma_px, 3, 7) < gric(h_err, cfg.parallax_sigma_px, 2, 8):
        return fm
    return None


def epipolar_residual(
    flow: npt.NDArray[np.float32], fm: npt.NDArray[np.float64], scale: float
) -> npt.NDArray[np.float32]:
    """(h, w) float32 Sampson distance of each pixel's flow to the fundamental matrix, pixels at the flow's scale.

    Args:
        flow: (h, w, 2) float32 displacements at the flow's scale.
        fm: (3, 3) fundamental matrix in pixels of the frame.
        scale: the flow's scale (h / H).
    """
    h, w = flow.shape[:2]
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    p = np.stack([xs.ravel(), ys.ravel()], axis=1) / scale
    q = p + flow.reshape(-1, 2).astype(np.float64) / scale
    return (np.sqrt(sampson_sq(fm, p, q)) * scale).reshape(h, w).astype(np.float32)


def explain_parallax(
    motion: FrameMotion,
    xy: npt.NDArray[np.float32],
    labels: npt.NDArray[np.int64],
    cfg: WorldConfig = WorldConfig(),
) -> FrameMotion:
    """`motion` with the world's 3D structure explained: where the pixel's nearest labelled track is the
    world's and the world's tracks need a fundamental matrix (`world_epipolar`), the camera residual becomes
    the smaller of it and the flow's distance to the world's epipolar line (`epipolar_residual`).

    A mover whose own tracks surround it keeps the homography's residual: the epipolar test's blind spot
    (an object moving along its epipolar line, as one followed by a camera moving parallel to it) is left
    to the tracks' clustering.

    Args:
        motion: the window's FrameMotion (forward and backward flows kept).
        xy: (N, T, 2) float32 positions of the window's labelled tracks, pixels.
        labels: (N,) int64 their motions (WORLD = the world; -1 ignored).
        cfg: parallax settings.

    Returns:
        A FrameMotion with a new residual (the same object when nothing changes).
    """
    if not cfg.parallax or motion.forward is None or motion.backward is None:
        return motion
    num = motion.residual.shape[0]
    world = labels == WORLD
    if world.sum() < cfg.parallax_min_points or num < 2:
        return motion
    residual = motion.residual.copy()
    h, w = residual.shape[1:]
    known = labels >= 0
    changed = False
    for t in range(num):
        other = t + 1 if t + 1 < num else t - 1
        fm = world_epipolar(xy[world, t], xy[world, other], cfg)
        if fm is None:
            continue
        flow = motion.forward[t] if other > t else motion.backward[t - 1]
        epi = epipolar_residual(flow, fm, motion.scale)
        # the pixels whose nearest labelled track is the world's
        seeds = np.zeros((h, w), np.uint8)
        pts = np.clip(np.round(xy[known, t] * motion.scale).astype(np.int64), 0, [w - 1, h - 1])
        seeds[pts[:, 1], pts[:, 0]] = np.where(labels[known] == WORLD, 1, 2).astype(np.uint8)
        _, nearest = cv2.distanceTransformWithLabels(
            (seeds == 0).astype(np.uint8), cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL
        )
        owner = np.zeros(int(nearest.max()) + 1, np.uint8)
        ys, xs = np.nonzero(seeds)
        owner[nearest[ys, xs]] = seeds[ys, xs]
        region = owner[nearest] == 1
        residual[t] = np.where(region, np.minimum(residual[t], epi), residual[t])
        changed = True
    if not changed:
        return motion
    return FrameMotion(residual, motion.fb_error, motion.scale, motion.forward, motion.backward)
