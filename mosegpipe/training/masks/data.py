"""The mask network's training data: frames with exact "not the world" truth, as network inputs.

Three sources, each turned into (features, truth) per frame with the pipeline's own flow code
(`moving_pixels.stack_motion`'s evidence, `features.clip_features`), cut into 5-frame stacks as a clip run
cuts them (each stack with the frames next to it as flow evidence, as `Frames.before / after` give it):

- "rendered": photo-textured rendered clips (`synth.render`: depth, a ground plane, a moving camera,
  0-3 moving planes and boxes, noise); clips with no object are the hard negatives (the whole frame
  is the world however the camera moves). Truth: every object pixel.
- "composites": DAVIS development objects pasted over DAVIS development clips (`synth.composite`),
  those that use no held-out clip. Truth: the pixels of objects that move in the world in that frame.
- "davis": the DAVIS-2016 development clips (`DAVIS_DEV`) but the held-out ones, with their human masks.

The held-out clips (`HELD_OUT`: every fifth development clip, fixed before any result) choose the
training step and the threshold. No validation clip (`DAVIS_VAL`) enters any source: `source_clips`
lists what each source reads, and a test holds it to that.

Each source's arrays are cached (`io.default_cache_dir`, keyed by the settings), float16.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from mosegpipe.data.davis import DAVIS_DEV, DAVIS_VAL, read_davis_clip
from mosegpipe.errors import ConfigError
from mosegpipe.masks.learned.features import clip_features, net_size
from mosegpipe.masks.moving_pixels import MotionMaskConfig
from mosegpipe.points.flow import frame_motion

log = logging.getLogger(__name__)

HELD_OUT = DAVIS_DEV[::5]
"""Development clips kept out of training to choose the step and threshold: every fifth (bear, dog-agility,
lucia, rollerblade), a rule fixed before any result."""

TRAIN_DAVIS = tuple(c for c in DAVIS_DEV if c not in HELD_OUT)
"""The development clips the network trains on (16)."""

STACK = 5
"""Frames per stack, as a clip run segments them."""


@dataclass(frozen=True)
class DataConfig:
    """What the training sources hold.

    Attributes:
        rendered_clips: rendered clips (seeds 0..n-1 mixed with `seed`).
        rendered_frames: frames per rendered clip.
        rendered_sizes: frame sizes drawn from, (H, W).
        no_object_share: share of rendered clips with no moving object (hard negatives).
        composites: composites drawn (those touching a held-out clip are left out).
        composite_seed: base seed of those composites; never `synth.composite.SEED`, the seed of the
            composites that `moseg eval composite` scores (the same as the embedding's `composite-own`).
        scale: the network's input scale (`LearnedMaskConfig.scale`).
        motion_blur_share: share of rendered clips whose frames are blurred along a line (a shaking camera's blur;
            0.3 with `water_clips` 12 scored held-out 0.738 / 0.743 against 0.790 / 0.761 on two seeds: off).
        water_clips: clips of rippling water with no object (`synth.water`; hard negatives, every pixel the world;
            the recipe reads them when `MaskTrainConfig.sources` names "water").
        water_seed: the first water clip's seed (above `synth.water.SCORED_SEEDS`, which the benchmark scores).
        seed: mixed into every random choice.
    """

    rendered_clips: int = 100
    rendered_frames: int = 10
    rendered_sizes: tuple[tuple[int, int], ...] = ((480, 640), (360, 640), (480, 854))
    no_object_share: float = 0.2
    composites: int = 20
    composite_seed: int = 1041
    scale: float = 0.25
    motion_blur_share: float = 0.0
    water_clips: int = 0
    water_seed: int = 1000
    seed: int = 42


@dataclass
class Frames4Net:
    """Network inputs and truth of a source's frames (each frame may have its own size).

    Attributes:
        features: per frame, (C, h, w) float16.
        truth: per frame, (h, w) float16 share of the pixel's area that is not the world.
        names: per frame, "<clip>/<t>".
    """

    features: list[npt.NDArray[np.float16]]
    truth: list[npt.NDArray[np.float16]]
    names: list[str]


def _area_truth(mask: npt.NDArray[np.bool_], hw: tuple[int, int]) -> npt.NDArray[np.float16]:
    import cv2

    return cv2.resize(mask.astype(np.float32), (hw[1], hw[0]), interpolation=cv2.INTER_AREA).astype(np.float16)


def stacks(num: int, size: int = STACK) -> list[tuple[int, int]]:
    """(first, end) of the consecutive stacks of `size` frames of a clip of `num` frames (a last stack of
    fewer, at least 2; a lone last frame joins the stack before)."""
    out = [(a, min(a + size, num)) for a in range(0, num, size)]
    if len(out) > 1 and out[-1][1] - out[-1][0] < 2:
        out[-2] = (out[-2][0], num)
        out.pop()
    return out


def clip_to_net(images: npt.NDArray[np.uint8], truth: npt.NDArray[np.bool_], name: str, scale: float) -> Frames4Net:
    """One clip's frames as network inputs and truth, stack by stack (the pipeline's flow settings)."""
    motion = frame_motion(images, MotionMaskConfig().flow)
    hw = net_size(images.shape[1:3], scale)
    out = Frames4Net([], [], [])
    for a, b in stacks(len(images)):
        feats = clip_features(images[a:b], motion.frames(a, b), scale)
        for t in range(a, b):
            out.features.append(feats[t - a].astype(np.float16))
            out.truth.append(_area_truth(truth[t], hw))
            out.names.append(f"{name}/{t}")
    return out


def _join(parts: list[Frames4Net]) -> Frames4Net:
    return Frames4Net(
        [f for p in parts for f in p.features], [t for p in parts for t in p.truth], [n for p in parts for n in p.names]
    )


def davis_frames(root: str | Path, clips: tuple[str, ...], scale: float) -> Frames4Net:
    """The DAVIS clips named (never a validation clip) as network inputs and truth."""
    if set(clips) & set(DAVIS_VAL):
        raise ValueError(f"validation clips never train or choose anything: {sorted(set(clips) & set(DAVIS_VAL))}")
    parts = []
    for name in clips:
        clip = read_davis_clip(root, name)
        parts.append(clip_to_net(clip.images, clip.gt, f"davis/{name}", scale))
        log.info("masknet data: davis/%s, %d frames", name, clip.num_frames)
    return _join(parts)


def render_config(cfg: DataConfig, i: int) -> Any:
    """The `synth.render.RenderConfig` of rendered training clip i (seeded by `cfg.seed` and i)."""
    from mosegpipe.synth.render import RenderConfig

    rng = np.random.default_rng([cfg.seed, 1, i])
    empty = rng.random() < cfg.no_object_share
    return RenderConfig(
        size_hw=cfg.rendered_sizes[int(rng.integers(len(cfg.rendered_sizes)))],
        frames=cfg.rendered_frames,
        num_objects=0 if empty else int(rng.integers(1, 4)),
        seed=int(rng.integers(2**31)),
        camera_motion=("static", "pan", "forward", "handheld")[int(rng.integers(4))],
        texture="photo",
        object_speed_px=(0.5, 6.0),
        ground=bool(rng.random() < 0.5),
        noise_std=float(rng.uniform(0.0, 3.0)),
    )


def rendered_frames(root: str | Path, cfg: DataConfig) -> Frames4Net:
    """Photo-textured rendered clips (the textures of `own_tracks.texture_photos`: no DAVIS frame)."""
    from mosegpipe.synth.render import render_clip
    from mosegpipe.training.own_tracks import texture_photos

    photos = [im for _, im in texture_photos(root)]
    parts = []
    for i in range(cfg.rendered_clips):
        clip = render_clip(render_config(cfg, i), photos)
        parts.append(clip_to_net(rendered_images(cfg, i, clip.frames), clip.masks > 0, f"rendered/{i}", cfg.scale))
    log.info("masknet data: %d rendered clips", cfg.rendered_clips)
    return _join(parts)


def rendered_images(cfg: DataConfig, i: int, frames: npt.NDArray[np.uint8]) -> npt.NDArray[np.uint8]:
    """Rendered clip i's frames as the network trains on them: with `cfg.motion_blur_share` chance blurred along a
    line (3-12 px, one direction per clip, the length varying by frame by x0.5-1.5; seeded by `cfg.seed` and i)."""
    import cv2

    rng = np.random.default_rng([cfg.seed, 3, i])
    if rng.random() >= cfg.motion_blur_share:
        return frames
    length, angle = rng.uniform(3.0, 12.0), rng.uniform(0.0, np.pi)
    out = np.empty_like(frames)
    for t, frame in enumerate(frames):
        size = max(2, round(length * rng.uniform(0.5, 1.5)))
        kernel = np.zeros((2 * size + 1, 2 * size + 1), np.float32)
        d = np.array([np.cos(angle), np.sin(angle)]) * size / 2
        p0, p1 = np.round(size - d).astype(int), np.round(size + d).astype(int)
        cv2.line(kernel, (int(p0[0]), int(p0[1])), (int(p1[0]), int(p1[1])), 1.0, 1)
        out[t] = cv2.filter2D(frame, -1, kernel / kernel.sum(), borderType=cv2.BORDER_REFLECT)
    return out


def water_frames(cfg: DataConfig) -> Frames4Net:
    """Clips of rippling water with no object (`synth.water`, seeds from `cfg.water_seed`): truth 0 everywhere."""
    from mosegpipe.synth.water import CAMERAS, SCORED_SEEDS, water_clip

    if cfg.water_seed < SCORED_SEEDS.stop:
        raise ConfigError(f"masknet water clips: seeds below {SCORED_SEEDS.stop} are the benchmark's; choose another")
    parts = []
    for i in range(cfg.water_clips):
        rng = np.random.default_rng([cfg.seed, 4, i])
        size = cfg.rendered_sizes[int(rng.integers(len(cfg.rendered_sizes)))]
        frames = water_clip(cfg.water_seed + i, cfg.rendered_frames, size, CAMERAS[i % len(CAMERAS)])
        parts.append(clip_to_net(frames, np.zeros(frames.shape[:3], bool), f"water/{i}", cfg.scale))
    log.info("masknet data: %d water clips", cfg.water_clips)
    return _join(parts)


def training_composites(
    root: str | Path, cfg: DataConfig, held_out: bool = False
) -> Iterator[tuple[Any, npt.NDArray[np.uint8]]]:
    """The development composites drawn with `cfg.composite_seed` that use no held-out clip (plate or object; with
    `held_out`, those that do), each with its (T, H, W) ids of the objects that move in the world in each frame
    (0 elsewhere).

    Raises:
        ConfigError: the seed is that of the scored development composites.
    """
    from mosegpipe.synth.composite import SEED, composite_set

    if cfg.composite_seed == SEED:
        raise ConfigError(f"masknet composites: seed {SEED} makes the scored development composites; choose another")
    for comp in composite_set(root, "dev", count=cfg.composites, seed=cfg.composite_seed):
        used = {comp.plate, *comp.sources}
        if bool(used & set(HELD_OUT)) != held_out or used & set(DAVIS_VAL):
            continue
        ids = np.asarray(comp.object_ids)
        moving = [np.isin(comp.masks[t], ids[comp.moving[t]]) for t in range(comp.num_frames)]
        yield comp, np.where(np.stack(moving), comp.masks, 0).astype(np.uint8)


def composite_frames(root: str | Path, cfg: DataConfig, held_out: bool = False) -> Frames4Net:
    """`training_composites` as network inputs; truth: the pixels of the objects that move in the world."""
    parts = [
        clip_to_net(comp.frames, moving > 0, f"composite/{comp.name}", cfg.scale)
        for comp, moving in training_composites(root, cfg, held_out)
    ]
    log.info("masknet data: %d composites", len(parts))
    return _join(parts)


def source_clips(cfg: DataConfig = DataConfig()) -> dict[str, tuple[str, ...]]:
    """The DAVIS clips each source may read (the composites: at most these, as plate or object)."""
    return {
        "davis": TRAIN_DAVIS,
        "composites": tuple(c for c in DAVIS_DEV if c not in HELD_OUT),
        "held-out": HELD_OUT,
        "composites-held-out": DAVIS_DEV,
        "rendered": (),
        "water": (),
    }


def _to_arrays(frames: Frames4Net) -> dict[str, npt.NDArray[Any]]:
    out: dict[str, npt.NDArray[Any]] = {"names": np.array(frames.names)}
    for i, (f, t) in enumerate(zip(frames.features, frames.truth)):
        out[f"f{i}"], out[f"t{i}"] = f, t
    return out


def _from_arrays(arrays: dict[str, npt.NDArray[Any]]) -> Frames4Net:
    names = [str(n) for n in arrays["names"]]
    return Frames4Net([arrays[f"f{i}"] for i in range(len(names))], [arrays[f"t{i}"] for i in range(len(names))], names)


def load_source(
    name: str, root: str | Path, cfg: DataConfig = DataConfig(), cache_dir: Path | None = None
) -> Frames4Net:
    """A source's frames ("rendered", "water", "composites", "davis", "held-out", "composites-held-out": the composites that
    use a held-out clip, which only the per-motion network's recipe scores), from the cache when there."""
    from mosegpipe.io.read import default_cache_dir
    from mosegpipe.io.write import write_npz
    from mosegpipe.training.own_tracks import cache_key

    key = cache_key(f"masknet-{name}", cfg=asdict(cfg), flow=MotionMaskConfig().flow, clips=source_clips(cfg)[name])
    path = Path(cache_dir or default_cache_dir()) / f"masknet-{name}-{key}.npz"
    if path.exists():
        with np.load(path) as z:
            return _from_arrays({k: z[k] for k in z.files})
    if name == "rendered":
        frames = rendered_frames(root, cfg)
    elif name == "water":
        frames = water_frames(cfg)
    elif name in ("composites", "composites-held-out"):
        frames = composite_frames(root, cfg, held_out=name == "composites-held-out")
    elif name in ("davis", "held-out"):
        frames = davis_frames(root, source_clips(cfg)[name], cfg.scale)
    else:
        raise ValueError(f"unknown masknet source {name!r}")
    path.parent.mkdir(parents=True, exist_ok=True)
    write_npz(path, **_to_arrays(frames))
    return frames
