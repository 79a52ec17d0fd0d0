"""Training clips made by the pipeline's own front end, labelled from the benchmarks' ground truth.

The benchmark trajectories are not what the tool meets: KT3DMoSeg's labelled tracks sit on an 8 px
seeding grid and cover some surfaces only, AdelaideRMF's correspondences are a curated set with a
fixed share of gross outliers. A model fitted to those point sets falls apart on our own tracks,
whose density and coverage differ (the context normalisation sees different statistics). Here the
benchmark images go through our own KLT tracker / SIFT matcher, and our points take labels from the
ground truth by motion agreement (`mosegpipe.evaluation.label_transfer`); points that cannot be
labelled reliably keep label -1: they enter the context normalisation but not the loss.

Tracking every window is slow next to training (about 0.3 s per 5-frame KT3DMoSeg window), so the
labelled points are cached on disk, one file per sequence / pair, under a folder named by a hash of
everything they depend on (front-end settings, transfer settings, frame count, format version).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
from collections.abc import Callable, Collection
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from mosegpipe.data.labels import remap_labels
from mosegpipe.errors import ConfigError
from mosegpipe.evaluation.label_transfer import (
    PairTransferConfig,
    TrackTransferConfig,
    transfer_match_labels,
    transfer_track_labels,
)
from mosegpipe.io.read import default_cache_dir, write_npz
from mosegpipe.points.klt import TrackConfig, track_klt
from mosegpipe.points.sift import MatchConfig, match_sift
from mosegpipe.points.trajectories import build_trajectories
from mosegpipe.synth.composite import Composite, CompositeConfig
from mosegpipe.types import Frames, LabeledClip

log = logging.getLogger(__name__)

CACHE_VERSION = 1
"""Bumped whenever the cached content changes meaning; part of every cache key."""

MIN_LABELLED = 10
"""A window with fewer labelled points than this teaches nothing and is left out."""


def cache_key(kind: str, **settings: Any) -> str:
    """A short stable hash of a cache's kind, format version and settings (dataclasses included)."""
    plain = {
        k: dataclasses.asdict(v) if dataclasses.is_dataclass(v) and not isinstance(v, type) else v
        for k, v in settings.items()
    }
    blob = json.dumps({"kind": kind, "version": CACHE_VERSION, **plain}, sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:12]


def _load_or_build(path: Path, build: Callable[[], dict[str, npt.NDArray[Any]]]) -> dict[str, npt.NDArray[Any]]:
    """The cached arrays at `path`, built (and written atomically) first when missing."""
    if path.exists():
        with np.load(path) as z:
            return {k: z[k] for k in z.files}
    arrays = build()
    write_npz(path, **arrays)
    return arrays


def kt3d_own_clips(
    data_root: str | Path,
    frames: int = 5,
    exclude: Collection[str] = (),
    track: TrackConfig = TrackConfig(),
    transfer: TrackTransferConfig = TrackTransferConfig(),
    cache_dir: str | Path | None = None,
) -> list[LabeledClip]:
    """Our KLT tracks of every F-frame window of the KT3DMoSeg sequences, labelled by motion agreement.

    Args:
        data_root: the data folder holding ``kt3dmoseg/``.
        frames: F, frames per window (every start is used, stride 1).
        exclude: sequence names to leave out (held-out folds never reach training).
        track: KLT settings (the pipeline's defaults: what `moseg run` produces).
        transfer: label-transfer settings.
        cache_dir: where tracked windows are cached (None = `default_cache_dir()`).

    Returns:
        LabeledClips named "<sequence>/f<a>-<b>" with traj (N, 2F) float32 pixels and labels (N,)
        int64: 0 = background (camera motion), 1.. = the sequence's objects, -1 = not labelled
        (context only). Windows with fewer than MIN_LABELLED labelled points are left out.

    Raises:
        DatasetError: the KT3DMoSeg folder is missing or malformed.
    """
    from mosegpipe.data.kt3dmoseg import kt3d_frame_paths, list_kt3d_sequences, read_kt3d_sequence
    from mosegpipe.io.read import read_image

    folder = (
        Path(cache_dir or default_cache_dir())
        / f"kt3d-own-f{frames}-{cache_key('kt3d-own', frames=frames, track=track, transfer=transfer)}"
    )
    clips: list[LabeledClip] = []
    for name in list_kt3d_sequences(data_root):
        if name in exclude:
            continue

        def build(name: str = name) -> dict[str, npt.NDArray[Any]]:
            seq = read_kt3d_sequence(data_root, name)
            images = [read_image(p) for p in kt3d_frame_paths(data_root, name)[: seq.num_frames]]
            out: dict[str, npt.NDArray[Any]] = {}
            for s in range(len(images) - frames + 1):
                tracks = track_klt(Frames(images=np.stack(images[s : s + frames]), source=name), track)
                traj = build_trajectories(tracks, frames=frames)
                window = slice(s, s + frames)
                labels = transfer_track_labels(
                    tracks.xy[traj.track_ids], seq.xy[:, window], seq.visible[:, window], seq.labels, transfer
                )
                out[f"{s}/traj"] = traj.data
                out[f"{s}/labels"] = labels
            log.info("%s: tracked %d windows", name, len(images) - frames + 1)
            return out

        arrays = _load_or_build(folder / f"{name}.npz", build)
        clips += _window_clips(arrays, name, frames, "kt3d-own", lambda labels: int((labels >= 0).sum()))
    return clips


