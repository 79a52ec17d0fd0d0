"""The recipe, stage by stage: frames -> tracks -> trajectories -> embeddings -> clusters -> masks -> files.

`segment_frames` / `segment_clip` / `segment_pair` return results in memory; `write_clip_outputs` /
`write_pair_outputs` write them into a fresh output folder atomically (built under a temporary name and
renamed when complete), so a failure never leaves half an output behind. `check_output_dir` lets a
caller refuse an occupied output folder before spending time on segmentation, and `decode_errors`
turns whatever OpenCV or the OS raise on a broken input into an InputError. The folder layout and
summary.json schema are in docs/OUTPUTS.md; whole videos are in mosegpipe.video.
"""

from __future__ import annotations

import contextlib
import logging
import shutil
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe import __version__
from mosegpipe.cluster import ClusterConfig, cluster_auto_k
from mosegpipe.errors import CheckpointError, InputError, OutputExistsError, TooFewTracksError
from mosegpipe.io import default_palette, read_image, read_video, video_info, write_json, write_npz, write_palette_png
from mosegpipe.masks import MaskConfig, labels_to_mask, labels_to_masks, overlay_mask
from mosegpipe.match import MatchConfig, match_sift
from mosegpipe.model import SubspaceNet, available_default_frames
from mosegpipe.track import TrackConfig, track_klt
from mosegpipe.trajectories import build_trajectories, resample_frames, trajectories_from_matches
from mosegpipe.types import Clustering, Frames, Matches, Tracks, Trajectories

log = logging.getLogger(__name__)

SUMMARY_SCHEMA = "mosegpipe.summary/1"


@dataclass(frozen=True)
class PipelineConfig:
    """Settings of one segmentation run.

    Attributes:
        frames: F, the number of frames segmented (the paper's clips are 5 frames).
        k: force this many motions (None = automatic K).
        min_tracks: fewer surviving tracks / matches than this is an error (too little texture).
        track: KLT settings.
        match: SIFT matching settings (pairs).
        cluster: automatic-K settings.
        mask: dense-mask settings.
        outlier_inlier_ratio: pairs: a cluster whose best fundamental-matrix RANSAC fit explains less
            than this fraction of its points is labelled as outliers.
    """

    frames: int = 5
    k: int | None = None
    min_tracks: int = 10
    track: TrackConfig = field(default_factory=TrackConfig)
    match: MatchConfig = field(default_factory=MatchConfig)
    cluster: ClusterConfig = field(default_factory=ClusterConfig)
    mask: MaskConfig = field(default_factory=MaskConfig)
    outlier_inlier_ratio: float = 0.5


