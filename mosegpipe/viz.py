"""Rerun recordings of a segmentation: frames, tracks, masks, the embedding and the K scores.

Every Rerun call of the project lives here. Each output file gets its own `rr.RecordingStream`
(never the global recording), so recordings can be written from several threads or in a batch
without mixing, and each is written atomically (temporary file, closed, then renamed).

Entity paths of a clip recording (:func:`write_recording`) and a video (:class:`VideoRecorder`):

- ``/``: AnnotationContext (static): a class per mask value, "the world (motion 0)", "motion i",
  254 "moving, no clustered motion" and 255 "unknown", in the colours of the overlays' track dots
  (:func:`point_colors`): the one colour table of mosegpipe.colours, the world's tracks white.
  Tracks, trails and embedding points take their colour from it.
- ``video/mask`` (``image1/mask``, ``image2/mask``): AnnotationContext (static), the same classes in
  the colours of the mask PNGs and the overlays (:func:`mask_colors`), the world transparent: the
  frame shows through untinted, as in the overlays; unknown the same grey as everywhere.
- ``video/frame``: the frame. Clips: an EncodedImage (JPEG; a raw Image when jpeg_quality is 0).
  Videos: a VideoFrameReference into ``video/asset``, the frames as one H.264 MP4 (AssetVideo,
  static); or JPEG images as for clips with VizConfig(video_frames="jpeg").
- ``video/mask``: SegmentationImage, values as in Segmentation.masks.
- ``video/tracks``: LineStrips2D, the recent history of each labelled track.
- ``video/points``: Points2D, the labelled tracks visible in the frame.
- ``embedding``: Points3D of the embedding (static; PCA to 3-D when E > 3, zero-padded when E < 3),
  centred and scaled into the cube [-1, 1]^3, drawn as ``embedding/box``.
- ``k_scores``: the score per candidate K as a stem chart (static, 2-D; geometry :func:`k_chart`):
  ``k_scores/k`` the K values ("K=2", ...) under the chart, ``k_scores/scores`` one point per K
  (the chosen K in a colour of its own), ``k_scores/values`` each score ("0.46") just beyond its
  point, away from its stem, ``k_scores/stems`` the stems and the zero line.
- ``summary``: TextDocument (static): the K written and why (:func:`k_statement`; summary.json's
  ``k_reason``), any other note on K, the counts.
- ``windows/k``, ``windows/k_margin`` (videos): Scalars at each window's first frame, the K chosen
  in the window (0 = left unlabelled) and how clearly its scores chose (`score_lead`: the best score
  minus the next best, >= 0; when the scores are given).

Time-varying entities use the sequence timeline "frame" (index of the frame in the source video).
Each file starts with its layout (a blueprint, sent as the default and active one, so that a viewer
opens with it rather than a layout of its own from the first data), then the annotation contexts,
logged once (a video names every class 0..254 up front: motions appear as it goes), then the data.
An image pair (:func:`write_pair_recording`) is static, with ``image1/...`` and ``image2/...``
in place of ``video/...`` and class 255 also standing for outlier matches.
"""

from __future__ import annotations

import io
import logging
import os
import re
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any, Literal

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe.colours import UNKNOWN_RGB, mask_rgba, point_palette, value_names
from mosegpipe.errors import InputError
from mosegpipe.io import H264Encoder, atomic_write
from mosegpipe.types import Frames, Matches, Tracks

if TYPE_CHECKING:
    # rerun is imported where it is used: it takes ~0.6 s, which `import mosegpipe` should not pay.
    import rerun as rr
    import rerun.blueprint as rrb

logger = logging.getLogger(__name__)

TIMELINE = "frame"
"""Name of the sequence timeline frames are logged on."""

MAX_CLASSES = 255
"""Most motions a recording can name: class ids are mask values (uint8: motion 0..254, 255 = unknown)."""

UNKNOWN_CLASS = 255
"""Class id of unknown mask pixels and of unlabelled / outlier points (label -1)."""

EMBEDDING_BOX = 1.0
"""Half-size of the cube the embedding is scaled into for display: every point lies in [-1, 1]^3."""

# The 3-D view looks at the cube's centre from this point, 5.24 half-sizes away: the cube's bounding
# sphere (radius sqrt(3)) fits any field of view of 39 degrees or more, whatever the panel's shape.
_EYE_POSITION = (3.0, -3.5, 2.5)

# Layout shares: the frame takes 3/4 of the width; the side column stacks summary, K chart and
# embedding. In a 1600x900 window that leaves the summary ~170 px, room for 8 lines; it has 3-5.
_MAIN_SHARES = [3.0, 1.0]
_SIDE_SHARES = {"summary": 1.0, "k_scores": 1.0, "embedding": 1.6}

_CHOSEN_COLOR = (255, 190, 0)
_OTHER_COLOR = (150, 150, 150)

