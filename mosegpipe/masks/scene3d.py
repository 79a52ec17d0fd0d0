"""The static world of any depth: every pixel judged against the camera's 3D motion over the window.

The camera residual (`mosegpipe.points.flow`) measures each pixel's flow against one homography: right for a
rotating or zooming camera and a distant or planar scene, wrong for near structure in front of a
translating camera (a wall, rocks, foliage), whose parallax it calls motion. Here, per frame t of a
window, the camera's motion to the window's farthest frames is estimated from all the window's tracks
(not only those already called the world), with depth: a fundamental matrix by MAGSAC++, chosen over a
homography by GRIC (`mosegpipe.group.twoview`) so that planar, distant and still scenes keep the homography's
residual. Where F is chosen, each pixel's flow chained to those frames is judged by plane + parallax:
its parallax must lie along its epipolar lines and keep one projective depth in every frame
(`twoview.shared_depth_residual`); that residual, per frame of gap, replaces the camera residual where
it is smaller.

Which consensus is the world still needs the world's evidence (`mosegpipe.group.world`): a frame is judged
only where most of the tracks labelled world are the fundamental matrix's inliers, and a pixel whose depth
lies beyond the farthest world track's is not explained. A mover that the camera follows moves along its
epipolar lines and keeps one depth too (to this geometry it is near structure): `WorldConfig.rigid_scene_region`
says which pixels may be explained ("world": those whose nearest labelled track is the world's, so that the
embedding's separation of a mover stands). Measured on the DAVIS dev clips in docs/RESULTS.md ("Which pixels
move: the camera's 3D motion"); off by default.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe.colours import WORLD
from mosegpipe.configs.grouping import WorldConfig
from mosegpipe.group import twoview
from mosegpipe.points.flow import FrameMotion


@dataclass(frozen=True)
class _View:
    """The camera's motion from the reference frame to one partner frame, from the tracks."""

    gap: int
    plane: npt.NDArray[np.float64]  # (3, 3) compatible homography
    epipole: npt.NDArray[np.float64]  # (3,)
    inliers: npt.NDArray[np.bool_]  # (N,) the fundamental matrix's inliers among the tracks
    prefers_f: bool


def partners(t: int, num: int) -> list[int]:
    """The frames frame t of a window of `num` frames is judged against: the farthest, and the farthest
    on the other side (or, with none there, the frame half way to the farthest); one when num <= 2."""
    far = 0 if t >= num - 1 - t else num - 1
    other = num - 1 if far == 0 else 0
    second = other if other != t else (t + far) // 2
    return [far] if second in (t, far) else [far, second]


def _view(
    p: npt.NDArray[np.float64], q: npt.NDArray[np.float64], gap: int, cfg: WorldConfig, fit: npt.NDArray[np.bool_]
) -> _View | None:
    """The view from p to q with F and H fitted to and gated on the tracks `fit`; its inliers among all tracks."""
    every_p, every_q = p, q
    p, q = p[fit], q[fit]
    fun, f_in = twoview.fit_with_inliers("fundamental", p, q, cfg.rigid_scene_px)
    hom, h_in = twoview.fit_with_inliers("homography", p, q, 2.0 * cfg.rigid_scene_px)
    if fun is None or hom is None or h_in.sum() < 8:
        return None
    samp, transfer = twoview.sampson_px(fun, p, q), twoview.transfer_px(hom, p, q)
    if cfg.rigid_scene_gate == "gric":
        sigma = cfg.rigid_scene_px / 2
        prefers_f = twoview.gric(np.square(samp), sigma, 3, 7) < twoview.gric(np.square(transfer), sigma, 2, 8)
    else:  # "parallax": a share of the tracks that F holds and H does not
        prefers_f = bool(np.mean(f_in & ~h_in) >= cfg.rigid_scene_parallax and f_in.sum() >= h_in.sum())
    plane = twoview.compatible_homography(fun, hom, p[h_in & f_in], q[h_in & f_in])
    inliers = f_in if fit.all() else twoview.sampson_px(fun, every_p, every_q) <= cfg.rigid_scene_px
    return _View(gap, plane, twoview.epipole(fun), inliers, prefers_f)


def world_depth_share(p: npt.NDArray[np.float64], q: npt.NDArray[np.float64], cfg: WorldConfig) -> float:
    """The share of the world's tracks p -> q that their own fundamental matrix holds and their own homography
    does not (0 without both fits): the world's own parallax. A world with none (a distant or planar scene, a
    rotating camera) leaves F free to take in any one mover along its epipolar lines."""
    fun, f_in = twoview.fit_with_inliers("fundamental", p, q, cfg.rigid_scene_px)
    hom, h_in = twoview.fit_with_inliers("homography", p, q, 2.0 * cfg.rigid_scene_px)
    if fun is None or hom is None:
        return 0.0
    return float(np.mean(f_in & ~h_in))


