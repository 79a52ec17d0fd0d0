"""DAVIS-2016 protocol: dense motion masks scored against the main moving object's human masks.

Usage (from the repository root, data in ../shared/data)::

    from mosegpipe.evaluation.davis import run_davis, format_table
    report = run_davis("../shared/data/davis2016-train", mode="clip5", method="flow-homography")
    table = format_table(report)  # plain text, one line per clip; report.to_dict() for JSON

or from the shell: `moseg eval davis --out DIR` (whole video) / `moseg eval davis-clip5 --out DIR`.

Modes (`MODES`): "clip5" runs a method on the first 5 frames of each clip and scores those 5;
"whole" runs it on all frames of the clip (25 here; the pipeline's whole-video mode) and scores all.
Every frame a method is given is scored, the first included: this is unsupervised motion
segmentation, there is no first-frame annotation to exclude (the semi-supervised DAVIS protocol
drops it).

Scores are DAVIS's (Perazzi et al., CVPR 2016): region similarity J (IoU, 1 when both masks are
empty) and boundary F (tolerance 0.008 of the image diagonal), reused from `evaluation.e2e`; per
clip each is summarised by its mean, recall (fraction of frames scoring above 0.5) and decay (the
DAVIS code's four overlapping bins over the frames, bin 0 minus bin 3: `clip_statistics`).

A method returns labels, not a foreground: (T, H, W) uint8, label k = motion k, 255 = unknown. The
headline scores what a user gets: the masks as written, with their documented meaning, 0 = the world
(background), every other known value a mover (foreground), 255 = unknown (not foreground;
`foreground_from_labels`). The pipeline's masks are read back from the files `moseg` writes
(`pipeline_method`). Beside it: "world off", the share of a clip's frames in which the label covering
most of the true background is not 0 (the world painted as a mover); "majority J", the score of the
earlier reading that took as background the label covering most pixels over the clip, a choice made
after the fact that the written masks never make (kept for comparison while the world's label is
being fixed); and "best single label", the one label whose mask scores the best mean J against the
truth (an oracle, for reference only).

Methods (`MaskMethod`): "pipeline" (segment_clip for clip5, segment_video for whole, with the given
or default PipelineConfig) and "flow-homography", the classical reference (`flow_homography_labels`):
DIS optical flow, the camera's motion as a robust homography, foreground where the flow departs from
it. A clip on which a method raises a MosegError (too few tracks, ...) is scored as an empty
prediction (J = F = 0: DAVIS masks are never empty) and the error is kept in its row.
"""

from __future__ import annotations

import logging
import math
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from PIL import Image

from mosegpipe.apps.outputs import write_clip_outputs, write_video_outputs
from mosegpipe.data.davis import DavisClip, davis_part, davis_split, list_davis_clips, read_davis_clip
from mosegpipe.errors import MosegError, check_choice
from mosegpipe.evaluation.composite import LABEL_SHARE
from mosegpipe.evaluation.davis_scores import (
    best_single_label,
    clip_statistics,
    foreground_from_labels,
    majority_foreground,
    per_frame_scores,
    world_off_share,
)
from mosegpipe.evaluation.flow_baseline import FlowHomographyConfig as FlowHomographyConfig  # re-exported
from mosegpipe.evaluation.flow_baseline import flow_homography_labels
from mosegpipe.evaluation.identities import object_identities
from mosegpipe.evaluation.metrics import (
    background_points_moving,
    union_shares,
)
from mosegpipe.masks import UNKNOWN, WORLD
from mosegpipe.pipeline import PipelineConfig, segment_clip
from mosegpipe.runtime import set_threads

log = logging.getLogger("mosegpipe.evaluation.davis")

MODES: dict[str, int | None] = {"clip5": 5, "whole": None}
"""Mode -> frames read from each clip's start (None = all)."""

DAVIS_MODES = {"davis": "whole", "davis-clip5": "clip5"}
"""`moseg eval` protocol name -> mode."""

TrackPoints = list[tuple[npt.NDArray[np.float32], npt.NDArray[np.int64]]]
"""Per frame of a clip, the tracks' (xy (N, 2) float32 pixels, labels (N,) int64, -1 = unlabelled) as written."""


