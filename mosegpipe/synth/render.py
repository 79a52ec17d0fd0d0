"""Synthetic video clips with ground truth, for tests, samples and end-to-end measurement.

A clip is a small world of textured planar quads seen by a moving perspective camera: an endless
background wall (optionally with a ground plane in front of it) and a few independently moving
objects, each a textured plane or box. Every quad is drawn by warping its texture with the
homography between the texture and the quad's projection (cv2.warpPerspective), far to near
(painter's algorithm), and the same composite writes the ground-truth mask, so occlusions are
exact in the mask.

Mask convention: the mask value at a pixel is the motion-group id of the surface seen there.
0 = the static background (wall and ground: one group, moving in the image only when the camera
moves), i = object i (1..num_objects, ordered as RenderConfig.objects or as sampled).
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe.errors import InputError
from mosegpipe.synth.camera import PARALLAX_MOTIONS, VIDEO_MOTIONS, rotation_matrix, video_camera_poses
from mosegpipe.types import Frames

__all__ = [
    "CAMERA_MOTIONS",
    "SHAPES",
    "TEXTURES",
    "ObjectSpec",
    "RenderConfig",
    "RenderedClip",
    "render_clip",
    "write_clip",
]

logger = logging.getLogger(__name__)

CAMERA_MOTIONS = VIDEO_MOTIONS  # the motions the rendered protocols cycle through (see synth.camera)
"""Camera motions render_clip knows (and PARALLAX_MOTIONS: "truck")."""

TEXTURES: tuple[str, ...] = ("blobs", "checker", "mixed", "photo")
"""Texture kinds: quantised smooth noise (blobs), random-colour grids (checker), either per
surface (mixed), or random crops of real photographs (photo: render_clip's `photos`)."""

SHAPES: tuple[str, ...] = ("plane", "box")
"""Object shapes."""

_WALL_DEPTH_M = 10.0
_CAMERA_HEIGHT_M = 1.5  # the ground plane lies this far below the first camera
_NEAR_M = 0.1


@dataclass(frozen=True)
class ObjectSpec:
    """One moving object given explicitly (instead of sampled), in the first camera's frame.

    Coordinates are metres with x right, y down, z forward (depth).

    Attributes:
        shape: "plane" (a rectangle of width x height in its local x-y plane) or "box".
        centre_m: centre at frame 0, metres.
        size_m: (width, height, depth) metres; depth is ignored for planes.
        rotation: orientation at frame 0 as a rotation vector (axis * angle), radians.
        velocity_m: translation per frame, metres.
        spin: rotation per frame about the centre, rotation vector, radians.
    """

    shape: str = "plane"
    centre_m: tuple[float, float, float] = (0.0, 0.0, 4.0)
    size_m: tuple[float, float, float] = (1.0, 1.0, 1.0)
    rotation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    velocity_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    spin: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if self.shape not in SHAPES:
            raise InputError(f"ObjectSpec.shape={self.shape!r}: choose from {SHAPES}")
        if min(self.size_m[:2]) <= 0 or (self.shape == "box" and self.size_m[2] <= 0):
            raise InputError(f"ObjectSpec.size_m={self.size_m}: sizes must be > 0")


@dataclass(frozen=True)
class RenderConfig:
    """What render_clip draws.

    Attributes:
        size_hw: (H, W) of the frames, pixels.
        frames: T, number of frames.
        num_objects: moving objects to sample (ignored when objects is given).
        seed: seed of every random choice (layout, motion, textures, noise).
        camera_motion: "static", "pan" (slow yaw), "forward" (along the optical axis) or
            "handheld" (small rotation and translation jitter).
        texture: "blobs", "checker" or "mixed" (either, per surface), which have strong corners
            so that KLT can track them; or "photo": crops of the photographs given to render_clip,
            with their real mix of textured and flat areas.
        shapes: object shapes to sample from, see SHAPES.
        object_speed_px: range of each sampled object's image speed, pixels per frame.
        ground: also draw a ground plane (part of the background group) below the wall.
        noise_std: standard deviation of Gaussian pixel noise added to every frame, grey levels.
        fov_deg: horizontal field of view, degrees.
        objects: explicit objects; None samples num_objects of them.
        near_static: still boxes (label 0, part of the static world) standing 1.5-3 m from the first camera,
            pillars and rocks whose parallax against the wall 10 m away is large when the camera translates.
        follow: the first object also moves with the camera's mean translation per frame (a mover the
            camera follows: nearly still in the image while the world sweeps past).
    """

    size_hw: tuple[int, int] = (240, 320)
    frames: int = 5
    num_objects: int = 2
    seed: int = 0
    camera_motion: str = "static"
    texture: str = "mixed"
    shapes: tuple[str, ...] = SHAPES
    object_speed_px: tuple[float, float] = (1.0, 4.0)
    ground: bool = False
    noise_std: float = 0.0
    fov_deg: float = 60.0
    objects: tuple[ObjectSpec, ...] | None = None
    near_static: int = 0
    follow: bool = False

    def __post_init__(self) -> None:
        h, w = self.size_hw
        if h < 16 or w < 16:
            raise InputError(f"RenderConfig.size_hw={self.size_hw}: need at least 16x16")
        if self.frames < 1:
            raise InputError(f"RenderConfig.frames={self.frames}: need at least 1")
        if self.num_objects < 0 or self.num_objects > 254:
            raise InputError(f"RenderConfig.num_objects={self.num_objects}: need 0..254")
        if self.objects is not None and len(self.objects) > 254:
            raise InputError(f"RenderConfig.objects: {len(self.objects)} objects, at most 254")
        if self.camera_motion not in CAMERA_MOTIONS + PARALLAX_MOTIONS:
            raise InputError(
                f"RenderConfig.camera_motion={self.camera_motion!r}: choose from {CAMERA_MOTIONS + PARALLAX_MOTIONS}"
            )
        if not 0 <= self.near_static <= 16:
            raise InputError(f"RenderConfig.near_static={self.near_static}: need 0..16")
        if self.texture not in TEXTURES:
            raise InputError(f"RenderConfig.texture={self.texture!r}: choose from {TEXTURES}")
        if not self.shapes or set(self.shapes) - set(SHAPES):
            raise InputError(f"RenderConfig.shapes={self.shapes}: choose from {SHAPES}")
        lo, hi = self.object_speed_px
        if not 0 <= lo <= hi:
            raise InputError(f"RenderConfig.object_speed_px={self.object_speed_px}: need 0 <= low <= high")
        if not 10.0 <= self.fov_deg <= 120.0:
            raise InputError(f"RenderConfig.fov_deg={self.fov_deg}: need 10..120")
        if self.noise_std < 0:
            raise InputError(f"RenderConfig.noise_std={self.noise_std}: need >= 0")


@dataclass(frozen=True)
class RenderedClip:
    """A rendered clip with per-pixel ground truth.

    Attributes:
        frames: (T, H, W, 3) uint8 RGB.
        masks: (T, H, W) uint8 motion-group id of the surface seen at each pixel: 0 = static
            background (one group, moving in the image only with the camera), i = object i.
        object_ids: ids of the moving objects, (1, ..., num_objects); an object may be out of view
            or hidden in some frames.
        camera_motion: the camera motion kind.
        intrinsics: (3, 3) float64 pinhole camera matrix, pixels.
    """

    frames: npt.NDArray[np.uint8]
    masks: npt.NDArray[np.uint8]
    object_ids: tuple[int, ...]
    camera_motion: str
    intrinsics: npt.NDArray[np.float64] = field(repr=False)

    @property
    def num_frames(self) -> int:
        return int(self.frames.shape[0])

    @property
    def size_hw(self) -> tuple[int, int]:
        return int(self.frames.shape[1]), int(self.frames.shape[2])

    def label_at(self, t: int, xy: npt.ArrayLike) -> npt.NDArray[np.int64]:
        """Ground-truth group of arbitrary pixel positions in frame t.

        Args:
            t: frame index.
            xy: (N, 2) pixel coordinates (x right, y down; pixel centres at integers). Each is
                looked up at its nearest pixel; positions outside the image take the nearest
                border pixel.

        Returns:
            (N,) int64 mask values (motion-group ids).
        """
        if not -self.num_frames <= t < self.num_frames:
            raise InputError(f"frame {t} out of range for a clip of {self.num_frames} frames")
        pts = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        h, w = self.size_hw
        x = np.clip(np.rint(pts[:, 0]), 0, w - 1).astype(np.intp)
        y = np.clip(np.rint(pts[:, 1]), 0, h - 1).astype(np.intp)
        return self.masks[t, y, x].astype(np.int64)

    def to_frames(self, fps: float = 10.0) -> Frames:
        """The frames as a pipeline input."""
        return Frames(images=self.frames, fps=fps, source="render")


def _photo_texture(
    rng: np.random.Generator, photos: Sequence[npt.NDArray[np.uint8]], size_wh: tuple[int, int]
) -> npt.NDArray[np.uint8]:
    """A random crop of a random photograph resized to (h, w, 3): 25-100 % of the largest crop of
    that aspect, randomly mirrored, with a random gain and offset per channel."""
    w, h = size_wh
    photo = photos[int(rng.integers(len(photos)))]
    ph, pw = photo.shape[:2]
    scale = min(pw / w, ph / h) * float(rng.uniform(0.25, 1.0))
    cw, ch = max(int(w * scale), 8), max(int(h * scale), 8)
    cw, ch = min(cw, pw), min(ch, ph)
    x0, y0 = int(rng.integers(pw - cw + 1)), int(rng.integers(ph - ch + 1))
    crop = photo[y0 : y0 + ch, x0 : x0 + cw]
    if rng.random() < 0.5:
        crop = crop[:, ::-1]
    interp = cv2.INTER_AREA if cw > w else cv2.INTER_LINEAR
    tex = cv2.resize(np.ascontiguousarray(crop), (w, h), interpolation=interp).astype(np.float32)
    tex = tex * rng.uniform(0.7, 1.3, 3).astype(np.float32) + rng.uniform(-20, 20, 3).astype(np.float32)
    return np.clip(np.rint(tex), 0, 255).astype(np.uint8)


def _texture(
    rng: np.random.Generator, kind: str, size_wh: tuple[int, int], photos: Sequence[npt.NDArray[np.uint8]] = ()
) -> npt.NDArray[np.uint8]:
    """A random RGB texture (h, w, 3) uint8: many corners, cells of 6-20 texels; or a photo crop."""
    if kind == "photo":
        return _photo_texture(rng, photos, size_wh)
    w, h = size_wh
    if kind == "mixed":
        kind = "blobs" if rng.random() < 0.5 else "checker"
    levels = int(rng.integers(4, 7))
    palette = rng.integers(0, 256, (levels, 3))
    # Spread the palette in brightness too, so corners survive the conversion to grey for KLT.
    palette[:, int(rng.integers(3))] = np.linspace(20, 235, levels)[rng.permutation(levels)]
    cell = float(rng.uniform(6.0, 20.0))
    gw, gh = max(2, round(w / cell)), max(2, round(h / cell))
    if kind == "checker":
        grid = rng.integers(0, levels, (gh, gw)).astype(np.uint8)
        index = cv2.resize(grid, (w, h), interpolation=cv2.INTER_NEAREST)
    else:
        field_ = rng.random((gh, gw)).astype(np.float32)
        smooth = cv2.resize(field_, (w, h), interpolation=cv2.INTER_CUBIC)
        ranks = np.clip((smooth - smooth.min()) / max(float(np.ptp(smooth)), 1e-6), 0, 0.999)
        index = (ranks * levels).astype(np.uint8)
    tex = palette.astype(np.int16)[index]
    tex += rng.integers(-6, 7, tex.shape, dtype=np.int16)  # fine grain
    return np.clip(tex, 0, 255).astype(np.uint8)


@dataclass
class _Quad:
    """A textured planar rectangle: corner k of texture corners maps to corners_m[k]."""

    corners_m: npt.NDArray[np.float64]  # (4, 3) in the owner's local frame
    normal: npt.NDArray[np.float64]  # (3,) outward, local
    texture: npt.NDArray[np.uint8]


@dataclass
class Body:
    """A rigid group of quads with a pose per frame: x_world = rot[t] @ x_local + pos[t]."""

    label: int
    quads: list[_Quad]
    rot: npt.NDArray[np.float64]  # (T, 3, 3)
    pos: npt.NDArray[np.float64]  # (T, 3)
    cull: bool  # draw only faces turned towards the camera (closed boxes)


def _rect(w: float, h: float) -> npt.NDArray[np.float64]:
    """Corners (4, 3) of a w x h rectangle in the local z = 0 plane, centred, texture order."""
    return np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]]) * [w / 2, h / 2, 0]