@dataclass
class ClipResult:
    """Everything one clip's segmentation produced.

    Attributes:
        frames: the frames segmented.
        tracks: all KLT tracks (N_all, T).
        trajectories: the tracks visible in all frames (N rows, track_ids into `tracks`).
        embeddings: (N, E) float32 SubspaceNet embeddings.
        clustering: labels (N,) and the automatic-K evidence.
        masks: (T, H, W) uint8, 0 = no track nearby, k + 1 = motion k.
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


@dataclass
class PairResult:
    """Everything one image pair's segmentation produced.

    Attributes:
        images: the two RGB images (they may differ in size).
        matches: SIFT correspondences (N).
        embeddings: (N, E) float32.
        clustering: labels (N,) in 0..k-1 as clustered.
        labels: (N,) int64 final labels: motions 0..m-1, -1 for the outlier cluster (if one was found).
        outlier_cluster: which cluster was labelled outliers (None when none was).
        masks: two (H_i, W_i) uint8 masks, 0 = unknown / outlier, m + 1 = motion m.
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
        The model in eval mode.

    Raises:
        CheckpointError: the checkpoint is missing, corrupt or not a SubspaceNet, or no weights are shipped.
    """
    if checkpoint is not None:
        return SubspaceNet.from_checkpoint(checkpoint)
    shipped = 2 if frames == 2 else frames if frames in available_default_frames() else 5
    try:
        return SubspaceNet.default(frames=shipped)
    except CheckpointError as exc:
        raise CheckpointError(f"{exc}; pass --model CHECKPOINT to use other weights") from exc


def _model_info(model: SubspaceNet) -> dict[str, Any]:
    recipe = getattr(model, "recipe", None) or {}
    return {
        "recipe": recipe.get("name", "unknown"),
        "model_frames": model.cfg.in_dim // 2,
        "model_config": model.cfg.to_dict(),
    }


def _embed(model: SubspaceNet, traj: Trajectories) -> npt.NDArray[np.float32]:
    model_frames = model.cfg.in_dim // 2
    if traj.num_frames != model_frames:
        traj = resample_frames(traj, model_frames)
    return model.embed(traj.data)


def _check_k(k: int | None, n: int, source: str, what: str = "tracks") -> None:
    if k is not None and k < 1:
        raise InputError(f"--k {k} must be >= 1")
    if k is not None and k > n:
        raise InputError(f"{source}: --k {k} is larger than the number of {what} ({n})")


def _model_or_default(model: SubspaceNet | None, frames: int, timings: dict[str, float]) -> SubspaceNet:
    if model is not None:
        return model
    t0 = time.perf_counter()
    model = load_model(frames)
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


def segment_frames(frames: Frames, cfg: PipelineConfig = PipelineConfig(), model: SubspaceNet | None = None) -> ClipResult:
    """Segments the motions in a short stack of frames.

    Args:
        frames: Frames with images (T, H, W, 3) uint8 RGB; every frame is segmented.
        cfg: pipeline settings (cfg.frames is not used here: T is what the frames hold).
        model: the model (None = the shipped default for T frames).

    Returns:
        ClipResult; its masks are (T, H, W) uint8 with 0 = unknown and k + 1 = motion k.

    Raises:
        TooFewTracksError: fewer than cfg.min_tracks tracks live through all frames.
        InputError: cfg.k larger than the number of tracks.
        CheckpointError: no model given and no shipped weights.
    """
    timings: dict[str, float] = {}
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
    emb = _embed(model, traj)
    timings["embed"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    clustering = cluster_auto_k(emb, cfg.cluster, k=cfg.k)
    timings["cluster"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    masks = labels_to_masks(tracks, traj.track_ids, clustering.labels, cfg.mask)
    timings["masks"] = time.perf_counter() - t0
    return ClipResult(frames, tracks, traj, emb, clustering, masks, timings, _model_info(model))


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


def segment_clip(path: str | Path, cfg: PipelineConfig = PipelineConfig(), model: SubspaceNet | None = None) -> ClipResult:
    """Reads the first cfg.frames frames of a video file or frame folder and segments them.

    Args:
        path: a video file OpenCV can read or a folder of images (sorted by name).
        cfg: pipeline settings; cfg.frames frames are read.
        model: the model (None = the shipped default for cfg.frames).

    Returns:
        ClipResult (timings also hold "read").

    Raises:
        InputError: missing, unreadable, corrupt or truncated input, or fewer than cfg.frames frames.
        TooFewTracksError: see segment_frames.
    """
    t0 = time.perf_counter()
    with decode_errors(path):
        frames = read_video(path, max_frames=cfg.frames)
    if frames.num_frames < cfg.frames:
        claimed = _container_frames(path)
        hint = ""
        if claimed and claimed > frames.num_frames:
            hint = f" of the {claimed} its header lists (truncated or corrupt video?)"
        raise InputError(f"{path}: only {_frames(frames.num_frames)} could be read{hint}; --frames needs {cfg.frames}")
    read_s = time.perf_counter() - t0
    result = segment_frames(frames, cfg, model)
    result.timings = {"read": read_s, **result.timings}
    return result


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
    worst = min(ratios, key=ratios.get)
    return worst if ratios[worst] < min_ratio else None


def segment_pair(
    img1: str | Path | npt.NDArray[np.uint8],
    img2: str | Path | npt.NDArray[np.uint8],
    cfg: PipelineConfig = PipelineConfig(frames=2),
    model: SubspaceNet | None = None,
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
    images = []
    for img in (img1, img2):
        if isinstance(img, np.ndarray):
            images.append(img)
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
    emb = _embed(model, traj)
    timings["embed"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    clustering = cluster_auto_k(emb, cfg.cluster, k=cfg.k)
    outlier = _outlier_cluster(matches, clustering.labels, clustering.k, cfg.outlier_inlier_ratio)
    labels = clustering.labels.copy()
    if outlier is not None:
        labels[clustering.labels == outlier] = -1
        labels[clustering.labels > outlier] -= 1
    timings["cluster"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    inl = labels >= 0
    masks = (
        labels_to_mask(matches.xy1[inl], labels[inl], im1.shape[:2], cfg.mask),
        labels_to_mask(matches.xy2[inl], labels[inl], im2.shape[:2], cfg.mask),
    )
    timings["masks"] = time.perf_counter() - t0
    return PairResult((im1, im2), matches, emb, clustering, labels, outlier, masks, timings, _model_info(model))


def check_output_dir(out_dir: str | Path, overwrite: bool) -> None:
    """Fails early when `out_dir` cannot receive a run's outputs.

    An absent or empty folder is fine. A folder holding files is refused unless `overwrite`, and
    even then only when it is a moseg output folder (holds summary.json): --overwrite never deletes
    a folder of other files (an input folder given as --out by mistake, a home directory).

    Raises:
        OutputExistsError: it holds results and overwrite is False.
        InputError: it is a file, or it holds files that are not a moseg output.
    """
    out = Path(out_dir)
    if not out.exists():
        return
    if not out.is_dir():
        raise InputError(f"{out}: exists and is not a folder; choose another --out")
    if not any(out.iterdir()):
        return
    if not overwrite:
        raise OutputExistsError(f"{out}: already holds results; pass --overwrite to replace them")
    if not (out / "summary.json").is_file():
        raise InputError(f"{out}: holds files but no summary.json, so it is not a moseg output; refusing to replace it")


class _OutputDir:
    """Builds an output folder under a temporary name; renames it into place only when complete.

    The temporary folder `.NAME.partial` sits beside the final one (same file system, so the rename
    is atomic). On an exception (KeyboardInterrupt included) it is removed and the final folder is
    left as it was; on success an existing final folder is replaced (see check_output_dir).
    """

    def __init__(self, out_dir: Path, overwrite: bool) -> None:
        check_output_dir(out_dir, overwrite)
        # absolute(): "." or "" has no name to build the temporary sibling from.
        self.final = Path(out_dir).absolute()
        self.tmp = self.final.with_name(f".{self.final.name}.partial")

    def __enter__(self) -> Path:
        if self.tmp.exists():
            shutil.rmtree(self.tmp)
        self.tmp.mkdir(parents=True)
        return self.tmp

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc_type is not None:
            shutil.rmtree(self.tmp, ignore_errors=True)
            return
        if self.final.exists():
            old = self.final.with_name(f".{self.final.name}.old")
            shutil.rmtree(old, ignore_errors=True)
            self.final.rename(old)
            self.tmp.rename(self.final)
            shutil.rmtree(old, ignore_errors=True)
        else:
            self.tmp.rename(self.final)


def overlay_image(
    image: npt.NDArray[np.uint8],
    mask: npt.NDArray[np.uint8] | None,
    xy: npt.NDArray[np.float32],
    labels: npt.NDArray[np.int64],
    alpha: float = 0.45,
) -> npt.NDArray[np.uint8]:
    """An RGB picture for people: the mask blended over the image and each track as a dot in its label's colour.

    Args:
        image: (H, W, 3) uint8 RGB.
        mask: (H, W) uint8 mask values (0 = unknown, left unblended) or None.
        xy: (N, 2) float32 pixel positions of the tracks in this image.
        labels: (N,) int64 labels (-1 = outlier, drawn as a small grey cross); colour = palette[label + 1],
            the colour of the mask value label + 1.
        alpha: weight of the mask colour, 0..1.

    Returns:
        (H, W, 3) uint8 RGB.
    """
    palette = default_palette()
    out = overlay_mask(image, mask, palette, alpha) if mask is not None else image.copy()
    for (x, y), lab in zip(np.round(xy).astype(int), labels):
        if lab < 0:
            cv2.drawMarker(out, (int(x), int(y)), (160, 160, 160), cv2.MARKER_TILTED_CROSS, 5, 1)
        else:
            c = tuple(int(v) for v in palette[lab + 1])
            cv2.circle(out, (int(x), int(y)), 3, c, -1, lineType=cv2.LINE_AA)
            cv2.circle(out, (int(x), int(y)), 3, (0, 0, 0), 1, lineType=cv2.LINE_AA)
    return out


def _write_jpg(path: Path, rgb: npt.NDArray[np.uint8]) -> None:
    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 90])
    if not ok:
        raise InputError(f"{path}: could not encode overlay image")
    path.write_bytes(buf.tobytes())


def _write_masks_and_overlays(
    folder: Path,
    indices: list[int],
    images: Any,
    masks: Any,
    xys: list[npt.NDArray[np.float32]],
    labels: npt.NDArray[np.int64],
) -> None:
    """masks/NNNNNN.png (palette) and overlay/NNNNNN.jpg for each image, named by its index in the source."""
    palette = default_palette()
    (folder / "masks").mkdir()
    (folder / "overlay").mkdir()
    for index, image, mask, xy in zip(indices, images, masks, xys):
        write_palette_png(folder / "masks" / f"{index:06d}.png", mask, palette)
        _write_jpg(folder / "overlay" / f"{index:06d}.jpg", overlay_image(image, mask, xy, labels))


def clip_summary(result: ClipResult, cfg: PipelineConfig) -> dict[str, Any]:
    """The JSON summary of a clip run (schema: docs/OUTPUTS.md)."""
    c = result.clustering
    return {
        "schema": SUMMARY_SCHEMA,
        "kind": "clip",
        "source": result.frames.source,
        "version": __version__,
        "start": result.frames.start,
        "frames": result.frames.num_frames,
        "size_hw": list(result.frames.size_hw),
        "k": c.k,
        "k_method": c.method,
        "k_scores": {str(k): float(v) for k, v in c.scores.items()},
        "num_tracks_detected": result.tracks.num_tracks,
        "num_tracks_segmented": result.trajectories.num_points,
        "tracks_per_motion": np.bincount(c.labels, minlength=c.k).tolist(),
        "timings_s": {k: round(v, 4) for k, v in result.timings.items()},
        "model": result.model_info,
        "config": asdict(cfg),
    }


def write_clip_outputs(
    result: ClipResult,
    out_dir: str | Path,
    cfg: PipelineConfig = PipelineConfig(),
    overwrite: bool = False,
    rrd: bool = True,
) -> dict[str, Any]:
    """Writes summary.json, labels.npz, masks/*.png (palette), overlay/*.jpg and recording.rrd atomically.

    The folder layout and every field are documented in docs/OUTPUTS.md. Mask and overlay files are
    named after the source frame index (000000.png, ...).

    Args:
        result: what segment_clip / segment_frames returned.
        out_dir: output folder; built under a temporary name and renamed when complete.
        cfg: the settings the result was computed with (recorded in summary.json).
        overwrite: replace an existing moseg output folder.
        rrd: also write the Rerun recording.

    Returns:
        The summary dict that was written.

    Raises:
        OutputExistsError, InputError: see check_output_dir.
    """
    summary = clip_summary(result, cfg)
    with _OutputDir(Path(out_dir), overwrite) as tmp:
        traj = result.trajectories
        write_npz(
            tmp / "labels.npz",
            track_ids=traj.track_ids,
            labels=result.clustering.labels,
            xy=result.tracks.xy[traj.track_ids],
            embeddings=result.embeddings,
        )
        _write_masks_and_overlays(
            tmp,
            [result.frames.start + t for t in range(result.frames.num_frames)],
            result.frames.images,
            result.masks,
            [result.tracks.xy[traj.track_ids, t] for t in range(result.frames.num_frames)],
            result.clustering.labels,
        )
        if rrd:
            from mosegpipe.viz import write_recording

            t0 = time.perf_counter()
            write_recording(
                tmp / "recording.rrd",
                result.frames,
                result.tracks,
                traj.track_ids,
                result.clustering.labels,
                result.embeddings,
                result.masks,
                result.clustering.scores,
                result.clustering.k,
            )
            summary["timings_s"]["rrd"] = round(time.perf_counter() - t0, 4)
        write_json(tmp / "summary.json", summary)
    return summary


def pair_summary(result: PairResult, cfg: PipelineConfig, sources: tuple[str, str]) -> dict[str, Any]:
    """The JSON summary of a pair run (schema: docs/OUTPUTS.md)."""
    c = result.clustering
    motions = result.labels[result.labels >= 0]
    num_motions = int(motions.max()) + 1 if motions.size else 0
    return {
        "schema": SUMMARY_SCHEMA,
        "kind": "pair",
        "source": list(sources),
        "version": __version__,
        "size_hw": [list(result.images[0].shape[:2]), list(result.images[1].shape[:2])],
        "k": c.k,
        "num_motions": num_motions,
        "outlier_cluster": result.outlier_cluster,
        "num_outliers": int((result.labels < 0).sum()),
        "k_method": c.method,
        "k_scores": {str(k): float(v) for k, v in c.scores.items()},
        "num_matches": result.matches.num_matches,
        "matches_per_motion": np.bincount(motions, minlength=num_motions).tolist(),
        "timings_s": {k: round(v, 4) for k, v in result.timings.items()},
        "model": result.model_info,
        "config": asdict(cfg),
    }


def write_pair_outputs(
    result: PairResult,
    out_dir: str | Path,
    cfg: PipelineConfig = PipelineConfig(frames=2),
    overwrite: bool = False,
    sources: tuple[str, str] = ("", ""),
    rrd: bool = True,
) -> dict[str, Any]:
    """Writes summary.json, labels.npz, masks/00000{0,1}.png, overlay/00000{0,1}.jpg and recording.rrd atomically.

    Args:
        result: what segment_pair returned.
        out_dir: output folder; built under a temporary name and renamed when complete.
        cfg: the settings the result was computed with (recorded in summary.json).
        overwrite: replace an existing moseg output folder.
        sources: the two image paths, for summary.json.
        rrd: also write the Rerun recording.

    Returns:
        The summary dict that was written.

    Raises:
        OutputExistsError, InputError: see check_output_dir.
    """
    summary = pair_summary(result, cfg, sources)
    with _OutputDir(Path(out_dir), overwrite) as tmp:
        m = result.matches
        write_npz(
            tmp / "labels.npz",
            xy1=m.xy1,
            xy2=m.xy2,
            labels=result.labels,
            clusters=result.clustering.labels,
            embeddings=result.embeddings,
        )
        _write_masks_and_overlays(tmp, [0, 1], result.images, result.masks, [m.xy1, m.xy2], result.labels)
        if rrd:
            from mosegpipe.viz import write_pair_recording

            t0 = time.perf_counter()
            write_pair_recording(
                tmp / "recording.rrd",
                result.images,
                m,
                result.labels,
                result.embeddings,
                result.masks,
                result.clustering.scores,
                result.clustering.k,
            )
            summary["timings_s"]["rrd"] = round(time.perf_counter() - t0, 4)
        write_json(tmp / "summary.json", summary)
    return summary