def _chained(
    flows: tuple[list[npt.NDArray[np.float32]], list[npt.NDArray[np.float32]]],
    t: int,
    u: int,
    grid: npt.NDArray[np.float32],
) -> npt.NDArray[np.float32]:
    """(h, w, 2) float32: where each judged pixel of frame t goes in frame u along the window's flows (forward,
    backward; at the judging scale, in its pixels); `grid` is every judged pixel's own position."""
    at = grid.copy()
    forward, backward = flows
    for s in range(t, u) if u > t else range(t - 1, u - 1, -1):
        at += cv2.remap(
            forward[s] if u > t else backward[s], at, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
        )
    return at


def _world_side(
    xy: npt.NDArray[np.float32], labels: npt.NDArray[np.int64], hw: tuple[int, int], to_judge: float
) -> npt.NDArray[np.bool_]:
    """(h, w) bool at the judging scale: the pixels whose nearest labelled track is the world's."""
    return _nearest_side(xy, labels == WORLD, hw, to_judge)


def _nearest_side(
    xy: npt.NDArray[np.float32], side: npt.NDArray[np.bool_], hw: tuple[int, int], to_judge: float
) -> npt.NDArray[np.bool_]:
    """(h, w) bool at the judging scale: the pixels whose nearest track (of `xy`) is one of `side`'s."""
    h, w = hw
    seeds = np.zeros((h, w), np.uint8)
    pts = np.clip(np.round(xy * to_judge).astype(np.int64), 0, [w - 1, h - 1])
    seeds[pts[:, 1], pts[:, 0]] = np.where(side, 1, 2).astype(np.uint8)
    _, nearest = cv2.distanceTransformWithLabels(
        (seeds == 0).astype(np.uint8), cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL
    )
    owner = np.zeros(int(nearest.max()) + 1, np.uint8)
    ys, xs = np.nonzero(seeds)
    owner[nearest[ys, xs]] = seeds[ys, xs]
    held: npt.NDArray[np.bool_] = owner[nearest] == 1
    return held


def rigid_residual(
    motion: FrameMotion,
    xy: npt.NDArray[np.float32],
    labels: npt.NDArray[np.int64],
    t: int,
    cfg: WorldConfig = WorldConfig(),
    flows: tuple[list[npt.NDArray[np.float32]], list[npt.NDArray[np.float32]]] | None = None,
    long_span: tuple[npt.NDArray[np.bool_], npt.NDArray[np.bool_]] | None = None,
) -> npt.NDArray[np.float32] | None:
    """Frame t's residual to the camera's 3D motion, per frame of gap (full-resolution pixels, at the flow's
    scale), or None where a homography suffices or the world's tracks are not the 3D motion's consensus.

    Args:
        motion: the window's FrameMotion (forward and backward flows kept).
        xy: (N, T, 2) float32 the window's labelled tracks, full-resolution pixels.
        labels: (N,) int64 their motions (WORLD = the world).
        t: the frame.
        cfg: rigid_scene_px, rigid_scene_world, rigid_scene_scale, rigid_scene_region.
        flows: the window's forward and backward flows at the judging scale, in its pixels (None = made here).
        long_span: (known, static) per track from the long-span test (`mosegpipe.masks.rigid_tracks`): a pixel whose
            nearest known track is not the static world's is not explained (None = no such guard).
    """
    num, h, w = motion.residual.shape
    world = labels == WORLD
    pts = xy.astype(np.float64)
    others = partners(t, num)
    fit = world if cfg.rigid_scene_fit == "world" else np.ones(len(labels), bool)
    views = [_view(pts[:, t], pts[:, u], abs(u - t), cfg, fit) for u in others]
    if not views or any(v is None for v in views):
        return None
    chosen = [v for v in views if v is not None]
    far = chosen[0]
    if not far.prefers_f or far.inliers[world].mean() < cfg.rigid_scene_world:
        return None
    if cfg.rigid_scene_world_depth > 0 and world_depth_share(pts[world, t], pts[world, others[0]], cfg) < (
        cfg.rigid_scene_world_depth
    ):
        return None  # the world's own tracks show no depth: F would be fitted to a mover
    scales, sign, farthest = _track_depths(pts, t, others, chosen, world)
    # every pixel, at the judging scale
    js = cfg.rigid_scene_scale
    jh, jw = max(1, round(h * js)), max(1, round(w * js))
    flows = flows or judging_flows(motion, (jh, jw), js)
    ys, xs = np.mgrid[0:jh, 0:jw].astype(np.float32)
    grid = np.stack([xs, ys], axis=-1)
    to_full = 1.0 / (motion.scale * js)
    p = grid.reshape(-1, 2).astype(np.float64) * to_full
    dense_par, dense_bas = [], []
    far_at: list[npt.NDArray[np.float64]] = []  # where the pixels go in the farthest frame
    for u, v in zip(others, chosen):
        at = _chained(flows, t, u, grid).reshape(-1, 2).astype(np.float64) * to_full
        far_at = far_at or [at]
        mapped, basis = twoview.parallax_basis(v.plane, v.epipole, p)
        dense_par.append(at - mapped)
        dense_bas.append(basis)
    g, res = twoview.shared_depth_residual(dense_par, dense_bas, scales)
    res = res / far.gap
    res[sign * g < farthest] = np.inf  # beyond the world's farthest depth: not explained (a followed mover)
    if cfg.rigid_scene_region == "world":
        res[~_world_side(xy[:, t], labels, (jh, jw), motion.scale * js).ravel()] = np.inf
    elif cfg.rigid_scene_region == "faster":
        # nearer static structure sweeps past at least as fast as the world; a mover the camera follows lags
        world_step = float(np.median(np.linalg.norm(pts[world, others[0]] - pts[world, t], axis=1)))
        res[np.linalg.norm(far_at[0] - p, axis=1) < world_step] = np.inf
    if long_span is not None:
        known, still = long_span
        if known.any():
            moves = ~_nearest_side(xy[known, t], still[known], (jh, jw), motion.scale * js)
            res[moves.ravel()] = np.inf
    small = (res * motion.scale).reshape(jh, jw).astype(np.float32)
    out: npt.NDArray[np.float32] = cv2.resize(np.minimum(small, 1e6), (w, h), interpolation=cv2.INTER_LINEAR)
    return out