def _fewer_side(labels: npt.NDArray[np.int64]) -> int:
    """Tracks on the side (object 1 or rest 0) with fewer of them."""
    return min(int((labels == 1).sum()), int((labels == 0).sum()))


def _window_clips(
    arrays: dict[str, npt.NDArray[Any]],
    name: str,
    frames: int,
    dataset: str,
    labelled: Callable[[npt.NDArray[np.int64]], int],
) -> list[LabeledClip]:
    """The tracked windows of one sequence ("<start>/traj", "<start>/labels") as LabeledClips named
    "<name>/f<a>-<b>", leaving out those where `labelled(labels)` is under MIN_LABELLED."""
    clips = []
    for s in sorted(int(k.split("/")[0]) for k in arrays if k.endswith("/traj")):
        labels = arrays[f"{s}/labels"]
        if labelled(labels) < MIN_LABELLED:
            continue
        clips.append(
            LabeledClip(
                name=f"{name}/f{s + 1}-{s + frames}",
                traj=arrays[f"{s}/traj"],
                labels=labels,
                dataset=dataset,
                meta={"sequence": name, "start": s},
            )
        )
    return clips


def adelaide_own_clips(
    data_root: str | Path,
    exclude: Collection[str] = (),
    match: MatchConfig = MatchConfig(),
    transfer: PairTransferConfig = PairTransferConfig(),
    cache_dir: str | Path | None = None,
) -> list[LabeledClip]:
    """Our SIFT matches of the AdelaideRMF image pairs, labelled by motion agreement.

    Args:
        data_root: the data folder holding ``adelaidermf/``.
        exclude: pair names to leave out.
        match: SIFT settings (the pipeline's defaults: what `moseg pair` produces).
        transfer: label-transfer settings.
        cache_dir: where matched pairs are cached (None = `default_cache_dir()`).

    Returns:
        One LabeledClip per pair, traj (N, 4) float32 [x1, y1, x2, y2] pixels, labels (N,) int64 with
        gross outliers as group 0 when the pair has any, the motions after them in file order, and -1
        for matches that could not be labelled (context only).
    """
    from mosegpipe.data.adelaidermf import list_adelaide, read_adelaide_pair

    folder = (
        Path(cache_dir or default_cache_dir())
        / f"adelaide-own-{cache_key('adelaide-own', match=match, transfer=transfer)}"
    )
    clips = []
    for name in list_adelaide(data_root):
        if name in exclude:
            continue

        def build(name: str = name) -> dict[str, npt.NDArray[Any]]:
            pair = read_adelaide_pair(data_root, name)
            m = match_sift(pair.img1, pair.img2, match)
            raw = transfer_match_labels(m.xy1, m.xy2, pair.xy1, pair.xy2, pair.labels, transfer)
            labels = np.full(raw.shape, -1, dtype=np.int64)
            known = raw >= 0
            if known.any():
                labels[known] = remap_labels(raw[known])[0]  # file label 0 (outliers) -> group 0
            traj = np.concatenate([m.xy1, m.xy2], axis=1).astype(np.float32)
            return {"traj": traj, "labels": labels}

        arrays = _load_or_build(folder / f"{name}.npz", build)
        if int((arrays["labels"] >= 0).sum()) < MIN_LABELLED:
            continue
        clips.append(
            LabeledClip(
                name=name, traj=arrays["traj"], labels=arrays["labels"], dataset="adelaide-own", meta={"sequence": name}
            )
        )
    return clips