@dataclass(frozen=True)
class MethodOutput:
    """What a mask method gives: labels, and the tracks' labelled points when it has tracks.

    Attributes:
        labels: (T, H, W) uint8 labels, k = motion k, 255 = unknown.
        points: the tracks per frame (`TrackPoints`); None for a method without tracks.
    """

    labels: npt.NDArray[np.uint8]
    points: TrackPoints | None = None


MaskMethod = Callable[[DavisClip, str], "npt.NDArray[np.uint8] | MethodOutput"]
"""A mask method: (clip, mode) -> (T, H, W) uint8 labels for clip.images, k = motion k, 255 = unknown
(or a MethodOutput with them and the tracks' labelled points).

The clip holds the frames to segment (images (T, H, W, 3) uint8 RGB, and frames_dir / start for
methods that read the frames themselves); it must not look at clip.gt.
"""


def pipeline_method(cfg: PipelineConfig | None = None, checkpoint: str | Path | None = None) -> MaskMethod:
    """The pipeline as a mask method: segment_clip on the frames folder for "clip5", segment_video
    for "whole" (window length cfg.frames), both from clip.start over clip.num_frames frames, each
    written as `moseg run` writes it (no recording) and its mask files read back: what is scored is
    what a user gets.

    The model is loaded once per method (as the CLI does: `numpy_net.load_embedder`), so a row's
    seconds are the segmentation's, not the model loading's.

    Args:
        cfg: pipeline settings (None = the defaults). For "clip5" cfg.frames and cfg.start are set
            from the clip.
        checkpoint: a checkpoint instead of the shipped weights.
    """
    from mosegpipe.embed.numpy_net import Embedder, load_embedder

    base = cfg if cfg is not None else PipelineConfig()
    models: dict[int, Embedder] = {}

    def model_for(frames: int) -> Embedder:
        if frames not in models:
            models[frames] = load_embedder(frames, checkpoint)
        return models[frames]

    def run(clip: DavisClip, mode: str) -> MethodOutput:
        with tempfile.TemporaryDirectory(prefix="moseg-davis-") as tmp:
            out = Path(tmp) / "out"
            seen: dict[int, tuple[npt.NDArray[np.float32], npt.NDArray[np.int64]]] = {}
            if mode == "clip5":
                clip_cfg = replace(base, frames=clip.num_frames, start=clip.start)
                result = segment_clip(clip.frames_dir, clip_cfg, model_for(clip.num_frames))
                write_clip_outputs(result, out, clip_cfg, rrd=False)
                ids = result.trajectories.track_ids
                for t in range(clip.num_frames):
                    on = result.tracks.visible[ids, t]
                    seen[clip.start + t] = (result.tracks.xy[ids[on], t], result.clustering.labels[on])
            else:
                video_cfg = replace(base, start=clip.start)
                write_video_outputs(
                    clip.frames_dir,
                    out,
                    video_cfg,
                    model_for(base.frames),
                    rrd=False,
                    max_frames=clip.num_frames,
                    on_frame=lambda fr, _mask: seen.__setitem__(fr.index, (fr.xy.copy(), fr.labels.copy())),
                )
            empty = (np.zeros((0, 2), np.float32), np.zeros(0, np.int64))
            points = [seen.get(clip.start + t, empty) for t in range(clip.num_frames)]
            return MethodOutput(read_written_masks(out, clip.start, clip.num_frames, clip.gt.shape[1:]), points)

    return run


def read_written_masks(folder: Path, start: int, num_frames: int, size_hw: tuple[int, ...]) -> npt.NDArray[np.uint8]:
    """The masks an output folder holds (masks/NNNNNN.png, named by source frame index), as written.

    Args:
        folder: a `moseg run` output folder.
        start: source index of the first frame.
        num_frames: frames to read.
        size_hw: (H, W) of the frames: a frame without a mask file is all UNKNOWN.

    Returns:
        (num_frames, H, W) uint8 mask values (the palette PNGs' indices).
    """
    out = np.full((num_frames, *size_hw), UNKNOWN, dtype=np.uint8)
    for t in range(num_frames):
        path = folder / "masks" / f"{start + t:06d}.png"
        if path.exists():
            with Image.open(path) as image:
                out[t] = np.asarray(image, dtype=np.uint8)
    return out