UNLABELLED_POINT_COLOR = UNKNOWN_RGB
"""Colour of unlabelled / outlier points (class 255): the unknown grey of every output (colours.UNKNOWN_RGB)."""


def class_ids_of(labels: npt.NDArray[np.int64]) -> npt.NDArray[np.uint16]:
    """Class ids of point labels: the label itself, UNKNOWN_CLASS for -1 (unlabelled / outlier)."""
    labels = np.asarray(labels, dtype=np.int64)
    return np.where(labels < 0, UNKNOWN_CLASS, labels).astype(np.uint16)


@dataclass(frozen=True)
class VizConfig:
    """Settings of the Rerun recording.

    Attributes:
        jpeg_quality: frames are stored as JPEG of this quality (1-100), 0 = raw RGB. Measured on
            5 frames of vtest.avi at 640x480 with masks and ~440 tracks: 0.52 MB at 85 against
            4.3 MB raw, written in about the same time (40-90 ms).
        mask_opacity: opacity of the segmentation over the frame, 0..1.
        point_radius_px: radius of the track points, pixels (UI points would scale with zoom).
        line_radius_px: half-width of the track history lines, pixels.
        trail_frames: frames of history drawn per track (None = all since the first frame);
            long videos get cluttered otherwise.
        embedding_radius: radius of the embedding points, in units of the display cube
            (half-size EMBEDDING_BOX = 1).
        max_side_px: frames (and masks, points) larger than this on their longer side are
            downscaled before logging (None = never); keeps whole-video recordings small.
        video_frames: how a VideoRecorder stores the frames: "h264" one H.264 MP4 (AssetVideo, no
            B-frames) and a VideoFrameReference per frame, "jpeg" an image per frame as for clips
            (the whole recording of vtest.avi 1.8x larger: benchmarks/output_size.py). Clips
            always log images.
    """

    jpeg_quality: int = 85
    mask_opacity: float = 0.45
    point_radius_px: float = 2.5
    line_radius_px: float = 0.75
    trail_frames: int | None = None
    embedding_radius: float = 0.02
    max_side_px: int | None = None
    video_frames: Literal["h264", "jpeg"] = "h264"

    def __post_init__(self) -> None:
        if not 0 <= self.jpeg_quality <= 100:
            raise ValueError(f"jpeg_quality={self.jpeg_quality} must be in 0..100")
        if self.trail_frames is not None and self.trail_frames < 1:
            raise ValueError(f"trail_frames={self.trail_frames} must be >= 1 or None")
        if self.max_side_px is not None and self.max_side_px < 16:
            raise ValueError(f"max_side_px={self.max_side_px} must be >= 16 or None")
        if self.video_frames not in ("h264", "jpeg"):
            raise ValueError(f"video_frames={self.video_frames!r} must be 'h264' or 'jpeg'")


VIDEO_VIZ = VizConfig(trail_frames=10, max_side_px=960)
"""Defaults of :class:`VideoRecorder`: short trails, frames at most 960 px wide, H.264 frames."""


def mask_colors() -> npt.NDArray[np.uint8]:
    """RGBA colour per mask value as the viewer draws the masks: the colours of the mask PNGs.

    Returns:
        (256, 4) uint8: colours.mask_rgba(), the palette of the mask PNGs and the overlays' tint,
        opaque, except the world (0): fully transparent, so that the frame shows through untinted,
        as overlay_mask leaves it.
    """
    return mask_rgba()


def point_colors() -> npt.NDArray[np.uint8]:
    """RGBA colour per class id as the viewer draws track points, trails and embedding points.

    Returns:
        (256, 4) uint8, opaque: colours.point_palette(), the colour of the track dots in the overlays
        (masks.overlay_image): the mask colour of the label, the world's tracks white, class 255
        (unlabelled / outlier) the unknown grey.
    """
    return np.concatenate([point_palette(), np.full((256, 1), 255, np.uint8)], axis=1)


def class_names(k: int, unknown: str = "unknown") -> dict[int, str]:
    """Class id -> display name (colours.value_names): motions 0..k-1 (0 "the world (motion 0)"),
    254 "moving, no clustered motion", 255 `unknown`."""
    return value_names(k, unknown)


def embedding_to_3d(embeddings: npt.NDArray[np.floating]) -> npt.NDArray[np.float32]:
    """Project an embedding to 3-D for display.

    Args:
        embeddings: (N, E) float.

    Returns:
        (N, 3) float32: the embedding itself for E = 3, zero-padded for E < 3, else its
        projection on the 3 principal axes (centred).
    """
    emb = np.asarray(embeddings, dtype=np.float64)
    if emb.ndim != 2:
        raise InputError(f"embeddings must be (N, E), got shape {emb.shape}")
    num, dim = emb.shape
    if dim <= 3:
        out = np.zeros((num, 3))
        out[:, :dim] = emb
        return out.astype(np.float32)
    centred = emb - emb.mean(axis=0)
    # Right singular vectors are the principal axes; fewer than 3 points leave fewer axes.
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    proj = centred @ vt[:3].T
    out = np.zeros((num, 3))
    out[:, : proj.shape[1]] = proj
    return out.astype(np.float32)


