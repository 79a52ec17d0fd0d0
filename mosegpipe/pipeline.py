"""The recipe, stage by stage: frames -> tracks -> trajectories -> embeddings -> clusters -> masks -> files.

`segment_frames` / `segment_clip` / `segment_pair` return results in memory; `write_clip_outputs` /
`write_pair_outputs` write them into a fresh output folder atomically (built under a temporary name and
renamed when complete), so a failure never leaves half an output behind.
"""

from __future__ import annotations

import logging
import shutil
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe import __version__
from mosegpipe.cluster import ClusterConfig, cluster_auto_k
from mosegpipe.errors import InputError, OutputExistsError, TooFewTracksError
from mosegpipe.io import default_palette, read_image, read_video, write_json, write_npz, write_palette_png
from mosegpipe.masks import MaskConfig, labels_to_mask, labels_to_masks
from mosegpipe.match import MatchConfig, match_sift
from mosegpipe.model import SubspaceNet
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
    """
    if checkpoint is not None:
        return SubspaceNet.from_checkpoint(checkpoint)
    if frames == 2:
        return SubspaceNet.default(frames=2)
    from mosegpipe.model import available_default_frames

    available = available_default_frames()
    return SubspaceNet.default(frames=frames if frames in available else 5)


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


def _check_k(k: int | None, n: int) -> None:
    if k is not None and (k < 1 or k > n):
        raise InputError(f"--k {k} is larger than the number of tracks ({n})" if k > n else f"--k {k} must be >= 1")


def segment_frames(frames: Frames, cfg: PipelineConfig = PipelineConfig(), model: SubspaceNet | None = None) -> ClipResult:
    """Segments the motions in a short stack of frames.

    Raises:
        TooFewTracksError: fewer than cfg.min_tracks tracks live through all frames.
        InputError: cfg.k larger than the number of tracks.
    """
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    model = model or load_model(frames.num_frames)
    timings["load_model"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    tracks = track_klt(frames, cfg.track)
    timings["track"] = time.perf_counter() - t0
    traj = build_trajectories(tracks, frames=frames.num_frames)
    if traj.num_points < cfg.min_tracks:
        raise TooFewTracksError(
            f"{frames.source or 'clip'}: only {traj.num_points} tracks survived {frames.num_frames} frames; "
            f"need at least {cfg.min_tracks} (textureless or blank frames?)"
        )
    _check_k(cfg.k, traj.num_points)
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


def segment_clip(path: str | Path, cfg: PipelineConfig = PipelineConfig(), model: SubspaceNet | None = None) -> ClipResult:
    """Reads the first cfg.frames frames of a video file or frame folder and segments them."""
    t0 = time.perf_counter()
    frames = read_video(path, max_frames=cfg.frames)
    if frames.num_frames < cfg.frames:
        raise InputError(f"{path}: only {frames.num_frames} frames, --frames needs {cfg.frames}")
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
    """Segments the motions between two images (they may differ in size); outliers get label -1."""
    timings: dict[str, float] = {}
    im1 = read_image(img1) if not isinstance(img1, np.ndarray) else img1
    im2 = read_image(img2) if not isinstance(img2, np.ndarray) else img2
    t0 = time.perf_counter()
    model = model or load_model(2)
    timings["load_model"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    matches = match_sift(im1, im2, cfg.match)
    timings["match"] = time.perf_counter() - t0
    if matches.num_matches < cfg.min_tracks:
        raise TooFewTracksError(f"only {matches.num_matches} matches between the images; need at least {cfg.min_tracks}")
    _check_k(cfg.k, matches.num_matches)
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


class _OutputDir:
    """Builds an output folder under a temporary name; renames it into place only when complete."""

    def __init__(self, out_dir: Path, overwrite: bool) -> None:
        self.final = Path(out_dir)
        if self.final.exists() and any(self.final.iterdir()) and not overwrite:
            raise OutputExistsError(f"{self.final}: already holds results; pass --overwrite to replace them")
        self.tmp = self.final.with_name(f".{self.final.name}.partial")
        self.overwrite = overwrite

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
        xy: (N, 2) pixel positions of the tracks in this image.
        labels: (N,) labels (-1 = outlier, drawn as a small grey cross).
    """
    palette = default_palette()
    out = image.copy()
    if mask is not None:
        colour = palette[mask]
        known = mask > 0
        out[known] = (alpha * colour[known] + (1 - alpha) * out[known]).astype(np.uint8)
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


def clip_summary(result: ClipResult, cfg: PipelineConfig) -> dict[str, Any]:
    """The JSON summary of a clip run (schema: docs/OUTPUTS.md)."""
    c = result.clustering
    return {
        "schema": SUMMARY_SCHEMA,
        "kind": "clip",
        "source": result.frames.source,
        "version": __version__,
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
    result: ClipResult, out_dir: str | Path, cfg: PipelineConfig = PipelineConfig(), overwrite: bool = False, rrd: bool = True
) -> dict[str, Any]:
    """Writes summary.json, labels.npz, masks/*.png (palette), overlay/*.jpg and recording.rrd atomically.

    Returns:
        The summary dict that was written.
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
        palette = default_palette()
        (tmp / "masks").mkdir()
        (tmp / "overlay").mkdir()
        for t in range(result.frames.num_frames):
            write_palette_png(tmp / "masks" / f"{t:06d}.png", result.masks[t], palette)
            xy = result.tracks.xy[traj.track_ids, t]
            _write_jpg(tmp / "overlay" / f"{t:06d}.jpg", overlay_image(result.frames.images[t], result.masks[t], xy, result.clustering.labels))
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
    """Writes summary.json, labels.npz, masks/{0,1}.png, overlay/{0,1}.jpg and recording.rrd atomically."""
    summary = pair_summary(result, cfg, sources)
    with _OutputDir(Path(out_dir), overwrite) as tmp:
        m = result.matches
        write_npz(tmp / "labels.npz", xy1=m.xy1, xy2=m.xy2, labels=result.labels, clusters=result.clustering.labels, embeddings=result.embeddings)
        palette = default_palette()
        (tmp / "masks").mkdir()
        (tmp / "overlay").mkdir()
        for i, (img, mask, xy) in enumerate(zip(result.images, result.masks, (m.xy1, m.xy2))):
            write_palette_png(tmp / "masks" / f"{i:06d}.png", mask, palette)
            _write_jpg(tmp / "overlay" / f"{i:06d}.jpg", overlay_image(img, mask, xy, result.labels))
        if rrd:
            from mosegpipe.viz import write_pair_recording

            write_pair_recording(tmp / "recording.rrd", result.images, m, result.labels, result.embeddings, result.masks, result.clustering.scores, result.clustering.k)
        write_json(tmp / "summary.json", summary)
    return summary
