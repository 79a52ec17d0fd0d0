"""Where the dev composites lose (issue 41): the whole-video pipeline with oracles put in at one stage each.

Rows (each the dev composites in whole-video mode, scored as `moseg eval composite` scores them):

- ``default``: the pipeline as it is.
- ``true-k``: each window's clustering is K-means on the embedding with the true K (the world plus the
  objects that move in that window and carry at least `MIN_TRACKS` of its tracks), no rigid-motion check:
  what the embedding gives when K is right.
- ``true-labels``: each window's tracks take their true group (the world 0, a still object in the world)
  and the masks are made from them by the normal mask stage: the ceiling that the tracks and the mask
  stage allow.
- ``true-pixels``: ``true-labels``, and each pixel written as moving that lies on a moving object takes the
  label most of that object's tracks carry in the frame (the moving pixels unchanged): the ceiling of a
  perfect choice of "which motion" per moving pixel (issue 42's per-motion output), given the moving pixels.

Per row: J per object, objects found, correct K, K written / true, track error, labels per object; then,
over the windows: K chosen by the embedding (before the rigid check) against the true K, the tracks per
moving object, the error of the embedding's K-means with the true K (`kmeans err`) and of its nearest
true centre (`centre err`, how far the embedding separates the groups at all); over the frames: the share
of each moving object's pixels that the motion masks mark moving (`obj moving`), and of the world's
(`world moving`), and the share of each object's pixels written as one of the moving labels.

    python benchmarks/composite_diagnosis.py --data-root /work/shared/data
    python benchmarks/composite_diagnosis.py --rows default,true-k --set cluster.k_max=6
"""

from __future__ import annotations

import argparse
import contextlib
import time
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from typing import Any
from unittest import mock

import numpy as np
import numpy.typing as npt

from mosegpipe.embed.numpy_net import load_embedder
from mosegpipe.evaluation import composite as ev
from mosegpipe.masks import UNKNOWN, WORLD
from mosegpipe.pipeline import PipelineConfig
from mosegpipe.pipeline import video as vid
from mosegpipe.runtime import set_threads
from mosegpipe.synth.composite import Composite, composite_set
from mosegpipe.types import Clustering

ROWS = ("default", "true-k", "true-labels", "true-pixels")
MIN_TRACKS = 3
"""An object counts in a window's true K from this many of the window's tracks."""


@dataclass
class _Probe:
    """What one composite's run records beside its masks."""

    clip: Composite
    row: str
    start: int = 0
    windows: list[dict[str, Any]] = field(default_factory=list)
    moving: dict[int, npt.NDArray[np.bool_]] = field(default_factory=dict)

    def truth(self, points: npt.NDArray[np.float32]) -> npt.NDArray[np.int64]:
        """(N,) true group of each track in the window starting at self.start: its object id when the
        object moves somewhere in the window, else 0 (the world)."""
        ids = self.clip.label_at(self.start, points[:, :2])
        f = points.shape[1] // 2
        mv = self.clip.moving[self.start : self.start + f].any(axis=0)
        moving_ids = {o for o, m in zip(self.clip.object_ids, mv) if m}
        return np.where(np.isin(ids, list(moving_ids)), ids, 0)


def _compact(truth: npt.NDArray[np.int64]) -> tuple[npt.NDArray[np.int64], int]:
    """Groups with >= MIN_TRACKS tracks numbered 0.. (the world first), the rest to the world; and their count."""
    vals, counts = np.unique(truth, return_counts=True)
    kept = [int(v) for v, c in zip(vals, counts) if v == 0 or c >= MIN_TRACKS]
    if 0 not in kept:
        kept = [0, *kept]
    order = {v: i for i, v in enumerate(sorted(kept))}
    return np.array([order.get(int(t), 0) for t in truth], np.int64), len(kept)