def fit_in_box(points: npt.NDArray[np.floating], half_size: float = EMBEDDING_BOX) -> npt.NDArray[np.float32]:
    """Centre 3-D points on their bounding box and scale them uniformly into [-half_size, half_size]^3.

    The longest side of the bounding box spans the cube; shapes and relative distances are kept.
    Coincident points (or none) stay at the centre. Non-finite coordinates become 0.

    Args:
        points: (N, 3) float.
        half_size: half the side of the cube.

    Returns:
        (N, 3) float32, every coordinate in [-half_size, half_size].
    """
    pts = np.nan_to_num(np.asarray(points, dtype=np.float64).reshape(-1, 3), nan=0.0, posinf=0.0, neginf=0.0)
    if not len(pts):
        return pts.astype(np.float32)
    low, high = pts.min(axis=0), pts.max(axis=0)
    extent = float((high - low).max()) / 2
    centred = pts - (low + high) / 2
    scaled = centred * (half_size / extent) if extent > 0 else np.zeros_like(centred)
    return np.clip(scaled, -half_size, half_size).astype(np.float32)


def k_margin(k_scores: Mapping[int, float], k: int) -> tuple[float, int] | None:
    """The chosen K's score minus the best other candidate's, and that runner-up K.

    Non-finite scores take no part. Negative when `k` was forced and scored lower.

    Returns:
        (margin, runner-up K), or None when `k` has no finite score or no rival has one (K forced,
        K = 1 outright).
    """
    finite = {c: float(v) for c, v in k_scores.items() if np.isfinite(v)}
    others = [c for c in finite if c != k]
    if k not in finite or not others:
        return None
    runner_up = max(others, key=lambda c: (finite[c], -c))
    return finite[k] - finite[runner_up], runner_up


def score_lead(k_scores: Mapping[int, float]) -> float | None:
    """How clearly the scores pick a K: the best score minus the next best (>= 0; 0 = a tie), None
    with fewer than two finite scores. Unlike `k_margin` it never dips below 0 when the K kept is not
    the best-scoring one (the rigid-motion check split a motion off, or K was capped)."""
    finite = sorted((float(v) for v in k_scores.values() if np.isfinite(v)), reverse=True)
    return finite[0] - finite[1] if len(finite) >= 2 else None


CHART_PX_PER_UNIT = 40.0
"""Screen pixels per unit of the K chart that its layout is made for: in a 1600x900 window the side
panel is about 400 x 225 px, so 8 candidates (10 units wide, about 5.5 tall) get 40-45 px a unit.
More pixels a unit only shrink the text against the chart; fewer can make neighbouring labels touch."""

# The viewer draws a point's label centred under the point: text 5 px below it, in a background
# box 2 + 4 px wider on each side and 4 px taller above and below (Rerun's 2-D label painter).
# Its body font is 13-14 px: at most 8 px a digit or letter (a point 4, a minus 6), 17 px a line.
_LABEL_CHAR_PX = {".": 4.0, "-": 6.0}
_LABEL_WIDE_PX = 8.0
_LABEL_LINE_PX = 17.0
_LABEL_TOP_PX = 1.0  # 5 px offset - 4 px of box above the text
_LABEL_PAD_X_PX = 6.0
_LABEL_BOTTOM_PX = 5.0 + _LABEL_LINE_PX + 4.0
_LABEL_GAP_PX = 8.0  # between a label's box and its point (radius up to 6 px) or the stems


def label_box(
    anchor: tuple[float, float], text: str, px_per_unit: float = CHART_PX_PER_UNIT
) -> tuple[float, float, float, float]:
    """Where the viewer draws the label of a 2-D point at `anchor`: (x0, y0, x1, y1) in the view's units
    (y down), background box included, at `px_per_unit` screen pixels a unit."""
    width = sum(_LABEL_CHAR_PX.get(c, _LABEL_WIDE_PX) for c in text)
    half = (width / 2 + _LABEL_PAD_X_PX) / px_per_unit
    x, y = anchor
    return (x - half, y + _LABEL_TOP_PX / px_per_unit, x + half, y + _LABEL_BOTTOM_PX / px_per_unit)


def short_score(value: float) -> str:
    """A score as the K chart writes it: two decimals, no leading zero (".46", "-.23", "1.00", "0").

    Scores lie in [-1, 1]; 4 characters at most keep neighbouring labels apart. Larger values keep 3
    significant digits."""
    if not np.isfinite(value):
        return "n/a"
    if abs(value) >= 9.995:
        return f"{value:.3g}"
    text = f"{value:.2f}"
    if text in ("0.00", "-0.00"):
        return "0"
    return text.replace("0.", ".", 1) if text.lstrip("-").startswith("0.") else text


