"""Image pairs: `segment_pair` (SIFT matches, one embedding, a cluster that no fundamental matrix
explains labelled as outliers) and its `PairResult`."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from mosegpipe.embed.numpy_net import Embedder
from mosegpipe.errors import TooFewTracksError
from mosegpipe.group.cluster import cluster_auto_k
from mosegpipe.group.twoview import robust_fit
from mosegpipe.group.world import world_cluster, world_first, world_scores
from mosegpipe.io.read import check_images, read_image
from mosegpipe.masks import labels_to_mask
from mosegpipe.pipeline.common import check_k, decode_errors, embed_at_model_frames, model_info, model_or_default
from mosegpipe.pipeline.config import PipelineConfig
from mosegpipe.points.sift import match_sift
from mosegpipe.points.trajectories import trajectories_from_matches
from mosegpipe.types import Clustering, Matches


@dataclass(frozen=True)
class PairResult:
    """Everything one image pair's segmentation produced.

    Attributes:
        images: the two RGB images (they may differ in size).
        matches: SIFT correspondences (N).
        embeddings: (N, E) float32.
        clustering: labels (N,) in 0..k-1 as clustered.
        labels: (N,) int64 final labels: motions 0..m-1 (0 = the world, `mosegpipe.group.world`), -1 for the outlier
            cluster (if one was found).
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
        _, inl = robust_fit(
            "fundamental",
            matches.xy1[idx].astype(np.float64),
            matches.xy2[idx].astype(np.float64),
            "ransac",
            2.0,
            confidence=0.99,
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
    model = model_or_default(model, 2, timings)
    t0 = time.perf_counter()
    matches = match_sift(im1, im2, cfg.match)
    timings["match"] = time.perf_counter() - t0
    if matches.num_matches < cfg.min_tracks:
        raise TooFewTracksError(
            f"{names}: only {matches.num_matches} SIFT matches; need at least {cfg.min_tracks} "
            "(blank, textureless or unrelated images?)"
        )
    check_k(cfg.k, matches.num_matches, names, "matches")
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
    # the world's motion is 0, told by where its matches lie in the first image (mosegpipe.group.world)
    motions = int(labels.max()) + 1 if (labels >= 0).any() else 0
    scores = world_scores(matches.xy1, labels, motions, im1.shape[:2], cfg=cfg.world)
    labels = world_first(labels, world_cluster(scores, cfg.world))
    timings["cluster"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    inl = labels >= 0
    masks = (
        labels_to_mask(matches.xy1[inl], labels[inl], im1.shape[:2], cfg.mask, im1),
        labels_to_mask(matches.xy2[inl], labels[inl], im2.shape[:2], cfg.mask, im2),
    )
    timings["masks"] = time.perf_counter() - t0
    return PairResult((im1, im2), matches, emb, clustering, labels, outlier, masks, timings, model_info(model))