def _box_quads(
    rng: np.random.Generator,
    size: npt.NDArray[np.float64],
    tex_kind: str,
    texels_per_m: float,
    photos: Sequence[npt.NDArray[np.uint8]] = (),
) -> list[_Quad]:
    """The six faces of a box of size (w, h, d) centred at the origin, outward normals."""
    quads = []
    half = size / 2
    # (axis of the normal, the two in-face axes) for the six faces
    for axis, (u, v) in ((0, (2, 1)), (1, (0, 2)), (2, (0, 1))):
        for sign in (-1.0, 1.0):
            corners = np.zeros((4, 3))
            for k, (su, sv) in enumerate(((-1, -1), (1, -1), (1, 1), (-1, 1))):
                corners[k, u] = su * half[u]
                corners[k, v] = sv * half[v]
                corners[k, axis] = sign * half[axis]
            normal = np.zeros(3)
            normal[axis] = sign
            tw = int(np.clip(size[u] * texels_per_m, 16, 1024))
            th = int(np.clip(size[v] * texels_per_m, 16, 1024))
            quads.append(_Quad(corners, normal, _texture(rng, tex_kind, (tw, th), photos)))
    return quads


def _sample_objects(rng: np.random.Generator, cfg: RenderConfig, f: float, cx: float, cy: float) -> list[ObjectSpec]:
    """Random objects at distinct depths (3-7 m), in view at frame 0, moving object_speed_px."""
    n = cfg.num_objects
    h, w = cfg.size_hw
    if n == 0:
        return []
    gap = 4.0 / n
    depths = 3.0 + gap * (np.arange(n) + rng.uniform(0.3, 0.7, n))
    depths = depths[rng.permutation(n)]
    specs = []
    for z in depths:
        shape = str(cfg.shapes[rng.integers(len(cfg.shapes))])
        u, v = rng.uniform(0.2, 0.8) * w, rng.uniform(0.2, 0.8) * h
        width = rng.uniform(0.15, 0.35) * w * z / f
        size = (width, width * rng.uniform(0.6, 1.4), width * rng.uniform(0.3, 0.9))
        centre = np.array([(u - cx) * z / f, (v - cy) * z / f, z])
        if cfg.ground:
            # Keep the object's bounding sphere above the ground.
            radius = 0.5 * float(np.linalg.norm(size))
            centre[1] = min(centre[1], _CAMERA_HEIGHT_M - 1.05 * radius)
        if shape == "plane":
            rotation = rng.uniform([-0.4, -0.5, -0.3], [0.4, 0.5, 0.3])
        else:
            rotation = rng.uniform([-0.3, 0.0, -0.2], [0.3, math.pi / 2, 0.2])
        speed_px = rng.uniform(*cfg.object_speed_px)
        angle = rng.uniform(0, 2 * math.pi)
        direction = np.array([math.cos(angle), math.sin(angle) * (0.3 if cfg.ground else 1.0), 0.0])
        direction /= np.linalg.norm(direction)
        velocity = direction * speed_px * z / f
        velocity[2] = rng.normal(0, 0.01)
        spin = rng.normal(0, 0.01, 3)
        specs.append(ObjectSpec(shape, tuple(centre), size, tuple(rotation), tuple(velocity), tuple(spin)))
    return specs


