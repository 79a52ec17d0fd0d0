"""Training clips made by the pipeline's own front end, labelled from the benchmarks' ground truth.

The benchmark trajectories are not what the tool meets: KT3DMoSeg's labelled tracks sit on an 8 px
seeding grid and cover some surfaces only, AdelaideRMF's correspondences are a curated set with a
fixed share of gross outliers. A model fitted to those point sets falls apart on our own tracks,
whose density and coverage differ (the context normalisation sees different statistics). Here the
benchmark images go through our own KLT tracker / SIFT matcher, and our points take labels from the
ground truth by motion agreement (`mosegpipe.evaluation.label_transfer`); points that cannot be
labelled reliably keep label -1: they enter the context normalisation but not the loss.

Tracking every window is slow next to training (about 0.3 s per 5-frame KT3DMoSeg window), so the
labelled points are cached on disk, one file per sequence / pair, under a folder named by a hash of
everything they depend on (front-end settings, transfer settings, frame count, format version).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import os
from collections.abc import Callable, Collection
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from mosegpipe.data.labels import remap_labels
from mosegpipe.evaluation.label_transfer import (
    PairTransferConfig,
    TrackTransferConfig,
    transfer_match_labels,
    transfer_track_labels,
)
from mosegpipe.io import write_npz
from mosegpipe.match import MatchConfig, match_sift
from mosegpipe.track import TrackConfig, track_klt
from mosegpipe.trajectories import build_trajectories
from mosegpipe.types import Frames, LabeledClip

log = logging.getLogger(__name__)

CACHE_VERSION = 1
"""Bumped whenever the cached content changes meaning; part of every cache key."""

MIN_LABELLED = 10
"""A window with fewer labelled points than this teaches nothing and is left out."""


def default_cache_dir() -> Path:
    """`$MOSEG_CACHE`, else `~/.cache/mosegpipe` (the tracked windows of the benchmarks)."""
    env = os.environ.get("MOSEG_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "mosegpipe"


def cache_key(kind: str, **settings: Any) -> str:
    """A short stable hash of a cache's kind, format version and settings (dataclasses included)."""
    plain = {
        k: dataclasses.asdict(v) if dataclasses.is_dataclass(v) and not isinstance(v, type) else v
        for k, v in settings.items()
    }
    blob = json.dumps({"kind": kind, "version": CACHE_VERSION, **plain}, sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:12]


def _load_or_build(path: Path, build: Callable[[], dict[str, npt.NDArray[Any]]]) -> dict[str, npt.NDArray[Any]]:
    """The cached arrays at `path`, built (and written atomically) first when missing."""
    if path.exists():
        with np.load(path) as z:
            return {k: z[k] for k in z.files}
    arrays = build()
    write_npz(path, **arrays)
    return arrays


