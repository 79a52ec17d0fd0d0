"""The recipe, stage by stage: frames -> tracks -> trajectories -> embeddings -> clusters -> masks.

Compute only: `segment_frames` / `segment_clip` / `segment_pair` return immutable results with their
timings, and `segment_video` walks a whole video as a stream of window results. Writing any of them
into an output folder is `mosegpipe.outputs`. `decode_errors` turns whatever OpenCV or the OS raise on a
broken input into an InputError.

Whole videos: consecutive F-frame windows, streamed, with motion labels kept consistent across windows.
Windows share their boundary frame (window w covers frames w(F-1) .. w(F-1)+F-1) and the tracker
re-seeds corners at every window start, so tracks run on from one window into the next. A window's
clusters take the global label of the previous window's cluster they share most tracks with
(Hungarian matching on the overlap counts); a cluster of new tracks starts a new global label, a
cluster that split off a known motion only once it splits off in two windows running (`match_labels`).
On a near tie of the automatic-K scores a window keeps the previous window's K. Only the current
window's frames (at most F images) are held.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
import types
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field, fields, is_dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, Union, get_args, get_origin, get_type_hints

import cv2
import numpy as np
import numpy.typing as npt
from scipy.optimize import linear_sum_assignment

from mosegpipe.cluster import ClusterConfig, cluster_auto_k
from mosegpipe.errors import CheckpointError, InputError, TooFewTracksError
from mosegpipe.io import check_images, iter_video, read_image, read_video, video_info
from mosegpipe.masks import MAX_LABEL, MaskConfig, labels_to_mask, labels_to_masks
from mosegpipe.match import MatchConfig, match_sift
from mosegpipe.rigid import RigidCheckConfig, label_by_rigid_motion, split_by_rigid_motion
from mosegpipe.track import KLTTracker, TrackConfig, spread_corners, track_klt, track_points, tracks_from_steps
from mosegpipe.trajectories import build_trajectories, trajectories_from_matches
from mosegpipe.types import Clustering, Frames, Matches, Tracks, Trajectories

if TYPE_CHECKING:
    from mosegpipe.inference import Embedder
    from mosegpipe.model import SubspaceNet

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class PipelineConfig:
    """Settings of one segmentation run.

    Attributes:
        frames: F, the number of frames segmented (the paper's clips are 5 frames).
        start: index of the first frame read from a video or frame folder (0-based, in the source);
            segment_clip reads frames start .. start + F - 1, segment_video starts its first window
            there. Not used by segment_frames / segment_pair (they are given their images).
        k: force this many motions (None = automatic K).
        min_tracks: fewer surviving tracks / matches than this is an error (too little texture).
        track: KLT settings.
        match: SIFT matching settings (pairs).
        cluster: automatic-K settings.
        rigid: the rigid-motion check after automatic K (clips, whole videos, tracks; not pairs, not
            with k given): groups of tracks that their cluster's rigid motion does not explain
            become clusters of their own (mosegpipe.rigid).
        mask: dense-mask settings.
        outlier_inlier_ratio: pairs: a cluster whose best fundamental-matrix RANSAC fit explains less
            than this fraction of its points is labelled as outliers.
        video_k_step: whole videos: a window tries K up to the previous window's K plus this (and at
            most cluster.k_max), so K rises by at most this much every F - 1 frames; None = the full
            sweep in every window. The sweep's larger K cost the most K-means time; on the long
            rendered clips the limit changed no segmentation (docs/RESULTS.md, "Speed").
        video_cut_survival: whole videos: a frame into which fewer than this fraction of the previous
            frame's tracks survive (of at least 2 * min_tracks) is a shot cut: the window ends on the
            frame before it, and tracking and clustering start afresh on it. None = no cut detection.
    """

    frames: int = 5
    start: int = 0
    k: int | None = None
    min_tracks: int = 10
    track: TrackConfig = field(default_factory=TrackConfig)
    match: MatchConfig = field(default_factory=MatchConfig)
    cluster: ClusterConfig = field(default_factory=ClusterConfig)
    rigid: RigidCheckConfig = field(default_factory=RigidCheckConfig)
    mask: MaskConfig = field(default_factory=MaskConfig)
    outlier_inlier_ratio: float = 0.5
    video_k_step: int | None = 2
    video_cut_survival: float | None = 0.25

    def __post_init__(self) -> None:
        if self.video_k_step is not None and self.video_k_step < 1:
            raise InputError(f"video_k_step={self.video_k_step} must be at least 1 (or None: no limit)")
        if self.video_cut_survival is not None and not 0 < self.video_cut_survival < 1:
            raise InputError(
                f"video_cut_survival={self.video_cut_survival} must lie in (0, 1) (or None: no cut detection)"
            )

    @classmethod
    def from_dict(cls, data: Any, where: str = "config") -> PipelineConfig:
        """The settings from their `dataclasses.asdict` form (summary.json `config`), checked field by field.

        A field left out takes its default (a summary written before the field existed), except
        `rigid`, `video_cut_survival` and `mask.extra_tracks`: a summary without them was made before
        the rigid-motion check (the shot-cut test, the extra mask tracks) existed, so it stays off and
        a replay segments as that run did. An unknown field, a value of the wrong type or one the
        config classes refuse is an error.

        Args:
            data: a dict as `asdict(cfg)` gives it (nested dicts for track, match, cluster, mask).
            where: how errors name the dict (`summary.json: config`).

        Raises:
            InputError: naming the field, e.g. `summary.json: config.track.max_corners: expected an
                integer, got 'many'`.
        """
        config = _dataclass_from_dict(cls, data, where)
        assert isinstance(config, cls)
        if isinstance(data, Mapping) and "rigid" not in data:
            config = replace(config, rigid=RigidCheckConfig(enabled=False))
        if isinstance(data, Mapping) and "video_cut_survival" not in data:
            config = replace(config, video_cut_survival=None)
        if isinstance(data, Mapping) and isinstance(data.get("mask"), Mapping) and "extra_tracks" not in data["mask"]:
            config = replace(config, mask=replace(config.mask, extra_tracks=0))
        return config


def _dataclass_from_dict(cls: type, data: Any, where: str) -> Any:
    if not isinstance(data, dict):
        raise InputError(f"{where}: expected a table of settings, got {type(data).__name__} {data!r}")
    hints = get_type_hints(cls)
    names = [f.name for f in fields(cls)]
    unknown = [key for key in data if key not in names]
    if unknown:
        raise InputError(f"{where}.{unknown[0]}: unknown setting (known: {', '.join(names)})")
    values = {name: _typed_value(hints[name], value, f"{where}.{name}") for name, value in data.items()}
    try:
        return cls(**values)
    except (ValueError, InputError) as exc:
        raise InputError(f"{where}: {' '.join(str(exc).split())}") from exc


_TYPE_NAMES = {bool: "true or false", int: "an integer", float: "a number", str: "a string"}


def _typed_value(hint: Any, value: Any, where: str) -> Any:
    """`value` checked against the type hint of a config field (JSON / TOML types: no coercion from strings)."""
    if is_dataclass(hint):
        return _dataclass_from_dict(hint, value, where)  # type: ignore[arg-type]
    origin = get_origin(hint)
    if origin is Union or origin is types.UnionType:
        options = get_args(hint)
        if value is None and type(None) in options:
            return None
        for option in options:
            if option is not type(None):
                with contextlib.suppress(InputError):
                    return _typed_value(option, value, where)
        wanted = " or ".join("null" if o is type(None) else _TYPE_NAMES.get(o, str(o)) for o in options)
        raise InputError(f"{where}: expected {wanted}, got {value!r}")
    if origin is Literal:
        if value not in get_args(hint):
            raise InputError(f"{where}: {value!r} is not one of {', '.join(map(repr, get_args(hint)))}")
        return value
    ok = {
        bool: isinstance(value, bool),
        int: isinstance(value, int) and not isinstance(value, bool),
        float: isinstance(value, (int, float)) and not isinstance(value, bool),
        str: isinstance(value, str),
    }
    if hint not in ok:
        raise TypeError(f"{where}: config fields of type {hint} are not supported")
    if not ok[hint]:
        raise InputError(f"{where}: expected {_TYPE_NAMES[hint]}, got {value!r}")
    return float(value) if hint is float else value


@dataclass(frozen=True)
class ClipResult:
    """Everything one clip's segmentation produced.

    Attributes:
        frames: the frames segmented.
        tracks: all KLT tracks (N_all, T).
        trajectories: the tracks visible in all frames (N rows, track_ids into `tracks`).
        embeddings: (N, E) float32 SubspaceNet embeddings.
        clustering: labels (N,) and the automatic-K evidence.
        masks: (T, H, W) uint8, k = motion k, 255 = no track nearby (unknown).
        timings: seconds per stage.
        model_info: the model's recipe name, input frames and checkpoint format.
    """

    frames: Frames
    tracks: Tracks
    trajectories: Trajectories
    embeddings: npt.NDArray[np.float32]
    clustering: Clustering
    masks: npt.NDArray[np.uint8]
    timings: dict[str, float]
    model_info: dict[str, Any]


@dataclass(frozen=True)
class PairResult:
    """Everything one image pair's segmentation produced.

    Attributes:
        images: the two RGB images (they may differ in size).
        matches: SIFT correspondences (N).
        embeddings: (N, E) float32.
        clustering: labels (N,) in 0..k-1 as clustered.
        labels: (N,) int64 final labels: motions 0..m-1, -1 for the outlier cluster (if one was found).
        outlier_cluster: which cluster was labelled outliers (None when none was).
        masks: two (H_i, W_i) uint8 masks, m = motion m, 255 = unknown / outlier.
        timings: seconds per stage.
        model_info: as in ClipResult.
    """

    images: tuple[npt.NDArray[np.uint8], npt.NDArray[np.uint8]]
    matches: Matches
    embeddings: npt.NDArray[np.float32]
    clustering: Clustering
    labels: npt.NDArray[np.int64]
    outlier_cluster: int | None
    masks: tuple[npt.NDArray[np.uint8], npt.NDArray[np.uint8]]
    timings: dict[str, float]
    model_info: dict[str, Any]


def load_model(frames: int, checkpoint: str | Path | None = None) -> SubspaceNet:
    """The shipped default model for `frames` (or a checkpoint file).

    Clips whose frame count has no shipped model are served by the 5-frame model after temporal
    resampling of each trajectory (see trajectories.resample_frames).

    Args:
        frames: F, the trajectory length the model will see (2 = image pairs).
        checkpoint: a checkpoint file to load instead of the shipped weights.

    Returns:
        The model in eval mode. A model loaded from `checkpoint` carries the file's resolved path as
        `checkpoint_path` (recorded by model_info in summary.json, so that a run can be replayed
        with the same weights; it travels with the model to batch workers).

    Raises:
        CheckpointError: the checkpoint is missing, corrupt or not a SubspaceNet, or no weights are shipped.
    """
    from mosegpipe.architecture import available_default_frames
    from mosegpipe.model import SubspaceNet

    if checkpoint is not None:
        model = SubspaceNet.from_checkpoint(checkpoint)
        # object.__setattr__: nn.Module's own __setattr__ is typed for tensors and modules only.
        object.__setattr__(model, "checkpoint_path", str(Path(checkpoint).resolve()))
        return model
    shipped = 2 if frames == 2 else frames if frames in available_default_frames() else 5
    try:
        return SubspaceNet.default(frames=shipped)
    except CheckpointError as exc:
        raise CheckpointError(f"{exc}; pass --model CHECKPOINT to use other weights") from exc


def model_info(model: Embedder) -> dict[str, Any]:
    """The model's recipe name, input frame count, configuration and checkpoint file, as recorded in
    summary.json ("checkpoint": the file given to load_model, None for the shipped weights or a
    model built in memory)."""
    recipe = getattr(model, "recipe", None) or {}
    return {
        "recipe": recipe.get("name", "unknown"),
        "model_frames": model.num_frames,
        "model_config": model.cfg.to_dict(),
        "checkpoint": getattr(model, "checkpoint_path", None),
    }


def embed_at_model_frames(model: Embedder, traj: Trajectories) -> npt.NDArray[np.float32]:
    """(N, E) embeddings of trajectories of any length, resampled in time to the model's F first."""
    return model.embed(traj)