def _warp_quad(
    image: npt.NDArray[np.uint8],
    mask: npt.NDArray[np.uint8],
    quad: _Quad,
    corners_px: npt.NDArray[np.float64],
    label: int,
    full: bool,
) -> None:
    """Composite one quad onto image/mask in place.

    full: cover the whole image, the texture repeating mirrored beyond the quad (the wall).
    """
    h, w = mask.shape
    th, tw = quad.texture.shape[:2]
    src = np.array([[0, 0], [tw, 0], [tw, th], [0, th]], dtype=np.float32)
    hom = cv2.getPerspectiveTransform(src, corners_px.astype(np.float32))
    if full:
        image[:] = cv2.warpPerspective(
            quad.texture, hom, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT_101
        )
        mask[:] = label
        return
    x0 = max(int(math.floor(corners_px[:, 0].min())), 0)
    y0 = max(int(math.floor(corners_px[:, 1].min())), 0)
    x1 = min(int(math.ceil(corners_px[:, 0].max())) + 1, w)
    y1 = min(int(math.ceil(corners_px[:, 1].max())) + 1, h)
    if x1 <= x0 or y1 <= y0:
        return
    shift = np.array([[1.0, 0.0, -x0], [0.0, 1.0, -y0], [0.0, 0.0, 1.0]])
    patch = cv2.warpPerspective(
        quad.texture, shift @ hom, (x1 - x0, y1 - y0), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT_101
    )
    inside = np.zeros((y1 - y0, x1 - x0), dtype=np.uint8)
    # 4 fractional bits: the polygon follows the sub-pixel corners.
    poly = np.round((corners_px - [x0, y0]) * 16).astype(np.int32)
    cv2.fillConvexPoly(inside, poly, 1, lineType=cv2.LINE_8, shift=4)
    sel = inside.astype(bool)
    image[y0:y1, x0:x1][sel] = patch[sel]
    mask[y0:y1, x0:x1][sel] = label


