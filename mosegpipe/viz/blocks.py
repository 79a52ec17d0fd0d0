"""Building blocks of the recordings: the blueprint's panels, annotation contexts, image layers,
trails, the K chart and embedding, and the in-memory sink each file is written from."""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe.errors import InputError
from mosegpipe.viz.common import (
    CHOSEN_COLOR,
    EMBEDDING_BOX,
    EYE_POSITION,
    OTHER_COLOR,
    SIDE_SHARES,
    VizConfig,
    embedding_to_3d,
    fit_in_box,
    k_chart,
    mask_colors,
    point_colors,
    split_note,
    summary_head,
)

if TYPE_CHECKING:
    # rerun is imported where it is used: it takes ~0.6 s, which `import mosegpipe` should not pay.
    import rerun as rr
    import rerun.blueprint as rrb

logger = logging.getLogger("mosegpipe.viz")


def view_panels(timeline: bool) -> list[Any]:
    """The viewer's blueprint and selection panels folded (open, they took a third of the width);
    the time panel open where there is a timeline to scrub."""
    import rerun.blueprint as rrb

    return [
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(state="expanded" if timeline else "collapsed"),
    ]


def side_column(k_scores: Mapping[int, float]) -> rrb.Vertical:
    """Summary, legend, K chart (when there are scores) and embedding, stacked."""
    import rerun.blueprint as rrb

    views: list[rrb.View] = [
        rrb.TextDocumentView(origin="summary", name="summary"),
        rrb.TextDocumentView(origin="legend", name="legend"),
    ]
    shares = [SIDE_SHARES["summary"], SIDE_SHARES["legend"]]
    if k_scores:
        chart = k_chart(k_scores)
        bounds = rrb.VisualBounds2D(x_range=chart.x_range, y_range=chart.y_range)
        views.append(rrb.Spatial2DView(origin="k_scores", name="score per K", visual_bounds=bounds))
        shares.append(SIDE_SHARES["k_scores"])
    eye = rrb.EyeControls3D(position=EYE_POSITION, look_target=(0.0, 0.0, 0.0), eye_up=(0.0, 0.0, 1.0))
    views.append(rrb.Spatial3DView(origin="embedding", name="embedding", eye_controls=eye))
    shares.append(SIDE_SHARES["embedding"])
    return rrb.Vertical(*views, row_shares=shares)


def _annotation_context(names: Mapping[int, str], colors: npt.NDArray[np.uint8]) -> rr.AnnotationContext:
    """The class names and colours (RGBA per class id), built as an Arrow array of Rerun's own type.

    From ClassDescription objects Rerun casts the array, which imports pyarrow.compute: ~0.1 s of
    a recording's first-use cost (benchmarks/output_size.py --startup).
    """
    import pyarrow as pa
    import rerun as rr

    rows = []
    for i, name in names.items():
        r, g, b, a = (int(c) for c in colors[i])
        info = {"id": i, "label": name, "color": (r << 24) | (g << 16) | (b << 8) | a}  # RGBA, packed
        rows.append(
            {"class_id": i, "class_description": {"info": info, "keypoint_annotations": [], "keypoint_connections": []}}
        )
    return rr.AnnotationContext(pa.array([rows], type=rr.components.AnnotationContext.arrow_type()))


def log_annotation_contexts(rec: rr.RecordingStream, origins: Sequence[str], names: Mapping[int, str]) -> None:
    """Once, static, before any data: the point colours at the root, the mask colours at each `origin/mask`.

    Re-logging a static context as classes appeared left whole-video recordings in Rerun's own
    colours (the background red, moving tracks blue): a context is logged once, with every class.
    """
    rec.log("/", _annotation_context(names, point_colors()), static=True)
    masks = _annotation_context(names, mask_colors())
    for origin in origins:
        rec.log(f"{origin}/mask", masks, static=True)


def _image_archetype(image: npt.NDArray[np.uint8], cfg: VizConfig) -> rr.Image | rr.EncodedImage:
    import rerun as rr

    if cfg.jpeg_quality == 0:
        return rr.Image(image, draw_order=0.0)
    bgr = cv2.cvtColor(image, cv2.COLOR_RGB2BGR) if image.ndim == 3 else image
    ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, cfg.jpeg_quality])
    if not ok:
        raise InputError(f"JPEG encoding of a {image.shape} frame failed")
    return rr.EncodedImage(contents=buf.tobytes(), media_type="image/jpeg", draw_order=0.0)