def kt3d_own_clips(
    data_root: str | Path,
    frames: int = 5,
    exclude: Collection[str] = (),
    track: TrackConfig = TrackConfig(),
    transfer: TrackTransferConfig = TrackTransferConfig(),
    cache_dir: str | Path | None = None,
) -> list[LabeledClip]:
    """Our KLT tracks of every F-frame window of the KT3DMoSeg sequences, labelled by motion agreement.

    Args:
        data_root: the data folder holding ``kt3dmoseg/``.
        frames: F, frames per window (every start is used, stride 1).
        exclude: sequence names to leave out (held-out folds never reach training).
        track: KLT settings (the pipeline's defaults: what `moseg run` produces).
        transfer: label-transfer settings.
        cache_dir: where tracked windows are cached (None = `default_cache_dir()`).

    Returns:
        LabeledClips named "<sequence>/f<a>-<b>" with traj (N, 2F) float32 pixels and labels (N,)
        int64: 0 = background (camera motion), 1.. = the sequence's objects, -1 = not labelled
        (context only). Windows with fewer than MIN_LABELLED labelled points are left out.

    Raises:
        DatasetError: the KT3DMoSeg folder is missing or malformed.
    """
    from mosegpipe.data.kt3dmoseg import kt3d_frame_paths, list_kt3d_sequences, read_kt3d_sequence
    from mosegpipe.io import read_image

    folder = (
        Path(cache_dir or default_cache_dir())
        / f"kt3d-own-f{frames}-{cache_key('kt3d-own', frames=frames, track=track, transfer=transfer)}"
    )
    clips: list[LabeledClip] = []
    for name in list_kt3d_sequences(data_root):
        if name in exclude:
            continue

        def build(name: str = name) -> dict[str, npt.NDArray[Any]]:
            seq = read_kt3d_sequence(data_root, name)
            images = [read_image(p) for p in kt3d_frame_paths(data_root, name)[: seq.num_frames]]
            out: dict[str, npt.NDArray[Any]] = {}
            for s in range(len(images) - frames + 1):
                tracks = track_klt(Frames(images=np.stack(images[s : s + frames]), source=name), track)
                traj = build_trajectories(tracks, frames=frames)
                window = slice(s, s + frames)
                labels = transfer_track_labels(
                    tracks.xy[traj.track_ids], seq.xy[:, window], seq.visible[:, window], seq.labels, transfer
                )
                out[f"{s}/traj"] = traj.data
                out[f"{s}/labels"] = labels
            log.info("%s: tracked %d windows", name, len(images) - frames + 1)
            return out

        arrays = _load_or_build(folder / f"{name}.npz", build)
        starts = sorted(int(k.split("/")[0]) for k in arrays if k.endswith("/traj"))
        for s in starts:
            labels = arrays[f"{s}/labels"]
            if int((labels >= 0).sum()) < MIN_LABELLED:
                continue
            clips.append(
                LabeledClip(
                    name=f"{name}/f{s + 1}-{s + frames}",
                    traj=arrays[f"{s}/traj"],
                    labels=labels,
                    dataset="kt3d-own",
                    meta={"sequence": name, "start": s},
                )
            )
    return clips


def adelaide_own_clips(
    data_root: str | Path,
    exclude: Collection[str] = (),
    match: MatchConfig = MatchConfig(),
    transfer: PairTransferConfig = PairTransferConfig(),
    cache_dir: str | Path | None = None,
) -> list[LabeledClip]:
    """Our SIFT matches of the AdelaideRMF image pairs, labelled by motion agreement.

    Args:
        data_root: the data folder holding ``adelaidermf/``.
        exclude: pair names to leave out.
        match: SIFT settings (the pipeline's defaults: what `moseg pair` produces).
        transfer: label-transfer settings.
        cache_dir: where matched pairs are cached (None = `default_cache_dir()`).

    Returns:
        One LabeledClip per pair, traj (N, 4) float32 [x1, y1, x2, y2] pixels, labels (N,) int64 with
        gross outliers as group 0 when the pair has any, the motions after them in file order, and -1
        for matches that could not be labelled (context only).
    """
    from mosegpipe.data.adelaidermf import list_adelaide, read_adelaide_pair

    folder = (
        Path(cache_dir or default_cache_dir())
        / f"adelaide-own-{cache_key('adelaide-own', match=match, transfer=transfer)}"
    )
    clips = []
    for name in list_adelaide(data_root):
        if name in exclude:
            continue

        def build(name: str = name) -> dict[str, npt.NDArray[Any]]:
            pair = read_adelaide_pair(data_root, name)
            m = match_sift(pair.img1, pair.img2, match)
            raw = transfer_match_labels(m.xy1, m.xy2, pair.xy1, pair.xy2, pair.labels, transfer)
            labels = np.full(raw.shape, -1, dtype=np.int64)
            known = raw >= 0
            if known.any():
                labels[known] = remap_labels(raw[known])[0]  # file label 0 (outliers) -> group 0
            traj = np.concatenate([m.xy1, m.xy2], axis=1).astype(np.float32)
            return {"traj": traj, "labels": labels}

        arrays = _load_or_build(folder / f"{name}.npz", build)
        if int((arrays["labels"] >= 0).sum()) < MIN_LABELLED:
            continue
        clips.append(
            LabeledClip(
                name=name, traj=arrays["traj"], labels=arrays["labels"], dataset="adelaide-own", meta={"sequence": name}
            )
        )
    return clips