def render_clip(cfg: RenderConfig = RenderConfig(), photos: Sequence[npt.NDArray[np.uint8]] = ()) -> RenderedClip:
    """Render a clip of textured planes and boxes with its ground-truth motion masks.

    Args:
        cfg: what to draw; the same cfg (and photos) always give the same clip.
        photos: RGB uint8 (H, W, 3) photographs that texture="photo" crops its textures from.

    Returns:
        RenderedClip with frames (T, H, W, 3) uint8 RGB and masks (T, H, W) uint8 (see the
        module docstring for the id convention).
    """
    if cfg.texture == "photo" and not photos:
        raise InputError('RenderConfig.texture="photo" needs photographs (render_clip\'s photos)')
    if any(p.ndim != 3 or p.shape[2] != 3 or p.dtype != np.uint8 for p in photos):
        raise InputError("render_clip: photos must be RGB uint8 arrays (H, W, 3)")
    rng = np.random.default_rng(cfg.seed)
    h, w = cfg.size_hw
    frames = cfg.frames
    f = 0.5 * w / math.tan(0.5 * math.radians(cfg.fov_deg))
    cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
    intrinsics = np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])
    cam_rot, cam_centre = video_camera_poses(rng, cfg.camera_motion, frames)
    specs = list(cfg.objects) if cfg.objects is not None else _sample_objects(rng, cfg, f, cx, cy)
    if cfg.follow and specs:
        step = (cam_centre[-1] - cam_centre[0]) / max(frames - 1, 1)
        lead = specs[0]
        specs[0] = dataclasses.replace(lead, velocity_m=tuple(np.asarray(lead.velocity_m) + step))

    background = _background_bodies(rng, cfg, photos)
    bodies = _object_bodies(rng, cfg, specs, f, photos)
    if cfg.near_static:  # drawn with the objects, in depth order (they stand in front of them)
        bodies += _near_static_bodies(rng, cfg, cam_centre, f, cx, photos)

    images = np.empty((frames, h, w, 3), dtype=np.uint8)
    masks = np.zeros((frames, h, w), dtype=np.uint8)
    for k in range(frames):
        centre_depth = [((b.pos[k] - cam_centre[k]) @ cam_rot[k].T)[2] for b in bodies]
        order = np.argsort(centre_depth)[::-1]  # farthest first
        for body in background + [bodies[j] for j in order]:
            for quad in body.quads:
                world = quad.corners_m @ body.rot[k].T + body.pos[k]
                corners = (world - cam_centre[k]) @ cam_rot[k].T  # (4, 3) camera frame
                if (corners[:, 2] <= _NEAR_M).any():
                    continue  # never the case for sampled scenes; explicit ones may come too close
                if body.cull:
                    normal = body.rot[k] @ quad.normal
                    if float(np.dot(cam_rot[k] @ normal, corners.mean(axis=0))) >= 0:
                        continue  # faces away from the camera
                px = f * corners[:, :2] / corners[:, 2:3] + [cx, cy]
                full = body is background[0]
                _warp_quad(images[k], masks[k], quad, px, body.label, full)
    if cfg.noise_std > 0:
        noise = rng.normal(0, cfg.noise_std, images.shape).astype(np.float32)
        noisy = images.astype(np.float32) + noise
        images = np.clip(np.rint(noisy), 0, 255).astype(np.uint8)
    return RenderedClip(
        frames=images,
        masks=masks,
        object_ids=tuple(range(1, len(specs) + 1)),
        camera_motion=cfg.camera_motion,
        intrinsics=intrinsics,
    )