def _flow_homography_method(clip: DavisClip, mode: str) -> npt.NDArray[np.uint8]:
    return flow_homography_labels(clip.images)


METHODS = ("pipeline", "flow-homography")


def get_method(method: str | MaskMethod, cfg: PipelineConfig | None = None) -> MaskMethod:
    """A built-in method by name ("pipeline" with `cfg`, "flow-homography"), or `method` itself.

    Raises:
        ConfigError: an unknown name.
    """
    if callable(method):
        return method
    if check_choice("method", method, METHODS) == "pipeline":
        return pipeline_method(cfg)
    return _flow_homography_method


# ---------------------------------------------------------------------------------------------
# Protocol


@dataclass(frozen=True)
class DavisRow:
    """One clip's scores.

    Attributes:
        clip: clip name.
        part: "dev" or "val" (data.davis split).
        frames: frames scored.
        j_mean, j_recall, j_decay: region similarity statistics (the masks as written: 0 = background).
        f_mean, f_recall, f_decay: boundary F statistics (the masks as written).
        best_label_j: mean J of the best single label (oracle).
        world_off: share of frames in which the label covering most of the true background is not 0.
        majority_j: mean J with the clip's most common label as background (the earlier, after-the-fact
            reading; for comparison).
        fp_share: mean over frames of the union's share that is background written as moving (false positives).
        miss_share: mean over frames of the union's share that is the object written as world (misses);
            j_mean + fp_share + miss_share = 1.
        bg_tracks_moving: the share of labelled track points on the true background labelled as a mover
            (NaN for a method without tracks).
        k: labels found over the clip (255 excluded); 0 on failure.
        seconds: wall time of the method on the clip (reading and scoring excluded).
        error: the MosegError's message when the method failed ("" otherwise).
        labels: the object's identities over the clip: the moving labels (not 0, not 255) that covered most of
            it, and at least a tenth, in some frame (`identities.object_identities`; 1 = one throughout, 0 = never found).
        switches: how often its identity changed (`identities.identity_switches`).
    """

    clip: str
    part: str
    frames: int
    j_mean: float
    j_recall: float
    j_decay: float
    f_mean: float
    f_recall: float
    f_decay: float
    best_label_j: float
    k: int
    seconds: float
    error: str = ""
    world_off: float = 0.0
    majority_j: float = 0.0
    labels: int = 0
    switches: int = 0
    fp_share: float = 0.0
    miss_share: float = 0.0
    bg_tracks_moving: float = math.nan


SCORE_FIELDS = (
    "j_mean",
    "j_recall",
    "j_decay",
    "f_mean",
    "f_recall",
    "f_decay",
    "best_label_j",
    "world_off",
    "majority_j",
    "fp_share",
    "miss_share",
    "bg_tracks_moving",
    "k",
    "labels",
    "switches",
    "seconds",
)
"""The DavisRow fields averaged in a report's means."""