def davis_dev_own_clips(
    data_root: str | Path,
    frames: int = 5,
    exclude: Collection[str] = (),
    track: TrackConfig = TrackConfig(),
    boundary_px: int = 5,
    cache_dir: str | Path | None = None,
) -> list[LabeledClip]:
    """Our KLT tracks of every F-frame window of the DAVIS-2016 train clips of the development part.

    The validation part (`data.davis.DAVIS_VAL`) is never read: it stays held out for scoring. Labels
    from the human masks: 1 = inside the mask of the main moving object in every frame of the window,
    0 = farther than `boundary_px` from it in every frame, -1 (context only) otherwise. Other moving
    things are 0 here, as the masks leave them out: a weak label of the background.

    Args:
        data_root: the data folder holding ``davis2016-train/``.
        frames: F, frames per window (every start is used, stride 1).
        exclude: clip names to leave out.
        track: KLT settings (the pipeline's defaults).
        boundary_px: tracks this close to the mask's border in some frame stay unlabelled.
        cache_dir: where tracked windows are cached (None = `default_cache_dir()`).

    Returns:
        LabeledClips named "<clip>/f<a>-<b>", traj (N, 2F) float32 pixels, labels (N,) int64.
    """
    import cv2

    from mosegpipe.data.davis import davis_split, list_davis_clips, read_davis_clip

    folder = (
        Path(cache_dir or default_cache_dir())
        / f"davis-dev-own-f{frames}-{cache_key('davis-dev-own', frames=frames, track=track, boundary_px=boundary_px)}"
    )
    kernel = np.ones((2 * boundary_px + 1, 2 * boundary_px + 1), np.uint8)
    clips: list[LabeledClip] = []
    for name in davis_split(list_davis_clips(data_root), "dev"):
        if name in exclude:
            continue

        def build(name: str = name) -> dict[str, npt.NDArray[Any]]:
            clip = read_davis_clip(data_root, name)
            inside = np.stack([cv2.erode(g.astype(np.uint8), kernel) > 0 for g in clip.gt])
            near = np.stack([cv2.dilate(g.astype(np.uint8), kernel) > 0 for g in clip.gt])
            height, width = clip.gt.shape[1:]
            out: dict[str, npt.NDArray[Any]] = {}
            for s in range(clip.num_frames - frames + 1):
                tracks = track_klt(Frames(images=clip.images[s : s + frames], source=name), track)
                traj = build_trajectories(tracks, frames=frames)
                xy = np.round(traj.data.reshape(-1, frames, 2)).astype(np.int64)
                xs, ys = np.clip(xy[..., 0], 0, width - 1), np.clip(xy[..., 1], 0, height - 1)
                ts = np.arange(s, s + frames)[None, :]
                labels = np.full(len(xy), -1, np.int64)
                labels[inside[ts, ys, xs].all(axis=1)] = 1
                labels[~near[ts, ys, xs].any(axis=1)] = 0
                out[f"{s}/traj"] = traj.data
                out[f"{s}/labels"] = labels
            log.info("%s: tracked %d windows", name, clip.num_frames - frames + 1)
            return out

        arrays = _load_or_build(folder / f"{name}.npz", build)
        clips += _window_clips(arrays, name, frames, "davis-dev-own", _fewer_side)
    return clips


@dataclass(frozen=True)
class RenderedTracksConfig:
    """What `rendered_own_clips` renders and how it labels our tracks of it.

    Attributes:
        num_clips: clips rendered (seeds 0..num_clips-1 mixed with `seed`).
        sizes_hw: frame sizes drawn from, (H, W): a wide KITTI-like one and two common video ones.
        objects: (min, max) moving objects per clip.
        camera_motions: camera motions drawn from (synth.camera.VIDEO_MOTIONS).
        object_speed_px: range of the objects' image speed, pixels per frame.
        ground_prob: chance of a ground plane below the wall.
        noise_std: range of the Gaussian pixel noise, grey levels.
        boundary_px: a track closer than this to a change of mask label (in its first or last
            frame) stays unlabelled: KLT windows straddling two surfaces follow either.
        seed: mixed into every clip's seed.
        near_static: (min, max) still boxes 1.5-3 m from the camera per clip, part of the static world (label 0).
        follow_prob: chance that the camera follows the first object (RenderConfig.follow).
    """

    num_clips: int = 400
    sizes_hw: tuple[tuple[int, int], ...] = ((375, 1242), (480, 640), (360, 640))
    objects: tuple[int, int] = (1, 4)
    camera_motions: tuple[str, ...] = ("static", "pan", "forward", "handheld")
    object_speed_px: tuple[float, float] = (0.5, 6.0)
    ground_prob: float = 0.5
    noise_std: tuple[float, float] = (0.0, 3.0)
    boundary_px: int = 3
    seed: int = 0
    near_static: tuple[int, int] = (0, 0)
    follow_prob: float = 0.0


