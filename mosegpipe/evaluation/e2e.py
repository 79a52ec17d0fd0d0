"""End-to-end scores: the whole pipeline (tracking or matching included) against benchmark ground truth.

The benchmark protocols in benchmark.py feed SubspaceNet the datasets' own trajectories. Here the
pipeline finds its own points (KLT tracks, SIFT matches) as it would on a user's video, and the
ground truth is carried over to them:

- "kt3d-video": the first F frames of each KT3DMoSeg sequence go through `segment_frames`. Each of our
  tracks takes the label of the nearest ground-truth trajectory in frame 1 (among those visible in
  frame 1, not only those visible in all F frames: more of the image is covered that way). The
  ground-truth trajectories were seeded on a regular 8 px grid (integer coordinates), so our corners
  sit up to ~5.7 px from the nearest seed: within 3 px only ~5 % of our tracks find one, within 5 px
  ~15 %. The default radius is therefore 5 px. A match is dropped when the ground-truth trajectory
  is also visible in frame F and lies more than twice the radius from our track there (the two
  points followed different surfaces, e.g. across an object boundary). Tracks without a match are
  not scored. The KT3DMoSeg coordinates may be 1-based (MATLAB); at most 1 px, well inside the radius.
  Beside k_true (the true motions among the scored tracks) a row holds k_true_5, the motions that at least
  `SEEN_TRACKS` (5) scored tracks carry: a motion that one or two of our tracks carry (a far car, or a track
  that the transfer gave a neighbour's label) is not one that a group of tracks can be found for (the joint
  grouping's smallest group is 10 tracks), so the summary reports correct K against both.
- "adelaide-pairs": each AdelaideRMF pair goes through `segment_pair`. Our match takes the label of
  the nearest ground-truth correspondence in image 1 within 3 px, kept only when the two agree in
  image 2 within 3 px as well. The release's coordinates sit about +0.75 px from OpenCV's SIFT
  keypoints in x and y (measured: median offset of nearby points on every pair; a 1-based,
  VLFeat-style convention), well inside the radius. Ground-truth gross outliers (label 0) count as
  one group and our outliers (label -1) as one more predicted group, as in the dataset protocol.
- "rendered": synthetic clips from mosegpipe.synth.render with exact per-pixel masks; the dense masks are
  scored with the DAVIS region similarity J and boundary F-measure (see `metrics.mask_scores`), and the
  tracks with the misclassification error against the mask value under each track in frame 1.

Every protocol returns one row (dict) per clip; `report.summarize_rows` and `report.format_rows` turn
rows into a summary and a Markdown table; the records are in `protocols.PROTOCOLS`. A clip that the pipeline cannot segment (too few tracks) gives a row
with error NaN and is counted in the summary's "num_unscored".
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe.embed.model import SubspaceNet
from mosegpipe.errors import MosegError
from mosegpipe.evaluation.identities import identity_switches, object_j
from mosegpipe.evaluation.label_transfer import nearest_within
from mosegpipe.evaluation.metrics import BOUNDARY_TOLERANCE, mask_scores, misclassification_error
from mosegpipe.masks import UNKNOWN
from mosegpipe.pipeline import PipelineConfig, clip_masks, segment_frames, segment_pair
from mosegpipe.points.trajectories import trajectories_from_matches
from mosegpipe.types import Frames

log = logging.getLogger(__name__)

KT3D_MAX_DIST_PX = 5.0
"""Label-transfer radius for KT3DMoSeg, pixels (its ground truth lies on an 8 px grid; see module doc)."""

SEEN_TRACKS = 5
"""kt3d-video's k_true_5: a true motion counts when at least this many scored tracks carry it (module doc)."""

ADELAIDE_MAX_DIST_PX = 3.0
"""Label-transfer radius for AdelaideRMF in each image, pixels."""


# ---------------------------------------------------------------------------------------------
# Protocols


