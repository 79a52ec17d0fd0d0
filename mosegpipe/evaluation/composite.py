"""Composite protocol (issue 41): several movers in real textures, each scored as an object of its own.

Usage::

    moseg eval composite --out DIR                 # the 10 development composites, whole-video mode
    moseg eval composite --folds val --out DIR     # the 10 validation composites (report once)
    moseg eval composite-clip5 --folds dev-03,dev-07 --out DIR   # first 5 frames as one clip

`--folds` takes a part ("dev", "val", "all") or composite names; the default is "dev". The clips are
`mosegpipe.synth.composite.composite_set` (DAVIS dev clips for dev, val clips for val; 25 frames at
427x240, 2-4 objects, the plate's own object included), written as PNG frames to a temporary folder and
segmented from there as a user's frame folder would be: "composite" with `segment_video` (the masks it
yields are the frames' written masks), "composite-clip5" with `segment_clip` on frames 0-4.

Scores of one clip (`score_clip`), all on the masks as written (0 = the world, 255 = unknown):

- **J per object**: each true object is matched to one written label by the Hungarian method on the IoU
  over the whole clip (sum of intersections over sum of unions); 0 and 255 are never matched to an
  object, and an object left without a label (or with IoU 0) scores 0. An object's J is the mean over
  the clip's frames of DAVIS's region similarity (1 on a frame where neither it nor its label shows).
  `j_object` is the mean over the clip's objects; `objects_found` the share matched at all. This is
  DAVIS-2017's per-video matching (one label per object for the whole video: a label switch costs the
  frames after it); beside it `j_object_frame`, the same with a matching per frame (which forgives
  switches), and `switches_per_object`, the mean over objects of their identity switches
  (`identities.identity_switches`: changes of the moving label covering most of an object, in the frames
  where it shows at least `MIN_SHARE` of the frame and that label more than `LABEL_SHARE` of it).
- **correct K**: per window (the pipeline's windows in whole-video mode, the one clip in clip5 mode),
  the moving labels written (labels other than 0 and 255 covering at least `MIN_SHARE` of the frame in
  one of the window's frames) against the true objects that move in the world in that window and show
  at least as much; `correct_k` is the share of windows where the two are equal, `k_pred` / `k_true`
  their means. A still object (`Composite.moving`) is part of the world while it stands.
- **track error**: each labelled track takes its most frequent label over the frames it was labelled
  in, and the true id under its first position (0 = world); misclassification error (Hungarian,
  `metrics.misclassification_error`) over the clip's tracks, in percent.
- **labels per object**: the moving labels (not 0, not 255) that cover more than `LABEL_SHARE` of an
  object's pixels in some frame where it shows at least `MIN_SHARE` of the frame; mean over the
  objects that got at least one (1 = one identity throughout; objects never found are in J, not here).
"""

from __future__ import annotations

import logging
import tempfile
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe.errors import ConfigError, MosegError
from mosegpipe.evaluation.identities import identity_switches, labels_on_object, match_objects_video, object_j
from mosegpipe.evaluation.metrics import jaccard, misclassification_error
from mosegpipe.masks import UNKNOWN, WORLD

if TYPE_CHECKING:
    from mosegpipe.embed.numpy_net import Embedder
    from mosegpipe.evaluation.records import EvalRequest, EvalResult
    from mosegpipe.pipeline import PipelineConfig
    from mosegpipe.synth.composite import Composite

log = logging.getLogger(__name__)

MIN_SHARE = 0.002
"""A label or an object counts in a frame from this share of the frame's pixels (205 px at 427x240)."""

LABEL_SHARE = 0.1
"""A label counts for an object (labels per object) when it covers more than this share of its pixels."""

COMPOSITE_MODES = {"composite": "whole", "composite-clip5": "clip5"}
"""`moseg eval` protocol name -> mode."""

CLIP_FRAMES = 5
"""Frames of a clip5 run."""


# ---------------------------------------------------------------------------------------------
# Scores


def _moving_labels(pred: npt.NDArray[np.uint8]) -> npt.NDArray[np.int64]:
    vals = np.unique(pred)
    return vals[(vals != WORLD) & (vals != UNKNOWN)].astype(np.int64)


