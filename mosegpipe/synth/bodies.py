"""The 3-D scene of a synthetic clip (mosegpipe.synth.trajectories): the background's and the objects'
points and motions (Body, BodyWorld), which points an object hides, and outlier tracks."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from mosegpipe.synth.camera import (
    PinholeCamera,
    axis_angle_matrix,
    random_sign,
    random_unit,
    rotation_matrices,
)


def log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def background_points(
    rng: np.random.Generator, cam: PinholeCamera, n: int, driving: bool, depth_m: float, ground_m: float
) -> tuple[npt.NDArray[np.float64], str]:
    """World points (n, 3) of the static scene, all visible in frame 0, and the scene kind.

    ground_m is the camera height above the road in driving scenes.
    """
    uv = rng.uniform([0.0, 0.0], [cam.w - 1.0, cam.h - 1.0], (n, 2))
    r = cam.rays(uv)
    if driving:
        kind = "road"
        half_width = rng.uniform(4.0, 12.0)  # distance to walls / parked cars / buildings
        far = rng.uniform(40.0, 100.0)
        with np.errstate(divide="ignore"):
            road = np.where(r[:, 1] > 0, ground_m / r[:, 1], np.inf)
            wall = half_width / np.abs(r[:, 0])
        depth = np.minimum(np.minimum(road, wall), far)
        clutter = rng.random(n) < 0.25  # poles, trees, parked cars in front of the walls
        depth = np.where(clutter, depth * rng.uniform(0.3, 1.0, n), depth)
    elif rng.random() < 0.3:
        kind = "plane"
        tilt = rng.uniform(0.0, 50.0) * math.pi / 180.0
        axis = np.array([*rng.normal(size=2), 0.0])
        normal = axis_angle_matrix(axis / np.linalg.norm(axis), tilt) @ np.array([0, 0, 1.0])
        depth = depth_m / np.maximum(r @ normal, 0.1)
        depth = np.minimum(depth, 10 * depth_m) * (1.0 + rng.normal(0, 0.005, n))
    else:
        kind = "surface"
        # A smooth random depth map plus some points on nearer clutter: structured, not i.i.d.
        freq = rng.normal(0, 3.0, (4, 2)) / cam.w
        phase = rng.uniform(0, 2 * math.pi, 4)
        amp = rng.uniform(0.1, 0.5, 4)
        log_depth = np.sin(uv @ freq.T + phase) @ amp
        depth = depth_m * np.exp(log_depth)
        clutter = rng.random(n) < 0.2
        depth = np.where(clutter, depth * rng.uniform(0.4, 1.0, n), depth)
    return r * depth[:, None], kind


@dataclass
class Body:
    """One body in its own frame: world point x = centre + R(motion) @ orient @ q(local)."""

    kind: str
    local: npt.NDArray[np.float64]  # (n, 3) metres
    centre: npt.NDArray[np.float64]  # (3,)
    orient: npt.NDArray[np.float64]  # (3, 3)
    vel: npt.NDArray[np.float64]  # (3,) translation over the clip, metres, at scale 1
    acc: npt.NDArray[np.float64]  # (3,)
    spin: npt.NDArray[np.float64]  # (3,) rotation vector over the clip, radians, at scale 1
    spin_acc: npt.NDArray[np.float64]  # (3,)
    deform: npt.NDArray[np.float64]  # (n, 3) per-point deformation over the clip, at scale 1
    hinge_part: npt.NDArray[np.bool_]  # (n,) points on the hinged part
    hinge_point: npt.NDArray[np.float64]  # (3,) local
    hinge_rotvec: npt.NDArray[np.float64]  # (3,) local hinge rotation over the clip at scale 1
    target_px: float


def _shape_points(
    rng: np.random.Generator, n: int, half: npt.NDArray[np.float64], box: bool
) -> npt.NDArray[np.float64]:
    """Points (n, 3) on the surface of a box or ellipsoid with half-extents half (3,)."""
    if box:
        p = rng.uniform(-1.0, 1.0, (n, 3))
        area = np.array([half[1] * half[2], half[0] * half[2], half[0] * half[1]])
        # Pick a face per point with probability proportional to its area, put the point on it.
        axis = np.searchsorted(np.cumsum(area / area.sum())[:2], rng.random(n))
        p[np.arange(n), axis] = np.where(rng.random(n) < 0.5, -1.0, 1.0)
    else:
        p = random_unit(rng, n)
    return p * half


def object_body(
    rng: np.random.Generator,
    cam: PinholeCamera,
    n: int,
    kind: str,
    driving: bool,
    depth_m: float,
    ground_m: float,
    motion_range: tuple[float, float],
) -> Body:
    """Sample one moving object of n points placed so that its centre is in view in frame 0."""
    if driving:
        # Cars, vans, cyclists, pedestrians on the road, heading along it (either way) or crossing.
        depth = rng.uniform(5.0, 35.0)
        if kind == "rigid" or kind == "planar":
            half = rng.uniform([0.8, 0.7, 1.8], [1.0, 1.2, 3.0])
        else:
            half = rng.uniform([0.25, 0.8, 0.25], [0.5, 0.95, 0.9])
        u = rng.uniform(0.1, 0.9) * cam.w
        centre = np.array([(u - cam.cx) * depth / cam.f, ground_m - half[1], depth])
        yaw = (0.0 if rng.random() < 0.5 else math.pi) + rng.normal(0, 0.15)
        if rng.random() < 0.2:
            yaw += math.pi / 2  # crossing traffic
        orient = axis_angle_matrix(np.array([0.0, 1.0, 0.0]), yaw)
        heading = orient @ np.array([0.0, 0.0, 1.0])
        vel = heading * rng.uniform(0.3, 1.0) * 2 * half[2]
        spin = np.array([0.0, rng.normal(0, 0.05), 0.0])
    else:
        depth = rng.uniform(0.35, 0.85) * depth_m
        uv = rng.uniform([0.1 * cam.w, 0.1 * cam.h], [0.9 * cam.w, 0.9 * cam.h])
        centre = cam.rays(uv[None])[0] * depth
        footprint = log_uniform(rng, 0.04, 0.35) * cam.w  # object width on screen, pixels
        half = 0.5 * footprint * depth / cam.f * rng.uniform(0.4, 1.0, 3)
        orient = axis_angle_matrix(random_unit(rng), rng.uniform(0, math.pi))
        vel = random_unit(rng) * rng.uniform(0.3, 1.0) * 2 * half.max()
        spin = random_unit(rng) * rng.uniform(0.0, 0.3)
    if kind == "planar":
        half = half.copy()
        half[rng.integers(3)] = 0.005 * half.max()
    local = _shape_points(rng, n, half, box=kind == "planar" or rng.random() < 0.6)
    acc = vel * rng.uniform(-0.3, 0.3) + random_unit(rng) * 0.1 * math.sqrt(vel @ vel)
    spin_acc = spin * rng.uniform(-0.3, 0.3)
    deform = np.zeros((n, 3))
    hinge_part = np.zeros(n, dtype=bool)
    hinge_point = np.zeros(3)
    hinge_rotvec = np.zeros(3)
    size = float(half.max())
    if kind == "nonrigid":
        # A smooth displacement field: a few random sinusoids over the body, 5-30 % of its size.
        freq = rng.normal(0, 1.5 / size, (3, 3))
        phase = rng.uniform(0, 2 * math.pi, 3)
        amp = rng.normal(0, rng.uniform(0.05, 0.3) * size, (3, 3))
        deform = np.sin(local @ freq.T + phase) @ amp
    elif kind == "articulated":
        split = int(np.argmax(half))
        hinge_point[split] = rng.uniform(-0.3, 0.3) * half[split]
        hinge_part = local[:, split] > hinge_point[split]
        axis = np.zeros(3)
        axis[(split + rng.integers(1, 3)) % 3] = 1.0
        hinge_rotvec = axis * rng.uniform(0.3, 1.0) * random_sign(rng)
    return Body(
        kind,
        local,
        centre,
        orient,
        vel,
        acc,
        spin,
        spin_acc,
        deform,
        hinge_part,
        hinge_point,
        hinge_rotvec,
        log_uniform(rng, *motion_range),
    )


class BodyWorld:
    """All points of all bodies, vectorised; positions(scale) gives (F, N, 3) world points."""

    def __init__(self, bodies: list[Body], frames: int) -> None:
        self.frames = frames
        self.sizes = np.array([len(b.local) for b in bodies])
        self.body = np.repeat(np.arange(len(bodies)), self.sizes)
        self.local = np.concatenate([b.local for b in bodies])
        self.deform = np.concatenate([b.deform for b in bodies])
        self.hinge_part = np.concatenate([b.hinge_part for b in bodies])
        self.centre = np.stack([b.centre for b in bodies])
        self.orient = np.stack([b.orient for b in bodies])
        self.vel = np.stack([b.vel for b in bodies])
        self.acc = np.stack([b.acc for b in bodies])
        self.spin = np.stack([b.spin for b in bodies])
        self.spin_acc = np.stack([b.spin_acc for b in bodies])
        self.hinge_point = np.stack([b.hinge_point for b in bodies])
        self.hinge_rotvec = np.stack([b.hinge_rotvec for b in bodies])
        self.kinds = [b.kind for b in bodies]
        self.starts = np.concatenate([[0], np.cumsum(self.sizes)])
        self.has_hinge = any(b.kind == "articulated" for b in bodies)
        tau = np.arange(frames, dtype=np.float64) / (frames - 1)  # normalised time 0..1
        self.tau = tau[:, None, None]
        self.tau2 = (tau**2)[:, None, None]

    def positions(self, scale: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """World points (F, N, 3) with every body's motion multiplied by scale (B,)."""
        f, b = self.frames, len(scale)
        s = scale[None, :, None]
        rot = rotation_matrices((s * (self.spin * self.tau + self.spin_acc * self.tau2)).reshape(-1, 3))
        # Row-vector form: x_world = x_local @ (R(t) @ orient)^T.
        rot_t = np.transpose(rot.reshape(f, b, 3, 3) @ self.orient, (1, 0, 3, 2))  # (B, F, 3, 3)
        trans = self.centre + s * (self.vel * self.tau + self.acc * self.tau2)  # (F, B, 3)
        hinge_t = None
        if self.has_hinge:
            hinge = rotation_matrices((s * self.hinge_rotvec * self.tau).reshape(-1, 3))
            hinge_t = np.transpose(hinge.reshape(f, b, 3, 3), (1, 0, 3, 2))
        out = np.empty((f, len(self.body), 3))
        # Points are stored body by body; a batched matmul per body beats one gathered einsum.
        for i, (lo, hi) in enumerate(zip(self.starts[:-1], self.starts[1:])):
            local = np.broadcast_to(self.local[lo:hi], (f, hi - lo, 3))
            if self.kinds[i] == "nonrigid":
                local = local + scale[i] * self.tau * self.deform[lo:hi]
            elif self.kinds[i] == "articulated" and hinge_t is not None:
                pivot = self.hinge_point[i]
                bent = (local - pivot) @ hinge_t[i] + pivot
                local = np.where(self.hinge_part[lo:hi, None], bent, local)
            out[:, lo:hi] = local @ rot_t[i] + trans[:, i, None, :]
        return out


