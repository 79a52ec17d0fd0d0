"""Composite clips in real textures: objects cut out of real clips with their human masks and moved over
other real clips, with exact per-object masks (issue 41, item 1).

A composite is made of

- a *plate*: the first `frames` frames of one clip (its camera motion kept). Its own annotated object
  stays in the picture and is labelled as object 1: its mask is known (the human mask, as exact as
  that is). Anything else moving in the plate (a second person, water) is not labelled: it counts as
  the world. The plate's camera motion, frame 0 -> t, is estimated once as a homography of its
  background (`plate_camera`: corners tracked outside the object, RANSAC), so that an object can stand
  still *in the scene*, not on the screen.
- *pasted objects* 2, 3, ...: the object of another clip, cut out with its mask, either its frame 0
  ("still": the cut-out warped rigidly) or its own frames ("live": the object's own articulated motion
  and its clip's camera motion carried along), resized to 30-50 % of the frame height, and moved along
  a smooth path in the plate's frame-0 coordinates (`ObjectPath`): a translation along a slightly bent
  line plus, by the path's kind, a rotation, a change of scale or a perspective tilt (the cut-out's
  plane turning about an axis). The path is then carried by the plate's camera, so an object whose path
  holds still moves with the scene, i.e. it does not move in the world. Paths start and end on
  opposite sides of the frame's middle, so they cross; a later object is drawn over an earlier one
  (object id = depth order: i hides every id below it, the plate's object included).
- timing: a still cut-out may move throughout, stop, start late, or pause (`TIMINGS`), with
  smooth (raised-cosine) speed changes. `Composite.moving` says per frame which objects move in the
  world (the plate's and the live objects always count as moving).

The masks are exact by construction: a pixel shows object i exactly where i's warped mask (nearest
neighbour) is set and no higher id's is; the RGB of the cut-out is warped bilinearly from its whole
source frame, so its edges blend with its own original surroundings, never with black.

Everything is a pure function of the seed and the inputs (OpenCV's RANSAC seeds itself): the same
call gives the same clip, bit for bit. `composite_set` builds the development composites from the
DAVIS development clips only and the validation composites from the validation clips only (plate and
objects alike; `mosegpipe.data.davis.DAVIS_VAL`).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe.errors import check_choice

log = logging.getLogger(__name__)

PATH_KINDS = ("translation", "rotation", "scale", "perspective")
"""What changes along an object's path besides its position."""

TIMINGS = ("moving", "stops", "starts", "pauses")
"""When a still cut-out moves: throughout, until some frame, from some frame, or all but a stretch."""

SIZE_HW = (240, 427)
"""Default composite size (H, W): the DAVIS 854x480 frames at half size, to keep runs short."""

PLATE_ID = 1
"""The plate's own annotated object's id in the masks."""


@dataclass(frozen=True)
class Sprite:
    """A cut-out: source frames and the object's mask in them, at the composite's scale.

    Attributes:
        images: (S, h, w, 3) uint8 RGB source frames (S = 1 for a still cut-out).
        masks: (S, h, w) bool, the object in each.
        anchors_xy: (S, 2) the point of each source frame that sits on the path, pixels: the centre of
            the object's box in frame 0 for a still cut-out; for a live one its mask's centroid in each
            frame (the object's own travel in its clip is replaced by the path, its articulation kept).
        height_px: the object's box height in frame 0, pixels (the path's scale 1 maps it to this).
        name: where it came from (a clip name).
    """

    images: npt.NDArray[np.uint8]
    masks: npt.NDArray[np.bool_]
    anchors_xy: npt.NDArray[np.float64]
    height_px: float
    name: str = ""

    @property
    def is_live(self) -> bool:
        """Whether it has frames of its own (the object's own motion) rather than one still."""
        return int(self.images.shape[0]) > 1

    def at(self, t: int) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.bool_], npt.NDArray[np.float64]]:
        """Source frame, mask and anchor for composite frame t (a short live sprite holds its last frame)."""
        s = min(t, int(self.images.shape[0]) - 1)
        return self.images[s], self.masks[s], self.anchors_xy[s]