@dataclass(frozen=True)
class KChart:
    """Geometry of the K-score stem chart, in the 2-D view's coordinates (x right = K, y down).

    Attributes:
        ks: (C,) the candidate K values, increasing.
        scores: (C,) their scores (NaN shown as 0).
        tips: (C, 2) the end of each stem (K, -score scaled): larger scores sit higher.
        value_labels: (C,) each score as written on the chart (:func:`short_score`).
        value_xy: (C, 2) where each score's label hangs from (the viewer draws it under that point):
            above the tip for scores >= 0, below it for negative ones, so that no label lies on a
            stem or the zero line.
        label_y: y of the K labels, under every stem and score label.
        x_range, y_range: the bounds that frame the whole chart, labels included.
    """

    ks: npt.NDArray[np.int64]
    scores: npt.NDArray[np.float64]
    tips: npt.NDArray[np.float32]
    value_labels: list[str]
    value_xy: npt.NDArray[np.float32]
    label_y: float
    x_range: tuple[float, float]
    y_range: tuple[float, float]

    def label_boxes(
        self, px_per_unit: float = CHART_PX_PER_UNIT
    ) -> tuple[list[tuple[float, float, float, float]], list[tuple[float, float, float, float]]]:
        """The boxes of the score labels and of the K labels (:func:`label_box`) at `px_per_unit`."""
        values = [
            label_box((float(x), float(y)), text, px_per_unit) for (x, y), text in zip(self.value_xy, self.value_labels)
        ]
        k_labels = [label_box((float(c), self.label_y), f"K={c}", px_per_unit) for c in self.ks]
        return values, k_labels


def k_chart(k_scores: Mapping[int, float]) -> KChart:
    """Lay out the score per K as stems from a zero line, one per candidate (see KChart).

    The tallest stem is 0.45 x (candidates + 1) long, so the chart is about twice as wide as tall
    whatever the range of the scores. Each score is written beyond the end of its stem (above a
    positive one, below a negative one) with a gap, in the short form of :func:`short_score`,
    further out where it would touch its left neighbour's label, so that at CHART_PX_PER_UNIT or
    more no label touches another, a stem, the zero line or the K labels.
    """
    ks = np.array(sorted(k_scores), dtype=np.int64)
    scores = np.nan_to_num(np.array([k_scores[int(c)] for c in ks], dtype=np.float64), nan=0.0)
    top = float(np.abs(scores).max()) if len(scores) else 0.0
    height = 0.45 * (len(ks) + 1)
    y = -scores / top * height if top > 0 else np.zeros_like(scores)
    tips = np.stack([ks.astype(np.float64), y], axis=1).astype(np.float32)
    unit = 1.0 / CHART_PX_PER_UNIT
    gap, box = _LABEL_GAP_PX * unit, _LABEL_BOTTOM_PX * unit
    labels = [short_score(float(v)) for v in scores]
    # Hanging above the tip, a label's box ends `gap` over it; under a negative tip it starts `gap` below.
    value_y = np.where(scores >= 0, y - gap - box, y + gap)
    # A label as wide as a neighbour's half-way mark at about the same height moves on, away from its tip.
    placed: list[tuple[float, float, float, float]] = []
    for i, (c, text) in enumerate(zip(ks, labels)):
        away = -1.0 if scores[i] >= 0 else 1.0
        while True:
            mine = label_box((float(c), float(value_y[i])), text)
            hit = [b for b in placed if mine[0] < b[2] and b[0] < mine[2] and mine[1] < b[3] and b[1] < mine[3]]
            if not hit:
                break
            edge = min(b[1] for b in hit) - mine[3] if away < 0 else max(b[3] for b in hit) - mine[1]
            value_y[i] += edge + away * _LABEL_TOP_PX * unit
        placed.append(mine)
    value_xy = np.stack([ks.astype(np.float64), value_y], axis=1).astype(np.float32)
    bottoms = np.concatenate([[0.0], y, value_y[scores < 0] + box])
    label_y = float(bottoms.max()) + gap
    x_lo, x_hi = (float(ks.min()) - 1.0, float(ks.max()) + 1.0) if len(ks) else (-1.0, 1.0)
    y_lo = float(min(0.0, float(value_y.min()) if len(ks) else 0.0)) - gap
    y_hi = label_y + box + gap
    return KChart(ks, scores, tips, labels, value_xy, label_y, (x_lo, x_hi), (y_lo, y_hi))


# ---------------------------------------------------------------------------------------------
# Building blocks
# ---------------------------------------------------------------------------------------------


