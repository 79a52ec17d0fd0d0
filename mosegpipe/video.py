"""Whole videos: consecutive F-frame windows, streamed, with motion labels kept consistent across windows.

Windows share their boundary frame (window w covers frames w(F-1) .. w(F-1)+F-1) and the tracker
re-seeds corners at every window start, so tracks run on from one window into the next. A window's
clusters take the global label of the previous window's cluster they share most tracks with
(Hungarian matching on the overlap counts); a cluster that matches nothing starts a new global label.
Only the current window's frames are held in memory, so memory stays flat in video length.
"""

from __future__ import annotations

import logging
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt
from scipy.optimize import linear_sum_assignment

from mosegpipe import __version__
from mosegpipe.cluster import cluster_auto_k
from mosegpipe.errors import InputError, TooFewTracksError
from mosegpipe.io import default_palette, iter_video, video_info, write_json, write_npz, write_palette_png
from mosegpipe.masks import labels_to_mask
from mosegpipe.model import SubspaceNet
from mosegpipe.pipeline import PipelineConfig, _embed, _model_info, _OutputDir, overlay_image
from mosegpipe.track import KLTTracker
from mosegpipe.types import Trajectories

log = logging.getLogger(__name__)


def match_labels(
    prev: dict[int, int], ids: npt.NDArray[np.int64], clusters: npt.NDArray[np.int64], k: int, next_label: int
) -> tuple[npt.NDArray[np.int64], int]:
    """Maps this window's clusters to global labels through the tracks shared with the previous window.

    Args:
        prev: track id -> global label from the previous window.
        ids: (N,) track ids of this window's trajectories.
        clusters: (N,) cluster of each, in 0..k-1.
        k: number of clusters in this window.
        next_label: the first unused global label.

    Returns:
        ((N,) global labels, updated next_label).
    """
    old = np.array([prev.get(int(i), -1) for i in ids], dtype=np.int64)
    shared = old >= 0
    mapping: dict[int, int] = {}
    if shared.any():
        olds = np.unique(old[shared])
        overlap = np.zeros((k, olds.size), dtype=np.int64)
        for c, o in zip(clusters[shared], old[shared]):
            overlap[c, np.searchsorted(olds, o)] += 1
        rows, cols = linear_sum_assignment(-overlap)
        for r, c in zip(rows, cols):
            if overlap[r, c] > 0:
                mapping[int(r)] = int(olds[c])
    for c in range(k):
        if c not in mapping:
            mapping[c] = next_label
            next_label += 1
    return np.array([mapping[int(c)] for c in clusters], dtype=np.int64), next_label