def sprite_from(images: npt.ArrayLike, masks: npt.ArrayLike, name: str = "") -> Sprite:
    """A sprite from source frames and masks: one frame is anchored at the centre of the object's box,
    several at each frame's mask centroid (a frame without the object keeps the anchor before).

    Args:
        images: (S, h, w, 3) uint8 RGB.
        masks: (S, h, w) bool, the object.
        name: a label for the record.

    Raises:
        ValueError: shapes differ or the object is absent from frame 0.
    """
    im = np.asarray(images, dtype=np.uint8)
    mk = np.asarray(masks, dtype=bool)
    if im.ndim != 4 or mk.shape != im.shape[:3]:
        raise ValueError(f"images {im.shape} and masks {mk.shape} do not pair up as (S, h, w, 3) / (S, h, w)")
    ys, xs = np.nonzero(mk[0])
    if ys.size == 0:
        raise ValueError(f"sprite {name!r}: no object pixel in frame 0")
    anchors = np.empty((im.shape[0], 2), dtype=np.float64)
    anchors[0] = ((float(xs.min()) + float(xs.max())) / 2, (float(ys.min()) + float(ys.max())) / 2)
    if im.shape[0] > 1:
        anchors[0] = (xs.mean(), ys.mean())
        for s in range(1, im.shape[0]):
            yy, xx = np.nonzero(mk[s])
            anchors[s] = (xx.mean(), yy.mean()) if yy.size else anchors[s - 1]
    return Sprite(im, mk, anchors, float(ys.max() - ys.min() + 1), name)