def occluded_mask(
    uv: npt.NDArray[np.float64],
    z: npt.NDArray[np.float64],
    body: npt.NDArray[np.int64],
    objects: Sequence[int],
    ok: npt.NDArray[np.bool_],
) -> npt.NDArray[np.bool_]:
    """(N,) True for points hidden behind an object in some frame.

    An object's silhouette is approximated by the ellipse of its projected points' covariance
    (for points spread over a convex outline the outline lies near Mahalanobis distance 2); points
    of other bodies inside it and farther than the object's mean depth are hidden.
    """
    obj = np.asarray(objects)
    member = (body[None, :] == obj[:, None]) & ok  # (O, N)
    n = np.maximum(member.sum(axis=1), 1)[None, :, None]  # (1, O, 1)
    w = member.astype(np.float64)
    mean = (w @ uv) / n  # (F, O, 2)
    second = w @ np.concatenate([uv * uv, uv[..., :1] * uv[..., 1:]], axis=-1) / n  # (F, O, 3)
    var_x = second[..., 0] - mean[..., 0] ** 2 + 1.0
    var_y = second[..., 1] - mean[..., 1] ** 2 + 1.0
    cov_xy = second[..., 2] - mean[..., 0] * mean[..., 1]
    det = np.maximum(var_x * var_y - cov_xy**2, 1e-9)
    depth = (w @ z[..., None])[..., 0] / n[..., 0]  # (F, O)
    ex = uv[:, None, :, 0] - mean[..., 0, None]  # (F, O, N)
    ey = uv[:, None, :, 1] - mean[..., 1, None]
    # Squared Mahalanobis distance with the closed-form 2x2 inverse.
    m2 = var_y[..., None] * ex**2 - 2 * cov_xy[..., None] * ex * ey + var_x[..., None] * ey**2
    inside = m2 < 3.0 * det[..., None]
    behind = z[:, None, :] > depth[..., None]
    hidden = inside & behind & (body[None, None, :] != obj[None, :, None])
    hidden &= (member.sum(axis=1) >= 3)[None, :, None]
    return hidden.any(axis=(0, 1))


def outlier_tracks(
    rng: np.random.Generator,
    n: int,
    frames: int,
    w: int,
    h: int,
    start: npt.NDArray[np.float64] | None,
    pair: bool,
) -> npt.NDArray[np.float64]:
    """Gross-outlier tracks (F, n, 2) inside the image.

    Pairs: independent uniform points in both images. Clips: a mix of tracks jumping to random
    places and random walks with large steps, starting at start (n, 2) when given.
    """
    hi = np.array([w - 1.0, h - 1.0])
    uv = rng.uniform(0.0, 1.0, (frames, n, 2)) * hi
    if pair:
        return uv
    if start is not None:
        uv[0] = start
    step = np.exp(rng.uniform(math.log(2.0), math.log(0.05 * w), n))[None, :, None]
    walk = uv[0] + np.concatenate([np.zeros((1, n, 2)), (rng.normal(size=(frames - 1, n, 2)) * step).cumsum(axis=0)])
    jumpy = rng.random(n) < 0.3
    uv[:, ~jumpy] = walk[:, ~jumpy]
    return np.clip(uv, 0.0, hi)
