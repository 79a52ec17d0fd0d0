"""The camera of every synthetic world: rotations, the pinhole camera, camera motions and their poses.

Both generators put a moving pinhole camera in front of moving bodies, in the same coordinates (metres;
x right, y down, z forward; frame 0's camera frame is the world frame; poses are world->camera
rotations and camera centres). Their motion vocabularies differ where the scenes do:

- rendered video (`render`, VIDEO_MOTIONS): "static", "pan" (slow yaw), "forward" (a short walk along
  the optical axis, at most 1.5 m so the camera never reaches the objects 3 m away) and "handheld";
- synthetic trajectories (`trajectories`, TRAJECTORY_MOTIONS): "driving" (KITTI-like: 0.2-1.5 m per
  frame with slow yaw, pitch and roll), "handheld", "static" and "pan".

Each pose sampler keeps its own random draws: the generated clips, and so the rendered protocol and the
training data of the shipped weights, are functions of them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe.errors import InputError

VIDEO_MOTIONS: tuple[str, ...] = ("static", "pan", "forward", "handheld")
"""Camera motions of rendered clips (render.RenderConfig.camera_motion) that the rendered protocols cycle through."""

PARALLAX_MOTIONS: tuple[str, ...] = ("truck",)
"""Camera motions with strong parallax that no protocol cycles through (so the protocols' clips stay as they
are): "truck" moves sideways 4-10 cm a frame (at most 2.5 m in all) while turning slowly back towards the
scene, as a camera following something along a wall does."""

TRAJECTORY_MOTIONS: tuple[str, ...] = ("driving", "handheld", "static", "pan")
"""Camera ego-motions of synthetic trajectories (trajectories.SyntheticConfig.camera_motions)."""

NEAR_M = 0.2
"""Depth below which synthetic trajectory points count as behind the camera, metres."""


def rotation_matrix(rotvec: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Rotation matrix (3, 3) of one rotation vector (axis * angle, radians), OpenCV's Rodrigues (the renderer's)."""
    r, _ = cv2.Rodrigues(np.asarray(rotvec, dtype=np.float64).reshape(3, 1))
    return r