PhotoLoader = Callable[[], list[tuple[str, npt.NDArray[np.uint8]]]]
"""Reads one texture source: its (name, RGB uint8 image) pairs."""


def texture_sources(data_root: str | Path, exclude: Collection[str] = ()) -> list[tuple[str, PhotoLoader]]:
    """The files that texture rendered clips, each with a loader, without reading any image.

    AdelaideRMF pairs (both images), the OpenCV sample PNGs and every 100th / 34th frame of the sample
    videos. KT3DMoSeg frames are deliberately not among them, so that no KT3DMoSeg leave-one-out fold
    sees its test sequence through a texture; AdelaideRMF pairs named in `exclude` are left out too.

    Returns:
        (source name, loader) pairs in a fixed order.
    """
    from mosegpipe.data.adelaidermf import list_adelaide, read_adelaide_pair
    from mosegpipe.io.read import read_image, read_video

    root = Path(data_root)
    sources: list[tuple[str, PhotoLoader]] = []

    def pair_images(name: str) -> list[tuple[str, npt.NDArray[np.uint8]]]:
        pair = read_adelaide_pair(root, name)
        return [(f"adelaidermf/{name}/1", pair.img1), (f"adelaidermf/{name}/2", pair.img2)]

    def image(png: Path) -> list[tuple[str, npt.NDArray[np.uint8]]]:
        return [(f"videos/{png.name}", read_image(png))]

    def video_frames(clip: str, every: int) -> list[tuple[str, npt.NDArray[np.uint8]]]:
        frames = read_video(root / "videos" / clip).images
        return [(f"videos/{clip}/{t}", frames[t]) for t in range(0, len(frames), every)]

    if (root / "adelaidermf").is_dir():
        for name in list_adelaide(root):
            if name not in exclude:
                sources.append((f"adelaidermf/{name}", partial(pair_images, name)))
    videos = root / "videos"
    for png in sorted(videos.glob("*.png")) if videos.is_dir() else []:
        sources.append((f"videos/{png.name}", partial(image, png)))
    for clip, every in (("vtest.avi", 100), ("tree.avi", 34)):
        if (videos / clip).is_file():
            sources.append((f"videos/{clip}/every-{every}", partial(video_frames, clip, every)))
    return sources


def texture_photos(data_root: str | Path, exclude: Collection[str] = ()) -> list[tuple[str, npt.NDArray[np.uint8]]]:
    """The photographs of `texture_sources`, read: (name, RGB uint8 image) pairs in a fixed order."""
    return [photo for _, load in texture_sources(data_root, exclude) for photo in load()]


def label_rendered_tracks(
    clip: Any, xy: npt.NDArray[np.floating], boundary_px: int, start: int = 0
) -> npt.NDArray[np.int64]:
    """Labels of tracked points from a rendered clip's masks: the surface under the point in every
    frame when it is the same one (and no other lies within `boundary_px` in the first and last
    frame), else -1.

    Args:
        clip: a synth.render.RenderedClip, or anything with its `label_at(t, xy)` (a synth.composite.Composite).
        xy: (N, F, 2) our track positions in frames start..start+F-1 of the clip.
        boundary_px: see RenderedTracksConfig.
        start: the clip's frame of xy[:, 0].

    Returns:
        (N,) int64 mask ids (0 = background, i = object i) or -1.
    """
    n, f = xy.shape[:2]
    per_frame = np.stack([clip.label_at(start + t, xy[:, t]) for t in range(f)], axis=1)
    labels = per_frame[:, 0].copy()
    ok = (per_frame == labels[:, None]).all(axis=1)
    b = boundary_px
    for t in (0, f - 1):
        for dx, dy in ((b, 0), (-b, 0), (0, b), (0, -b), (b, b), (-b, -b), (b, -b), (-b, b)):
            ok &= clip.label_at(start + t, xy[:, t] + [dx, dy]) == labels
    labels[~ok] = -1
    return labels.astype(np.int64)


