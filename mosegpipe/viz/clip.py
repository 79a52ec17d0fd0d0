"""A clip's recording (write_recording): frames on the "frame" timeline, tracks, masks, embedding, K scores."""

from __future__ import annotations

import os
import time
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from mosegpipe.errors import InputError
from mosegpipe.io.read import atomic_write
from mosegpipe.types import Frames, Tracks
from mosegpipe.viz.blocks import (
    Sink,
    log_annotation_contexts,
    log_embedding_and_scores,
    log_image_layers,
    log_legend,
    log_trails,
    log_written,
    side_column,
    view_panels,
)
from mosegpipe.viz.common import (
    MAIN_SHARES,
    MAX_CLASSES,
    TIMELINE,
    VizConfig,
    class_ids_of,
    class_names,
    legend_markdown,
)

if TYPE_CHECKING:
    import rerun.blueprint as rrb


def _validate_clip(
    frames: Frames,
    tracks: Tracks,
    track_ids: npt.NDArray[np.int64],
    labels: npt.NDArray[np.int64],
    embeddings: npt.NDArray[np.floating],
    masks: npt.NDArray[np.uint8] | None,
    k: int,
) -> None:
    num_frames = frames.num_frames
    if tracks.num_frames != num_frames or tracks.size_hw != frames.size_hw:
        raise InputError(
            f"tracks cover {tracks.num_frames} frames of {tracks.size_hw}, frames are {num_frames} of {frames.size_hw}"
        )
    if not len(track_ids) == len(labels) == len(embeddings):
        raise InputError(f"{len(track_ids)} track ids, {len(labels)} labels, {len(embeddings)} embeddings: must match")
    if len(track_ids) and (track_ids.min() < 0 or track_ids.max() >= tracks.num_tracks):
        raise InputError(f"track ids must be in 0..{tracks.num_tracks - 1}")
    if not 1 <= k <= MAX_CLASSES:
        raise InputError(f"k={k} must be in 1..{MAX_CLASSES}")
    if len(labels) and (labels.min() < 0 or labels.max() >= k):
        raise InputError(f"labels must be in 0..{k - 1} for k={k}, got {labels.min()}..{labels.max()}")
    if masks is not None and masks.shape != (num_frames, *frames.size_hw):
        raise InputError(f"masks have shape {masks.shape}, expected {(num_frames, *frames.size_hw)}")


def _clip_blueprint(k_scores: Mapping[int, float]) -> rrb.Blueprint:
    """The frame with its tracks and masks, beside the side column (summary, K chart, embedding)."""
    import rerun.blueprint as rrb

    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial2DView(origin="video", name="frame, tracks and masks"),
            side_column(k_scores),
            column_shares=MAIN_SHARES,
        ),
        *view_panels(timeline=True),
    )


def write_recording(
    path: str | os.PathLike[str],
    frames: Frames,
    tracks: Tracks,
    track_ids: npt.NDArray[np.int64],
    labels: npt.NDArray[np.int64],
    embeddings: npt.NDArray[np.floating],
    masks: npt.NDArray[np.uint8] | None,
    k_scores: dict[int, float],
    k: int,
    app_id: str = "mosegpipe",
    cfg: VizConfig = VizConfig(),
    k_note: str = "",
    k_method: str = "",
) -> Path:
    """Write a Rerun .rrd recording of one segmented clip, with a default blueprint, atomically.

    The recording streams to a temporary file next to `path`; the stream is flushed and closed
    (which writes the rrd footer) before the file is renamed, so `path` is always complete.

    Args:
        path: output .rrd file.
        frames: Frames, images (T, H, W, 3) uint8 RGB.
        tracks: Tracks over the same T frames.
        track_ids: (N,) int64 rows of `tracks` that were segmented (Trajectories.track_ids).
        labels: (N,) int64 cluster of each, in 0..k-1.
        embeddings: (N, E) float embedding of each (SubspaceNet output).
        masks: (T, H, W) uint8 dense masks (label, 255 unknown), or None.
        k_scores: criterion value per candidate K (may be empty when K was forced).
        k: number of clusters.
        app_id: Rerun application id (the viewer groups recordings and blueprints by it).
        cfg: display settings (max_side_px and video_frames are ignored: clips are logged at full
            size, as images).
        k_note, k_method: Clustering.note and .method; the summary says the K written and why
            (:func:`k_statement`, as summary.json's k_reason).

    Returns:
        The path written.

    Raises:
        InputError: inconsistent shapes or labels out of range.
    """
    started = time.perf_counter()
    track_ids = np.asarray(track_ids, dtype=np.int64).reshape(-1)
    labels = np.asarray(labels, dtype=np.int64).reshape(-1)
    embeddings = np.asarray(embeddings)
    _validate_clip(frames, tracks, track_ids, labels, embeddings, masks, k)
    class_ids = class_ids_of(labels)
    xy, visible = tracks.xy[track_ids], tracks.visible[track_ids]  # (N, T, 2), (N, T)
    blueprint = _clip_blueprint(k_scores)
    summary = f"{len(track_ids)} tracks, {frames.num_frames} frames of {frames.source or '(in memory)'}\n"

    final = Path(path)
    with atomic_write(final) as tmp:
        sink = Sink(tmp, app_id, final, blueprint)
        rec, written = sink.rec, False
        try:
            log_annotation_contexts(rec, ["video"] if masks is not None else [], class_names(k))
            log_embedding_and_scores(rec, class_ids, embeddings, k_scores, k, summary, cfg, k_note, k_method)
            log_legend(rec, legend_markdown(labels, masks))
            for t in range(frames.num_frames):
                rec.set_time(TIMELINE, sequence=frames.start + t)
                seen = visible[:, t]
                mask = None if masks is None else masks[t]
                log_image_layers(rec, "video", frames.images[t], mask, xy[seen, t], class_ids[seen], cfg)
                first = 0 if cfg.trail_frames is None else max(0, t + 1 - cfg.trail_frames)
                history = visible[seen, first : t + 1]  # (M, L): each seen track's visible past
                log_trails(rec, xy[seen, first : t + 1][history], history.sum(axis=1), class_ids[seen], cfg)
            written = True
        finally:
            sink.finish(write=written)
    log_written(final, f"{frames.num_frames} frames, {len(track_ids)} tracks", started)
    return final