def log_image_layers(
    rec: rr.RecordingStream,
    origin: str,
    image: npt.NDArray[np.uint8] | None,
    mask: npt.NDArray[np.uint8] | None,
    xy: npt.NDArray[np.float32],
    class_ids: npt.NDArray[np.uint16],
    cfg: VizConfig,
    static: bool = False,
) -> None:
    """Image (unless None: a video asset holds it), segmentation and points under `origin`."""
    import rerun as rr

    if image is not None:
        rec.log(f"{origin}/frame", _image_archetype(image, cfg), static=static)
    if mask is not None:
        rec.log(f"{origin}/mask", rr.SegmentationImage(mask, opacity=cfg.mask_opacity, draw_order=1.0), static=static)
    points = rr.Points2D(xy, class_ids=class_ids, radii=cfg.point_radius_px, draw_order=3.0)
    rec.log(f"{origin}/points", points, static=static)


def _line_strips(points: npt.NDArray[np.float32], lengths: npt.NDArray[np.int64]) -> Any:
    """Strips as an Arrow array of Rerun's LineStrip2D type, built from flat points and lengths.

    Rerun's own conversion walks the strips one by one in Python: for ~500 trails a frame that was
    most of a clip recording's logging time (benchmarks/output_size.py --startup).

    Args:
        points: (P, 2) float32, the strips' points one strip after the other.
        lengths: (M,) points per strip (sums to P).
    """
    import pyarrow as pa
    import rerun as rr

    strip_type = rr.components.LineStrip2D.arrow_type()
    offsets = np.zeros(len(lengths) + 1, dtype=np.int32)
    np.cumsum(lengths, out=offsets[1:])
    flat = pa.array(np.ascontiguousarray(points, dtype=np.float32).reshape(-1), type=pa.float32())
    values = pa.FixedSizeListArray.from_arrays(flat, type=strip_type.value_type)
    return pa.ListArray.from_arrays(pa.array(offsets, type=pa.int32()), values, type=strip_type)


def log_trails(
    rec: rr.RecordingStream,
    points: npt.NDArray[np.float32],
    lengths: npt.NDArray[np.int64],
    class_ids: npt.NDArray[np.uint16],
    cfg: VizConfig,
) -> None:
    """Track histories as line strips: `points` (P, 2) holds the M trails one after the other,
    `lengths` (M,) their numbers of points; trails of fewer than 2 points are left out."""
    import rerun as rr

    lengths = np.asarray(lengths, dtype=np.int64)
    keep = lengths >= 2
    if keep.any():
        points = points[np.repeat(keep, lengths)]
        lines = rr.LineStrips2D(
            _line_strips(points, lengths[keep]), class_ids=class_ids[keep], radii=cfg.line_radius_px, draw_order=2.0
        )
        rec.log("video/tracks", lines)
    else:
        # Nothing to draw (first frame): clear so that no older history shows through.
        rec.log("video/tracks", rr.Clear(recursive=False))


def _log_k_chart(rec: rr.RecordingStream, k_scores: Mapping[int, float], k: int) -> None:
    """The stem chart of k_chart(): stems and zero line, a point per K, the score labels, the K labels."""
    import rerun as rr

    chart = k_chart(k_scores)
    x_lo, x_hi = float(chart.ks.min()) - 0.5, float(chart.ks.max()) + 0.5
    strips = [[(x_lo, 0.0), (x_hi, 0.0)]] + [[(float(x), 0.0), (float(x), float(y))] for x, y in chart.tips]
    rec.log("k_scores/stems", rr.LineStrips2D(strips, colors=OTHER_COLOR, radii=rr.Radius.ui_points(1.0)), static=True)
    colors = [CHOSEN_COLOR if c == k else OTHER_COLOR for c in chart.ks]
    radii = rr.Radius.ui_points([6.0 if c == k else 4.0 for c in chart.ks])
    rec.log("k_scores/scores", rr.Points2D(chart.tips, colors=colors, radii=radii), static=True)
    # The labels hang from points of their own (a tip's own label would lie on its stem); their
    # 0.5-point dots hide under the labels' boxes.
    k_xy = np.stack([chart.ks, np.full(len(chart.ks), chart.label_y)], axis=1).astype(np.float32)
    for entity, xy, texts in (
        ("k_scores/values", chart.value_xy, chart.value_labels),
        ("k_scores/k", k_xy, [f"K={c}" for c in chart.ks]),
    ):
        points = rr.Points2D(xy, colors=colors, radii=rr.Radius.ui_points(0.5), labels=texts, show_labels=True)
        rec.log(entity, points, static=True)