@dataclass(frozen=True)
class DavisReport:
    """Scores of one method in one mode over some clips.

    Attributes:
        mode: "clip5" or "whole".
        method: the method's name.
        rows: one per clip, in clip order.
        means: part ("dev", "val", "all") -> field -> mean over that part's rows (failed clips
            included, as scored), plus "clips" and "failed" counts; parts without rows are left out.
    """

    mode: str
    method: str
    rows: list[DavisRow]
    means: dict[str, dict[str, float]] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form: mode, method, rows (dicts) and means."""
        return {"mode": self.mode, "method": self.method, "rows": [asdict(r) for r in self.rows], "means": self.means}


def score_clip(labels: npt.ArrayLike, gt: npt.ArrayLike, points: TrackPoints | None = None) -> dict[str, float]:
    """The DavisRow scores of one clip's labels.

    Args:
        labels: (T, H, W) uint8 labels, 255 = unknown.
        gt: (T, H, W) bool ground truth.
        points: the tracks' labelled points per frame (None: bg_tracks_moving is NaN).

    Returns:
        dict with the j_*, f_*, best_label_j, world_off, majority_j, fp_share, miss_share,
        bg_tracks_moving, k, labels and switches fields of DavisRow.
    """
    lab = np.asarray(labels, dtype=np.uint8)
    fg = foreground_from_labels(lab)
    j, f = per_frame_scores(fg, gt)
    shares = np.array([union_shares(p, g) for p, g in zip(fg, np.asarray(gt, dtype=bool))]).reshape(-1, 2)
    j_majority, _ = per_frame_scores(majority_foreground(lab), gt)
    jm, jr, jd = clip_statistics(j)
    fm, fr, fd = clip_statistics(f)
    present = np.unique(lab)
    obj = np.asarray(gt, dtype=bool).astype(np.uint8)
    identities = object_identities(lab, obj, [1], share=LABEL_SHARE, ignore=(WORLD, UNKNOWN))[1]
    return {
        "j_mean": jm,
        "j_recall": jr,
        "j_decay": jd,
        "f_mean": fm,
        "f_recall": fr,
        "f_decay": fd,
        "best_label_j": best_single_label(lab, gt)[1],
        "world_off": world_off_share(lab, gt),
        "majority_j": float(np.mean(j_majority)),
        "fp_share": float(shares[:, 0].mean()),
        "miss_share": float(shares[:, 1].mean()),
        "bg_tracks_moving": math.nan if points is None else background_points_moving(points, gt, WORLD),
        "k": int(np.count_nonzero(present != UNKNOWN)),
        "labels": len(set(identities)),
        "switches": sum(a != b for a, b in zip(identities, identities[1:])),
    }


WORLD_OFF_LIMIT = 0.1
"""A clip counts as "world off" in a report's means when more than this share of its frames is."""


def _mean(values: Sequence[float]) -> float:
    """The mean of the values that are not NaN (NaN when none is)."""
    x = np.asarray(values, np.float64)
    return float(x[~np.isnan(x)].mean()) if (~np.isnan(x)).any() else math.nan


def summarize_rows(rows: Sequence[DavisRow]) -> dict[str, dict[str, float]]:
    """Means of SCORE_FIELDS per part ("dev", "val") and over all rows, with clip and failure counts and
    the number of clips with the world off label 0 in more than WORLD_OFF_LIMIT of their frames."""
    means: dict[str, dict[str, float]] = {}
    for part in ("dev", "val", "all"):
        chosen = [r for r in rows if part == "all" or r.part == part]
        if chosen:
            means[part] = {name: _mean([getattr(r, name) for r in chosen]) for name in SCORE_FIELDS}
            found = [r.labels for r in chosen if r.labels > 0]  # labels per object: of the objects found
            means[part]["labels"] = float(np.mean(found)) if found else float("nan")
            means[part].update(
                clips=len(chosen),
                failed=sum(bool(r.error) for r in chosen),
                world_off_clips=sum(r.world_off > WORLD_OFF_LIMIT for r in chosen),
            )
    return means