def _check_k(k: int | None, n: int, source: str, what: str = "tracks") -> None:
    if k is not None and k < 1:
        raise InputError(f"--k {k} must be >= 1")
    if k is not None and k > n:
        raise InputError(f"{source}: --k {k} is larger than the number of {what} ({n})")


def check_rigid(
    clustering: Clustering, points: npt.NDArray[np.float32], size_hw: tuple[int, int], cfg: PipelineConfig
) -> Clustering:
    """`clustering` after the rigid-motion check (unchanged when K was given or the check is off).

    Its note then says how many groups the check split off, after automatic K's own note.
    """
    if cfg.k is not None or not cfg.rigid.enabled:
        return clustering
    labels, split = split_by_rigid_motion(points, clustering.labels, size_hw, cfg.rigid)
    if not split:
        return clustering
    what = f"the rigid-motion check split off {split} group{'s' if split > 1 else ''} (K = {clustering.k} -> {clustering.k + split})"
    note = f"{clustering.note}; {what}" if clustering.note else what
    return replace(clustering, labels=labels, k=clustering.k + split, note=note)


def _model_or_default(model: Embedder | None, frames: int, timings: dict[str, float]) -> Embedder:
    if model is not None:
        return model
    from mosegpipe.inference import load_embedder

    t0 = time.perf_counter()
    model = load_embedder(frames)
    timings["load_model"] = time.perf_counter() - t0
    return model


