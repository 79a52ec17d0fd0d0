"""Rerun recordings of a segmentation: frames, tracks, masks, the embedding and the K scores.

Every Rerun call of the project lives here. Each output file gets its own `rr.RecordingStream`
(never the global recording), so recordings can be written from several threads or in a batch
without mixing, and each is written atomically (temporary file, closed, then renamed).

Entity paths of a clip recording (:func:`write_recording`) and a video (:class:`VideoRecorder`):

- ``/``: AnnotationContext (static): class i "motion i" (motion label i; 0 = the dominant motion,
  usually the background) and class 255 "unknown", with the colours of io.default_palette(): the
  same values, names and colours as the mask PNGs and labels.npz.
- ``video/frame``: the frame (JPEG EncodedImage, or a raw Image when jpeg_quality is 0).
- ``video/mask``: SegmentationImage, values as in Segmentation.masks.
- ``video/tracks``: LineStrips2D, the recent history of each labelled track.
- ``video/points``: Points2D, the labelled tracks visible in the frame.
- ``embedding``: Points3D of the embedding (static; PCA to 3-D when E > 3, zero-padded when E < 3).
- ``k_scores``: BarChart of the criterion per candidate K (static); ``summary``: TextDocument.

Time-varying entities use the sequence timeline "frame" (index of the frame in the source video).
An image pair (:func:`write_pair_recording`) is static, with ``image1/...`` and ``image2/...``
in place of ``video/...`` and class 255 also standing for outlier matches.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe.errors import InputError
from mosegpipe.io import atomic_write, default_palette
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
        embedding_radius: radius of the embedding points, in embedding units.
        max_side_px: frames (and masks, points) larger than this on their longer side are
            downscaled before logging (None = never); keeps whole-video recordings small.
    """

    jpeg_quality: int = 85
    mask_opacity: float = 0.45
    point_radius_px: float = 2.5
    line_radius_px: float = 0.75
    trail_frames: int | None = None
    embedding_radius: float = 0.01
    max_side_px: int | None = None

    def __post_init__(self) -> None:
        if not 0 <= self.jpeg_quality <= 100:
            raise ValueError(f"jpeg_quality={self.jpeg_quality} must be in 0..100")
        if self.trail_frames is not None and self.trail_frames < 1:
            raise ValueError(f"trail_frames={self.trail_frames} must be >= 1 or None")
        if self.max_side_px is not None and self.max_side_px < 16:
            raise ValueError(f"max_side_px={self.max_side_px} must be >= 16 or None")


VIDEO_VIZ = VizConfig(trail_frames=10, max_side_px=960)
"""Defaults of :class:`VideoRecorder`: short trails and frames at most 960 px wide."""


def class_names(k: int, unknown: str = "unknown") -> dict[int, str]:
    """Class id -> display name: i "motion i" for i = 0..k-1 (0 "motion 0 (dominant)"), 255 `unknown`."""
    names = {i: f"motion {i}" for i in range(k)}
    if k:
        names[0] = "motion 0 (dominant)"
    return {**names, UNKNOWN_CLASS: unknown}


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


# ---------------------------------------------------------------------------------------------
# Building blocks
# ---------------------------------------------------------------------------------------------


def _side_views() -> list[rrb.View]:
    import rerun.blueprint as rrb

    return [
        rrb.Spatial3DView(origin="embedding", name="embedding"),
        rrb.BarChartView(origin="k_scores", name="score per K"),
        rrb.TextDocumentView(origin="summary", name="summary"),
    ]


def _annotation_context(num_classes: int, unknown: str = "unknown") -> rr.AnnotationContext:
    import rerun as rr

    palette = default_palette()
    return rr.AnnotationContext(
        [
            rr.ClassDescription(info=rr.AnnotationInfo(id=i, label=name, color=tuple(int(c) for c in palette[i])))
            for i, name in class_names(num_classes, unknown).items()
        ]
    )


def _image_archetype(image: npt.NDArray[np.uint8], cfg: VizConfig) -> rr.Image | rr.EncodedImage:
    import rerun as rr

    if cfg.jpeg_quality == 0:
        return rr.Image(image, draw_order=0.0)
    bgr = cv2.cvtColor(image, cv2.COLOR_RGB2BGR) if image.ndim == 3 else image
    ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, cfg.jpeg_quality])
    if not ok:
        raise InputError(f"JPEG encoding of a {image.shape} frame failed")
    return rr.EncodedImage(contents=buf.tobytes(), media_type="image/jpeg", draw_order=0.0)