def match_objects(pred: npt.ArrayLike, gt: npt.ArrayLike, object_ids: Sequence[int]) -> dict[int, int | None]:
    """Each true object to one written label, by the Hungarian method on the IoU over the clip.

    Args:
        pred: (T, H, W) uint8 written labels, 0 = world, 255 = unknown (neither is ever matched).
        gt: (T, H, W) int true ids, 0 = world.
        object_ids: the true objects (ids in gt).

    Returns:
        {object id: label or None}: None when no label is left for it or its IoU with every one left is 0.
    """
    p, g = np.asarray(pred), np.asarray(gt)
    if p.shape != g.shape:
        raise ValueError(f"pred has shape {p.shape} but gt has shape {g.shape}")
    return match_objects_video(p, g, object_ids, ignore=(WORLD, UNKNOWN))


def j_per_object(
    pred: npt.ArrayLike, gt: npt.ArrayLike, object_ids: Sequence[int]
) -> tuple[dict[int, float], dict[int, int | None]]:
    """Mean over frames of each object's J against its matched label (`match_objects`; unmatched: 0).

    Returns:
        ({object id: J}, {object id: label or None}).
    """
    p, g = np.asarray(pred), np.asarray(gt)
    match = match_objects(p, g, object_ids)
    scores = {}
    for oid, lab in match.items():
        if lab is None:
            scores[oid] = 0.0
            continue
        scores[oid] = float(np.mean([jaccard(pf == lab, gf == oid) for pf, gf in zip(p, g)]))
    return scores, match


def labels_per_object(
    pred: npt.ArrayLike,
    gt: npt.ArrayLike,
    object_ids: Sequence[int],
    share: float = LABEL_SHARE,
    min_share: float = MIN_SHARE,
) -> dict[int, int]:
    """How many moving labels each object was given over the clip.

    A label (not 0, not 255) counts for an object when it covers more than `share` of the object's
    pixels in at least one frame where the object shows at least `min_share` of the frame.

    Returns:
        {object id: number of labels} for every object (0: never given a moving label).
    """
    p, g = np.asarray(pred), np.asarray(gt)
    min_px = min_share * g.shape[1] * g.shape[2]
    out = {}
    for oid in object_ids:
        seen: set[int] = set()
        for vals, counts, n in labels_on_object(p, g, oid, min_px):
            seen.update(int(v) for v, c in zip(vals, counts) if v not in (WORLD, UNKNOWN) and c > share * n)
        out[int(oid)] = len(seen)
    return out


def window_k(
    pred: npt.ArrayLike,
    gt: npt.ArrayLike,
    object_ids: Sequence[int],
    moving: npt.ArrayLike,
    windows: Iterable[tuple[int, int]],
    min_share: float = MIN_SHARE,
) -> list[tuple[int, int]]:
    """(K written, K true) per window.

    Args:
        pred: (T, H, W) written labels.
        gt: (T, H, W) true ids.
        object_ids: the true objects, in the order of `moving`'s columns.
        moving: (T, len(object_ids)) bool, whether each object moves in the world in each frame.
        windows: (first frame, number of frames) each.
        min_share: a label / object counts in a frame from this share of the frame's pixels.

    Returns:
        One (moving labels written, moving objects shown) per window.
    """
    p, g, mv = np.asarray(pred), np.asarray(gt), np.asarray(moving, dtype=bool)
    min_px = min_share * g.shape[1] * g.shape[2]
    out = []
    for start, n in windows:
        written: set[int] = set()
        true: set[int] = set()
        for t in range(start, start + n):
            vals, counts = np.unique(p[t], return_counts=True)
            written.update(int(v) for v, c in zip(vals, counts) if v not in (WORLD, UNKNOWN) and c >= min_px)
            for i, oid in enumerate(object_ids):
                if mv[t, i] and np.count_nonzero(g[t] == oid) >= min_px:
                    true.add(int(oid))
        out.append((len(written), len(true)))
    return out


def track_error(track_labels: npt.ArrayLike, track_truth: npt.ArrayLike) -> float:
    """Misclassification error of tracks against the true ids under them, in percent (NaN: no track).

    Args:
        track_labels: (N,) int, each track's label.
        track_truth: (N,) int, the true id under each track's first position (0 = world).
    """
    lab, tru = np.asarray(track_labels, dtype=np.int64), np.asarray(track_truth, dtype=np.int64)
    if lab.size == 0:
        return float("nan")
    return 100.0 * misclassification_error(lab, tru)


