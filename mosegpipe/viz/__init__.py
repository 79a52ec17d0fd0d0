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

Modules: common (class ids and colours, VizConfig, the embedding's cube, the K chart's geometry,
k_statement), blocks (the pieces every recording is logged with, and the in-memory sink), clip
(write_recording), pair (write_pair_recording) and video (VideoRecorder). Every public name is
re-exported here.
"""

from __future__ import annotations

from mosegpipe.viz.blocks import (
    log_annotation_contexts,
    log_image_layers,
    log_trails,
)
from mosegpipe.viz.clip import (
    write_recording,
)
from mosegpipe.viz.common import (
    CHART_PX_PER_UNIT,
    EMBEDDING_BOX,
    MAX_CLASSES,
    TIMELINE,
    UNKNOWN_CLASS,
    UNLABELLED_POINT_COLOR,
    VIDEO_VIZ,
    KChart,
    VizConfig,
    class_ids_of,
    class_names,
    embedding_to_3d,
    fit_in_box,
    k_chart,
    k_margin,
    k_statement,
    label_box,
    mask_colors,
    point_colors,
    score_lead,
    short_score,
)
from mosegpipe.viz.pair import (
    write_pair_recording,
)
from mosegpipe.viz.video import (
    VideoRecorder,
    log_window_k,
    video_blueprint,
)

__all__ = [
    "CHART_PX_PER_UNIT",
    "EMBEDDING_BOX",
    "KChart",
    "MAX_CLASSES",
    "TIMELINE",
    "UNKNOWN_CLASS",
    "UNLABELLED_POINT_COLOR",
    "VIDEO_VIZ",
    "VideoRecorder",
    "VizConfig",
    "class_ids_of",
    "class_names",
    "embedding_to_3d",
    "fit_in_box",
    "k_chart",
    "k_margin",
    "k_statement",
    "label_box",
    "log_annotation_contexts",
    "log_image_layers",
    "log_trails",
    "log_window_k",
    "mask_colors",
    "point_colors",
    "score_lead",
    "short_score",
    "video_blueprint",
    "write_pair_recording",
    "write_recording",
]