def _background_bodies(
    rng: np.random.Generator, cfg: RenderConfig, photos: Sequence[npt.NDArray[np.uint8]]
) -> list[Body]:
    """The still wall (label 0) that fills the view, and the ground in front of it when cfg.ground."""
    h, w = cfg.size_hw
    frames = cfg.frames
    still_rot = np.broadcast_to(np.eye(3), (frames, 3, 3))
    still_pos = np.zeros((frames, 3))
    # The wall covers the first view 1.5 times over; beyond it the texture repeats mirrored.
    wall_w = 1.5 * 2 * _WALL_DEPTH_M * math.tan(0.5 * math.radians(cfg.fov_deg))
    wall_h = wall_w * h / w
    wall_texels = int(np.clip(1.5 * w, 64, 2048))
    wall = _Quad(
        _rect(wall_w, wall_h) + [0, 0, _WALL_DEPTH_M],
        np.array([0.0, 0.0, -1.0]),
        _texture(rng, cfg.texture, (wall_texels, round(wall_texels * h / w)), photos),
    )
    background = [Body(0, [wall], still_rot, still_pos, cull=False)]
    if cfg.ground:
        near, far = 2.0, _WALL_DEPTH_M
        half = 0.5 * wall_w
        corners = np.array(
            [
                [-half, _CAMERA_HEIGHT_M, far],
                [half, _CAMERA_HEIGHT_M, far],
                [half, _CAMERA_HEIGHT_M, near],
                [-half, _CAMERA_HEIGHT_M, near],
            ]
        )
        tex = _texture(rng, cfg.texture, (wall_texels, wall_texels // 2), photos)
        background.append(Body(0, [_Quad(corners, np.array([0.0, -1.0, 0.0]), tex)], still_rot, still_pos, cull=False))
    return background


def _near_static_bodies(
    rng: np.random.Generator,
    cfg: RenderConfig,
    cam_centre: npt.NDArray[np.float64],
    f: float,
    cx: float,
    photos: Sequence[npt.NDArray[np.uint8]],
) -> list[Body]:
    """cfg.near_static still boxes (label 0) 1.5-3 m away, standing on the ground's level, spread over the
    stretch the camera's translation sweeps so that some are in view in most frames."""
    frames = cfg.frames
    travel = cam_centre[:, 0]
    lo, hi = float(travel.min()), float(travel.max())
    bodies = []
    for _ in range(cfg.near_static):
        z = rng.uniform(1.5, 3.0)
        half_view = z * cx / f
        x = rng.uniform(lo - half_view, hi + half_view)
        size = np.array([rng.uniform(0.2, 0.6), rng.uniform(1.0, 2.5), rng.uniform(0.2, 0.6)])
        centre = np.array([x, _CAMERA_HEIGHT_M - 0.5 * size[1], z])
        quads = _box_quads(rng, size, cfg.texture, f / z, photos)
        spin = rotation_matrix(np.array([0.0, rng.uniform(-0.5, 0.5), 0.0]))
        bodies.append(Body(0, quads, np.broadcast_to(spin, (frames, 3, 3)).copy(), np.tile(centre, (frames, 1)), True))
    return bodies


def _object_bodies(
    rng: np.random.Generator,
    cfg: RenderConfig,
    specs: Sequence[ObjectSpec],
    f: float,
    photos: Sequence[npt.NDArray[np.uint8]],
) -> list[Body]:
    """The moving objects (labels 1, 2, ...), textured about one texel a pixel at their starting depth."""
    frames = cfg.frames
    bodies: list[Body] = []
    t = np.arange(frames, dtype=np.float64)[:, None]
    for i, spec in enumerate(specs):
        size = np.asarray(spec.size_m, dtype=np.float64)
        z0 = max(float(spec.centre_m[2]), 0.5)
        texels_per_m = f / z0  # about one texel per pixel at the starting depth
        if spec.shape == "plane":
            tw = int(np.clip(size[0] * texels_per_m, 16, 1024))
            th = int(np.clip(size[1] * texels_per_m, 16, 1024))
            quads = [
                _Quad(_rect(size[0], size[1]), np.array([0.0, 0.0, -1.0]), _texture(rng, cfg.texture, (tw, th), photos))
            ]
        else:
            quads = _box_quads(rng, size, cfg.texture, texels_per_m, photos)
        orient = rotation_matrix(spec.rotation)
        rot = np.stack([rotation_matrix(np.asarray(spec.spin) * k) @ orient for k in range(frames)])
        pos = np.asarray(spec.centre_m) + t * np.asarray(spec.velocity_m)
        bodies.append(Body(i + 1, quads, rot, pos, cull=spec.shape == "box"))
    return bodies


def write_clip(clip: RenderedClip, folder: str | Path, video: bool = False, fps: float = 10.0) -> Path:
    """Write a rendered clip to a folder (created if needed; files there are overwritten).

    Writes frames as 000000.png, 000001.png, ... (RGB PNG), masks as gt_000000.png, ... (8-bit
    grayscale PNG, value = motion-group id) and masks.npz (masks (T, H, W) uint8, object_ids),
    plus clip.avi (MJPG) when video is True.

    Args:
        clip: the clip.
        folder: output folder.
        video: also write an .avi of the frames.
        fps: frame rate of the .avi.

    Returns:
        The folder.

    Raises:
        InputError: when a file cannot be written.
    """
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    for k, (frame, mask) in enumerate(zip(clip.frames, clip.masks)):
        for path, image in (
            (out / f"{k:06d}.png", cv2.cvtColor(frame, cv2.COLOR_RGB2BGR)),
            (out / f"gt_{k:06d}.png", mask),
        ):
            if not cv2.imwrite(str(path), image):
                raise InputError(f"{path}: could not write the image")
    ids = np.asarray(clip.object_ids, dtype=np.int64)
    np.savez_compressed(out / "masks.npz", masks=clip.masks, object_ids=ids)
    if video:
        h, w = clip.size_hw
        path = out / "clip.avi"
        writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (w, h))  # type: ignore[attr-defined]
        if not writer.isOpened():
            raise InputError(f"{path}: could not open an MJPG video writer")
        try:
            for frame in clip.frames:
                writer.write(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
        finally:
            writer.release()
    logger.debug("wrote %d frames to %s", clip.num_frames, out)
    return out