def _panels(timeline: bool) -> list[Any]:
    """The viewer's blueprint and selection panels folded (open, they took a third of the width);
    the time panel open where there is a timeline to scrub."""
    import rerun.blueprint as rrb

    return [
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(state="expanded" if timeline else "collapsed"),
    ]


def _side_column(k_scores: Mapping[int, float]) -> rrb.Vertical:
    """Summary, K chart (when there are scores) and embedding, stacked."""
    import rerun.blueprint as rrb

    views: list[rrb.View] = [rrb.TextDocumentView(origin="summary", name="summary")]
    shares = [_SIDE_SHARES["summary"]]
    if k_scores:
        chart = k_chart(k_scores)
        bounds = rrb.VisualBounds2D(x_range=chart.x_range, y_range=chart.y_range)
        views.append(rrb.Spatial2DView(origin="k_scores", name="score per K", visual_bounds=bounds))
        shares.append(_SIDE_SHARES["k_scores"])
    eye = rrb.EyeControls3D(position=_EYE_POSITION, look_target=(0.0, 0.0, 0.0), eye_up=(0.0, 0.0, 1.0))
    views.append(rrb.Spatial3DView(origin="embedding", name="embedding", eye_controls=eye))
    shares.append(_SIDE_SHARES["embedding"])
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
    rec.log("k_scores/stems", rr.LineStrips2D(strips, colors=_OTHER_COLOR, radii=rr.Radius.ui_points(1.0)), static=True)
    colors = [_CHOSEN_COLOR if c == k else _OTHER_COLOR for c in chart.ks]
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


_RIGID_SPLIT = re.compile(r"the rigid-motion check split off (\d+) groups? \(K = (\d+) -> (\d+)\)")


def _split_note(note: str) -> tuple[int, str]:
    """(groups the rigid-motion check split off, the rest of the note) from a Clustering.note, whose
    rigid part pipeline.check_rigid writes as "the rigid-motion check split off S group(s) (K = a -> b)"."""
    found = _RIGID_SPLIT.search(note)
    if found is None:
        return 0, note
    rest = (note[: found.start()] + note[found.end() :]).strip("; ")
    return int(found.group(1)), rest


def k_statement(k: int, k_scores: Mapping[int, float], note: str = "", method: str = "") -> str:
    """One line on the K that was written and why: summary.json's `k_reason` and the recording's summary.

    E.g. "K = 3 written: automatic K chose 2 (score 0.459, runner-up K = 3: 0.436), the rigid-motion
    check split off 1 group"; "K = 2 written: automatic K chose it (score 0.6, runner-up K = 1:
    0.05)"; "K = 4 written: given (--k)"; "K = 1 written, without a score per K (<the note>)".

    Args:
        k: the K written (Clustering.k).
        k_scores: automatic K's score per candidate (Clustering.scores).
        note: Clustering.note: how many groups the rigid-motion check split off is read from it.
        method: Clustering.method ("fixed": K was given).
    """
    head = f"K = {k} written"
    if method == "fixed":
        return f"{head}: given (--k)"
    split, rest = _split_note(note)
    chosen = k - split
    finite = {c: float(v) for c, v in k_scores.items() if np.isfinite(v)}
    if not finite:
        text = f"{head}, without a score per K" + (f" ({rest})" if rest else "")
    else:
        text = f"{head}: automatic K chose {chosen if split else 'it'}"
        if chosen in finite:
            margin = k_margin(finite, chosen)
            rival = f", runner-up K = {margin[1]}: {finite[margin[1]]:.3g}" if margin is not None else ""
            text += f" (score {finite[chosen]:.3g}{rival})"
    if split:
        text += f", the rigid-motion check split off {split} group{'s' if split > 1 else ''}"
    return text


def _summary_head(k: int, k_scores: Mapping[int, float], note: str, method: str) -> str:
    """First lines of a summary: the K written and why (k_statement), then any other note on K."""
    statement = k_statement(k, k_scores, note, method)
    rest = _split_note(note)[1]
    return f"**{statement}**\n\n" + (f"note: {rest}\n\n" if rest and rest not in statement else "")