@dataclass(frozen=True)
class Segmentation:
    """What the pipeline wrote for one composite.

    Attributes:
        masks: (T, H, W) uint8 written labels, 255 = unknown (also for frames it never reached).
        windows: (first frame, frames) of each window (clip5: one).
        track_labels: (N,) int64 each labelled track's label.
        track_first: (N, 3) float64 (frame, x, y) of each of those tracks' first position.
        seconds: wall time of the pipeline.
        error: the MosegError's first line when it failed ("" otherwise).
    """

    masks: npt.NDArray[np.uint8]
    windows: tuple[tuple[int, int], ...]
    track_labels: npt.NDArray[np.int64]
    track_first: npt.NDArray[np.float64]
    seconds: float = 0.0
    error: str = ""


def score_clip(clip: Composite, seg: Segmentation) -> dict[str, Any]:
    """One composite's row: J per object, correct K, track error, labels per object (see the module doc)."""
    t_len = seg.masks.shape[0]
    gt = clip.masks[:t_len]
    moving = clip.moving[:t_len]
    j, match = j_per_object(seg.masks, gt, clip.object_ids)
    ks = window_k(seg.masks, gt, clip.object_ids, moving, seg.windows)
    per = labels_per_object(seg.masks, gt, clip.object_ids)
    given = [n for n in per.values() if n > 0]
    min_px = int(np.ceil(MIN_SHARE * gt.shape[1] * gt.shape[2]))
    j_frame = object_j(seg.masks, gt, clip.object_ids, per_video=False, ignore=(WORLD, UNKNOWN))
    switches = identity_switches(seg.masks, gt, clip.object_ids, min_px, LABEL_SHARE, ignore=(WORLD, UNKNOWN))
    truth = np.array([clip.label_at(int(f), [x, y])[0] for f, x, y in seg.track_first], dtype=np.int64).reshape(-1)
    return {
        "objects": len(clip.object_ids),
        "j_object": float(np.mean(list(j.values()))) if j else float("nan"),
        "j_per_object": " ".join(f"{j[o]:.2f}" for o in clip.object_ids),
        "j_object_frame": float(np.mean(list(j_frame.values()))) if j_frame else float("nan"),
        "switches_per_object": float(np.mean(list(switches.values()))) if switches else float("nan"),
        "objects_found": float(np.mean([m is not None for m in match.values()])) if match else float("nan"),
        "correct_k": float(np.mean([a == b for a, b in ks])) if ks else 0.0,
        "k_pred": float(np.mean([a for a, _ in ks])) if ks else 0.0,
        "k_true": float(np.mean([b for _, b in ks])) if ks else 0.0,
        "track_error": track_error(seg.track_labels, truth),
        "num_tracks": int(seg.track_labels.size),
        "labels_per_object": float(np.mean(given)) if given else float("nan"),
    }


# ---------------------------------------------------------------------------------------------
# Running the pipeline


def _write_frames(folder: Path, frames: npt.NDArray[np.uint8]) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for t, image in enumerate(frames):
        cv2.imwrite(str(folder / f"{t:05d}.png"), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))


def _first_positions(
    labels: dict[int, list[int]], first: dict[int, tuple[int, float, float]]
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float64]]:
    ids = sorted(labels)
    lab = np.array([np.bincount(labels[i]).argmax() for i in ids], dtype=np.int64)
    pos = np.array([first[i] for i in ids], dtype=np.float64).reshape(-1, 3)
    return lab, pos