def _near_scene(cfg: RenderedTracksConfig, rng: np.random.Generator) -> dict[str, Any]:
    """The near static structure and camera following of one rendered clip (none by default: the draws of
    the default clips are left as they were)."""
    if cfg.near_static == (0, 0) and cfg.follow_prob == 0:
        return {}
    near = int(rng.integers(cfg.near_static[0], cfg.near_static[1] + 1))
    return {"near_static": near, "follow": bool(rng.random() < cfg.follow_prob)}


def rendered_own_clips(
    data_root: str | Path,
    frames: int = 5,
    exclude: Collection[str] = (),
    cfg: RenderedTracksConfig = RenderedTracksConfig(),
    track: TrackConfig = TrackConfig(),
    cache_dir: str | Path | None = None,
) -> list[LabeledClip]:
    """Our KLT tracks of rendered clips textured with real photographs, labelled from the rendered masks.

    Every clip is a random scene (synth.render) of 1-4 moving planes and boxes in front of a wall,
    each surface a crop of a photograph (`texture_photos`), under a random camera motion, tracked by
    the pipeline's own KLT tracker over F frames; labels are exact (the rendered masks) except near
    surface boundaries (-1, context only).

    Returns:
        LabeledClips named "rendered/<i>" with traj (N, 2F) float32 pixels and labels (N,) int64
        (0 = background, 1.. = objects in depth order of the scene, -1 = unlabelled); clips with fewer
        than MIN_LABELLED labelled points or a single labelled group are left out.
    """
    from mosegpipe.synth.render import RenderConfig, render_clip

    sources = texture_sources(data_root, exclude)
    if not sources:
        return []
    key = cache_key("rendered-own", frames=frames, cfg=cfg, track=track, photos=[n for n, _ in sources])
    path = Path(cache_dir or default_cache_dir()) / f"rendered-own-f{frames}-{key}.npz"

    def build() -> dict[str, npt.NDArray[Any]]:
        # The photographs are read only here: a cached build needs none of them.
        images = [im for _, load in sources for _, im in load()]
        out: dict[str, npt.NDArray[Any]] = {}
        for i in range(cfg.num_clips):
            rng = np.random.default_rng([cfg.seed, i])
            render_cfg = RenderConfig(
                size_hw=cfg.sizes_hw[int(rng.integers(len(cfg.sizes_hw)))],
                frames=frames,
                num_objects=int(rng.integers(cfg.objects[0], cfg.objects[1] + 1)),
                seed=int(rng.integers(2**31)),
                camera_motion=cfg.camera_motions[int(rng.integers(len(cfg.camera_motions)))],
                texture="photo",
                object_speed_px=cfg.object_speed_px,
                ground=bool(rng.random() < cfg.ground_prob),
                noise_std=float(rng.uniform(*cfg.noise_std)),
                **_near_scene(cfg, rng),
            )
            clip = render_clip(render_cfg, images)
            tracks = track_klt(clip.to_frames(), track)
            traj = build_trajectories(tracks, frames=frames)
            labels = label_rendered_tracks(clip, tracks.xy[traj.track_ids], cfg.boundary_px)
            out[f"{i}/traj"] = traj.data
            out[f"{i}/labels"] = labels
            if (i + 1) % 50 == 0:
                log.info("rendered-own: %d / %d clips tracked", i + 1, cfg.num_clips)
        return out

    arrays = _load_or_build(path, build)
    clips = []
    for i in range(cfg.num_clips):
        labels = arrays[f"{i}/labels"]
        known = labels[labels >= 0]
        if known.size < MIN_LABELLED or np.unique(known).size < 2:
            continue
        clips.append(
            LabeledClip(name=f"rendered/{i}", traj=arrays[f"{i}/traj"], labels=labels, dataset="rendered-own", meta={})
        )
    return clips


@dataclass(frozen=True)
class CompositeTracksConfig:
    """What `composite_own_clips` composes and how it labels our tracks of it.

    Attributes:
        num_clips: composites made ("train-00" ... in the cache; composite i is `composite_set`'s i-th
            development composite under `seed`: plate = development clip i mod 20).
        seed: base seed of the composites; never `synth.composite.SEED`, the seed of the composites that
            `moseg eval composite` scores.
        composite: how each is drawn (default: as the scored ones, 25 frames at 427x240, 2-4 objects).
        boundary_px: a track closer than this to a change of mask id (in its first or last frame)
            stays unlabelled.
    """

    num_clips: int = 40
    seed: int = 1041
    composite: CompositeConfig = CompositeConfig()
    boundary_px: int = 3