def _log_image_layers(
    rec: rr.RecordingStream,
    origin: str,
    image: npt.NDArray[np.uint8],
    mask: npt.NDArray[np.uint8] | None,
    xy: npt.NDArray[np.float32],
    class_ids: npt.NDArray[np.uint16],
    cfg: VizConfig,
    static: bool = False,
) -> None:
    """Image, segmentation and points under `origin` (frame, mask, points)."""
    import rerun as rr

    rec.log(f"{origin}/frame", _image_archetype(image, cfg), static=static)
    if mask is not None:
        rec.log(f"{origin}/mask", rr.SegmentationImage(mask, opacity=cfg.mask_opacity, draw_order=1.0), static=static)
    points = rr.Points2D(xy, class_ids=class_ids, radii=cfg.point_radius_px, draw_order=3.0)
    rec.log(f"{origin}/points", points, static=static)


def _log_trails(
    rec: rr.RecordingStream,
    strips: list[npt.NDArray[np.float32]],
    class_ids: npt.NDArray[np.uint16],
    cfg: VizConfig,
) -> None:
    import rerun as rr

    keep = [i for i, strip in enumerate(strips) if len(strip) >= 2]
    if keep:
        lines = rr.LineStrips2D(
            [strips[i] for i in keep], class_ids=class_ids[keep], radii=cfg.line_radius_px, draw_order=2.0
        )
        rec.log("video/tracks", lines)
    else:
        # Nothing to draw (first frame): clear so that no older history shows through.
        rec.log("video/tracks", rr.Clear(recursive=False))


def _log_embedding_and_scores(
    rec: rr.RecordingStream,
    class_ids: npt.NDArray[np.uint16],
    embeddings: npt.NDArray[np.floating],
    k_scores: dict[int, float],
    summary: str,
    cfg: VizConfig,
) -> None:
    """Embedding, K scores and a markdown summary: one static row each."""
    import rerun as rr

    rec.log(
        "embedding",
        rr.Points3D(embedding_to_3d(embeddings), class_ids=class_ids, radii=cfg.embedding_radius),
        static=True,
    )
    ks = sorted(k_scores)
    if ks:
        values = np.nan_to_num(np.array([k_scores[c] for c in ks], dtype=np.float64))
        rec.log("k_scores", rr.BarChart(values, abscissa=np.array(ks, dtype=np.float64)), static=True)
        summary += "\n| K | score |\n|---|---|\n" + "".join(f"| {c} | {k_scores[c]:.6g} |\n" for c in ks)
    rec.log("summary", rr.TextDocument(summary, media_type="text/markdown"), static=True)


class _Sink:
    """A recording stream into memory, written to its file by Python when finished.

    Rerun's own file sink writes on a thread of its own: when the disk fills up, that thread dies
    and the next flush waits forever (dropping the stream too), Ctrl-C cannot stop it, and Rerun
    prints its own error lines. Here the stream goes to a memory buffer and Python writes the bytes,
    so a full disk is an ordinary OSError (ENOSPC) raised in the caller's thread. The price is that
    the recording is held in memory until it is written (a 5-frame clip: about 0.5 MB; a whole
    video: about 0.2 MB per frame at 960 px). Draining the buffer in pieces does not give a
    readable .rrd (one footer per drain), so it is drained once.
    """

    def __init__(self, tmp: Path, app_id: str, blueprint: rrb.Blueprint, final: Path) -> None:
        import rerun as rr

        self.tmp = tmp
        self.final = final
        self.rec = rr.RecordingStream(app_id)
        self._memory = self.rec.memory_recording()
        self.rec.send_blueprint(blueprint, make_active=False, make_default=True)

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
        cfg: display settings (max_side_px is ignored: clips are logged at full size).

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
            rrb.Vertical(*_side_views(), row_shares=[3, 2, 1]),
            column_shares=[2, 1],
        ),
        # The time panel stays open: scrubbing through the frames is the main interaction.
        collapse_panels=False,
    )
    summary = f"**K = {k}**, {len(track_ids)} tracks, {frames.num_frames} frames of {frames.source or '(in memory)'}\n"

    final = Path(path)
    with atomic_write(final) as tmp:
        sink = _Sink(tmp, app_id, blueprint, final)
        rec, written = sink.rec, False
        try:
            rec.log("/", _annotation_context(k), static=True)
            _log_embedding_and_scores(rec, class_ids, embeddings, k_scores, summary, cfg)
            for t in range(frames.num_frames):
                rec.set_time(TIMELINE, sequence=frames.start + t)
                seen = visible[:, t]
                mask = None if masks is None else masks[t]
                _log_image_layers(rec, "video", frames.images[t], mask, xy[seen, t], class_ids[seen], cfg)
                first = 0 if cfg.trail_frames is None else max(0, t + 1 - cfg.trail_frames)
                strips = [xy[n, first : t + 1][visible[n, first : t + 1]] for n in np.flatnonzero(seen)]
                _log_trails(rec, strips, class_ids[seen], cfg)
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
            rrb.Vertical(*_side_views(), row_shares=[3, 2, 1]),
            column_shares=[2, 1],
        ),
        collapse_panels=True,  # no timeline to scrub
    )
    outliers = int((labels < 0).sum())
    summary = f"**K = {k}**, {matches.num_matches} matches ({outliers} outliers)\n"

    final = Path(path)
    with atomic_write(final) as tmp:
        sink = _Sink(tmp, app_id, blueprint, final)
        rec, written = sink.rec, False
        try:
            rec.log("/", _annotation_context(num_classes, unknown="unknown / outlier"), static=True)
            _log_embedding_and_scores(rec, class_ids, embeddings, k_scores, summary, cfg)
            for i, xy in enumerate((matches.xy1, matches.xy2)):
                mask = None if masks is None else masks[i]
                _log_image_layers(rec, f"image{i + 1}", images[i], mask, xy, class_ids, cfg, static=True)
            written = True
        finally:
            sink.finish(write=written)
    _log_written(final, f"pair, {matches.num_matches} matches", started)
    return final