@contextlib.contextmanager
def decode_errors(source: str | Path) -> Iterator[None]:
    """Turns what OpenCV or the OS raise while reading a broken input into an InputError naming it.

    The readers raise InputError for the failures they foresee; a corrupt stream can still make an
    OpenCV decoder throw cv2.error, and an unreadable file raise OSError (permissions, I/O errors).
    Wrap reads only: an OSError while writing outputs is not the input's fault.

    Raises:
        InputError: in place of cv2.error or OSError raised in the block.
    """
    try:
        yield
    except (cv2.error, OSError) as exc:
        lines = str(exc).strip().splitlines()
        detail = " ".join(lines[-1].split())[:200] if lines else type(exc).__name__
        raise InputError(f"{source}: cannot read it ({detail})") from exc


def segment_frames(frames: Frames, cfg: PipelineConfig = PipelineConfig(), model: Embedder | None = None) -> ClipResult:
    """Segments the motions in a short stack of frames.

    Args:
        frames: Frames with images (T, H, W, 3) uint8 RGB; every frame is segmented.
        cfg: pipeline settings (cfg.frames is not used here: T is what the frames hold).
        model: the model (None = the shipped default for T frames).

    Returns:
        ClipResult; its masks are (T, H, W) uint8 with k = motion k and 255 = unknown.

    Raises:
        TooFewTracksError: fewer than cfg.min_tracks tracks live through all frames.
        InputError: cfg.k larger than the number of tracks.
        CheckpointError: no model given and no shipped weights.
    """
    timings: dict[str, float] = {}
    check_images(frames.images, f"{frames.source or 'frames'}: images", stack=True)
    model = _model_or_default(model, frames.num_frames, timings)
    t0 = time.perf_counter()
    tracks = track_klt(frames, cfg.track)
    timings["track"] = time.perf_counter() - t0
    traj = build_trajectories(tracks, frames=frames.num_frames)
    if traj.num_points < cfg.min_tracks:
        raise TooFewTracksError(
            f"{frames.source or 'clip'}: only {traj.num_points} tracks survived {frames.num_frames} frames; "
            f"need at least {cfg.min_tracks} (textureless or blank frames?)"
        )
    _check_k(cfg.k, traj.num_points, frames.source or "clip")
    t0 = time.perf_counter()
    emb = embed_at_model_frames(model, traj)
    timings["embed"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    clustering = cluster_auto_k(emb, cfg.cluster, k=cfg.k, points=traj.data)
    clustering = check_rigid(clustering, traj.data, tracks.size_hw, cfg)
    timings["cluster"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    masks = clip_masks(frames.images, tracks, traj.track_ids, clustering.labels, cfg)
    timings["masks"] = time.perf_counter() - t0
    return ClipResult(frames, tracks, traj, emb, clustering, masks, timings, model_info(model))


def clip_masks(
    images: npt.NDArray[np.uint8],
    tracks: Tracks,
    track_ids: npt.NDArray[np.int64],
    labels: npt.NDArray[np.int64],
    cfg: PipelineConfig = PipelineConfig(),
) -> npt.NDArray[np.uint8]:
    """The dense masks of a clip from its labelled tracks (segment_frames' mask stage).

    With cfg.mask.extra_tracks, more corners spread over the first image away from the tracks are
    tracked through the clip and labelled by motion (`label_by_rigid_motion`); those with a label
    join the labelled tracks for the masks only.

    Args:
        images: (T, H, W, 3) uint8 RGB frames.
        tracks: the clip's tracks (N rows over the T frames).
        track_ids: (M,) rows of `tracks` that carry labels (live through the whole clip).
        labels: (M,) their labels.
        cfg: mask settings (and the rigid-motion settings that label the extra tracks).

    Returns:
        (T, H, W) uint8 masks, 255 = unknown.
    """
    budget = cfg.mask.extra_tracks
    if budget > 0 and len(track_ids) and images.shape[0] >= 2:
        corners = spread_corners(images[0], budget, tracks.xy[tracks.visible[:, 0], 0], cfg.track)
        extra = track_points(images, corners, cfg.track)
        full = np.flatnonzero(extra.visible.all(axis=1))
        data = extra.xy[full].reshape(len(full), 2 * len(images))
        known = tracks.xy[track_ids].reshape(len(track_ids), 2 * len(images))
        found = label_by_rigid_motion(data, known, labels, cfg.rigid)
        keep = found >= 0
        rows = full[keep]
        track_ids = np.concatenate([track_ids, tracks.num_tracks + np.arange(rows.size)])
        labels = np.concatenate([labels, found[keep]])
        tracks = Tracks(
            xy=np.concatenate([tracks.xy, extra.xy[rows]]),
            visible=np.concatenate([tracks.visible, extra.visible[rows]]),
            size_hw=tracks.size_hw,
        )
    return labels_to_masks(tracks, track_ids, labels, cfg.mask, images)


def _frames(n: int) -> str:
    return "1 frame" if n == 1 else f"{n} frames"


def _container_frames(path: str | Path) -> int | None:
    """The frame count a video container claims (None for folders, images or when it does not say)."""
    try:
        with decode_errors(path):
            info = video_info(path)
    except InputError:
        return None
    return info["num_frames"] if info["kind"] == "video" else None


def segment_clip(path: str | Path, cfg: PipelineConfig = PipelineConfig(), model: Embedder | None = None) -> ClipResult:
    """Reads cfg.frames frames from frame cfg.start of a video file or frame folder and segments them.

    Args:
        path: a video file OpenCV can read or a folder of images (sorted by name).
        cfg: pipeline settings; cfg.frames frames are read, from frame cfg.start.
        model: the model (None = the shipped default for cfg.frames).

    Returns:
        ClipResult (timings also hold "read").

    Raises:
        InputError: missing, unreadable, corrupt or truncated input, fewer than cfg.frames frames
            from cfg.start, or cfg.start past the end.
        TooFewTracksError: see segment_frames.
    """
    t0 = time.perf_counter()
    with decode_errors(path):
        frames = read_video(path, max_frames=cfg.frames, start=cfg.start)
    if frames.num_frames < cfg.frames:
        claimed = _container_frames(path)
        hint = ""
        if claimed and claimed - cfg.start > frames.num_frames:
            hint = f" of the {claimed} its header lists (truncated or corrupt video?)"
        after = f" from frame {cfg.start}" if cfg.start else ""
        raise InputError(
            f"{path}: only {_frames(frames.num_frames)} could be read{after}{hint}; --frames needs {cfg.frames}"
        )
    read_s = time.perf_counter() - t0
    result = segment_frames(frames, cfg, model)
    return replace(result, timings={"read": read_s, **result.timings})


def _outlier_cluster(matches: Matches, labels: npt.NDArray[np.int64], k: int, min_ratio: float) -> int | None:
    """The cluster that no single fundamental matrix explains (lowest RANSAC inlier ratio below min_ratio)."""
    if k < 2:
        return None
    ratios = {}
    for c in range(k):
        idx = np.flatnonzero(labels == c)
        if idx.size < 8:
            ratios[c] = 0.0
            continue
        _, inl = cv2.findFundamentalMat(
            matches.xy1[idx].astype(np.float64), matches.xy2[idx].astype(np.float64), cv2.FM_RANSAC, 2.0, 0.99
        )
        ratios[c] = 0.0 if inl is None else float(inl.mean())
    worst = min(ratios, key=lambda c: ratios[c])
    return worst if ratios[worst] < min_ratio else None


def segment_pair(
    img1: str | Path | npt.NDArray[np.uint8],
    img2: str | Path | npt.NDArray[np.uint8],
    cfg: PipelineConfig = PipelineConfig(frames=2),
    model: Embedder | None = None,
) -> PairResult:
    """Segments the motions between two images (they may differ in size); outliers get label -1.

    Args:
        img1, img2: image files, or (H_i, W_i, 3) uint8 RGB arrays.
        cfg: pipeline settings (cfg.frames is not used: a pair is 2 frames).
        model: the model (None = the shipped 2-frame default).

    Returns:
        PairResult.

    Raises:
        InputError: a missing or unreadable image, or cfg.k larger than the number of matches.
        TooFewTracksError: fewer than cfg.min_tracks SIFT matches.
    """
    timings: dict[str, float] = {}
    images: list[npt.NDArray[np.uint8]] = []
    for img in (img1, img2):
        if isinstance(img, np.ndarray):
            images.append(check_images(img, f"image {len(images) + 1}"))
            continue
        with decode_errors(img):
            images.append(read_image(img))
    im1, im2 = images
    names = " and ".join(str(i) if not isinstance(i, np.ndarray) else "<array>" for i in (img1, img2))
    model = _model_or_default(model, 2, timings)
    t0 = time.perf_counter()
    matches = match_sift(im1, im2, cfg.match)
    timings["match"] = time.perf_counter() - t0
    if matches.num_matches < cfg.min_tracks:
        raise TooFewTracksError(
            f"{names}: only {matches.num_matches} SIFT matches; need at least {cfg.min_tracks} "
            "(blank, textureless or unrelated images?)"
        )
    _check_k(cfg.k, matches.num_matches, names, "matches")
    traj = trajectories_from_matches(matches)
    t0 = time.perf_counter()
    emb = embed_at_model_frames(model, traj)
    timings["embed"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    clustering = cluster_auto_k(emb, cfg.cluster, k=cfg.k, points=traj.data)
    outlier = _outlier_cluster(matches, clustering.labels, clustering.k, cfg.outlier_inlier_ratio)
    labels = clustering.labels.copy()
    if outlier is not None:
        labels[clustering.labels == outlier] = -1
        labels[clustering.labels > outlier] -= 1
    timings["cluster"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    inl = labels >= 0
    masks = (
        labels_to_mask(matches.xy1[inl], labels[inl], im1.shape[:2], cfg.mask, im1),
        labels_to_mask(matches.xy2[inl], labels[inl], im2.shape[:2], cfg.mask, im2),
    )
    timings["masks"] = time.perf_counter() - t0
    return PairResult((im1, im2), matches, emb, clustering, labels, outlier, masks, timings, model_info(model))


_MIN_SHARE = 0.5  # a cluster continues a global label only if most of its shared tracks carried it
_MIN_NEW_TRACKS = 15  # a cluster with fewer tracks (and fewer than _MIN_NEW_SHARE of the window's) is not
_MIN_NEW_SHARE = 0.05  # trusted as a new motion: it joins the label most of its shared tracks carried, or
# stays unlabelled. On the long rendered clips 15 tracks gave 2.39 labels per object, 5 % alone 2.49.
_MIN_CONTINUED = 0.25  # a cluster continues a label only if this share of its tracks carried labels before


@dataclass
class LabelBook:
    """Global motion labels across windows, with reuse once the uint8 mask range is spent.

    Attributes:
        next_label: the next never-used label.
        last_window: label -> the last window that used it.
        num_reused: how many times a label was handed out again (only after 255 labels).
        max_label: largest label a mask can hold (mask value = label <= 254; 255 = unknown).
        pending: track id -> split candidate of the last window: the tracks of a cluster that
            split off a known motion, which kept that motion's label (see match_labels).
    """

    next_label: int = 0
    last_window: dict[int, int] = field(default_factory=dict)
    num_reused: int = 0
    max_label: int = MAX_LABEL
    pending: dict[int, int] = field(default_factory=dict)

    def new_label(self, busy: set[int]) -> int:
        """A label for a motion that continues none seen before: the next unused one, else the least
        recently used label that is not in `busy`."""
        if self.next_label <= self.max_label:
            self.next_label += 1
            return self.next_label - 1
        free = [lab for lab in self.last_window if lab not in busy]
        if not free:
            raise InputError(f"more than {self.max_label + 1} motions live at once; masks cannot hold them")
        self.num_reused += 1
        return min(free, key=lambda lab: self.last_window[lab])


def match_labels(
    prev: dict[int, int],
    ids: npt.NDArray[np.int64],
    clusters: npt.NDArray[np.int64],
    k: int,
    book: LabelBook,
    window: int = 0,
) -> npt.NDArray[np.int64]:
    """Maps this window's clusters to global labels through the tracks shared with the previous window.

    1. Clusters and previous labels are paired by the Hungarian method on their overlap counts
       (maximum total overlap, one-to-one). A pair is kept only when at least half of the cluster's
       shared tracks carried that label and at least a quarter of its tracks carried a label at all
       (across a camera cut the few tracks that survive it say nothing about the new shot).
    2. A cluster left over whose tracks are known (that quarter carried labels) is a piece of the
       motions they carried: K-means split a motion (over-segmentation) or joined two. It takes the
       label most of its shared tracks carried, as in the window before, and becomes a split
       candidate. Only when a candidate splits off again in the next window (at least half of the
       cluster's shared tracks were one candidate's) does it get a new label: a motion that
       separates from another is labelled one window late, a split that comes and goes never.
    3. The remaining clusters are new tracks (objects entering the view, a new shot): a new label,
       unless the cluster is too small to trust (fewer than _MIN_NEW_TRACKS tracks and under
       _MIN_NEW_SHARE of the window's), which stays unlabelled (-1).

    Args:
        prev: track id -> global label from the previous labelled window.
        ids: (N,) int64 track ids of this window's trajectories.
        clusters: (N,) int64 cluster of each, in 0..k-1.
        k: number of clusters in this window.
        book: the global label state (updated, its split candidates included).
        window: index of this window (for least-recently-used label reuse).

    Returns:
        (N,) int64 global labels.
    """
    old = np.array([prev.get(int(i), -1) for i in ids], dtype=np.int64)
    candidate = np.array([book.pending.get(int(i), -1) for i in ids], dtype=np.int64)
    shared = old >= 0
    mapping: dict[int, int] = {}
    sizes = np.bincount(clusters, minlength=k)
    small = max(min(_MIN_NEW_TRACKS, 0.25 * clusters.size), _MIN_NEW_SHARE * clusters.size)
    splits: dict[int, int] = {}  # cluster -> the label it split off (it keeps that label for now)
    confirmed: set[int] = set()  # clusters that split off in two windows running: new labels
    if shared.any():
        olds = np.unique(old[shared])
        overlap = np.zeros((k, olds.size), dtype=np.int64)
        np.add.at(overlap, (clusters[shared], np.searchsorted(olds, old[shared])), 1)
        per_cluster = overlap.sum(axis=1)
        known = per_cluster >= _MIN_CONTINUED * sizes
        for r in range(k):
            mine = candidate[(clusters == r) & (candidate >= 0)]
            if known[r] and sizes[r] >= small and mine.size and np.bincount(mine).max() >= _MIN_SHARE * per_cluster[r]:
                confirmed.add(r)
        overlap[list(confirmed)] = 0  # a recurring split continues none of the labels
        rows, cols = linear_sum_assignment(-overlap)
        for r, c in zip(rows, cols):
            if known[r] and overlap[r, c] > 0 and overlap[r, c] >= _MIN_SHARE * per_cluster[r]:
                mapping[int(r)] = int(olds[c])
        for r in range(k):
            if r in mapping or r in confirmed or not known[r] or per_cluster[r] == 0:
                continue
            mapping[r] = int(olds[int(overlap[r].argmax())])
            if sizes[r] >= small:
                splits[r] = mapping[r]
    book.pending = {int(i): int(c) for i, c in zip(ids, clusters) if int(c) in splits}
    # The dominant motion takes label 0 when no cluster carries 0 on, e.g. after a camera cut: the
    # clips' convention (mask value 0 = the dominant motion) holds for videos too.
    if 0 not in mapping and 0 not in mapping.values() and book.next_label > 0:
        mapping[0] = 0
    busy = set(mapping.values()) | set(prev.values())
    for c in range(k):
        if c in mapping:
            continue
        if sizes[c] < small and k > 1:
            # Too few tracks to trust as a motion that just appeared: left unlabelled (-1).
            mapping[c] = -1
            continue
        mapping[c] = book.new_label(busy)
        busy.add(mapping[c])
    for lab in mapping.values():
        if lab >= 0:
            book.last_window[lab] = window
    return np.array([mapping[int(c)] for c in clusters], dtype=np.int64)


_Frame = tuple[int, npt.NDArray[np.uint8], npt.NDArray[np.int64], npt.NDArray[np.float32]]


@dataclass(frozen=True)
class VideoFrame:
    """One frame of a whole-video run with the labels of its tracks.

    Attributes:
        index: frame index in the source (0-based).
        image: (H, W, 3) uint8 RGB.
        track_ids: (N,) int64 ids of the tracks live in this frame.
        xy: (N, 2) float32 pixel positions of those tracks.
        labels: (N,) int64 global motion label of each track, -1 = unlabelled. A track that ends
            inside its window (lost before the window's last frame, so not clustered there) keeps
            the label the window before gave it.
        mask: (H, W) uint8, label = motion, 255 = unknown; None when segment_video was asked for
            no masks (see `frame_mask`).
    """

    index: int
    image: npt.NDArray[np.uint8]
    track_ids: npt.NDArray[np.int64]
    xy: npt.NDArray[np.float32]
    labels: npt.NDArray[np.int64]
    mask: npt.NDArray[np.uint8] | None


def frame_mask(frame: VideoFrame, cfg: MaskConfig = MaskConfig()) -> npt.NDArray[np.uint8]:
    """The dense mask of one whole-video frame from its labelled tracks (what segment_video computes).

    Returns:
        (H, W) uint8, label = motion, 255 = unknown.
    """
    if frame.mask is not None:
        return frame.mask
    keep = frame.labels >= 0
    return labels_to_mask(frame.xy[keep], frame.labels[keep], frame.image.shape[:2], cfg, frame.image)


@dataclass(frozen=True)
class WindowResult:
    """One F-frame window of a whole video.

    Attributes:
        start: index of the window's first frame.
        num_frames: frames in the window (F, or fewer for the last one).
        num_tracks: tracks live through the whole window.
        k: motions found in it (0 = left unlabelled: too few tracks).
        track_ids: (N,) int64 ids of the labelled tracks (empty when unlabelled).
        labels: (N,) int64 their global labels.
        frames: the frames this window adds (its first frame belongs to the previous window, except
            for the first window), with labels and masks.
        num_motions: global labels handed out so far.
        num_labels_reused: labels handed out again so far (only after 255 labels).
        num_frames_read: frames read from the source so far.
        k_note: automatic K's note on this window (Clustering.note: e.g. the K choice was
            ambiguous); "" when none.
        k_scores: automatic K's score per candidate K in this window (Clustering.scores); empty
            when K was forced or the window was left unlabelled.
        shot_start: the window starts on a shot cut (PipelineConfig.video_cut_survival): its
            tracks were detected afresh there, and it shares no frame with the window before.
    """

    start: int
    num_frames: int
    num_tracks: int
    k: int
    track_ids: npt.NDArray[np.int64]
    labels: npt.NDArray[np.int64]
    frames: tuple[VideoFrame, ...]
    num_motions: int
    num_labels_reused: int
    num_frames_read: int
    k_note: str = ""
    k_scores: Mapping[int, float] = field(default_factory=dict)
    shot_start: bool = False

    @property
    def is_labelled(self) -> bool:
        """Whether the window had enough tracks to be segmented."""
        return self.k > 0

    @property
    def is_k_ambiguous(self) -> bool:
        """Whether automatic K found two K scoring within ClusterConfig.ambiguity_margin here."""
        return self.k_note.startswith(AMBIGUOUS_K_NOTE)

    def record(self) -> dict[str, int | bool]:
        """The window's row in summary.json."""
        return {
            "start": self.start,
            "frames": self.num_frames,
            "num_tracks": self.num_tracks,
            "k": self.k,
            "k_ambiguous": self.is_k_ambiguous,
            "shot_start": self.shot_start,
        }


AMBIGUOUS_K_NOTE = "the K choice is ambiguous"
"""How cluster_auto_k's note (and warning) for an ambiguous K choice starts."""


@contextlib.contextmanager
def _warnings_held(logger: logging.Logger) -> Iterator[None]:
    """Keeps `logger`'s WARNING records of this thread from its handlers while the block runs.

    Whole-video mode reports automatic K's ambiguity warnings once for all windows, not once per
    window (hundreds of lines on a long video); the notes themselves are kept (WindowResult.k_note).
    Other threads' records pass: a clip segmented beside this video keeps its warning.
    """
    thread = threading.get_ident()

    def keep(record: logging.LogRecord) -> bool:
        return record.thread != thread or record.levelno != logging.WARNING

    logger.addFilter(keep)
    try:
        yield
    finally:
        logger.removeFilter(keep)


def _ranges(spans: list[tuple[int, int]], shown: int = 3) -> str:
    """`frames 0-4, 8-12, 16-20 and 4 more`: the first `shown` of some (first, last) frame ranges."""
    listed = ", ".join(f"{first}-{last}" for first, last in spans[:shown])
    more = f" and {len(spans) - shown} more" if len(spans) > shown else ""
    return f"frames {listed}{more}"


def check_video_settings(cfg: PipelineConfig, max_frames: int | None) -> None:
    """Fails early on settings a whole-video run cannot use.

    Raises:
        InputError: cfg.frames < 2 or max_frames < 1.
    """
    if cfg.frames < 2:
        raise InputError(f"--frames {cfg.frames}: whole-video mode needs windows of at least 2 frames")
    if max_frames is not None and max_frames < 1:
        raise InputError(f"--max-frames {max_frames} must be >= 1")


def video_frames_to_read(path: str | Path, cfg: PipelineConfig, max_frames: int | None = None) -> int | None:
    """How many frames segment_video will read: for a progress bar's total (None when not known).

    A frame folder knows its length; a video file only what its container header claims (which
    may be wrong for a truncated file: the run then ends early). Unreadable input gives None here:
    segment_video reports it.
    """
    try:
        with decode_errors(path):
            claimed = video_info(path)["num_frames"]
    except InputError:
        return None
    if claimed is None:
        return max_frames
    available = max(0, int(claimed) - cfg.start)
    return available if max_frames is None else min(available, max_frames)


def segment_video(
    path: str | Path,
    cfg: PipelineConfig = PipelineConfig(),
    model: Embedder | None = None,
    max_frames: int | None = None,
    masks: bool = True,
) -> Iterator[WindowResult]:
    """Segments a whole video window by window, streamed: yields each window as soon as it is labelled.

    Args:
        path: video file or frame folder.
        cfg: pipeline settings; cfg.frames is the window length F (>= 2).
        model: the model (None = shipped default for cfg.frames).
        max_frames: stop after this many frames (None = whole video).
        masks: compute each frame's dense mask; False leaves VideoFrame.mask None for the caller
            to compute with `frame_mask` (e.g. on another thread, as outputs.write_video_outputs does).

    Yields:
        WindowResult per window, in order; together their `frames` cover every frame read once.

    Raises:
        InputError: unreadable input, fewer than F frames, F < 2 or max_frames < 1.
        TooFewTracksError: no window had cfg.min_tracks tracks through all its frames (raised once
            the video is exhausted).

    Only the tracks live through a whole window are clustered; one that ends inside it (leaving the
    view, occluded) keeps the label it had in the window before for its last frames, so an object
    leaving the view keeps its label while its tracks last.

    A shot cut (fewer than cfg.video_cut_survival of a frame's tracks survive into the next frame)
    ends the window on the frame before it, however short; tracking restarts on the cut frame
    (`KLTTracker.restart`), which starts the next window (WindowResult.shot_start), so no track and
    no window spans two shots. The motions of the new shot get labels of their own, the dominant one 0.

    Automatic K keeps the previous window's K when that K scores within cfg.cluster.ambiguity_margin
    of the best (`cluster_auto_k`'s prefer_k): a change of K needs clear evidence; and it tries K only
    up to the previous window's K + cfg.video_k_step. Automatic K's
    warning that its choice is ambiguous is logged once, after the last window
    ("K was ambiguous in 3 of 40 windows: ..."), not per window; each window keeps its note
    (WindowResult.k_note, summary.json `windows[].k_ambiguous`).
    """
    check_video_settings(cfg, max_frames)
    f = cfg.frames
    model = model or load_model(f)
    with decode_errors(path):
        info = video_info(path)
    tracker = KLTTracker(replace(cfg.track, reseed=True, reseed_every=f - 1))
    book = LabelBook()
    prev: dict[int, int] = {}
    prev_k = 0  # K of the last labelled window (0: none yet)
    num_windows = 0
    num_labelled = 0
    num_frames = 0
    ambiguous: list[tuple[int, int]] = []  # (first, last) frame of each window whose K was ambiguous
    cluster_log = logging.getLogger(cluster_auto_k.__module__)

    def label_window(window: list[_Frame], first_labelled: bool) -> WindowResult:
        """Clusters the tracks live through the whole window and labels its frames (all but the first
        when the window before labelled that one: windows share their boundary frame)."""
        nonlocal prev, prev_k, num_windows, num_labelled
        new = window[1:] if first_labelled else window
        before = prev  # the last labelled window's labels: tracks that end inside this window keep theirs
        tracks, row_ids = tracks_from_steps([(ids, xy) for _, _, ids, xy in window], window[0][1].shape[:2])
        traj = build_trajectories(tracks)
        common = row_ids[traj.track_ids]  # tracker ids of the tracks live through the whole window
        k = 0
        note = ""
        scores: dict[int, float] = {}
        labels_by_id: dict[int, int] = {}
        glob = np.zeros(0, dtype=np.int64)
        labelled_ids = np.zeros(0, dtype=np.int64)
        if len(window) >= 2 and common.size >= max(cfg.min_tracks, 2):
            emb = embed_at_model_frames(model, Trajectories(data=traj.data, track_ids=common))
            forced = None if cfg.k is None else min(cfg.k, common.size)
            with _warnings_held(cluster_log):
                sweep = cfg.cluster
                if prev_k and cfg.video_k_step is not None:
                    k_max = max(sweep.k_min, min(sweep.k_max, prev_k + cfg.video_k_step))
                    sweep = replace(sweep, k_max=k_max)
                clustering = cluster_auto_k(emb, sweep, k=forced, points=traj.data, prefer_k=prev_k or None)
            sweep_k = clustering.k  # the next window's preferred K: the embedding's, before the check
            clustering = check_rigid(clustering, traj.data, tracks.size_hw, cfg)
            k, note, scores = clustering.k, clustering.note, dict(clustering.scores)
            glob = match_labels(prev, common, clustering.labels, k, book, num_windows)
            labelled_ids = common[glob >= 0]
            glob = glob[glob >= 0]
            labels_by_id = {int(i): int(g) for i, g in zip(labelled_ids, glob)}
            prev, prev_k = labels_by_id, sweep_k
            num_labelled += 1
        elif len(window) < 2:
            log.info("frame %d: a shot of one frame; left unlabelled", window[0][0])
        else:
            log.warning("frames %d-%d: only %d tracks; left unlabelled", window[0][0], window[-1][0], common.size)
        log.info("frames %d-%d: %d tracks, K = %d%s", window[0][0], window[-1][0], common.size, k, note and f"; {note}")
        labelled = []
        for t, img, ids, xy in new:
            lab = np.array([labels_by_id.get(int(i), before.get(int(i), -1)) for i in ids], dtype=np.int64)
            fr = VideoFrame(t, img, ids, xy, lab, None)
            labelled.append(replace(fr, mask=frame_mask(fr, cfg.mask)) if masks else fr)
        num_windows += 1
        result = WindowResult(
            start=window[0][0],
            num_frames=len(window),
            num_tracks=int(common.size),
            k=k,
            track_ids=labelled_ids,
            labels=glob,
            frames=tuple(labelled),
            num_motions=book.next_label,
            num_labels_reused=book.num_reused,
            num_frames_read=num_frames,
            k_note=note,
            k_scores=scores,
            shot_start=window[0][0] in cuts,
        )
        if result.is_k_ambiguous:
            ambiguous.append((window[0][0], window[-1][0]))
        return result

    window: list[_Frame] = []
    first_done = False  # whether window[0] was labelled by the window before (it starts on its last frame)
    cuts: set[int] = set()  # frames that start a new shot
    frames_iter = iter_video(path, start=cfg.start, max_frames=max_frames)
    while True:
        with decode_errors(path):
            item = next(frames_iter, None)
        if item is None:
            break
        t, frame = item
        ids, xy = tracker.step(frame)
        num_frames += 1
        if window and _is_cut(window[-1][2], ids, cfg):
            # A shot cut: the window ends on the frame before, a new one starts on this frame with
            # tracks detected afresh (the few that survived the cut landed on unrelated content).
            cuts.add(t)
            ids, xy = tracker.restart(frame)
            if not first_done or len(window) > 1:
                yield label_window(window, first_done)
            window, first_done = [], False
        window.append((t, frame, ids, xy))
        if len(window) == f:
            # Later windows start on the previous one's last frame, already labelled there.
            yield label_window(window, first_done)
            window, first_done = [window[-1]], True
    if num_frames < f:
        raise InputError(f"{path}: only {_frames(num_frames)} could be read; --frames needs {f}")
    if not first_done or len(window) > 1:
        yield label_window(window, first_done)
    if cuts:
        shown = ", ".join(str(c) for c in sorted(cuts)[:5]) + (f" and {len(cuts) - 5} more" if len(cuts) > 5 else "")
        log.info("shot cuts at frames %s: tracking started afresh there", shown)
    if num_labelled == 0:
        raise TooFewTracksError(
            f"{path}: no window had at least {cfg.min_tracks} tracks through its {f} frames (textureless video?)"
        )
    claimed = info.get("num_frames")
    if max_frames is None and info["kind"] == "video" and claimed and num_frames < claimed - cfg.start:
        log.warning(
            "%s: decoding stopped after %d of the %d frames the header lists", path, cfg.start + num_frames, claimed
        )
    if ambiguous:
        log.warning(
            "K was ambiguous in %d of %d windows: %s (runner-up within %g; summary.json windows[].k_ambiguous); "
            "pass --k to decide",
            len(ambiguous),
            num_windows,
            _ranges(ambiguous),
            cfg.cluster.ambiguity_margin,
        )


def _is_cut(before: npt.NDArray[np.int64], after: npt.NDArray[np.int64], cfg: PipelineConfig) -> bool:
    """Whether fewer than cfg.video_cut_survival of the track ids `before` (one frame) live on `after`."""
    if cfg.video_cut_survival is None or before.size < 2 * cfg.min_tracks:
        return False
    survived = np.count_nonzero(np.isin(before, after, assume_unique=True))
    return bool(survived < cfg.video_cut_survival * before.size)


@dataclass(frozen=True)
class TracksResult:
    """The segmentation of point tracks made elsewhere (CoTracker, TAPIR, a tracker of one's own).

    Attributes:
        tracks: the tracks as given (N tracks over T frames).
        trajectories: the tracks visible in every frame of the window (M rows, track_ids into `tracks`).
        start: first frame of the window segmented.
        embeddings: (M, E) float32 SubspaceNet embeddings.
        clustering: labels (M,) and the automatic-K evidence.
        labels: (N,) int64 motion of every given track, -1 for a track not visible throughout the window.
        timings: seconds per stage.
        model_info: as in ClipResult.
    """

    tracks: Tracks
    trajectories: Trajectories
    start: int
    embeddings: npt.NDArray[np.float32]
    clustering: Clustering
    labels: npt.NDArray[np.int64]
    timings: dict[str, float]
    model_info: dict[str, Any]


def segment_tracks(
    xy: npt.ArrayLike,
    visible: npt.ArrayLike | None = None,
    cfg: PipelineConfig = PipelineConfig(),
    model: Embedder | None = None,
    start: int = 0,
    frames: int | None = None,
) -> TracksResult:
    """Segments the motions of point tracks from another tracker with our embedding and clustering.

    Tracks visible in every frame of the window [start, start + frames) are embedded (resampled in
    time to the model's frame count when the window is longer or shorter) and clustered with
    cfg.cluster; the others get label -1.

    Args:
        xy: (N, T, 2) pixel coordinates, x right and y down (CoTracker's (T, N, 2) output transposed).
        visible: (N, T) bool, True where a track is visible (None = everywhere; TAPIR gives
            `occluded`, i.e. its negation).
        cfg: pipeline settings (cfg.frames is not used: the window is `frames`).
        model: the model (None = the shipped default for the window's length).
        start: first frame of the window.
        frames: window length F >= 2 (None = from `start` to the last frame).

    Returns:
        TracksResult.

    Raises:
        InputError: arrays of the wrong shape or type, NaN/inf where visible, a window outside the
            frames, or cfg.k larger than the number of tracks.
        TooFewTracksError: fewer than cfg.min_tracks tracks are visible through the whole window.
    """
    arr = np.asarray(xy)
    if arr.ndim != 3 or arr.shape[2] != 2 or arr.dtype.kind not in "iuf" or arr.shape[0] == 0:
        raise InputError(f"xy must be an (N, T, 2) array of pixel coordinates, got {arr.dtype} {arr.shape}")
    num, num_frames = arr.shape[:2]
    vis = np.ones((num, num_frames), dtype=bool) if visible is None else np.asarray(visible)
    if vis.shape != (num, num_frames) or vis.dtype.kind not in "bui":
        raise InputError(f"visible must be an ({num}, {num_frames}) bool array, got {vis.dtype} {vis.shape}")
    vis = vis.astype(bool)
    if not np.all(np.isfinite(arr[vis])):
        raise InputError("xy holds NaN or inf where the tracks are visible")
    for name, value in (("start", start), ("frames", frames)):
        if value is not None and (isinstance(value, bool) or not isinstance(value, (int, np.integer))):
            raise InputError(f"{name}={value!r} must be an integer")
    window = num_frames - start if frames is None else frames
    if start < 0 or window < 2 or start + window > num_frames:
        raise InputError(f"start={start}, frames={window}: the window must hold 2 or more of the {num_frames} frames")
    finite = np.where(vis[..., None], arr, 0.0).astype(np.float32)
    span = finite[vis].max(axis=0) if vis.any() else np.zeros(2)
    tracks = Tracks(xy=finite, visible=vis, size_hw=(int(span[1]) + 1, int(span[0]) + 1))
    timings: dict[str, float] = {}
    model = _model_or_default(model, window, timings)
    traj = build_trajectories(tracks, frames=window, start=start)
    if traj.num_points < cfg.min_tracks:
        raise TooFewTracksError(
            f"only {traj.num_points} of {num} tracks are visible in all frames {start}..{start + window - 1}; "
            f"need at least {cfg.min_tracks} (choose a shorter window with frames/start)"
        )
    _check_k(cfg.k, traj.num_points, "tracks")
    t0 = time.perf_counter()
    emb = embed_at_model_frames(model, traj)
    timings["embed"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    clustering = cluster_auto_k(emb, cfg.cluster, k=cfg.k, points=traj.data)
    clustering = check_rigid(clustering, traj.data, tracks.size_hw, cfg)
    timings["cluster"] = time.perf_counter() - t0
    labels = np.full(num, -1, dtype=np.int64)
    labels[traj.track_ids] = clustering.labels
    return TracksResult(tracks, traj, start, emb, clustering, labels, timings, model_info(model))