def _with_outlier_group(labels: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
    """Our outliers (-1) as one more predicted group, after the motions."""
    out = labels.astype(np.int64, copy=True)
    if (out < 0).any():
        out[out < 0] = out.max(initial=-1) + 1
    return out


def _score(pred: npt.NDArray[np.int64], gt: npt.NDArray[np.int64]) -> tuple[int, float]:
    """(k_true among the scored points, misclassification error or NaN when nothing is scored)."""
    if gt.size == 0:
        return 0, float("nan")
    return int(np.unique(gt).size), misclassification_error(pred, gt)


def motions_seen(gt: npt.NDArray[np.int64], least: int = SEEN_TRACKS) -> int:
    """How many true motions at least `least` of the scored points carry (`gt`: their (M,) true labels)."""
    return int(np.count_nonzero(np.bincount(np.asarray(gt, np.int64)) >= least)) if np.size(gt) else 0


def same_point_scores(
    traj: npt.NDArray[np.float32],
    emb: npt.NDArray[np.float32],
    scored: npt.NDArray[np.bool_],
    gt: npt.NDArray[np.int64],
    cfg: PipelineConfig,
    baselines: Sequence[str] = (),
) -> dict[str, float]:
    """SubspaceNet with the true K, and baselines with the true K, on the very points the pipeline segmented.

    Every method clusters all N points (as the pipeline does) and is scored on the `scored` ones.

    Args:
        traj: (N, 2F) trajectory matrix the pipeline embedded, pixels.
        emb: (N, E) its embeddings.
        scored: (N,) bool, the points with a ground-truth label.
        gt: (scored.sum(),) their ground-truth labels.
        cfg: pipeline settings (K-means settings of cfg.cluster).
        baselines: names from evaluation.baselines.BASELINES.

    Returns:
        {"error_true_k": ..., "<baseline>@K": ...}; NaN when nothing is scored.
    """
    from mosegpipe.evaluation.baselines import BASELINES
    from mosegpipe.group.cluster import cluster_auto_k

    k = int(np.unique(gt).size)
    if k == 0:
        return {"error_true_k": float("nan"), **{f"{b}@K": float("nan") for b in baselines}}
    k = min(k, traj.shape[0])
    out = {"error_true_k": misclassification_error(cluster_auto_k(emb, cfg.cluster, k=k).labels[scored], gt)}
    for b in baselines:
        out[f"{b}@K"] = misclassification_error(BASELINES[b](traj, k)[scored], gt)
    return out


def kt3d_video_rows(
    data_root: str | Path,
    model: SubspaceNet | None,
    cfg: PipelineConfig = PipelineConfig(),
    frames: int | None = None,
    max_dist_px: float = KT3D_MAX_DIST_PX,
    names: Sequence[str] | None = None,
    warmup: bool = True,
    baselines: Sequence[str] | None = None,
) -> list[dict[str, Any]]:
    """The full clip pipeline on the first F frames of every KT3DMoSeg sequence.

    Args:
        data_root: the data folder holding ``kt3dmoseg/``.
        model: the F-frame model (None = the shipped default).
        cfg: pipeline settings (its `frames` is replaced by F).
        frames: F, frames per clip (None = cfg.frames; the paper uses 5).
        max_dist_px: label-transfer radius in frame 1, pixels (see the module docstring).
        names: only these sequences (None = all 22).
        warmup: run the first clip once untimed, so that one-off costs stay out of `seconds`.
        baselines: also score SubspaceNet with the true K and these baselines with the true K on
            the same tracks (`same_point_scores`); None = neither.

    Returns:
        One row per sequence: name, num_tracks (tracks segmented), num_scored (tracks with a
        ground-truth label), k_true (ground-truth groups among the scored tracks), k_true_5 (those that at
        least SEEN_TRACKS scored tracks carry), k_pred, error
        (misclassification over the scored tracks, NaN when none), seconds (segment_frames:
        tracking, embedding, automatic K, masks; reading the JPEGs excluded), and with
        `baselines` error_true_k and `<baseline>@K`.

    Raises:
        DatasetError: the KT3DMoSeg folder is missing or malformed.
    """
    from mosegpipe.data.kt3dmoseg import kt3d_frame_paths, list_kt3d_sequences, read_kt3d_sequence
    from mosegpipe.io.read import read_image

    f = cfg.frames if frames is None else frames
    cfg = replace(cfg, frames=f)
    rows = []
    for n, name in enumerate(names if names is not None else list_kt3d_sequences(data_root)):
        seq = read_kt3d_sequence(data_root, name)
        paths = kt3d_frame_paths(data_root, name)[:f]
        zero = dict.fromkeys(("num_tracks", "num_scored", "k_true", "k_true_5", "k_pred"), 0)
        row: dict[str, Any] = {"name": seq.name, **zero}
        if len(paths) < f or seq.num_frames < f:
            log.warning("%s: only %d frames, need %d; not scored", name, min(len(paths), seq.num_frames), f)
            rows.append({**row, "error": float("nan"), "seconds": 0.0})
            continue
        clip = Frames(images=np.stack([read_image(p) for p in paths]), source=str(seq.frames_dir))
        try:
            if warmup and n == 0:
                segment_frames(clip, cfg, model)
            t0 = time.perf_counter()
            result = segment_frames(clip, cfg, model)
            seconds = time.perf_counter() - t0
        except MosegError as exc:
            log.warning("%s: %s; not scored", name, exc)
            rows.append({**row, "error": float("nan"), "seconds": 0.0})
            continue
        scored, gt = _transferred_labels(result.tracks.xy[result.trajectories.track_ids], seq, f, max_dist_px)
        k_true, error = _score(result.clustering.labels[scored], gt)
        row.update(
            num_tracks=result.trajectories.num_points,
            num_scored=int(scored.sum()),
            k_true=k_true,
            k_true_5=motions_seen(gt),
            k_pred=result.clustering.k,
            error=error,
            seconds=seconds,
        )
        if baselines is not None:
            row.update(same_point_scores(result.trajectories.data, result.embeddings, scored, gt, cfg, baselines))
        rows.append(row)
        log.info("%s: %d/%d tracks scored, error %.4f", name, scored.sum(), scored.size, error)
    return rows


def _transferred_labels(
    xy: npt.NDArray[np.float32], seq: Any, f: int, max_dist_px: float
) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.int64]]:
    """(which of the tracks `xy` (N, F, 2) are scored, the ground-truth label of each scored one): a track
    takes the label of the nearest ground-truth point within max_dist_px in frame 1, unless the two
    part ways by frame F."""
    in_first = np.flatnonzero(seq.visible[:, 0])
    idx = nearest_within(xy[:, 0], seq.xy[in_first, 0], max_dist_px)
    matched = idx >= 0
    gt_rows = np.where(matched, in_first[np.maximum(idx, 0)], -1)
    # Drop pairs that part ways by frame F: the two points followed different surfaces.
    last = f - 1
    seen_last = matched & seq.visible[np.maximum(gt_rows, 0), last]
    apart = np.linalg.norm(xy[:, last] - seq.xy[np.maximum(gt_rows, 0), last], axis=1) > 2 * max_dist_px
    scored = matched & ~(seen_last & apart)
    return scored, seq.labels[gt_rows[scored]]