# ---------------------------------------------------------------------------------------------
# A whole video, streamed
# ---------------------------------------------------------------------------------------------


class VideoRecorder:
    """Streams a segmented video into one .rrd file, frame by frame, with flat memory.

    Labels are global motion ids that may grow as the video goes on; the annotation context is
    re-logged (static: the last one wins) whenever a new id appears. Track trails are kept for
    the last `cfg.trail_frames` frames per track id. The file appears under its final name only
    after close(); abort() (or leaving a `with` block by an exception) removes it.

    Example:
        >>> with VideoRecorder("out/recording.rrd") as rec:  # doctest: +SKIP
        ...     for t, frame in iter_video(path):
        ...         rec.log_frame(t, frame, xy, ids, labels, mask)
    """

    def __init__(self, path: str | os.PathLike[str], app_id: str = "mosegpipe", cfg: VizConfig = VIDEO_VIZ) -> None:
        import rerun.blueprint as rrb

        self.path = Path(path)
        self.cfg = cfg
        self._started = time.perf_counter()
        self._trail_len = cfg.trail_frames or 10**9
        self._trails: dict[int, list[npt.NDArray[np.float32]]] = {}
        self._num_classes = 0
        self._num_frames = 0
        # atomic_write's context is held open across calls; close()/abort() finish it.
        self._target = atomic_write(self.path)
        tmp = self._target.__enter__()
        blueprint = rrb.Blueprint(rrb.Spatial2DView(origin="video", name="video"), collapse_panels=False)
        try:
            self._sink: _Sink | None = _Sink(tmp, app_id, blueprint, self.path)
        except BaseException as exc:
            self._target.__exit__(type(exc), exc, exc.__traceback__)
            raise

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
            t: frame index in the source (the "frame" timeline).
            image: (H, W, 3) uint8 RGB.
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
        needed = int(labels.max()) + 1 if len(labels) else 0
        if needed > self._num_classes or self._num_frames == 0:
            self._num_classes = max(needed, self._num_classes, 1)
            rec.log("/", _annotation_context(self._num_classes), static=True)
        rec.set_time(TIMELINE, sequence=int(t))
        class_ids = class_ids_of(labels)
        _log_image_layers(rec, "video", image, mask, xy, class_ids, self.cfg)
        live = set(ids.tolist())
        for stale in [i for i in self._trails if i not in live]:
            del self._trails[stale]  # a lost track never comes back (KLTTracker ids are not reused)
        strips = []
        for i, p in zip(ids.tolist(), xy):
            trail = self._trails.setdefault(i, [])
            trail.append(p)
            del trail[: -self._trail_len]
            strips.append(np.array(trail, dtype=np.float32))
        _log_trails(rec, strips, class_ids, self.cfg)
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

    def close(self) -> Path:
        """Finish the file and move it to its final name. Safe to call twice.

        Returns:
            The path written.
        """
        if self._sink is not None:
            sink, self._sink = self._sink, None
            try:
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