def rotation_matrices(rotvec: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Rotation matrices (M, 3, 3) from rotation vectors (M, 3) (axis * angle, radians).

    A zero vector gives the identity exactly, which keeps static points exactly static.
    """
    theta = np.sqrt((rotvec * rotvec).sum(axis=-1))[:, None, None]
    k = rotvec / np.maximum(theta[:, :, 0], 1e-300)
    skew = np.zeros((len(k), 3, 3))
    skew[:, 0, 1] = -k[:, 2]
    skew[:, 0, 2] = k[:, 1]
    skew[:, 1, 0] = k[:, 2]
    skew[:, 1, 2] = -k[:, 0]
    skew[:, 2, 0] = -k[:, 1]
    skew[:, 2, 1] = k[:, 0]
    c = np.cos(theta)
    return c * np.eye(3) + np.sin(theta) * skew + (1.0 - c) * (k[:, :, None] * k[:, None, :])


def axis_angle_matrix(axis: npt.NDArray[np.float64], angle: float) -> npt.NDArray[np.float64]:
    """One rotation matrix (3, 3) about a unit axis (3,), angle in radians."""
    # Scalar Rodrigues in plain Python: a dozen NumPy calls on 3-vectors cost more than this.
    x, y, z = (float(v) for v in axis)
    c, s = math.cos(angle), math.sin(angle)
    d = 1.0 - c
    return np.array(
        [
            [c + x * x * d, x * y * d - z * s, x * z * d + y * s],
            [y * x * d + z * s, c + y * y * d, y * z * d - x * s],
            [z * x * d - y * s, z * y * d + x * s, c + z * z * d],
        ]
    )


def random_unit(rng: np.random.Generator, n: int | None = None) -> npt.NDArray[np.float64]:
    """Random unit vector(s), uniform on the sphere: (3,) or (n, 3)."""
    g = rng.normal(size=(3,) if n is None else (n, 3))
    return g / np.sqrt((g * g).sum(axis=-1, keepdims=True))


def random_sign(rng: np.random.Generator) -> float:
    """-1.0 or 1.0 with equal probability (Generator.choice is slow for this)."""
    return -1.0 if rng.random() < 0.5 else 1.0


@dataclass
class PinholeCamera:
    """Pinhole camera over F frames: x_cam = rot[t] @ (x_world - centre[t]).

    Frame 0's camera frame is the world frame (x right, y down, z forward, metres).
    """

    f: float
    cx: float
    cy: float
    h: int
    w: int
    rot: npt.NDArray[np.float64]  # (F, 3, 3) world -> camera
    centre: npt.NDArray[np.float64]  # (F, 3) camera centre in the world, metres

    def project(self, xyz: npt.NDArray[np.float64]) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """World points (F, N, 3) -> pixels (F, N, 2) and depth (F, N)."""
        cam = (xyz - self.centre[:, None, :]) @ np.transpose(self.rot, (0, 2, 1))
        z = cam[..., 2]
        scale = (self.f / np.maximum(z, NEAR_M))[..., None]
        return cam[..., :2] * scale + np.array([self.cx, self.cy]), z

    def rays(self, uv: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """Frame-0 rays (N, 3) with z = 1 through pixels (N, 2)."""
        r = np.ones((len(uv), 3))
        r[:, 0] = (uv[:, 0] - self.cx) / self.f
        r[:, 1] = (uv[:, 1] - self.cy) / self.f
        return r


def video_camera_poses(
    rng: np.random.Generator, kind: str, frames: int
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """World->camera rotations (T, 3, 3) and camera centres (T, 3) of rendered clips; frame 0 is the world frame.

    Args:
        rng: the clip's random generator (its draws are part of the clip's seed).
        kind: one of VIDEO_MOTIONS or PARALLAX_MOTIONS.
        frames: T.
    """
    t = np.arange(frames, dtype=np.float64)[:, None]
    deg = math.pi / 180.0
    span = max(frames - 1, 1)
    if kind == "static":
        rotvec = np.zeros((frames, 3))
        centre = np.zeros((frames, 3))
    elif kind == "pan":
        rate = min(rng.uniform(0.3, 0.8), 8.0 / span) * deg * rng.choice([-1.0, 1.0])
        rotvec = t * np.array([rng.normal(0, 0.1) * abs(rate), rate, 0.0])
        centre = np.zeros((frames, 3))
    elif kind == "forward":
        # At most 1.5 m in all, so the camera never reaches the nearest objects (3 m).
        speed = min(rng.uniform(0.05, 0.15), 1.5 / span)
        rotvec = np.zeros((frames, 3))
        centre = t * np.array([0.0, 0.0, speed])
    elif kind == "truck":
        speed = min(rng.uniform(0.04, 0.10), 2.5 / span) * random_sign(rng)
        # turning back towards the scene 10 m ahead by a share of the angle the translation sweeps
        rate = -rng.uniform(0.2, 0.6) * math.atan(speed / 10.0)
        rotvec = t * np.array([0.0, rate, 0.0])
        centre = t * np.array([speed, 0.0, 0.0]) + rng.normal(0, 0.005, (frames, 3)).cumsum(axis=0)
        centre -= centre[0]
    else:  # handheld
        step = min(1.0, 10.0 / span)
        rotvec = (rng.normal(0, 0.2 * deg * step, (frames, 3))).cumsum(axis=0)
        centre = (rng.normal(0, 0.015 * step, (frames, 3))).cumsum(axis=0)
        rotvec -= rotvec[0]
        centre -= centre[0]
    rot = np.stack([rotation_matrix(r).T for r in rotvec])
    return rot, centre


def trajectory_camera_poses(
    rng: np.random.Generator, kind: str, frames: int, depth_m: float
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """World->camera rotations (F, 3, 3) and centres (F, 3) of synthetic trajectories for one ego-motion kind.

    Args:
        rng: the clip's random generator.
        kind: one of TRAJECTORY_MOTIONS.
        frames: F.
        depth_m: the typical scene depth, metres; handheld translations scale with it.
    """
    t = np.arange(frames, dtype=np.float64)[:, None]
    deg = math.pi / 180.0
    if kind == "static":
        rotvec = np.zeros((frames, 3))
        centre = np.zeros((frames, 3))
    elif kind == "pan":
        axis = np.array([rng.normal(0, 0.3), 1.0, rng.normal(0, 0.1)])  # mostly yaw, some tilt
        axis /= np.linalg.norm(axis)
        rate = rng.uniform(0.2, 2.0) * deg * random_sign(rng)
        rotvec = t * rate * axis
        centre = np.zeros((frames, 3))
    elif kind == "driving":
        # KITTI at 10 fps: 0.2-1.5 m per frame, heading changes of at most ~1.5 deg per frame.
        speed = rng.uniform(0.2, 1.5)
        yaw = rng.uniform(-1.5, 1.5) * deg * t[:, 0]
        pitch = rng.normal(0, 0.1 * deg, frames).cumsum()
        roll = rng.normal(0, 0.05 * deg, frames).cumsum()
        rotvec = np.stack([pitch - pitch[0], yaw, roll - roll[0]], axis=1)
        heading = np.stack([np.sin(yaw), np.zeros(frames), np.cos(yaw)], axis=1)
        steps = speed * heading[:-1]
        centre = np.concatenate([np.zeros((1, 3)), np.cumsum(steps, axis=0)])
        centre[:, 1] += np.concatenate([[0.0], rng.normal(0, 0.01, frames - 1).cumsum()])
    elif kind == "handheld":
        rot_rate = rng.uniform(0.0, 1.0) * deg * random_unit(rng)
        trans_rate = rng.uniform(0.002, 0.03) * depth_m * random_unit(rng)
        jitter_r = rng.normal(0, 0.15 * deg, (frames, 3)).cumsum(axis=0)
        jitter = 0.3 * float(np.linalg.norm(trans_rate)) + 1e-4
        jitter_t = rng.normal(0, jitter, (frames, 3)).cumsum(axis=0)
        rotvec = t * rot_rate + jitter_r - jitter_r[0]
        centre = t * trans_rate + jitter_t - jitter_t[0]
    else:
        raise InputError(f"unknown camera motion {kind!r}; choose from {TRAJECTORY_MOTIONS}")
    # rotvec is the camera->world rotation; the projection needs world->camera.
    return np.transpose(rotation_matrices(rotvec), (0, 2, 1)), centre