def _track_depths(
    pts: npt.NDArray[np.float64], t: int, others: list[int], chosen: list[_View], world: npt.NDArray[np.bool_]
) -> tuple[list[float], float, float]:
    """The tracks' depths from frame t to its partners: the partners' depth scales c_u (the first 1), the sign of
    the near side, and the world's farthest depth (its 2nd percentile less a tenth of its spread; farther is not
    the world's)."""
    far = chosen[0]
    par, bas = [], []
    for u, v in zip(others, chosen):
        mapped, basis = twoview.parallax_basis(v.plane, v.epipole, pts[:, t])
        par.append(pts[:, u] - mapped)
        bas.append(basis)
    ref = np.sum(par[0] * bas[0], axis=1) / np.maximum(np.sum(bas[0] ** 2, axis=1), 1e-12)
    scales = [1.0] + [
        twoview.depth_scale(r[far.inliers], b[far.inliers], ref[far.inliers]) for r, b in zip(par[1:], bas[1:])
    ]
    depth, _ = twoview.shared_depth_residual(par, bas, scales)
    sign = twoview.near_sign(depth[far.inliers])
    return scales, sign, twoview.farthest_depth(sign * depth[world & far.inliers])


def judging_flows(
    motion: FrameMotion, hw: tuple[int, int], scale: float
) -> tuple[list[npt.NDArray[np.float32]], list[npt.NDArray[np.float32]]]:
    """The window's forward and backward flows resized to (h, w) = `scale` of the flow's, in those pixels."""
    assert motion.forward is not None and motion.backward is not None

    def small(flow: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
        out: npt.NDArray[np.float32] = cv2.resize(flow, (hw[1], hw[0]), interpolation=cv2.INTER_AREA) * np.float32(
            scale
        )
        return out

    return [small(f) for f in motion.forward], [small(f) for f in motion.backward]


def explain_rigid_scene(
    motion: FrameMotion,
    xy: npt.NDArray[np.float32],
    labels: npt.NDArray[np.int64],
    cfg: WorldConfig = WorldConfig(),
    long_span: tuple[npt.NDArray[np.bool_], npt.NDArray[np.bool_]] | None = None,
) -> FrameMotion:
    """`motion` with each frame's camera residual the smaller of it and the residual to the camera's 3D
    motion (`rigid_residual`) where that motion needs depth (cfg.rigid_scene; the module's docstring).

    Args:
        motion: the window's FrameMotion (forward and backward flows kept).
        xy: (N, T, 2) float32 positions of the window's labelled tracks, pixels.
        labels: (N,) int64 their motions (WORLD = the world; -1 ignored).
        cfg: the rigid_scene settings.
        long_span: (known, static) per track of the long-span test, a guard (`rigid_residual`); None = none.

    Returns:
        A FrameMotion with a new residual (the same object when nothing changes).
    """
    num = motion.residual.shape[0]
    keep = labels >= 0
    if not cfg.rigid_scene or motion.forward is None or motion.backward is None or num < 2:
        return motion
    if keep.sum() < max(cfg.parallax_min_points, 8) or (labels[keep] == WORLD).sum() < 8:
        return motion
    xy, labels = xy[keep], labels[keep]
    if long_span is not None:
        long_span = (long_span[0][keep], long_span[1][keep])
    residual = motion.residual
    h, w = residual.shape[1:]
    js = cfg.rigid_scene_scale
    flows = judging_flows(motion, (max(1, round(h * js)), max(1, round(w * js))), js)
    for t in range(num):
        rigid = rigid_residual(motion, xy, labels, t, cfg, flows, long_span)
        if rigid is None:
            continue
        if residual is motion.residual:
            residual = residual.copy()
        np.minimum(residual[t], rigid, out=residual[t])
    if residual is motion.residual:
        return motion
    return FrameMotion(residual, motion.fb_error, motion.scale, motion.forward, motion.backward)