def run_davis(
    root: str | Path,
    mode: str = "clip5",
    method: str | MaskMethod = "pipeline",
    clips: Sequence[str] | None = None,
    part: str = "all",
    cfg: PipelineConfig | None = None,
    threads: int | None = 1,
    name: str | None = None,
) -> DavisReport:
    """Runs a mask method on DAVIS clips and scores it.

    Args:
        root: the ``davis2016-train`` folder (or a data root holding it).
        mode: "clip5" (first 5 frames) or "whole" (all frames).
        method: "pipeline", "flow-homography" or a MaskMethod callable.
        clips: clip names (None = every clip under root); then filtered by `part`.
        part: "dev", "val" or "all" (data.davis.DAVIS_VAL).
        cfg: pipeline settings for method "pipeline" (None = defaults).
        threads: set torch / OpenCV / BLAS threads to this first (runtime.set_threads; one is fastest
            on the 2-core machines); None leaves them as they are.
        name: the method's name in the report (None = the name given, or the callable's __name__).

    Returns:
        DavisReport, rows in clip order.

    Raises:
        ConfigError: unknown mode, method or part.
        DatasetError: a clip cannot be read (data errors are not scored as failures).
    """
    max_frames = MODES[check_choice("mode", mode, MODES)]
    run = get_method(method, cfg)
    if name is None:
        name = method if isinstance(method, str) else getattr(method, "__name__", "custom")
    if threads is not None:
        set_threads(threads)
    names = davis_split(list(clips) if clips is not None else list_davis_clips(root), part)
    rows = []
    for clip_name in names:
        clip = read_davis_clip(root, clip_name, max_frames=max_frames)
        error = ""
        t0 = time.perf_counter()
        points: TrackPoints | None = None
        try:
            given = run(clip, mode)
            labels = given.labels if isinstance(given, MethodOutput) else given
            points = given.points if isinstance(given, MethodOutput) else None
        except MosegError as exc:
            error = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            labels = np.full(clip.gt.shape, UNKNOWN, dtype=np.uint8)
            log.warning("%s: %s", clip_name, error)
        seconds = time.perf_counter() - t0
        if labels.shape != clip.gt.shape:
            raise ValueError(f"method {name!r} gave labels {labels.shape} for {clip_name} {clip.gt.shape}")
        scores = score_clip(labels, clip.gt, points)
        row = DavisRow(
            clip=clip_name,
            part=davis_part(clip_name),
            frames=clip.num_frames,
            j_mean=scores["j_mean"],
            j_recall=scores["j_recall"],
            j_decay=scores["j_decay"],
            f_mean=scores["f_mean"],
            f_recall=scores["f_recall"],
            f_decay=scores["f_decay"],
            best_label_j=scores["best_label_j"],
            k=int(scores["k"]),
            seconds=seconds,
            error=error,
            world_off=scores["world_off"],
            majority_j=scores["majority_j"],
            labels=int(scores["labels"]),
            switches=int(scores["switches"]),
            fp_share=scores["fp_share"],
            miss_share=scores["miss_share"],
            bg_tracks_moving=scores["bg_tracks_moving"],
        )
        log.info("%s: J %.3f F %.3f (%.1f s)", clip_name, row.j_mean, row.f_mean, seconds)
        rows.append(row)
    return DavisReport(mode=mode, method=name, rows=rows, means=summarize_rows(rows))


def _fmt(value: float | int | str) -> str:
    if isinstance(value, float):
        return "nan" if math.isnan(value) else f"{value:.3f}"
    return str(value)


def format_table(report: DavisReport) -> str:
    """A plain-text table: one line per clip, then the dev / val / all means; failures listed below."""
    head = "clip|part|T|J|J rec|J dec|F|F rec|F dec|best-lbl J|world off|majority J|FP|miss|bg trk mov|K|labels|switches|s".split(
        "|"
    )
    lines = [[r.clip, r.part, str(r.frames)] + [_fmt(getattr(r, n)) for n in SCORE_FIELDS] for r in report.rows]
    for part, m in report.means.items():
        label = f"mean {part} ({int(m['clips'])}; world off {int(m['world_off_clips'])})"
        lines.append(
            [label, "", ""] + [f"{m[n]:.3f}" if n not in ("k", "labels") else f"{m[n]:.2f}" for n in SCORE_FIELDS]
        )
    widths = [max(len(h), *(len(row[i]) for row in lines)) for i, h in enumerate(head)]
    out = [f"DAVIS-2016 {report.mode}, method {report.method}"]
    out.append("  ".join(h.ljust(w) if i < 2 else h.rjust(w) for i, (h, w) in enumerate(zip(head, widths))))
    n_clips = len(report.rows)
    for i, row in enumerate(lines):
        if i == n_clips:
            out.append("-" * len(out[1]))
        out.append("  ".join(c.ljust(w) if j < 2 else c.rjust(w) for j, (c, w) in enumerate(zip(row, widths))))
    out += [f"failed: {r.clip}: {r.error}" for r in report.rows if r.error]
    return "\n".join(out)