def adelaide_pair_rows(
    data_root: str | Path,
    model: SubspaceNet | None,
    cfg: PipelineConfig = PipelineConfig(frames=2),
    max_dist_px: float = ADELAIDE_MAX_DIST_PX,
    names: Sequence[str] | None = None,
    warmup: bool = True,
    baselines: Sequence[str] | None = None,
) -> list[dict[str, Any]]:
    """The full pair pipeline (SIFT matching included) on every AdelaideRMF pair.

    Args:
        data_root: the data folder holding ``adelaidermf/``.
        model: the two-frame model (None = the shipped default).
        cfg: pipeline settings for `segment_pair`.
        max_dist_px: label-transfer radius, pixels, checked in both images.
        names: only these pairs (None = all 19).
        warmup: run the first pair once untimed.
        baselines: also score SubspaceNet and these baselines with the true K (outliers one group,
            no outlier cluster) on the same matches; None = neither.

    Returns:
        One row per pair: name, num_matches (our SIFT matches), num_scored (matches with a
        ground-truth correspondence within max_dist_px in both images), k_true (ground-truth groups
        among the scored matches, gross outliers counting as one), k_pred (our clusters, the
        outlier cluster included), error (misclassification over the scored matches with our
        outliers as one more group; NaN when none is scored), seconds (segment_pair).

    Raises:
        DatasetError: the AdelaideRMF folder is missing or malformed.
    """
    from mosegpipe.data.adelaidermf import list_adelaide, read_adelaide_pair

    rows = []
    for n, name in enumerate(names if names is not None else list_adelaide(data_root)):
        pair = read_adelaide_pair(data_root, name)
        row: dict[str, Any] = {"name": name, "num_matches": 0, "num_scored": 0, "k_true": 0, "k_pred": 0}
        try:
            if warmup and n == 0:
                segment_pair(pair.img1, pair.img2, cfg, model)
            t0 = time.perf_counter()
            result = segment_pair(pair.img1, pair.img2, cfg, model)
            seconds = time.perf_counter() - t0
        except MosegError as exc:
            log.warning("%s: %s; not scored", name, exc)
            rows.append({**row, "error": float("nan"), "seconds": 0.0})
            continue
        m = result.matches
        idx = nearest_within(m.xy1, pair.xy1, max_dist_px)
        gt_i = np.maximum(idx, 0)
        agree2 = np.linalg.norm(m.xy2 - pair.xy2[gt_i], axis=1) <= max_dist_px
        scored = (idx >= 0) & agree2
        pred = _with_outlier_group(result.labels)
        gt = pair.labels[gt_i[scored]]
        k_true, error = _score(pred[scored], gt)
        row.update(
            num_matches=m.num_matches,
            num_scored=int(scored.sum()),
            k_true=k_true,
            k_pred=result.clustering.k,
            error=error,
            seconds=seconds,
        )
        if baselines is not None:
            traj = trajectories_from_matches(m).data
            row.update(same_point_scores(traj, result.embeddings, scored, gt, cfg, baselines))
        rows.append(row)
    return rows