def _log_embedding_and_scores(
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
    box = rr.Boxes3D(half_sizes=[(EMBEDDING_BOX,) * 3], colors=_OTHER_COLOR, radii=rr.Radius.ui_points(0.5))
    rec.log("embedding/box", box, static=True)
    if k_scores:
        _log_k_chart(rec, k_scores, k - _split_note(k_note)[0])
        summary += "\nscore per K: " + ", ".join(f"{c}: {k_scores[c]:.3g}" for c in sorted(k_scores)) + "\n"
    head = _summary_head(k, k_scores, k_note, k_method)
    rec.log("summary", rr.TextDocument(head + summary, media_type="text/markdown"), static=True)


class _Sink:
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


def _log_written(final: Path, what: str, started: float) -> None:
    logger.info(
        "wrote %s (%s, %.1f kB) in %.2f s", final, what, final.stat().st_size / 1e3, time.perf_counter() - started
    )


# ---------------------------------------------------------------------------------------------
# A clip
# ---------------------------------------------------------------------------------------------


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
    import rerun.blueprint as rrb

    started = time.perf_counter()
    track_ids = np.asarray(track_ids, dtype=np.int64).reshape(-1)
    labels = np.asarray(labels, dtype=np.int64).reshape(-1)
    embeddings = np.asarray(embeddings)
    _validate_clip(frames, tracks, track_ids, labels, embeddings, masks, k)
    class_ids = class_ids_of(labels)
    xy, visible = tracks.xy[track_ids], tracks.visible[track_ids]  # (N, T, 2), (N, T)
    blueprint = rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial2DView(origin="video", name="frame, tracks and masks"),
            _side_column(k_scores),
            column_shares=_MAIN_SHARES,
        ),
        *_panels(timeline=True),
    )
    summary = f"{len(track_ids)} tracks, {frames.num_frames} frames of {frames.source or '(in memory)'}\n"

    final = Path(path)
    with atomic_write(final) as tmp:
        sink = _Sink(tmp, app_id, final, blueprint)
        rec, written = sink.rec, False
        try:
            log_annotation_contexts(rec, ["video"] if masks is not None else [], class_names(k))
            _log_embedding_and_scores(rec, class_ids, embeddings, k_scores, k, summary, cfg, k_note, k_method)
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
    _log_written(final, f"{frames.num_frames} frames, {len(track_ids)} tracks", started)
    return final


# ---------------------------------------------------------------------------------------------
# An image pair
# ---------------------------------------------------------------------------------------------


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
    class_ids = class_ids_of(labels)
    blueprint = rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Spatial2DView(origin="image1", name="image 1"),
                rrb.Spatial2DView(origin="image2", name="image 2"),
            ),
            _side_column(k_scores),
            column_shares=_MAIN_SHARES,
        ),
        *_panels(timeline=False),  # no timeline to scrub
    )
    outliers = int((labels < 0).sum())
    summary = f"{matches.num_matches} matches ({outliers} outliers)\n"

    final = Path(path)
    with atomic_write(final) as tmp:
        sink = _Sink(tmp, app_id, final, blueprint)
        rec, written = sink.rec, False
        try:
            names = class_names(num_classes, unknown="unknown / outlier")
            log_annotation_contexts(rec, ["image1", "image2"] if masks is not None else [], names)
            _log_embedding_and_scores(rec, class_ids, embeddings, k_scores, k, summary, cfg, k_note, k_method)
            for i, xy in enumerate((matches.xy1, matches.xy2)):
                mask = None if masks is None else masks[i]
                log_image_layers(rec, f"image{i + 1}", images[i], mask, xy, class_ids, cfg, static=True)
            written = True
        finally:
            sink.finish(write=written)
    _log_written(final, f"pair, {matches.num_matches} matches", started)
    return final


# ---------------------------------------------------------------------------------------------
# A whole video, streamed
# ---------------------------------------------------------------------------------------------


def video_blueprint(windows: bool, margins: bool) -> rrb.Blueprint:
    """The frame with its mask and tracks above; K per window (and its score margin) under it."""
    import rerun.blueprint as rrb

    frame = rrb.Spatial2DView(origin="video", name="frame, tracks and masks")
    if not windows:
        return rrb.Blueprint(frame, *_panels(timeline=True))
    series = [rrb.TimeSeriesView(origin="windows/k", name="K per window")]
    if margins:
        series.append(rrb.TimeSeriesView(origin="windows/k_margin", name="how clear K is (score lead)"))
    return rrb.Blueprint(rrb.Vertical(frame, rrb.Horizontal(*series), row_shares=[5.0, 1.0]), *_panels(timeline=True))