def _errors(emb: npt.NDArray[np.float32], truth: npt.NDArray[np.int64], k: int) -> tuple[float, float]:
    """(K-means error with the true K, nearest-true-centre error), percent."""
    from mosegpipe.evaluation.metrics import misclassification_error
    from mosegpipe.group.cluster import fixed_k

    x = np.asarray(emb, np.float64)
    km = fixed_k(x, PipelineConfig().cluster, k).labels if k > 1 else np.zeros(len(x), np.int64)
    centres = np.stack([x[truth == g].mean(axis=0) for g in range(k)])
    nearest = np.argmin(((x[:, None, :] - centres[None]) ** 2).sum(-1), axis=1)
    return 100.0 * misclassification_error(km, truth), 100.0 * float(np.mean(nearest != truth))


@contextlib.contextmanager
def _probed(probe: _Probe) -> Iterator[None]:
    """Patches the whole-video path so that `probe` records each window and puts in its row's oracle."""
    real_cluster_window, real_auto_k, real_rigid = vid._cluster_window, vid.cluster_auto_k, vid.check_rigid
    real_world, real_frame = vid.world_to_zero, vid._labelled_frame

    def cluster_window(window: Any, *args: Any, **kwargs: Any) -> Any:
        probe.start = int(window[0][0])
        return real_cluster_window(window, *args, **kwargs)

    def auto_k(emb: Any, cfg: Any, k: Any = None, points: Any = None, prefer_k: Any = None) -> Clustering:
        truth, k_true = _compact(probe.truth(np.asarray(points)))
        chosen = real_auto_k(emb, cfg, k, points, prefer_k)
        km_err, centre_err = _errors(np.asarray(emb), truth, k_true)
        per_obj = np.bincount(truth, minlength=k_true)[1:]
        probe.windows.append(
            dict(
                k_true=k_true,
                k_auto=chosen.k,
                tracks_obj=per_obj.tolist(),
                km_err=km_err,
                centre_err=centre_err,
                n=len(truth),
            )
        )
        if probe.row == "true-k":
            return real_auto_k(emb, cfg, k_true, points, None)
        if probe.row in ("true-labels", "true-pixels"):
            return Clustering(labels=truth, k=k_true)
        return chosen

    def rigid(clustering: Clustering, *args: Any, **kwargs: Any) -> Clustering:
        return clustering if probe.row != "default" else real_rigid(clustering, *args, **kwargs)

    def world(clustering: Clustering, *args: Any, **kwargs: Any) -> Clustering:
        return clustering if probe.row in ("true-labels", "true-pixels") else real_world(clustering, *args, **kwargs)

    def labelled_frame(item: Any, *args: Any, **kwargs: Any) -> Any:
        frame = real_frame(item, *args, **kwargs)
        if frame.moving is not None:
            probe.moving[int(frame.index)] = frame.moving
        if probe.row == "true-pixels" and frame.mask is not None:
            frame = replace(frame, mask=_true_pixels(probe.clip, frame))
        return frame

    with (
        mock.patch.object(vid, "_cluster_window", cluster_window),
        mock.patch.object(vid, "cluster_auto_k", auto_k),
        mock.patch.object(vid, "check_rigid", rigid),
        mock.patch.object(vid, "world_to_zero", world),
        mock.patch.object(vid, "_labelled_frame", labelled_frame),
    ):
        yield


def _true_pixels(clip: Composite, frame: Any) -> npt.NDArray[np.uint8]:
    """The frame's mask with each moving pixel on a moving object given the label most of its tracks carry."""
    t = int(frame.index)
    gt, mask = clip.masks[t], frame.mask.copy()
    written = (mask != WORLD) & (mask != UNKNOWN)
    under = clip.label_at(t, frame.xy)
    for obj, moves in zip(clip.object_ids, clip.moving[t]):
        labs = frame.labels[(under == obj) & (frame.labels >= 0)]
        if moves and labs.size:
            mask[written & (gt == obj)] = np.bincount(labs).argmax()
    out: npt.NDArray[np.uint8] = mask
    return out