def rendered_config(seed: int, size_hw: tuple[int, int] = (480, 640), frames: int = 5) -> Any:
    """The RenderConfig of seed `seed` in `rendered_rows`: 1-3 objects and the camera motions in turn.

    Returns:
        mosegpipe.synth.render.RenderConfig with num_objects 1 + seed % 3 and camera motion
        CAMERA_MOTIONS[seed % 4] (static, pan, forward, handheld), so ten seeds cover all twelve
        pairs but two.
    """
    from mosegpipe.synth.render import CAMERA_MOTIONS, RenderConfig

    return RenderConfig(
        size_hw=size_hw,
        frames=frames,
        num_objects=1 + seed % 3,
        seed=seed,
        camera_motion=CAMERA_MOTIONS[seed % len(CAMERA_MOTIONS)],
    )


def rendered_rows(
    model: SubspaceNet | None,
    cfg: PipelineConfig = PipelineConfig(),
    seeds: Iterable[int] = range(10),
    size_hw: tuple[int, int] = (480, 640),
    frames: int = 5,
    tolerance: float = BOUNDARY_TOLERANCE,
    warmup: bool = True,
    oracle: bool = True,
) -> list[dict[str, Any]]:
    """The full clip pipeline on rendered clips, scored on dense masks and on tracks.

    Args:
        model: the F-frame model (None = the shipped default).
        cfg: pipeline settings (its `frames` is replaced by `frames`).
        seeds: one clip per seed, see `rendered_config`.
        size_hw: (H, W) of the rendered frames, pixels.
        frames: F, frames per clip.
        tolerance: boundary tolerance of F, see `boundary_f`.
        warmup: segment the first clip once untimed.
        oracle: also score masks made from the ground-truth labels of the same tracks.

    Returns:
        One row per seed: seed, camera, num_tracks, k_true (ground-truth groups, background
        included, under the segmented tracks in frame 1), k_pred, track_error (misclassification
        of the tracks against the mask value under each in frame 1), J and F (`mask_scores` of the
        pipeline's masks, objects only, background matched but not averaged), with `oracle`
        J_oracle and F_oracle (the ground-truth track labels densified by the same mask stage:
        what perfect clustering would reach), seconds (segment_frames; rendering and scoring
        excluded). Scores are NaN when too few tracks survive.
    """
    from mosegpipe.synth.render import render_clip

    cfg = replace(cfg, frames=frames)
    rows = []
    for n, seed in enumerate(seeds):
        rcfg = rendered_config(seed, size_hw, frames)
        clip = render_clip(rcfg)
        row: dict[str, Any] = {"seed": seed, "camera": rcfg.camera_motion, "num_tracks": 0, "k_true": 0, "k_pred": 0}
        try:
            if warmup and n == 0:
                segment_frames(clip.to_frames(), cfg, model)
            t0 = time.perf_counter()
            result = segment_frames(clip.to_frames(), cfg, model)
            seconds = time.perf_counter() - t0
        except MosegError as exc:
            log.warning("seed %d: %s; not scored", seed, exc)
            nan = float("nan")
            row.update(track_error=nan, J=nan, F=nan)
            if oracle:
                row.update(J_oracle=nan, F_oracle=nan)
            rows.append({**row, "seconds": 0.0})
            continue
        ids = result.trajectories.track_ids
        gt_tracks = clip.label_at(0, result.tracks.xy[ids, 0])
        k_true, track_error = _score(result.clustering.labels, gt_tracks)
        scores = mask_scores(result.masks, clip.masks, background=0, unknown=UNKNOWN, tolerance=tolerance)
        row.update(
            num_tracks=int(ids.size),
            k_true=k_true,
            k_pred=result.clustering.k,
            track_error=track_error,
            J=scores.j,
            F=scores.f,
        )
        if oracle:
            # The ground-truth track labels through the same densification: the best J / F that
            # these tracks and mask settings allow.
            best = clip_masks(clip.frames, result.tracks, ids, gt_tracks, cfg)
            best_scores = mask_scores(best, clip.masks, background=0, unknown=UNKNOWN, tolerance=tolerance)
            row.update(J_oracle=best_scores.j, F_oracle=best_scores.f)
        rows.append({**row, "seconds": seconds})
    return rows