def speed_profile(timing: str, frames: int, rng: np.random.Generator, ramp: int = 3) -> npt.NDArray[np.float64]:
    """(frames - 1,) speed of each step t -> t + 1 in [0, 1]: 1 moving, 0 still, raised-cosine ramps.

    Args:
        timing: one of TIMINGS.
        frames: T.
        rng: draws the stop / start frames.
        ramp: steps over which the speed changes.
    """
    check_choice("timing", timing, TIMINGS)
    n = frames - 1
    on = np.ones(n, dtype=np.float64)
    if timing == "stops":
        on[int(rng.integers(int(0.4 * n), int(0.7 * n) + 1)) :] = 0
    elif timing == "starts":
        on[: int(rng.integers(int(0.3 * n), int(0.6 * n) + 1))] = 0
    elif timing == "pauses":
        a = int(rng.integers(int(0.3 * n), int(0.5 * n) + 1))
        on[a : a + max(2, n // 4)] = 0
    if ramp <= 1 or timing == "moving":
        return on
    # Smooth the on/off steps: a raised-cosine kernel keeps the speed in [0, 1] and exactly 0 deep in a stop.
    k = 0.5 - 0.5 * np.cos(2 * np.pi * (np.arange(ramp) + 1) / (ramp + 1))
    k /= k.sum()
    sm = np.convolve(np.pad(on, (ramp // 2, ramp - 1 - ramp // 2), mode="edge"), k, mode="valid")
    sm[on == 0] = np.minimum(sm[on == 0], 0.0)  # never creep while stopped: a stop is a stop
    return np.clip(sm, 0.0, 1.0)


@dataclass(frozen=True)
class ObjectPath:
    """A smooth path in the plate's frame-0 coordinates, from a sprite's centred coordinates.

    The matrix at progress u in [0, 1] is  T(c(u)) R(u * angle) S(1 + u * (scale - 1)) P(u * tilt),
    with c(u) = start + u (end - start) + sin(pi u) * bend * (the unit normal of end - start), P the
    homography of the sprite's plane turned by the tilt angles about its vertical (x) and horizontal
    (y) axes, seen with a focal length of 1.5 sprite heights.

    Attributes:
        kind: one of PATH_KINDS (for the record; the fields below say what changes).
        start_xy, end_xy: centre at progress 0 and 1, pixels.
        bend_px: sideways bulge of the line at half-way, pixels.
        angle_deg: rotation at progress 1 (image plane, degrees).
        scale: scale at progress 1 (1 = unchanged).
        tilt_deg: (about the vertical, about the horizontal axis) at progress 1, degrees.
        base_scale: sprite pixels -> composite pixels at progress 0.
        speed: (T - 1,) speed of each step (`speed_profile`); progress = its running sum, normalised.
    """

    kind: str
    start_xy: tuple[float, float]
    end_xy: tuple[float, float]
    bend_px: float = 0.0
    angle_deg: float = 0.0
    scale: float = 1.0
    tilt_deg: tuple[float, float] = (0.0, 0.0)
    base_scale: float = 1.0
    focal: float = 150.0
    speed: tuple[float, ...] = ()

    def progress(self, frames: int) -> npt.NDArray[np.float64]:
        """(T,) progress in [0, 1], 0 at frame 0 (all 0 when the object never moves)."""
        v = np.asarray(self.speed if self.speed else np.ones(frames - 1), dtype=np.float64)[: frames - 1]
        cum = np.concatenate([[0.0], np.cumsum(v)])
        return cum / cum[-1] if cum[-1] > 0 else cum

    def matrix(self, u: float) -> npt.NDArray[np.float64]:
        """(3, 3) sprite-centred coordinates -> plate frame-0 coordinates at progress u."""
        s0, s1 = np.asarray(self.start_xy, dtype=np.float64), np.asarray(self.end_xy, dtype=np.float64)
        d = s1 - s0
        normal = np.array([-d[1], d[0]]) / max(float(np.hypot(*d)), 1e-9)
        c = s0 + u * d + math.sin(math.pi * u) * self.bend_px * normal
        a = math.radians(u * self.angle_deg)
        rot = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
        sc = self.base_scale * (1 + u * (self.scale - 1))
        ax, ay = (math.radians(u * t) for t in self.tilt_deg)
        # The plane z = f turned about the y axis by ax and the x axis by ay, projected with focal f:
        # H = K [r1 r2 t] with K = diag(f, f, 1), t = (0, 0, f); it fixes the centre, turns the edges.
        ry = np.array([[math.cos(ax), 0, math.sin(ax)], [0, 1, 0], [-math.sin(ax), 0, math.cos(ax)]])
        rx = np.array([[1, 0, 0], [0, math.cos(ay), -math.sin(ay)], [0, math.sin(ay), math.cos(ay)]])
        r = rx @ ry
        f = self.focal
        tilt = np.diag([f, f, 1.0]) @ np.column_stack([r[:, 0], r[:, 1], [0.0, 0.0, f]])
        tilt /= tilt[2, 2]
        return np.array([[1, 0, c[0]], [0, 1, c[1]], [0, 0, 1]]) @ rot @ np.diag([sc, sc, 1.0]) @ tilt

    def moving(self, frames: int, eps: float = 1e-6) -> npt.NDArray[np.bool_]:
        """(T,) whether the path moves into or out of each frame (a frame between two still steps does not)."""
        step = np.diff(self.progress(frames)) > eps
        out = np.zeros(frames, dtype=bool)
        out[1:] |= step
        out[:-1] |= step
        return out


@dataclass(frozen=True)
class Composite:
    """One composite clip.

    Attributes:
        name: e.g. "dev-03".
        frames: (T, H, W, 3) uint8 RGB.
        masks: (T, H, W) uint8 object ids: 0 = the world (the plate's scene), i = object i, never 255.
        object_ids: the ids of the objects, in depth order (later on top).
        moving: (T, len(object_ids)) bool, whether each object moves in the world in each frame.
        kinds: per object, "plate" or "<path kind>/<timing>/<still|live>".
        sources: per object, the clip it was cut from (the plate's clip for object 1).
        plate: the plate's clip name.
        camera: (T, 3, 3) the plate's estimated homography frame 0 -> t.
    """

    name: str
    frames: npt.NDArray[np.uint8]
    masks: npt.NDArray[np.uint8]
    object_ids: tuple[int, ...]
    moving: npt.NDArray[np.bool_]
    kinds: tuple[str, ...] = ()
    sources: tuple[str, ...] = ()
    plate: str = ""
    camera: npt.NDArray[np.float64] = field(default_factory=lambda: np.eye(3)[None])

    @property
    def num_frames(self) -> int:
        return int(self.frames.shape[0])

    def label_at(self, t: int, xy: npt.ArrayLike) -> npt.NDArray[np.int64]:
        """(N,) object id under each (x, y) pixel position in frame t (rounded, clipped to the frame)."""
        p = np.rint(np.asarray(xy, dtype=np.float64).reshape(-1, 2)).astype(np.int64)
        h, w = self.masks.shape[1:]
        return self.masks[t, np.clip(p[:, 1], 0, h - 1), np.clip(p[:, 0], 0, w - 1)].astype(np.int64)


def compose(
    plate: npt.ArrayLike,
    plate_mask: npt.ArrayLike | None,
    sprites: Sequence[Sprite],
    paths: Sequence[ObjectPath],
    camera: npt.ArrayLike | None = None,
) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.uint8]]:
    """Pastes the sprites over the plate along their paths, in order (a later sprite on top).

    Args:
        plate: (T, H, W, 3) uint8 RGB background frames.
        plate_mask: (T, H, W) bool, the plate's own object (id PLATE_ID), or None (no plate object;
            the sprites are then ids 1, 2, ...).
        sprites: one per pasted object.
        paths: one per sprite.
        camera: (T, 3, 3) homographies plate frame 0 -> t that carry every path (None = identity).

    Returns:
        (frames (T, H, W, 3) uint8, masks (T, H, W) uint8 object ids, 0 = world).
    """
    if len(sprites) != len(paths):
        raise ValueError(f"{len(sprites)} sprites but {len(paths)} paths")
    frames = np.array(plate, dtype=np.uint8, copy=True)
    t_len, h, w = frames.shape[:3]
    masks = np.zeros((t_len, h, w), dtype=np.uint8)
    first = 1
    if plate_mask is not None:
        masks[np.asarray(plate_mask, dtype=bool)] = PLATE_ID
        first = PLATE_ID + 1
    cams = np.broadcast_to(np.eye(3), (t_len, 3, 3)) if camera is None else np.asarray(camera, dtype=np.float64)
    for i, (sprite, path) in enumerate(zip(sprites, paths)):
        oid = first + i
        u = path.progress(t_len)
        for t in range(t_len):
            image, mask, anchor = sprite.at(t)
            centre = np.array([[1, 0, -anchor[0]], [0, 1, -anchor[1]], [0, 0, 1]], dtype=np.float64)
            g = cams[t] @ path.matrix(float(u[t])) @ centre
            warped = cv2.warpPerspective(image, g, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            on = cv2.warpPerspective(mask.astype(np.uint8), g, (w, h), flags=cv2.INTER_NEAREST, borderValue=(0,)) > 0
            frames[t][on] = warped[on]
            masks[t][on] = oid
    return frames, masks


def plate_camera(
    images: npt.ArrayLike, exclude: npt.ArrayLike | None = None, max_corners: int = 400, ransac_px: float = 1.0
) -> npt.NDArray[np.float64]:
    """The plate's camera motion: (T, 3, 3) homographies frame 0 -> t of its background.

    Corners (Shi-Tomasi) outside the excluded pixels of frame t - 1 are tracked to frame t (pyramidal
    Lucas-Kanade), a homography is fitted by RANSAC and chained. A step with fewer than 12 tracked
    corners or no fit is taken as no motion.

    Args:
        images: (T, H, W, 3) uint8 RGB.
        exclude: (T, H, W) bool pixels not to track from (the plate's object), or None.
        max_corners: corners per frame.
        ransac_px: RANSAC reprojection threshold, pixels.
    """
    im = np.asarray(images, dtype=np.uint8)
    gray = [cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in im]
    out = np.repeat(np.eye(3)[None], len(gray), axis=0)
    kernel = np.ones((9, 9), np.uint8)
    ex = None if exclude is None else np.asarray(exclude, dtype=np.uint8)
    for t in range(1, len(gray)):
        allowed = None
        if ex is not None:
            allowed = (cv2.dilate(ex[t - 1], kernel) == 0).astype(np.uint8) * 255
        pts = cv2.goodFeaturesToTrack(gray[t - 1], max_corners, 0.01, 7, mask=allowed)
        step = np.eye(3)
        if pts is not None and len(pts) >= 12:
            nxt, status, _ = cv2.calcOpticalFlowPyrLK(gray[t - 1], gray[t], pts, None, winSize=(21, 21), maxLevel=3)
            ok = status.ravel() == 1
            if ok.sum() >= 12:
                hom, _ = cv2.findHomography(pts[ok], nxt[ok], cv2.RANSAC, ransac_px)
                if hom is not None:
                    step = hom
        out[t] = step @ out[t - 1]
    return out


@dataclass(frozen=True)
class CompositeConfig:
    """How composites are drawn.

    Attributes:
        size_hw: (H, W) of the composite, pixels.
        frames: T.
        num_objects: total objects (the plate's included) cycle through this range by index.
        height_frac: a pasted object's box height, as a fraction of H (drawn uniformly).
        speed_px: a pasted object's mean speed while moving, pixels per frame (drawn uniformly).
        live_share: the chance that a pasted object is live (its own frames) rather than still.
        plate_object: label the plate's own object (True) or leave it in the world.
    """

    size_hw: tuple[int, int] = SIZE_HW
    frames: int = 25
    num_objects: tuple[int, int] = (2, 4)
    height_frac: tuple[float, float] = (0.3, 0.5)
    speed_px: tuple[float, float] = (1.5, 4.0)
    live_share: float = 0.3
    plate_object: bool = True


def random_path(
    rng: np.random.Generator,
    kind: str,
    timing: str,
    size_hw: tuple[int, int],
    frames: int,
    sprite: Sprite,
    cfg: CompositeConfig,
) -> ObjectPath:
    """A path of the given kind and timing: from one side of the frame's middle across to the other.

    The box height is drawn from cfg.height_frac (kept under 45 % of the width, and the cut-out enlarged
    at most 1.5 times), the speed from
    cfg.speed_px; a rotation turns 20-45 degrees, a scale change ends at 0.6-0.8 or 1.3-1.6, a
    perspective tilt turns the plane 30-55 degrees about one axis (and up to 15 about the other).
    """
    check_choice("kind", kind, PATH_KINDS)
    h, w = size_hw
    target = float(rng.uniform(*cfg.height_frac)) * h
    box_w = float(sprite.masks[0].any(axis=0).sum())
    # At most 1.5x the source's pixels: more would show a blurred cut-out.
    base = min(target / sprite.height_px, 0.45 * w / max(box_w, 1.0), 1.5)
    speed = speed_profile(timing, frames, rng)
    travel = float(rng.uniform(*cfg.speed_px)) * max(float(speed.sum()), 1.0)
    centre = np.array([w / 2, h / 2])
    heading = float(rng.uniform(0, 2 * np.pi))
    direction = np.array([math.cos(heading), math.sin(heading)])
    offset = float(rng.uniform(-0.15, 0.15)) * np.array([w, h]) * np.array([-direction[1], direction[0]])
    start = centre - direction * travel / 2 + offset
    end = centre + direction * travel / 2 + offset
    lo, hi = np.array([0.1 * w, 0.15 * h]), np.array([0.9 * w, 0.85 * h])
    start, end = np.clip(start, lo, hi), np.clip(end, lo, hi)
    sign = 1.0 if rng.random() < 0.5 else -1.0
    angle = sign * float(rng.uniform(20, 45)) if kind == "rotation" else 0.0
    scale = float(rng.uniform(0.6, 0.8) if rng.random() < 0.5 else rng.uniform(1.3, 1.6)) if kind == "scale" else 1.0
    tilt = (0.0, 0.0)
    if kind == "perspective":
        big, small = sign * float(rng.uniform(30, 55)), float(rng.uniform(-15, 15))
        tilt = (big, small) if rng.random() < 0.5 else (small, big)
    return ObjectPath(
        kind=kind,
        start_xy=(float(start[0]), float(start[1])),
        end_xy=(float(end[0]), float(end[1])),
        bend_px=float(rng.uniform(-0.15, 0.15)) * travel,
        angle_deg=angle,
        scale=scale,
        tilt_deg=tilt,
        base_scale=base,
        focal=1.5 * target,
        speed=tuple(float(v) for v in speed),
    )


def make_composite(
    name: str,
    plate: npt.ArrayLike,
    plate_mask: npt.ArrayLike,
    sources: Sequence[tuple[str, npt.ArrayLike, npt.ArrayLike]],
    seed: int,
    cfg: CompositeConfig = CompositeConfig(),
    plate_name: str = "",
    camera: npt.ArrayLike | None = None,
) -> Composite:
    """One composite from a plate and object sources, all already at the composite's size.

    The object at position j of `sources` gets path kind PATH_KINDS[(seed + j) % 4]; its timing, still
    or live, placement and motion are drawn from `seed`.

    Args:
        name: the composite's name.
        plate: (T, H, W, 3) uint8 RGB, at least cfg.frames frames (the first are used).
        plate_mask: (T, H, W) bool, the plate's object.
        sources: (clip name, images (S, h, w, 3), masks (S, h, w)) per pasted object; S >= cfg.frames
            for a live cut-out (else it is still).
        seed: the random seed.
        cfg: settings (cfg.size_hw must be the plate's size).
        plate_name: the plate's clip name (for the record).
        camera: (T, 3, 3) the plate's homographies frame 0 -> t (None = `plate_camera`).

    Returns:
        Composite.
    """
    rng = np.random.default_rng(seed)
    t_len = cfg.frames
    pl = np.asarray(plate, dtype=np.uint8)[:t_len]
    pm = np.asarray(plate_mask, dtype=bool)[:t_len]
    if pl.shape[0] < t_len or pl.shape[1:3] != tuple(cfg.size_hw):
        raise ValueError(f"plate is {pl.shape}, need {t_len} frames of {cfg.size_hw}")
    cam = plate_camera(pl, pm) if camera is None else np.asarray(camera, dtype=np.float64)
    sprites, paths, kinds = [], [], []
    moving = [np.ones(t_len, dtype=bool)] if cfg.plate_object else []
    for j, (src_name, images, masks) in enumerate(sources):
        im, mk = np.asarray(images, dtype=np.uint8), np.asarray(masks, dtype=bool)
        live = im.shape[0] >= t_len and rng.random() < cfg.live_share
        sprite = sprite_from(im[:t_len], mk[:t_len], src_name) if live else sprite_from(im[:1], mk[:1], src_name)
        kind = PATH_KINDS[(seed + j) % len(PATH_KINDS)]
        timing = "moving" if live else TIMINGS[int(rng.integers(len(TIMINGS)))]
        path = random_path(rng, kind, timing, cfg.size_hw, t_len, sprite, cfg)
        sprites.append(sprite)
        paths.append(path)
        kinds.append(f"{kind}/{timing}/{'live' if live else 'still'}")
        moving.append(np.ones(t_len, dtype=bool) if live else path.moving(t_len))
    frames, ids = compose(pl, pm if cfg.plate_object else None, sprites, paths, cam)
    first = PLATE_ID + 1 if cfg.plate_object else 1
    object_ids = ((PLATE_ID,) if cfg.plate_object else ()) + tuple(range(first, first + len(sprites)))
    return Composite(
        name=name,
        frames=frames,
        masks=ids,
        object_ids=object_ids,
        moving=np.stack(moving, axis=1) if moving else np.zeros((t_len, 0), dtype=bool),
        kinds=(("plate",) if cfg.plate_object else ()) + tuple(kinds),
        sources=((plate_name,) if cfg.plate_object else ()) + tuple(s[0] for s in sources),
        plate=plate_name,
        camera=cam,
    )


def _resized(
    images: npt.NDArray[np.uint8], gt: npt.NDArray[np.bool_], size_hw: tuple[int, int]
) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.bool_]]:
    h, w = size_hw
    im = np.stack([cv2.resize(f, (w, h), interpolation=cv2.INTER_AREA) for f in images])
    mk = np.stack([cv2.resize(m.astype(np.float32), (w, h), interpolation=cv2.INTER_AREA) > 0.5 for m in gt])
    return im, mk


COMPOSITES_PER_PART = 10
"""Composites per part (dev / val) by default."""

SEED = 41
"""Base seed of the composites that `moseg eval composite` scores (training composites use others)."""


def composite_names(part: str, count: int = COMPOSITES_PER_PART) -> list[str]:
    """The names of a part's composites: "<part>-00", "<part>-01", ..."""
    return [f"{part}-{i:02d}" for i in range(count)]


def composite_set(
    root: str | Path,
    part: str,
    count: int = COMPOSITES_PER_PART,
    seed: int = SEED,
    cfg: CompositeConfig = CompositeConfig(),
    names: Sequence[str] | None = None,
) -> list[Composite]:
    """The composites of one part of the DAVIS split, from that part's clips only.

    Composite i uses clip i (mod the part's clips, in alphabetical order) as the plate and
    num_objects - 1 other clips of the same part, drawn from the seed, as pasted objects; num_objects
    cycles through cfg.num_objects (2, 3, 4, 2, ...).

    Args:
        root: the ``davis2016-train`` folder or a data root holding it.
        part: "dev" or "val".
        count: how many.
        seed: base seed (composite i of part p is a pure function of (seed, p, i)).
        cfg: settings.
        names: only these composites (e.g. ["dev-03"]); None = all `count`.

    Raises:
        ConfigError: an unknown part.
        DatasetError: a clip is missing or unreadable.
    """
    from mosegpipe.data.davis import DAVIS_DEV, DAVIS_VAL, read_davis_clip

    check_choice("part", part, ("dev", "val"))
    clips = list(DAVIS_DEV if part == "dev" else DAVIS_VAL)
    wanted = composite_names(part, count) if names is None else list(names)
    cache: dict[tuple[str, int], tuple[npt.NDArray[np.uint8], npt.NDArray[np.bool_]]] = {}

    def read(clip: str, frames: int) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.bool_]]:
        if (clip, frames) not in cache:
            c = read_davis_clip(root, clip, max_frames=frames)
            cache[(clip, frames)] = _resized(c.images, c.gt, cfg.size_hw)
        return cache[(clip, frames)]

    lo, hi = cfg.num_objects
    out = []
    for name in wanted:
        i = int(name.rsplit("-", 1)[1])
        rng = np.random.default_rng([seed, ("dev", "val").index(part), i])
        plate_clip = clips[i % len(clips)]
        k = lo + i % (hi - lo + 1)
        others = [c for c in clips if c != plate_clip]
        picked = [others[j] for j in rng.choice(len(others), size=k - (1 if cfg.plate_object else 0), replace=False)]
        plate, plate_mask = read(plate_clip, cfg.frames)
        sources = [(c, *read(c, cfg.frames)) for c in picked]
        sub_seed = int(rng.integers(2**31))
        out.append(make_composite(name, plate, plate_mask, sources, sub_seed, cfg, plate_name=plate_clip))
        log.info("%s: plate %s, objects %s", name, plate_clip, ", ".join(picked))
    return out
