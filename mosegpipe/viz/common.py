"""The vocabulary of the recordings: class ids and colours, display settings (VizConfig), the
embedding's cube, the K chart's geometry and the one line on K (k_statement)."""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt

from mosegpipe.colours import (
    MOVING_UNCLUSTERED,
    UNKNOWN,
    UNKNOWN_RGB,
    legend_rows,
    mask_rgba,
    point_palette,
    value_names,
)
from mosegpipe.errors import InputError
from mosegpipe.settings import Check, check_fields

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
EYE_POSITION = (3.0, -3.5, 2.5)

# Layout shares: the frame takes 3/4 of the width; the side column stacks summary, K chart and
# embedding. In a 1600x900 window that leaves the summary ~170 px, room for 8 lines; it has 3-5.
MAIN_SHARES = [3.0, 1.0]
SIDE_SHARES = {"summary": 1.0, "legend": 0.8, "k_scores": 1.0, "embedding": 1.6}

CHOSEN_COLOR = (255, 190, 0)
OTHER_COLOR = (150, 150, 150)

UNLABELLED_POINT_COLOR = UNKNOWN_RGB
"""Colour of unlabelled / outlier points (class 255): the unknown grey of every output (colours.UNKNOWN_RGB)."""


def class_ids_of(labels: npt.NDArray[np.int64]) -> npt.NDArray[np.uint16]:
    """Class ids of point labels: the label itself, UNKNOWN_CLASS for -1 (unlabelled / outlier)."""
    labels = np.asarray(labels, dtype=np.int64)
    return np.where(labels < 0, UNKNOWN_CLASS, labels).astype(np.uint16)


@dataclass(frozen=True)
class VizConfig:
    """Settings of the Rerun recording, one line each; sizes measured by benchmarks/output_size.py
    (docs/OUTPUTS.md, "recording.rrd").

    Attributes:
        jpeg_quality: frames are stored as JPEG of this quality (1-100), 0 = raw RGB.
        mask_opacity: opacity of the segmentation over the frame, 0..1.
        point_radius_px: radius of the track points, pixels (UI points would scale with zoom).
        line_radius_px: half-width of the track history lines, pixels.
        trail_frames: frames of history drawn per track (None = all since the first frame).
        embedding_radius: radius of the embedding points, in units of the display cube (half-size EMBEDDING_BOX = 1).
        max_side_px: frames (masks, points) larger than this on their longer side are downscaled first (None = never).
        video_frames: whole videos: "h264" one MP4 and a frame reference per frame, or "jpeg" an image per frame.
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
        check_fields(self, _VIZ_CHECKS)


_VIZ_CHECKS: tuple[Check, ...] = (
    ("jpeg_quality", lambda v: 0 <= v <= 100, "lie in 0..100"),
    ("trail_frames", lambda v: v >= 1, "be >= 1 (or None: all)"),
    ("max_side_px", lambda v: v >= 16, "be >= 16 (or None: never downscaled)"),
    ("video_frames", lambda v: v in ("h264", "jpeg"), "be h264 or jpeg"),
)
"""VizConfig's checks: (field, test, what the value must do)."""


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


_RIGID_SPLIT = re.compile(r"the rigid-motion check split off (\d+) groups? \(K = (\d+) -> (\d+)\)")


def split_note(note: str) -> tuple[int, str]:
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
    split, rest = split_note(note)
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


def legend_markdown(
    labels: npt.NDArray[np.int64],
    masks: Sequence[npt.NDArray[np.uint8]] | npt.NDArray[np.uint8] | None = None,
    unknown: str = "unknown",
) -> str:
    """The legend of a recording as a markdown table: per value its colour (hex, as the points and the mask
    draw it; colours.legend_rows), name and track count, the rows the overlays' legend shows.

    Args:
        labels: (N,) int64 track labels (-1 = unlabelled, not counted).
        masks: (H, W) uint8 masks: a row for 254 and 255 where one of them shows it.
        unknown: the name of 255.
    """
    shown = [v for v in (MOVING_UNCLUSTERED, UNKNOWN) if masks is not None and any((m == v).any() for m in masks)]
    rows = legend_rows(labels, np.array(shown, dtype=np.int64), unknown)
    lines = ["| value | colour | what | tracks |", "|---|---|---|---|"]
    lines += [f"| {v} | #{r:02x}{g:02x}{b:02x} | {name} | {n} |" for v, name, (r, g, b), n in rows]
    return "\n".join(lines) + "\n"


def summary_head(k: int, k_scores: Mapping[int, float], note: str, method: str) -> str:
    """First lines of a summary: the K written and why (k_statement), then any other note on K."""
    statement = k_statement(k, k_scores, note, method)
    rest = split_note(note)[1]
    return f"**{statement}**\n\n" + (f"note: {rest}\n\n" if rest and rest not in statement else "")