def long_rendered_clip(seed: int, size_hw: tuple[int, int] = (480, 640), frames: int = 120, cut: bool = True) -> Any:
    """A long rendered clip with objects entering and leaving and (with `cut`) one camera cut half-way.

    The two shots are independent renders (seeds `seed` and `seed + 1001`): after the cut the wall,
    the camera and the objects are new. The background is group 0 in both shots (one motion: the
    camera's); the second shot's objects get ids after the first shot's, so an identity carried
    across the cut is an error, as on real footage of other objects.

    Returns:
        mosegpipe.synth.render.RenderedClip of `frames` frames.
    """
    from mosegpipe.synth.render import CAMERA_MOTIONS, RenderConfig, RenderedClip, render_clip

    def shot(s: int, n: int) -> RenderedClip:
        return render_clip(
            RenderConfig(
                size_hw=size_hw,
                frames=n,
                num_objects=1 + s % 3,
                seed=s,
                camera_motion=CAMERA_MOTIONS[s % len(CAMERA_MOTIONS)],
                object_speed_px=(2.0, 6.0),  # fast enough to enter or leave within a shot
            )
        )

    if not cut:
        return shot(seed, frames)
    a, b = shot(seed, frames // 2), shot(seed + 1001, frames - frames // 2)
    b_masks = np.where(b.masks > 0, b.masks + len(a.object_ids), 0).astype(np.uint8)
    return RenderedClip(
        frames=np.concatenate([a.frames, b.frames]),
        masks=np.concatenate([a.masks, b_masks]),
        object_ids=a.object_ids + tuple(i + len(a.object_ids) for i in b.object_ids),
        camera_motion=f"{a.camera_motion}|{b.camera_motion}",
        intrinsics=a.intrinsics,
    )


def labels_per_object(
    pred_masks: npt.ArrayLike, gt_masks: npt.ArrayLike, min_px: int = 200, ignore: int | None = None
) -> dict[int, int]:
    """How many different predicted labels each ground-truth object was given over a video.

    A label counts for an object when it is the most frequent known label on the object's pixels in
    at least one frame where the object shows `min_px` pixels or more; 1 = one identity throughout.

    Args:
        pred_masks: (T, H, W) predicted labels, 255 = unknown.
        gt_masks: (T, H, W) ground-truth ids, 0 = background (not counted).
        min_px: frames where the object is smaller than this are skipped.
        ignore: a label not counted (e.g. 0, the dominant motion: then frames where an object was
            not told from the background do not count as a switch; only switches between motions do).

    Returns:
        {object id: number of labels} for every object visible with min_px pixels in some frame.
    """
    p, g = np.asarray(pred_masks), np.asarray(gt_masks)
    seen: dict[int, set[int]] = {}
    for t in range(g.shape[0]):
        ids, counts = np.unique(g[t], return_counts=True)
        for gid, n in zip(ids, counts):
            if gid == 0 or n < min_px:
                continue
            vals = p[t][(g[t] == gid) & (p[t] != 255)]
            if vals.size:
                seen.setdefault(int(gid), set()).add(int(np.bincount(vals).argmax()))
    return {gid: len(labs - {ignore}) for gid, labs in seen.items()}


def long_rendered_rows(
    model: SubspaceNet | None,
    cfg: PipelineConfig = PipelineConfig(),
    seeds: Iterable[int] = range(4),
    size_hw: tuple[int, int] = (480, 640),
    frames: int = 120,
    tolerance: float = BOUNDARY_TOLERANCE,
) -> list[dict[str, Any]]:
    """Whole-video mode on long rendered clips with a camera cut, scored with video-level J and F.

    Video-level means one assignment of predicted labels to ground-truth objects for the whole
    video (`mask_scores` over all T frames at once, as the DAVIS video metrics do): an object whose
    label switches part-way scores only the frames with the label it kept most.

    Args:
        model: the cfg.frames-frame model (None = the shipped default).
        cfg: pipeline settings; cfg.frames is the window length.
        seeds: one clip per seed, see `long_rendered_clip`.
        size_hw: (H, W) of the frames, pixels.
        frames: T, frames per clip.
        tolerance: boundary tolerance of F, see `boundary_f`.

    Returns:
        One row per seed: seed, camera (both shots), objects (ground-truth objects visible),
        num_motions (labels handed out), J and F (video level, objects only), labels_per_object
        (mean over objects of `labels_per_object`), max_labels_per_object, moving_labels_per_object
        (the same without label 0: identity switches between motions only, not frames where an
        object was taken for the background), j_object (J per object with one moving label per object for
        the whole video, DAVIS-2017's matching: `identities.object_j`), j_object_frame (the same matched
        frame by frame), switches_per_object (`identities.identity_switches`, moving labels), seconds and fps
        (segment_video with its masks; rendering and scoring excluded).
    """
    import tempfile

    from mosegpipe.pipeline import segment_video

    rows = []
    for seed in seeds:
        clip = long_rendered_clip(seed, size_hw, frames)
        with tempfile.TemporaryDirectory(prefix="moseg_long_") as tmp:
            for t, image in enumerate(clip.frames):
                cv2.imwrite(f"{tmp}/{t:06d}.png", cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
            pred = np.full(clip.masks.shape, 255, dtype=np.uint8)
            t0 = time.perf_counter()
            num_motions = 0
            try:
                for window in segment_video(tmp, cfg, model):
                    num_motions = window.num_motions
                    for fr in window.frames:
                        assert fr.mask is not None
                        pred[fr.index] = fr.mask
            except MosegError as exc:
                log.warning("seed %d: %s; not scored", seed, exc)
            seconds = time.perf_counter() - t0
        scores = mask_scores(pred, clip.masks, background=0, unknown=255, tolerance=tolerance)
        per = labels_per_object(pred, clip.masks)
        moving = labels_per_object(pred, clip.masks, ignore=0)
        shown = sorted(per)  # the objects visible with 200 px or more in some frame
        j_video = object_j(pred, clip.masks, shown, per_video=True)
        j_frame = object_j(pred, clip.masks, shown, per_video=False)
        switches = identity_switches(pred, clip.masks, shown, min_px=200)
        rows.append(
            {
                "seed": seed,
                "camera": clip.camera_motion,
                "objects": len(per),
                "num_motions": num_motions,
                "J": scores.j,
                "F": scores.f,
                "labels_per_object": float(np.mean(list(per.values()))) if per else float("nan"),
                "max_labels_per_object": max(per.values(), default=0),
                "moving_labels_per_object": float(np.mean(list(moving.values()))) if moving else float("nan"),
                "j_object": float(np.mean(list(j_video.values()))) if j_video else float("nan"),
                "j_object_frame": float(np.mean(list(j_frame.values()))) if j_frame else float("nan"),
                "switches_per_object": float(np.mean(list(switches.values()))) if switches else float("nan"),
                "seconds": seconds,
                "fps": frames / seconds if seconds > 0 else 0.0,
            }
        )
    return rows