def _pixel_shares(clip: Composite, masks: npt.NDArray[np.uint8], probe: _Probe) -> dict[str, float]:
    """Shares of moving objects' / the world's pixels marked moving, and of objects' pixels written moving."""
    obj_mv, world_mv, obj_written = [], [], []
    for t in range(masks.shape[0]):
        gt = clip.masks[t]
        moving_ids = [o for o, m in zip(clip.object_ids, clip.moving[t]) if m]
        on = np.isin(gt, moving_ids)
        world = ~on
        written = (masks[t] != WORLD) & (masks[t] != UNKNOWN)
        if on.any():
            obj_written.append(float(written[on].mean()))
            if t in probe.moving:
                obj_mv.append(float(probe.moving[t][on].mean()))
        if t in probe.moving and world.any():
            world_mv.append(float(probe.moving[t][world].mean()))
    mean = lambda v: float(np.mean(v)) if v else float("nan")  # noqa: E731
    return {"obj_moving": mean(obj_mv), "world_moving": mean(world_mv), "obj_written": mean(obj_written)}


def run_row(clips: list[Composite], row: str, cfg: PipelineConfig, model: Any) -> dict[str, Any]:
    """One row over the clips: the composite scores' means and the probes' means."""
    scores, windows, shares = [], [], []
    t0 = time.process_time()
    for clip in clips:
        probe = _Probe(clip, row)
        with _probed(probe):
            seg = ev.segment_composite(clip, "whole", cfg, model)
        scores.append(ev.score_clip(clip, seg))
        windows += probe.windows
        shares.append(_pixel_shares(clip, seg.masks, probe))
    out = {key: float(np.nanmean([s[key] for s in scores])) for key in ev.SUMMARY_FIELDS}
    tracks = [n for w in windows for n in w["tracks_obj"]]
    out.update(
        k_auto=float(np.mean([w["k_auto"] for w in windows])),
        k_true_tracks=float(np.mean([w["k_true"] for w in windows])),
        auto_k_right=float(np.mean([w["k_auto"] == w["k_true"] for w in windows])),
        tracks_obj_median=float(np.median(tracks)) if tracks else float("nan"),
        tracks_obj_lt10=float(np.mean(np.array(tracks) < 10)) if tracks else float("nan"),
        tracks_window=float(np.mean([w["n"] for w in windows])),
        km_err=float(np.mean([w["km_err"] for w in windows])),
        centre_err=float(np.mean([w["centre_err"] for w in windows])),
        cpu_s=time.process_time() - t0,
        **{key: float(np.nanmean([s[key] for s in shares])) for key in shares[0]},
    )
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data-root", default=None, help="the DAVIS data root (default: $MOSEG_DATA)")
    parser.add_argument("--part", default="dev", choices=("dev",), help="composites (dev only: choices are made there)")
    parser.add_argument("--rows", default=",".join(ROWS), help=f"rows to run, of {', '.join(ROWS)}")
    parser.add_argument("--names", default=None, help="only these composites, e.g. dev-01,dev-05")
    parser.add_argument("--set", action="append", default=[], help="a pipeline setting, dotted.path=value")
    args = parser.parse_args()
    import os

    set_threads(1)
    root = args.data_root or os.environ.get("MOSEG_DATA")
    cfg = PipelineConfig().with_settings(args.set)
    model = load_embedder(cfg.frames)
    names = args.names.split(",") if args.names else None
    clips = composite_set(root, args.part, names=names)
    head = (
        "| row | J per object | found | correct K | K written / true | track error % | labels / object "
        "| embedding K / true K (tracks) | K right | tracks per object (median, < 10) "
        "| kmeans err % | centre err % | obj moving | world moving | obj written moving |"
    )
    print(head)
    print("|" + "---|" * 15)
    for row in args.rows.split(","):
        if row not in ROWS:
            raise SystemExit(f"--rows {row}: one of {', '.join(ROWS)}")
        m = run_row(clips, row, replace(cfg), model)
        print(
            f"| {row} | {m['j_object']:.3f} | {m['objects_found']:.2f} | {100 * m['correct_k']:.0f} % | "
            f"{m['k_pred']:.1f} / {m['k_true']:.1f} | {m['track_error']:.1f} | {m['labels_per_object']:.2f} | "
            f"{m['k_auto']:.2f} / {m['k_true_tracks']:.2f} | {100 * m['auto_k_right']:.0f} % | "
            f"{m['tracks_obj_median']:.0f}, {100 * m['tracks_obj_lt10']:.0f} % | {m['km_err']:.1f} | "
            f"{m['centre_err']:.1f} | {m['obj_moving']:.2f} | {m['world_moving']:.3f} | {m['obj_written']:.2f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