def segment_video(
    path: str | Path,
    out_dir: str | Path,
    cfg: PipelineConfig = PipelineConfig(),
    model: SubspaceNet | None = None,
    overwrite: bool = False,
    rrd: bool = True,
    max_frames: int | None = None,
) -> dict[str, Any]:
    """Segments a whole video window by window and writes masks, overlay video, labels, summary (and .rrd).

    Args:
        path: video file or frame folder.
        out_dir: output folder (built atomically).
        cfg: pipeline settings; cfg.frames is the window length F (>= 2).
        model: the model (None = shipped default for cfg.frames).
        overwrite: replace an existing output folder.
        rrd: also write a Rerun recording (frames downscaled to keep it small).
        max_frames: stop after this many frames (None = whole video).

    Returns:
        The summary dict written to summary.json.
    """
    from mosegpipe.pipeline import load_model

    f = cfg.frames
    if f < 2:
        raise InputError(f"--frames {f}: whole-video mode needs windows of at least 2 frames")
    model = model or load_model(f)
    info = video_info(path)
    fps = float(info.get("fps") or 0.0) or 10.0
    tracker = KLTTracker(replace(cfg.track, reseed=True, reseed_every=f - 1))
    palette = default_palette()
    t_start = time.perf_counter()
    with _OutputDir(Path(out_dir), overwrite) as tmp:
        (tmp / "masks").mkdir()
        writer: cv2.VideoWriter | None = None
        recorder = None
        if rrd:
            from mosegpipe.viz import VideoRecorder

            recorder = VideoRecorder(tmp / "recording.rrd")
        window: list[tuple[int, npt.NDArray[np.uint8], npt.NDArray[np.int64], npt.NDArray[np.float32]]] = []
        prev: dict[int, int] = {}
        next_label = 0
        windows: list[dict[str, Any]] = []
        label_ids: list[npt.NDArray[np.int64]] = []
        label_vals: list[npt.NDArray[np.int64]] = []
        label_win: list[npt.NDArray[np.int64]] = []
        num_frames = 0

        def flush(frames_in_window: list[Any], first_written: bool) -> None:
            nonlocal next_label, prev, writer
            common = frames_in_window[0][2]
            for _, _, ids, _ in frames_in_window[1:]:
                common = np.intersect1d(common, ids)
            labels_by_id: dict[int, int] = {}
            k = 0
            if common.size >= max(cfg.min_tracks, 2):
                cols = []
                for _, _, ids, xy in frames_in_window:
                    cols.append(xy[np.searchsorted(ids, common)])
                data = np.concatenate(cols, axis=1).astype(np.float32)
                traj = Trajectories(data=data, track_ids=common)
                emb = _embed(model, traj)
                k_forced = None if cfg.k is None else min(cfg.k, common.size)
                clustering = cluster_auto_k(emb, cfg.cluster, k=k_forced)
                k = clustering.k
                glob, next_label = match_labels(prev, common, clustering.labels, k, next_label)
                labels_by_id = {int(i): int(g) for i, g in zip(common, glob)}
                label_ids.append(common)
                label_vals.append(glob)
                label_win.append(np.full(common.size, len(windows), dtype=np.int64))
            else:
                log.warning("window at frame %d: only %d tracks; left unlabelled", frames_in_window[0][0], common.size)
            windows.append({"start": frames_in_window[0][0], "num_tracks": int(common.size), "k": k})
            prev = labels_by_id or prev
            for j, (t, img, ids, xy) in enumerate(frames_in_window):
                if j == 0 and first_written:
                    continue
                lab = np.array([labels_by_id.get(int(i), -1) for i in ids], dtype=np.int64)
                keep = lab >= 0
                mask = labels_to_mask(xy[keep], lab[keep], img.shape[:2], cfg.mask)
                write_palette_png(tmp / "masks" / f"{t:06d}.png", mask, palette)
                over = overlay_image(img, mask, xy[keep], lab[keep])
                if writer is None:
                    writer = cv2.VideoWriter(
                        str(tmp / "overlay.avi"), cv2.VideoWriter_fourcc(*"MJPG"), fps, (img.shape[1], img.shape[0])
                    )
                writer.write(cv2.cvtColor(over, cv2.COLOR_RGB2BGR))
                if recorder is not None:
                    recorder.log_frame(t, img, xy[keep], ids[keep], lab[keep], mask)

        written_any = False
        for t, frame in iter_video(path, max_frames=max_frames):
            ids, xy = tracker.step(frame)
            window.append((t, frame, ids, xy))
            num_frames += 1
            if len(window) == f:
                flush(window, written_any)
                written_any = True
                window = [window[-1]]
        if not written_any:
            raise InputError(f"{path}: only {num_frames} frames, --frames needs {f}")
        if len(window) > 1:
            flush(window, True)
        if writer is not None:
            writer.release()
        if recorder is not None:
            recorder.close()
        if not label_ids:
            raise TooFewTracksError(f"{path}: no window had at least {cfg.min_tracks} tracks (textureless video?)")
        write_npz(
            tmp / "labels.npz",
            track_ids=np.concatenate(label_ids),
            labels=np.concatenate(label_vals),
            window=np.concatenate(label_win),
        )
        seconds = time.perf_counter() - t_start
        summary = {
            "schema": "mosegpipe.summary/1",
            "kind": "video",
            "source": str(path),
            "version": __version__,
            "frames": num_frames,
            "window_frames": f,
            "num_windows": len(windows),
            "num_motions": next_label,
            "windows": windows,
            "seconds": round(seconds, 3),
            "fps": num_frames / seconds if seconds > 0 else 0.0,
            "model": _model_info(model),
        }
        write_json(tmp / "summary.json", summary)
    return summary
