"""An image pair's recording (write_pair_recording): static, image1/... and image2/...."""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import numpy.typing as npt

from mosegpipe.errors import InputError
from mosegpipe.io.read import atomic_write
from mosegpipe.types import Matches
from mosegpipe.viz.blocks import (
    Sink,
    log_annotation_contexts,
    log_embedding_and_scores,
    log_image_layers,
    log_legend,
    log_written,
    side_column,
    view_panels,
)
from mosegpipe.viz.common import MAIN_SHARES, MAX_CLASSES, VizConfig, class_ids_of, class_names, legend_markdown


def _validate_pair(
    images: Sequence[npt.NDArray[np.uint8]],
    matches: Matches,
    labels: npt.NDArray[np.int64],
    embeddings: npt.NDArray[np.floating],
    masks: Sequence[npt.NDArray[np.uint8]] | None,
    k: int,
) -> int:
    """The number of classes to name (max(k, labels.max() + 1)); InputError on inconsistent inputs."""
    if len(images) != 2 or (masks is not None and len(masks) != 2):
        raise InputError(
            f"a pair needs 2 images and 2 masks, got {len(images)} and {None if masks is None else len(masks)}"
        )
    if not matches.num_matches == len(labels) == len(embeddings):
        raise InputError(
            f"{matches.num_matches} matches, {len(labels)} labels, {len(embeddings)} embeddings: must match"
        )
    sizes = (matches.size1_hw, matches.size2_hw)
    for i in range(2):
        if images[i].shape[:2] != sizes[i] or (masks is not None and masks[i].shape != sizes[i]):
            raise InputError(f"image {i + 1} / mask {i + 1} sizes do not match the matches' {sizes[i]}")
    num_classes = max(k, int(labels.max()) + 1 if len(labels) else 0)
    if not 1 <= num_classes <= MAX_CLASSES or (len(labels) and labels.min() < -1):
        raise InputError(f"labels must be in -1..{MAX_CLASSES - 1} and k in 1..{MAX_CLASSES}; got k={k}")
    return num_classes


def write_pair_recording(
    path: str | os.PathLike[str],
    images: Sequence[npt.NDArray[np.uint8]],
    matches: Matches,
    labels: npt.NDArray[np.int64],
    embeddings: npt.NDArray[np.floating],
    masks: Sequence[npt.NDArray[np.uint8]] | None,
    k_scores: dict[int, float],
    k: int,
    app_id: str = "mosegpipe",
    cfg: VizConfig = VizConfig(),
    k_note: str = "",
    k_method: str = "",
) -> Path:
    """Write a Rerun .rrd recording of a segmented image pair (static, no timeline), atomically.

    Args:
        path: output .rrd file.
        images: the two (H_i, W_i, 3) uint8 RGB images (sizes may differ).
        matches: Matches between them (N correspondences).
        labels: (N,) int64 motion of each match, -1 for an outlier (shown as class 255).
        embeddings: (N, E) float embedding of each match.
        masks: the two (H_i, W_i) uint8 masks (label, 255 unknown / outlier), or None.
        k_scores: criterion value per candidate K (may be empty).
        k: number of clusters; classes up to max(k, labels.max() + 1) are named.
        app_id: Rerun application id.
        cfg: display settings.
        k_note, k_method: Clustering.note and .method (see write_recording).

    Returns:
        The path written.

    Raises:
        InputError: inconsistent shapes or labels out of range.
    """
    import rerun.blueprint as rrb

    started = time.perf_counter()
    labels = np.asarray(labels, dtype=np.int64).reshape(-1)
    embeddings = np.asarray(embeddings)
    num_classes = _validate_pair(images, matches, labels, embeddings, masks, k)
    class_ids = class_ids_of(labels)
    blueprint = rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Spatial2DView(origin="image1", name="image 1"),
                rrb.Spatial2DView(origin="image2", name="image 2"),
            ),
            side_column(k_scores),
            column_shares=MAIN_SHARES,
        ),
        *view_panels(timeline=False),  # no timeline to scrub
    )
    outliers = int((labels < 0).sum())
    summary = f"{matches.num_matches} matches ({outliers} outliers)\n"

    final = Path(path)
    with atomic_write(final) as tmp:
        sink = Sink(tmp, app_id, final, blueprint)
        rec, written = sink.rec, False
        try:
            names = class_names(num_classes, unknown="unknown / outlier")
            log_annotation_contexts(rec, ["image1", "image2"] if masks is not None else [], names)
            log_embedding_and_scores(rec, class_ids, embeddings, k_scores, k, summary, cfg, k_note, k_method)
            log_legend(rec, legend_markdown(labels, masks, unknown="unknown / outlier"))
            for i, xy in enumerate((matches.xy1, matches.xy2)):
                mask = None if masks is None else masks[i]
                log_image_layers(rec, f"image{i + 1}", images[i], mask, xy, class_ids, cfg, static=True)
            written = True
        finally:
            sink.finish(write=written)
    log_written(final, f"pair, {matches.num_matches} matches", started)
    return final