def label_composite_tracks(
    comp: Composite, xy: npt.NDArray[np.floating], start: int, boundary_px: int
) -> npt.NDArray[np.int64]:
    """Labels of tracked points of a composite's window from its exact per-object masks.

    A point takes the object id under it (`label_rendered_tracks`: the same id in every frame, not
    within `boundary_px` of another in the first and last frame, else -1). An object that stands still
    in the world in every frame of the window is the world (0), as `moseg eval composite` counts it;
    one that moves in some of the window's frames only (starting, stopping) is left unlabelled (-1).

    Args:
        comp: the composite.
        xy: (N, F, 2) positions in frames start..start+F-1.
        start: the window's first frame.
        boundary_px: see CompositeTracksConfig.

    Returns:
        (N,) int64: 0 = world, i = object i (moving), -1 = unlabelled (context only).
    """
    ids = label_rendered_tracks(comp, xy, boundary_px, start=start)
    labels = ids.copy()
    moving = comp.moving[start : start + xy.shape[1]]
    for col, oid in enumerate(comp.object_ids):
        if not moving[:, col].all():
            labels[ids == oid] = -1 if moving[:, col].any() else 0
    return labels


def composite_own_clips(
    data_root: str | Path,
    frames: int = 5,
    exclude: Collection[str] = (),
    cfg: CompositeTracksConfig = CompositeTracksConfig(),
    track: TrackConfig = TrackConfig(),
    cache_dir: str | Path | None = None,
) -> list[LabeledClip]:
    """Our KLT tracks of every F-frame window of composites of the DAVIS development clips.

    The composites are `synth.composite.composite_set(data_root, "dev", ...)` under `cfg.seed` (plates
    and cut-outs from the development clips only, never a validation clip; other arrangements than the
    scored development composites, which use `synth.composite.SEED`); each window is tracked by the
    pipeline's KLT tracker and labelled by `label_composite_tracks`.

    Args:
        data_root: the data folder holding ``davis2016-train/``.
        frames: F, frames per window (every start is used, stride 1).
        exclude: DAVIS clip names: composites that use one (as plate or cut-out) are left out.
        cfg: which composites and how tracks are labelled.
        track: KLT settings (the pipeline's defaults).
        cache_dir: where tracked windows are cached (None = `default_cache_dir()`).

    Returns:
        LabeledClips named "composite/<i>/f<a>-<b>" with traj (N, 2F) float32 pixels and labels (N,) int64;
        windows with fewer than MIN_LABELLED labelled points or one labelled group only are left out.

    Raises:
        ConfigError: cfg.seed is the scored composites' seed.
        DatasetError: a DAVIS clip is missing or unreadable.
    """
    from mosegpipe.synth.composite import SEED, composite_names, composite_set

    if cfg.seed == SEED:
        raise ConfigError(f"composite-own: seed {SEED} makes the scored development composites; choose another")
    folder = (
        Path(cache_dir or default_cache_dir())
        / f"composite-own-f{frames}-{cache_key('composite-own', frames=frames, cfg=cfg, track=track)}"
    )
    clips: list[LabeledClip] = []
    for i, name in enumerate(composite_names("dev", cfg.num_clips)):

        def build(name: str = name) -> dict[str, npt.NDArray[Any]]:
            (comp,) = composite_set(data_root, "dev", seed=cfg.seed, cfg=cfg.composite, names=[name])
            out: dict[str, npt.NDArray[Any]] = {"sources": np.array(comp.sources, dtype=str)}
            for s in range(comp.num_frames - frames + 1):
                tracks = track_klt(Frames(images=comp.frames[s : s + frames], source=name), track)
                traj = build_trajectories(tracks, frames=frames)
                out[f"{s}/traj"] = traj.data
                out[f"{s}/labels"] = label_composite_tracks(comp, tracks.xy[traj.track_ids], s, cfg.boundary_px)
            log.info("composite-own %s: tracked %d windows", name, comp.num_frames - frames + 1)
            return out

        arrays = _load_or_build(folder / f"train-{i:02d}.npz", build)
        if set(arrays["sources"].tolist()) & set(exclude):
            continue
        clips += _window_clips(arrays, f"composite/{i:02d}", frames, "composite-own", _labelled_if_two_groups)
    return clips


def _labelled_if_two_groups(labels: npt.NDArray[np.int64]) -> int:
    """Labelled points, or 0 when they hold fewer than two groups (nothing to tell apart)."""
    known = labels[labels >= 0]
    return int(known.size) if np.unique(known).size >= 2 else 0