class VideoRecorder:
    """Streams a segmented video into one .rrd file, frame by frame, with flat memory.

    Labels are global motion ids that may grow as the video goes on; the annotation contexts name
    every class 0..254 from the start (logged once, before any data). The layout is sent first:
    the frame with its mask and tracks above, K per window (and its score margin) under it. Track
    trails are kept for
    the last `cfg.trail_frames` frames per track id. With cfg.video_frames "h264" the frames are
    encoded into one H.264 MP4 in memory as they come (about 8 kB a frame at 768x576) and logged
    at close() as an AssetVideo with a VideoFrameReference per frame; the masks, points and trails
    are logged frame by frame either way. The file appears under its final name only after
    close(); abort() (or leaving a `with` block by an exception) removes it.

    Args:
        path: output .rrd file.
        app_id: Rerun application id.
        cfg: display settings.
        fps: frame rate stored in the video asset (the frames are shown on the "frame" timeline
            whatever it is).
        windows: the layout has a chart of K per window (log_window).
        margins: the layout has a chart of the K score margin per window (False when K is forced:
            no window has a margin).

    Example:
        >>> with VideoRecorder("out/recording.rrd", fps=25.0) as rec:  # doctest: +SKIP
        ...     for t, frame in iter_video(path):
        ...         rec.log_frame(t, frame, xy, ids, labels, mask)
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        app_id: str = "mosegpipe",
        cfg: VizConfig = VIDEO_VIZ,
        fps: float = 10.0,
        windows: bool = True,
        margins: bool = True,
    ) -> None:
        if not fps > 0:
            raise InputError(f"{path}: fps={fps} must be > 0")
        self.path = Path(path)
        self.cfg = cfg
        self._started = time.perf_counter()
        self._trail_len = cfg.trail_frames or 10**9
        self._trails: dict[int, list[npt.NDArray[np.float32]]] = {}
        self._num_frames = 0
        self._num_windows = 0
        self._frame_times: list[int] = []
        self._encoder: H264Encoder | None = None
        self._video = io.BytesIO()
        if cfg.video_frames == "h264":
            self._encoder = H264Encoder(self._video, fps, self.path, b_frames=False)
        # atomic_write's context is held open across calls; close()/abort() finish it.
        self._target = atomic_write(self.path)
        tmp = self._target.__enter__()
        try:
            self._sink: _Sink | None = _Sink(tmp, app_id, self.path, video_blueprint(windows, margins))
            log_annotation_contexts(self._sink.rec, ["video"], class_names(MAX_CLASSES))
        except BaseException as exc:
            self._close_encoder(flush=False)
            self._target.__exit__(type(exc), exc, exc.__traceback__)
            raise

    def log_window(self, start: int, k: int, k_scores: Mapping[int, float] | None = None) -> None:
        """Log the K chosen in a window (and how clearly its scores chose it, `score_lead`), at the window's
        first frame.

        Args:
            start: frame index of the window's first frame (the "frame" timeline).
            k: motions found in the window, 0 = left unlabelled (too few tracks).
            k_scores: the window's score per candidate K (None or empty: no margin is logged).

        Raises:
            InputError: the recorder is closed.
        """
        if self._sink is None:
            raise InputError(f"{self.path}: recorder already closed")
        log_window_k(self._sink.rec, start, k, k_scores, first=self._num_windows == 0)
        self._num_windows += 1

    def log_frame(
        self,
        t: int,
        image: npt.NDArray[np.uint8],
        xy: npt.NDArray[np.float32],
        ids: npt.NDArray[np.int64],
        labels: npt.NDArray[np.int64],
        mask: npt.NDArray[np.uint8] | None = None,
    ) -> None:
        """Log one frame.

        Args:
            t: frame index in the source (the "frame" timeline); increasing from call to call.
            image: (H, W, 3) uint8 RGB; with H.264 frames, the same size in every call.
            xy: (M, 2) float32 pixel positions of the labelled points in this frame.
            ids: (M,) int64 their track ids (stable across frames: trails follow them).
            labels: (M,) int64 their motion ids, 0..254 (-1 = unlabelled, shown as class 255).
            mask: (H, W) uint8 mask (label, 255 unknown), or None.

        Raises:
            InputError: the recorder is closed, or shapes/labels are invalid.
        """
        if self._sink is None:
            raise InputError(f"{self.path}: recorder already closed")
        xy = np.asarray(xy, dtype=np.float32).reshape(-1, 2)
        ids = np.asarray(ids, dtype=np.int64).reshape(-1)
        labels = np.asarray(labels, dtype=np.int64).reshape(-1)
        if not len(xy) == len(ids) == len(labels):
            raise InputError(f"frame {t}: {len(xy)} points, {len(ids)} ids, {len(labels)} labels: must match")
        if len(labels) and (labels.min() < -1 or labels.max() >= MAX_CLASSES):
            raise InputError(f"frame {t}: labels must be in -1..{MAX_CLASSES - 1}, got {labels.min()}..{labels.max()}")
        if mask is not None and mask.shape != image.shape[:2]:
            raise InputError(f"frame {t}: mask {mask.shape} and image {image.shape[:2]} sizes differ")
        image, mask, xy = self._downscale(image, mask, xy)
        rec = self._sink.rec
        rec.set_time(TIMELINE, sequence=int(t))
        class_ids = class_ids_of(labels)
        if self._encoder is not None:
            self._encoder.add(image)
            self._frame_times.append(int(t))
        log_image_layers(rec, "video", None if self._encoder is not None else image, mask, xy, class_ids, self.cfg)
        live = set(ids.tolist())
        for stale in [i for i in self._trails if i not in live]:
            del self._trails[stale]  # a lost track never comes back (KLTTracker ids are not reused)
        lengths = np.zeros(len(ids), dtype=np.int64)
        for n, (i, p) in enumerate(zip(ids.tolist(), xy)):
            trail = self._trails.setdefault(i, [])
            trail.append(p)
            del trail[: -self._trail_len]
            lengths[n] = len(trail)
        points = [p for i in ids.tolist() for p in self._trails[i]]
        flat = np.array(points, dtype=np.float32).reshape(-1, 2)
        log_trails(rec, flat, lengths, class_ids, self.cfg)
        self._num_frames += 1

    def _downscale(
        self, image: npt.NDArray[np.uint8], mask: npt.NDArray[np.uint8] | None, xy: npt.NDArray[np.float32]
    ) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.uint8] | None, npt.NDArray[np.float32]]:
        side = max(image.shape[:2])
        if self.cfg.max_side_px is None or side <= self.cfg.max_side_px:
            return image, mask, xy
        scale = self.cfg.max_side_px / side
        size_wh = (max(1, round(image.shape[1] * scale)), max(1, round(image.shape[0] * scale)))
        image = cv2.resize(image, size_wh, interpolation=cv2.INTER_AREA)
        if mask is not None:
            mask = cv2.resize(mask, size_wh, interpolation=cv2.INTER_NEAREST)
        # Pixel centres map as (x + 0.5) * s - 0.5.
        return image, mask, ((xy + 0.5) * scale - 0.5).astype(np.float32)

    def _close_encoder(self, flush: bool) -> None:
        if self._encoder is not None:
            encoder, self._encoder = self._encoder, None
            encoder.close(flush=flush)

    def _log_video_asset(self, rec: rr.RecordingStream) -> None:
        """The encoded frames as one AssetVideo, and a VideoFrameReference per logged frame."""
        import rerun as rr

        if self._encoder is None:
            return
        self._close_encoder(flush=True)
        if not self._frame_times:
            return
        asset = rr.AssetVideo(contents=self._video.getvalue(), media_type="video/mp4")
        self._video = io.BytesIO()
        rec.log("video/asset", asset, static=True)
        stamps = asset.read_frame_timestamps_nanos()
        if len(stamps) != len(self._frame_times):
            raise RuntimeError(f"{self.path}: {len(self._frame_times)} frames encoded, the video holds {len(stamps)}")
        num = len(stamps)
        rec.send_columns(
            "video/frame",
            indexes=[rr.TimeColumn(TIMELINE, sequence=self._frame_times)],
            columns=rr.VideoFrameReference.columns(
                timestamp=stamps,
                video_reference=["video/asset"] * num,
                draw_order=np.zeros(num, np.float32),
            ),
        )

    def close(self) -> Path:
        """Finish the file and move it to its final name. Safe to call twice.

        Returns:
            The path written.
        """
        if self._sink is not None:
            sink, self._sink = self._sink, None
            try:
                try:
                    self._log_video_asset(sink.rec)
                except BaseException:
                    self._close_encoder(flush=False)
                    sink.finish(write=False)
                    raise
                sink.finish()
            except BaseException as exc:
                self._target.__exit__(type(exc), exc, exc.__traceback__)
                raise
            self._target.__exit__(None, None, None)
            _log_written(self.path, f"{self._num_frames} frames", self._started)
        return self.path

    def abort(self) -> None:
        """Stop recording and remove the temporary file; nothing is written under the final name."""
        if self._sink is not None:
            sink, self._sink = self._sink, None
            try:
                self._close_encoder(flush=False)
                sink.finish(write=False)
            finally:
                err = RuntimeError(f"{self.path}: recording aborted")
                self._target.__exit__(RuntimeError, err, None)

    def __enter__(self) -> VideoRecorder:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


def log_window_k(
    rec: Any, start: int, k: int, k_scores: Mapping[int, float] | None = None, first: bool = False
) -> None:
    """Logs a window's K and how clearly its scores chose it (`score_lead`) at the window's first frame.

    Args:
        rec: the rr.RecordingStream.
        start: frame index of the window's first frame (the "frame" timeline).
        k: motions found in the window, 0 = left unlabelled.
        k_scores: the window's score per candidate K (None or empty: no score lead is logged).
        first: the first window of the recording: the two series' styles are logged first.
    """
    import rerun as rr

    if first:
        rec.log("windows/k", rr.SeriesLines(names="K", interpolation_mode="StepAfter"), static=True)
        rec.log("windows/k", rr.SeriesPoints(names="K", markers="circle", marker_sizes=3.0), static=True)
        style = rr.SeriesLines(names="best K's score minus the next K's (0 = a tie)", interpolation_mode="StepAfter")
        rec.log("windows/k_margin", style, static=True)
    rec.set_time(TIMELINE, sequence=int(start))
    rec.log("windows/k", rr.Scalars(float(k)))
    lead = score_lead(k_scores or {}) if k > 0 else None
    if lead is not None:
        rec.log("windows/k_margin", rr.Scalars(lead))