def log_legend(rec: rr.RecordingStream, legend: str, static: bool = True) -> None:
    """The legend (viz.legend_markdown: value, colour, name and tracks per motion) as the markdown document
    `legend` (static, or at the stream's current time)."""
    import rerun as rr

    rec.log("legend", rr.TextDocument(legend, media_type="text/markdown"), static=static)


def log_embedding_and_scores(
    rec: rr.RecordingStream,
    class_ids: npt.NDArray[np.uint16],
    embeddings: npt.NDArray[np.floating],
    k_scores: Mapping[int, float],
    k: int,
    summary: str,
    cfg: VizConfig,
    k_note: str = "",
    k_method: str = "",
) -> None:
    """Embedding (in its cube), K chart and a markdown summary: static rows. The chart marks the K
    that automatic K chose (k less the groups the rigid-motion check split off, read from k_note)."""
    import rerun as rr

    points = rr.Points3D(fit_in_box(embedding_to_3d(embeddings)), class_ids=class_ids, radii=cfg.embedding_radius)
    rec.log("embedding", points, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)  # +Z up, as the eye
    box = rr.Boxes3D(half_sizes=[(EMBEDDING_BOX,) * 3], colors=OTHER_COLOR, radii=rr.Radius.ui_points(0.5))
    rec.log("embedding/box", box, static=True)
    if k_scores:
        _log_k_chart(rec, k_scores, k - split_note(k_note)[0])
        summary += "\nscore per K: " + ", ".join(f"{c}: {k_scores[c]:.3g}" for c in sorted(k_scores)) + "\n"
    head = summary_head(k, k_scores, k_note, k_method)
    rec.log("summary", rr.TextDocument(head + summary, media_type="text/markdown"), static=True)


class Sink:
    """A recording stream into memory, written to its file by Python when finished.

    Rerun's own file sink writes on a thread of its own: when the disk fills up, that thread dies
    and the next flush waits forever (dropping the stream too), Ctrl-C cannot stop it, and Rerun
    prints its own error lines. Here the stream goes to a memory buffer and Python writes the bytes,
    so a full disk is an ordinary OSError (ENOSPC) raised in the caller's thread. The price is that
    the recording is held in memory until it is written (a 5-frame clip: about 0.5 MB; a whole
    video at 768x576: about 0.11 MB per frame with H.264 frames, most of it track trails, 0.19 MB
    with JPEG frames; benchmarks/output_size.py). Draining the buffer in pieces does not give a
    readable .rrd (one footer per drain), so it is drained once.
    """

    def __init__(self, tmp: Path, app_id: str, final: Path, blueprint: rrb.Blueprint | None = None) -> None:
        import rerun as rr

        self.tmp = tmp
        self.final = final
        self.rec = rr.RecordingStream(app_id)
        self._memory = self.rec.memory_recording()
        if blueprint is not None:
            self.send_blueprint(blueprint)

    def send_blueprint(self, blueprint: rrb.Blueprint) -> None:
        """The recording's layout, as its default and the active one.

        Sent before any data: a viewer that gets data first builds a layout of its own and keeps
        it (a default that is not active only applies to a viewer that has none yet).
        """
        self.rec.send_blueprint(blueprint, make_active=True, make_default=True)
        # the layout's messages reach the sink before any data is logged: under load the batcher thread
        # could otherwise write the first data ahead of them
        self.rec.flush(timeout_sec=_FLUSH_TIMEOUT_S)

    def finish(self, write: bool = True) -> None:
        """Ends the stream; writes the recording to `tmp` when `write` (OSError when that fails)."""
        try:
            self.rec.flush(timeout_sec=_FLUSH_TIMEOUT_S)
            data = self._memory.drain_as_bytes()
        finally:
            self.rec.disconnect()
        if write:
            try:
                with open(self.tmp, "wb") as fh:
                    fh.write(data)
            except OSError as exc:  # a write error names no file: say which one
                raise OSError(exc.errno, exc.strerror or str(exc), str(self.final)) from exc


# Flushing a memory sink only encodes what was logged; it takes milliseconds per frame.
_FLUSH_TIMEOUT_S = 120.0


def log_written(final: Path, what: str, started: float) -> None:
    logger.info(
        "wrote %s (%s, %.1f kB) in %.2f s", final, what, final.stat().st_size / 1e3, time.perf_counter() - started
    )
