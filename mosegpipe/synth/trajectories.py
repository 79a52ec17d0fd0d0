"""Synthetic multi-body point trajectories, generated on the fly for training.

The real benchmarks are small (22 KT3DMoSeg clips, 155 Hopkins sequences, 19 AdelaideRMF pairs),
so training mixes in clips drawn from a simple 3-D world:

* a perspective pinhole camera (focal length from a sampled field of view, principal point at the
  image centre) with one of four ego-motions: "driving" (forward along the optical axis with a
  slow yaw, as on KITTI), "handheld" (small rotation and translation plus jitter), "static" and
  "pan" (rotation only);
* one to six bodies: the static background seen by the moving camera (a road-and-walls corridor, a
  depth-varied surface, or a nearly planar wall) and objects with their own motion: rigid
  boxes/ellipsoids, near-planar slabs, non-rigid bodies (a rigid motion plus a smooth per-point
  deformation) and articulated ones (two rigid parts joined by a hinge);
* tracking errors: Gaussian noise, a small random-walk drift per point, gross outliers.

Each object's motion is scaled so that its points move a sampled number of pixels (mean over the
points, at the last frame) away from where they would be if the object stood still. Small values
(a few pixels over five frames) are what make KT3DMoSeg hard: KITTI cars move slowly relative to
the camera, so the range reaches down to 1 px.

Everything is vectorised over points; loops run over the (at most six) bodies only. One 5-frame
clip of 500 points takes about 2 ms on one CPU core (NumPy call overhead dominates; 1000 points
about 3 ms).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from mosegpipe.errors import InputError
from mosegpipe.synth.bodies import (
    Body,
    BodyWorld,
    background_points,
    log_uniform,
    object_body,
    occluded_mask,
    outlier_tracks,
)
from mosegpipe.synth.camera import (
    NEAR_M,
    TRAJECTORY_MOTIONS,
    PinholeCamera,
    trajectory_camera_poses,
)
from mosegpipe.synth.seeded import SeededClips
from mosegpipe.types import LabeledClip

logger = logging.getLogger("mosegpipe.synth.trajectories")

__all__ = [
    "CAMERA_MOTIONS",
    "OBJECT_KINDS",
    "PAIR_CONFIG",
    "SyntheticConfig",
    "SyntheticDataset",
    "generate_clip",
    "generate_pair",
]

CAMERA_MOTIONS = TRAJECTORY_MOTIONS  # the ego-motions SyntheticConfig.camera_motions accepts (see synth.camera)
"""Camera ego-motions the generator knows."""

OBJECT_KINDS: tuple[str, ...] = ("rigid", "planar", "nonrigid", "articulated")
"""Kinds of moving objects the generator knows."""

_MAX_TRIES = 100
# Points are drawn with this margin so that culling (leaving the image, occlusion) still leaves
# about the requested number; each body is then cut back to its target count.
_OVERSAMPLE = 1.4
# Points closer than this to the camera (metres) are treated as behind it.


@dataclass(frozen=True)
class SyntheticConfig:
    """What the generator samples from. Ranges are (low, high) and inclusive.

    Attributes:
        frames: F, frames per clip (>= 2); trajectories have 2F columns.
        num_bodies: range of the number of independently moving bodies, the background included
            when present (see background_prob). Bodies left with fewer than min_points_per_group
            visible points are dropped, so a clip can hold fewer.
        num_points: range of the number of points requested, outliers included. Points that
            leave the image or get occluded are culled, so a clip can hold fewer; it holds more
            only when the sampled inliers cannot give every kept body min_points_per_group.
        noise_px: range of the per-clip standard deviation of Gaussian tracking noise, pixels.
        drift_px: range of the per-clip standard deviation of one step of the per-point random
            walk (tracker drift), pixels per frame; the first frame has no drift.
        outlier_ratio: range of the fraction of gross outliers among all points, in [0, 1).
        outliers_as_group: True: outliers get their own label (the last one, recorded in
            meta["outlier_label"]). False: each outlier is a failed track of an inlier point -- it
            starts on that point and wanders off -- and keeps that point's label.
        camera_motions: camera ego-motions to sample from, see CAMERA_MOTIONS.
        image_sizes: (H, W) image sizes to sample from, pixels.
        random_size_prob: probability of a random size between the listed ones instead (width
            and aspect ratio uniform within the listed ranges).
        object_kinds: kinds of moving objects to sample from, see OBJECT_KINDS.
        relative_motion_px: range (sampled log-uniformly) of an object's motion relative to the
            static scene: mean distance, at the last frame, between its points and where they
            would be had the object not moved, pixels.
        background_prob: probability that the static background is one of the bodies.
        object_weight: range (log-uniform) of an object's share of points relative to the
            background's (relative to 1.0 when there is no background); small values give objects
            of only min_points_per_group..20 points next to a background of hundreds.
        min_points_per_group: bodies with fewer visible points than this are dropped.
    """

    frames: int = 5
    num_bodies: tuple[int, int] = (1, 6)
    num_points: tuple[int, int] = (150, 1000)
    noise_px: tuple[float, float] = (0.0, 1.5)
    drift_px: tuple[float, float] = (0.0, 0.3)
    outlier_ratio: tuple[float, float] = (0.0, 0.0)
    outliers_as_group: bool = True
    camera_motions: tuple[str, ...] = CAMERA_MOTIONS
    image_sizes: tuple[tuple[int, int], ...] = ((480, 640), (720, 1280), (1080, 1920), (375, 1242))
    random_size_prob: float = 0.25
    object_kinds: tuple[str, ...] = OBJECT_KINDS
    relative_motion_px: tuple[float, float] = (1.0, 60.0)
    background_prob: float = 1.0
    object_weight: tuple[float, float] = (0.02, 0.6)
    min_points_per_group: int = 8

    def __post_init__(self) -> None:
        if self.frames < 2:
            raise InputError(f"SyntheticConfig.frames={self.frames}: need at least 2")
        for name in (
            "num_bodies",
            "num_points",
            "noise_px",
            "drift_px",
            "outlier_ratio",
            "relative_motion_px",
            "object_weight",
        ):
            lo, hi = getattr(self, name)
            if not 0 <= lo <= hi:
                raise InputError(f"SyntheticConfig.{name}=({lo}, {hi}): need 0 <= low <= high")
        if self.num_bodies[0] < 1 or self.num_bodies[1] > 32:
            raise InputError(f"SyntheticConfig.num_bodies={self.num_bodies}: need 1..32")
        if self.num_points[0] < 1:
            raise InputError(f"SyntheticConfig.num_points={self.num_points}: need at least 1")
        if self.outlier_ratio[1] >= 1.0:
            raise InputError(f"SyntheticConfig.outlier_ratio={self.outlier_ratio}: need < 1")
        if self.relative_motion_px[0] <= 0 or self.object_weight[0] <= 0:
            raise InputError("SyntheticConfig.relative_motion_px and object_weight need low > 0")
        if not self.camera_motions or set(self.camera_motions) - set(CAMERA_MOTIONS):
            raise InputError(f"SyntheticConfig.camera_motions={self.camera_motions}: choose from {CAMERA_MOTIONS}")
        if not self.object_kinds or set(self.object_kinds) - set(OBJECT_KINDS):
            raise InputError(f"SyntheticConfig.object_kinds={self.object_kinds}: choose from {OBJECT_KINDS}")
        if not self.image_sizes or any(h < 16 or w < 16 for h, w in self.image_sizes):
            raise InputError(f"SyntheticConfig.image_sizes={self.image_sizes}: need (H, W) >= 16")
        if self.min_points_per_group < 1:
            raise InputError(f"SyntheticConfig.min_points_per_group={self.min_points_per_group}: need >= 1")
        if self.num_bodies[0] * self.min_points_per_group > self.num_points[1]:
            raise InputError(
                f"SyntheticConfig: num_bodies={self.num_bodies} bodies of min_points_per_group="
                f"{self.min_points_per_group} points do not fit in num_points={self.num_points}"
            )


PAIR_CONFIG = SyntheticConfig(
    frames=2,
    num_bodies=(1, 4),
    num_points=(100, 700),
    noise_px=(0.0, 1.0),
    drift_px=(0.0, 0.0),
    # AdelaideRMF pairs hold 21-73 % gross outliers.
    outlier_ratio=(0.1, 0.6),
    camera_motions=("static", "handheld"),
    image_sizes=((480, 640),),
    random_size_prob=0.0,
    object_kinds=("rigid",),
    # Objects are moved by hand between the two shots: large displacements.
    relative_motion_px=(10.0, 120.0),
    background_prob=0.3,
    object_weight=(0.3, 1.0),
)
"""AdelaideRMF-like two-view defaults for generate_pair: 1-4 rigid objects moved between two
shots of a static or slightly moved 640x480 camera, sparse points, 10-60 % gross outliers."""


def _sample_image_size(rng: np.random.Generator, cfg: SyntheticConfig) -> tuple[int, int]:
    if rng.random() >= cfg.random_size_prob:
        h, w = cfg.image_sizes[rng.integers(len(cfg.image_sizes))]
        return int(h), int(w)
    widths = [w for _, w in cfg.image_sizes]
    aspects = [w / h for h, w in cfg.image_sizes]
    w = rng.uniform(min(widths), max(widths))  # type: ignore[assignment]
    aspect = rng.uniform(min(aspects), max(aspects))
    return max(16, round(w / aspect)), max(16, round(w))


def _take(rng: np.random.Generator, body: npt.NDArray[np.int64], cap: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
    """Indices of at most cap[b] random members of each group b of body (N,)."""
    order = np.lexsort((rng.random(len(body)), body))
    sorted_body = body[order]
    first = np.searchsorted(sorted_body, sorted_body)
    rank = np.arange(len(body)) - first
    return np.sort(order[rank < cap[sorted_body]])


def _draw(rng: np.random.Generator, cfg: SyntheticConfig, pair: bool, name: str) -> LabeledClip | None:
    """One attempt; None when too few bodies survived culling."""
    frames = cfg.frames
    h, w = _sample_image_size(rng, cfg)
    fov = rng.uniform(50.0, 90.0) * math.pi / 180.0
    f = 0.5 * w / math.tan(0.5 * fov)
    motion = str(cfg.camera_motions[rng.integers(len(cfg.camera_motions))])
    driving = motion == "driving"
    depth_m = 15.0 if driving else log_uniform(rng, 1.0, 20.0)
    ground_m = rng.uniform(1.4, 1.8)  # camera height above the road (driving)
    rot, centre = trajectory_camera_poses(rng, motion, frames, depth_m)
    cam = PinholeCamera(f, (w - 1) / 2.0, (h - 1) / 2.0, h, w, rot, centre)

    min_pts = cfg.min_points_per_group
    need, ratio, has_bg, num_objects, target, drawn = _point_budget(rng, cfg)
    bodies, bg_kind = _scene_bodies(rng, cfg, cam, has_bg, num_objects, drawn, driving, depth_m, ground_m)
    world = BodyWorld(bodies, frames)
    kinds = [b.kind for b in bodies]
    objects = [i for i, b in enumerate(bodies) if b.kind != "background"]

    uv, z, moved = _scaled_projection(cam, world, bodies, objects)
    noise = float(rng.uniform(*cfg.noise_px))
    drift = float(rng.uniform(*cfg.drift_px))
    n = uv.shape[1]
    err = rng.normal(0.0, noise, uv.shape) if noise > 0 else np.zeros(uv.shape)
    if drift > 0:
        walk = rng.normal(0.0, drift, (frames - 1, n, 2)).cumsum(axis=0)
        err[1:] += walk
    obs = uv + err
    ok = (z > NEAR_M).all(axis=0)
    ok &= ((obs >= 0) & (obs <= np.array([w - 1.0, h - 1.0]))).all(axis=(0, 2))
    if objects:
        ok &= ~occluded_mask(uv, z, world.body, objects, ok)  # type: ignore[arg-type,operator]
    keep = np.flatnonzero(ok)
    keep = keep[_take(rng, world.body[keep], target)]
    body = world.body[keep]
    count = np.bincount(body, minlength=len(bodies))
    alive = count >= min_pts
    if alive.sum() < need:
        return None
    keep = keep[alive[body]]
    relabel = np.cumsum(alive) - 1
    labels = relabel[world.body[keep]]
    tracks = obs[:, keep]  # (F, n_in, 2)
    num_in = len(keep)
    kinds_alive = [k for k, a in zip(kinds, alive) if a]
    moved_alive = [float(m) for m, a in zip(moved, alive) if a]

    tracks, labels, num_out, outlier_label = _with_outliers(
        rng, cfg, ratio, num_in, tracks, labels, kinds_alive, w, h, pair
    )
    is_outlier = np.arange(len(labels)) >= num_in
    perm = rng.permutation(len(labels))
    traj = np.ascontiguousarray(tracks[:, perm].transpose(1, 0, 2)).reshape(len(perm), 2 * frames)
    meta: dict[str, Any] = {
        "camera_motion": motion,
        "image_size_hw": (h, w),
        "focal_px": f,
        "background_kind": bg_kind,
        "body_kinds": tuple(kinds_alive),
        "relative_motion_px": tuple(moved_alive),
        "noise_px": noise,
        "drift_px": drift,
        "outlier_ratio": num_out / len(labels),
        "outlier_label": outlier_label,
        "is_outlier": is_outlier[perm],
    }
    return LabeledClip(
        name=name,
        traj=traj.astype(np.float32),
        labels=labels[perm].astype(np.int64),
        dataset="synthetic",
        meta=meta,
    )


def _point_budget(
    rng: np.random.Generator, cfg: SyntheticConfig
) -> tuple[int, float, bool, int, npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """(bodies a clip must keep, outlier ratio, whether there is a background, objects, each body's
    target number of points, the points drawn for it before culling)."""
    min_pts = cfg.min_points_per_group
    need = 2 if cfg.num_bodies[0] >= 2 else 1  # bodies a clip must keep
    num_bodies = int(rng.integers(cfg.num_bodies[0], cfg.num_bodies[1] + 1))
    total = int(rng.integers(cfg.num_points[0], cfg.num_points[1] + 1))
    ratio = float(rng.uniform(*cfg.outlier_ratio))
    inliers = max(1, round(total * (1.0 - ratio)))
    # No more bodies than the inlier budget can give min_points_per_group each.
    num_bodies = max(need, min(num_bodies, inliers // min_pts))
    has_bg = rng.random() < cfg.background_prob
    num_objects = num_bodies - int(has_bg)
    weights = np.array([1.0] * int(has_bg) + [log_uniform(rng, *cfg.object_weight) for _ in range(num_objects)])
    target = np.maximum(min_pts, np.round(inliers * weights / weights.sum())).astype(np.int64)
    # Raising small bodies to the minimum is paid for by the largest ones.
    excess = int(target.sum()) - inliers
    for i in np.argsort(-target):
        cut = min(max(excess, 0), int(target[i]) - min_pts)
        target[i] -= cut
        excess -= cut
    drawn = np.ceil(target * _OVERSAMPLE).astype(np.int64)
    return need, ratio, has_bg, num_objects, target, drawn


def _scene_bodies(
    rng: np.random.Generator,
    cfg: SyntheticConfig,
    cam: PinholeCamera,
    has_bg: bool,
    num_objects: int,
    drawn: npt.NDArray[np.int64],
    driving: bool,
    depth_m: float,
    ground_m: float,
) -> tuple[list[Body], str | None]:
    """The background (when there is one) and the objects, with the kind of background drawn (None: none)."""
    bodies: list[Body] = []
    bg_kind = None
    if has_bg:
        xyz, bg_kind = background_points(rng, cam, int(drawn[0]), driving, depth_m, ground_m)
        zero = np.zeros(3)
        bodies.append(
            Body(
                "background",
                xyz,
                zero,
                np.eye(3),
                zero,
                zero,
                zero,
                zero,
                np.zeros_like(xyz),
                np.zeros(len(xyz), bool),
                zero,
                zero,
                0.0,
            )
        )
    for i in range(num_objects):
        kind = str(cfg.object_kinds[rng.integers(len(cfg.object_kinds))])
        bodies.append(
            object_body(rng, cam, int(drawn[i + int(has_bg)]), kind, driving, depth_m, ground_m, cfg.relative_motion_px)
        )
    return bodies, bg_kind


def _scaled_projection(
    cam: PinholeCamera, world: BodyWorld, bodies: list[Body], objects: list[int]
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """(image points, depths, each body's mean displacement in px) once each object's motion is scaled
    to its target relative motion."""
    # Scale each object's motion to its target relative motion. Perspective makes the pixel
    # displacement only roughly linear in the scale, hence one secant refinement.
    target_px = np.array([b.target_px for b in bodies])
    scale = np.where(target_px > 0, 1.0, 0.0)
    counts = np.maximum(world.sizes, 1)
    uv_still = None
    for _ in range(2 if objects else 1):
        xyz = world.positions(scale)
        uv, z = cam.project(xyz)
        if uv_still is None:
            # Frame 0 is the same at any scale: where every point would stay, never moving,
            # seen from the last camera.
            last = replace(cam, rot=cam.rot[-1:], centre=cam.centre[-1:])
            uv_still = last.project(xyz[:1])[0][0]
        disp = np.linalg.norm(uv[-1] - uv_still, axis=1)
        moved = np.bincount(world.body, weights=disp, minlength=len(bodies)) / counts
        # Cap: keeps rotations below ~1 rad over the clip for tiny, far objects.
        scale = np.minimum(scale * target_px / np.maximum(moved, 1e-6), 3.0)
    return uv, z, moved


def _with_outliers(
    rng: np.random.Generator,
    cfg: SyntheticConfig,
    ratio: float,
    num_in: int,
    tracks: npt.NDArray[np.float64],
    labels: npt.NDArray[np.int64],
    kinds_alive: list[str],
    w: int,
    h: int,
    pair: bool,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64], int, int | None]:
    """(tracks, labels, number of outliers, their label when they are a group of their own) with the outlier
    tracks after the `num_in` inliers; an outlier group's kind is appended to `kinds_alive`."""
    frames = cfg.frames
    num_out = round(ratio / (1.0 - ratio) * num_in) if ratio > 0 else 0
    outlier_label = None
    if num_out:
        if cfg.outliers_as_group:
            out_tracks = outlier_tracks(rng, num_out, frames, w, h, None, pair)
            outlier_label = len(kinds_alive)
            out_labels = np.full(num_out, outlier_label)
            kinds_alive.append("outlier")
        else:
            host = rng.integers(num_in, size=num_out)
            out_tracks = outlier_tracks(rng, num_out, frames, w, h, tracks[0, host], pair)
            out_labels = labels[host]
        tracks = np.concatenate([tracks, out_tracks], axis=1)
        labels = np.concatenate([labels, out_labels])
    return tracks, labels, num_out, outlier_label


def generate_clip(
    rng: np.random.Generator, cfg: SyntheticConfig = SyntheticConfig(), *, name: str = "synthetic"
) -> LabeledClip:
    """Draw one synthetic multi-body clip.

    Args:
        rng: the random source; the same generator state gives the same clip.
        cfg: what to sample from.
        name: the clip's name.

    Returns:
        LabeledClip with traj (N, 2F) float32 pixel coordinates (x_1, y_1, ..., x_F, y_F), every
        point inside [0, W-1] x [0, H-1] in every frame; labels (N,) int64 contiguous in 0..K-1,
        the background (when present) being 0, the outlier group (when present) the last one;
        dataset "synthetic"; meta with "camera_motion", "image_size_hw", "focal_px",
        "background_kind", "body_kinds" (kind per label), "relative_motion_px" (measured
        per inlier label; 0 for the background), "noise_px", "drift_px", "outlier_ratio"
        (actual), "outlier_label" (int or None) and "is_outlier" ((N,) bool).

    Raises:
        InputError: when no draw in 100 leaves enough bodies with min_points_per_group visible
            points (e.g. a huge min_points_per_group with few points).
    """
    return _generate(rng, cfg, pair=False, name=name)


def generate_pair(
    rng: np.random.Generator, cfg: SyntheticConfig = PAIR_CONFIG, *, name: str = "synthetic-pair"
) -> LabeledClip:
    """Draw one two-view sample with gross outliers, like an AdelaideRMF image pair.

    Outliers are independent random points in both images. cfg.frames is taken as 2 whatever
    its value; see PAIR_CONFIG for the defaults.

    Args:
        rng: the random source.
        cfg: what to sample from.
        name: the sample's name.

    Returns:
        LabeledClip as for generate_clip with F = 2: traj (N, 4) float32 [x1, y1, x2, y2] pixels.

    Raises:
        InputError: as generate_clip.
    """
    if cfg.frames != 2:
        cfg = replace(cfg, frames=2)
    return _generate(rng, cfg, pair=True, name=name)


def _generate(rng: np.random.Generator, cfg: SyntheticConfig, pair: bool, name: str) -> LabeledClip:
    for attempt in range(_MAX_TRIES):
        clip = _draw(rng, cfg, pair, name)
        if clip is not None:
            return clip
        logger.debug("synthetic draw %d left too few bodies; drawing again", attempt)
    raise InputError(
        f"{cfg}: no draw in {_MAX_TRIES} left enough bodies with {cfg.min_points_per_group} visible points"
    )


class SyntheticDataset(SeededClips):
    """A fixed-length, lazily generated sequence of synthetic clips.

    Clip i is drawn from np.random.default_rng((base_seed, i)), so it is the same on every call
    and on every worker, without materialising the others.

    Args:
        length: number of clips.
        cfg: what to sample from (PAIR_CONFIG-like configs with pair=True for two views).
        base_seed: non-negative seed; datasets with different seeds are independent.
        pair: draw with generate_pair instead of generate_clip.
    """

    def __init__(
        self,
        length: int,
        cfg: SyntheticConfig | None = None,
        base_seed: int = 0,
        pair: bool = False,
    ) -> None:
        if length < 0:
            raise InputError(f"SyntheticDataset length={length}: need >= 0")
        if base_seed < 0:
            raise InputError(f"SyntheticDataset base_seed={base_seed}: need >= 0")
        self.length = length
        self.cfg = cfg if cfg is not None else (PAIR_CONFIG if pair else SyntheticConfig())
        self.base_seed = base_seed
        self.pair = pair

    def _make(self, i: int) -> LabeledClip:
        rng = np.random.default_rng((self.base_seed, i))
        name = f"synthetic/{self.base_seed}/{i:07d}"
        if self.pair:
            return generate_pair(rng, self.cfg, name=name)
        return generate_clip(rng, self.cfg, name=name)