def segment_composite(clip: Composite, mode: str, cfg: PipelineConfig, model: Embedder) -> Segmentation:
    """Runs the pipeline on a composite written as a PNG frame folder.

    Args:
        clip: the composite.
        mode: "whole" (segment_video over all frames, windows of cfg.frames) or "clip5" (segment_clip
            on frames 0-4; the masks of those frames only).
        cfg: pipeline settings.
        model: the embedder for cfg.frames (whole) or CLIP_FRAMES (clip5).

    Returns:
        Segmentation; on a MosegError every mask is 255, no window or track, and `error` says why.
    """
    from mosegpipe.pipeline import segment_clip, segment_video

    t_len = clip.num_frames if mode == "whole" else min(CLIP_FRAMES, clip.num_frames)
    masks = np.full((t_len, *clip.masks.shape[1:]), UNKNOWN, dtype=np.uint8)
    windows: list[tuple[int, int]] = []
    labels: dict[int, list[int]] = {}
    first: dict[int, tuple[int, float, float]] = {}
    with tempfile.TemporaryDirectory(prefix="moseg-composite-") as tmp:
        folder = Path(tmp) / clip.name
        _write_frames(folder, clip.frames)
        t0 = time.perf_counter()
        try:
            if mode == "whole":
                for window in segment_video(folder, cfg, model):
                    if window.frames:
                        windows.append((window.frames[0].index, len(window.frames)))
                    for fr in window.frames:
                        assert fr.mask is not None
                        masks[fr.index] = fr.mask
                        for tid, xy, lab in zip(fr.track_ids, fr.xy, fr.labels):
                            first.setdefault(int(tid), (fr.index, float(xy[0]), float(xy[1])))
                            if lab >= 0:
                                labels.setdefault(int(tid), []).append(int(lab))
            else:
                result = segment_clip(folder, replace(cfg, frames=t_len, start=0), model)
                masks[:] = result.masks
                windows.append((0, t_len))
                ids = result.trajectories.track_ids
                for tid, xy, lab in zip(ids, result.tracks.xy[ids, 0], result.clustering.labels):
                    first[int(tid)] = (0, float(xy[0]), float(xy[1]))
                    if lab >= 0:
                        labels[int(tid)] = [int(lab)]
        except MosegError as exc:
            seconds = time.perf_counter() - t0
            msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            log.warning("%s: %s", clip.name, msg)
            empty = np.zeros((0, 3), dtype=np.float64)
            return Segmentation(masks, (), np.zeros(0, dtype=np.int64), empty, seconds, msg)
        seconds = time.perf_counter() - t0
    lab, pos = _first_positions(labels, first)
    return Segmentation(masks, tuple(windows), lab, pos, seconds)


_SHORT = {"translation": "trans", "rotation": "rot", "perspective": "persp"}


def _short(kind: str) -> str:
    return "/".join(_SHORT.get(part, part) for part in kind.split("/"))


def composite_rows(
    clips: Sequence[Composite], mode: str, cfg: PipelineConfig, model: Embedder | None = None
) -> list[dict[str, Any]]:
    """The pipeline on each composite, scored: one row per clip (name, plate, kinds, the scores, seconds, error)."""
    from mosegpipe.embed.numpy_net import load_embedder

    net = model or load_embedder(cfg.frames if mode == "whole" else CLIP_FRAMES)
    rows = []
    for clip in clips:
        seg = segment_composite(clip, mode, cfg, net)
        row = {"name": clip.name, "plate": clip.plate, **score_clip(clip, seg), "seconds": seg.seconds}
        row["kinds"] = " ".join(_short(k) for k in clip.kinds)
        row["error"] = seg.error
        log.info("%s: J/object %.3f, correct K %.2f", clip.name, row["j_object"], row["correct_k"])
        rows.append(row)
    return rows


SUMMARY_FIELDS = (
    "j_object",
    "j_object_frame",
    "switches_per_object",
    "objects_found",
    "correct_k",
    "k_pred",
    "k_true",
    "track_error",
    "labels_per_object",
)


def summarize(rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Means over the rows per part ("dev", "val" from the names) and over all (NaN rows left out of a mean)."""
    out: dict[str, Any] = {}
    for part in ("dev", "val", "all"):
        chosen = [r for r in rows if part == "all" or r["name"].startswith(part + "-")]
        if not chosen:
            continue
        m = {}
        for key in SUMMARY_FIELDS:
            vals = [float(r[key]) for r in chosen if not np.isnan(float(r[key]))]
            m[key] = float(np.mean(vals)) if vals else float("nan")
        m.update(clips=len(chosen), failed=sum(bool(r["error"]) for r in chosen))
        m["seconds"] = float(sum(r["seconds"] for r in chosen))
        out[part] = m
    return out


def format_table(rows: Sequence[dict[str, Any]], summary: dict[str, Any], title: str) -> str:
    """A Markdown table: one line per composite, then the means per part."""
    head = "| clip | plate | objects (path kinds) | J per object | J / object (per video / per frame) | switches / object | found | correct K | K written / true | track error % | labels / object | s |"
    lines = [f"### {title}", "", head, "|" + "---|" * 12]
    for r in rows:
        lines.append(
            f"| {r['name']} | {r['plate']} | {r['objects']} ({r['kinds']}) | {r['j_per_object']} | {r['j_object']:.3f} / {r['j_object_frame']:.3f} | "
            f"{r['switches_per_object']:.2f} | "
            f"{r['objects_found']:.2f} | {r['correct_k']:.2f} | {r['k_pred']:.1f} / {r['k_true']:.1f} | "
            f"{r['track_error']:.1f} | {r['labels_per_object']:.2f} | {r['seconds']:.1f} |"
        )
    for part, m in summary.items():
        lines.append(
            f"| **mean {part}** ({m['clips']}, failed {m['failed']}) | | | | **{m['j_object']:.3f}** / {m['j_object_frame']:.3f} | "
            f"{m['switches_per_object']:.2f} | {m['objects_found']:.2f} | "
            f"**{m['correct_k']:.2f}** | {m['k_pred']:.1f} / {m['k_true']:.1f} | **{m['track_error']:.1f}** | "
            f"**{m['labels_per_object']:.2f}** | {m['seconds']:.0f} |"
        )
    lines += [f"\nfailed: {r['name']}: {r['error']}" for r in rows if r["error"]]
    return "\n".join(lines)


def pick_folds(folds: Sequence[str] | None) -> list[tuple[str, list[str] | None]]:
    """--folds -> [(part, names or None = all of the part)]: default dev; "dev", "val", "all" or names."""
    from mosegpipe.synth.composite import composite_names

    chosen = list(folds) if folds else ["dev"]
    out: dict[str, list[str] | None] = {}
    for item in chosen:
        if item == "all":
            out["dev"], out["val"] = None, None
        elif item in ("dev", "val"):
            out[item] = None
        else:
            part = item.split("-", 1)[0]
            if part not in ("dev", "val") or item not in composite_names(part, 100):
                raise ConfigError(f"--folds {item}: not a composite (dev, val, all, or names such as dev-03)")
            if out.get(part, []) is not None:
                out.setdefault(part, []).append(item)  # type: ignore[union-attr]
    return list(out.items())


def run_composite(name: str, req: EvalRequest, cfg: PipelineConfig) -> EvalResult:
    """`moseg eval composite` / `composite-clip5` (`name`): generates the composites of the parts or names
    that --folds picks (default: dev), runs the pipeline with `cfg` on each, writes results.md/csv/json."""
    from mosegpipe.embed.numpy_net import load_embedder
    from mosegpipe.evaluation.records import EvalResult
    from mosegpipe.evaluation.report import write_results
    from mosegpipe.synth.composite import composite_set

    if req.data_root is None:
        raise ConfigError(f"{name} needs the DAVIS clips (--data-root)")
    mode = COMPOSITE_MODES[name]
    model = load_embedder(cfg.frames if mode == "whole" else CLIP_FRAMES, req.model)
    rows: list[dict[str, Any]] = []
    for part, names in pick_folds(req.folds):
        clips = composite_set(req.data_root, part, names=names)
        part_rows = composite_rows(clips, mode, cfg, model)
        rows += part_rows
        if req.progress is not None:
            m = summarize(part_rows)[part]
            req.progress(
                f"{part}: J per object {m['j_object']:.3f} (per frame {m['j_object_frame']:.3f}), correct K {m['correct_k']:.2f}, "
                f"track error {m['track_error']:.1f} %, labels per object {m['labels_per_object']:.2f}"
            )
    summary = summarize(rows)
    config = {
        "protocol": name,
        "mode": mode,
        "frames": cfg.frames,
        "method": cfg.method,
        "mask_method": cfg.mask.method,
        "k_method": req.k_method,
        "k_max": req.k_max,
        "rigid_check": req.rigid_check,
        "points": cfg.tracker,
        "model": str(req.model or "shipped default"),
        "folds": list(req.folds) if req.folds else ["dev"],
        **({"preset": req.preset} if req.preset is not None else {}),
        **({"settings": list(req.settings)} if req.settings else {}),
    }
    table = format_table(rows, summary, f"{name} ({mode})")
    write_results(req.out_dir, rows, summary, config, table)
    return EvalResult(rows, summary, table)
