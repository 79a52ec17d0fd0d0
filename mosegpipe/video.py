"""Whole videos: consecutive F-frame windows, streamed, with motion labels kept consistent across windows.

Windows share their boundary frame (window w covers frames w(F-1) .. w(F-1)+F-1) and the tracker
re-seeds corners at every window start, so tracks run on from one window into the next. A window's
clusters take the global label of the previous window's cluster they share most tracks with
(Hungarian matching on the overlap counts); a cluster that matches nothing starts a new global label.

Memory: only the current window's frames (at most F images) are held; what grows with the video
is one small row per window (track ids and labels for labels.npz, a few KB) and the per-track
trails the recorder keeps for live tracks only.
"""

from __future__ import annotations

import logging
import time
from contextlib import ExitStack
from dataclasses import asdict, dataclass, field, replace
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
from mosegpipe.masks import MAX_LABEL, labels_to_mask
from mosegpipe.model import SubspaceNet
from mosegpipe.pipeline import (
    SUMMARY_SCHEMA,
    PipelineConfig,
    _embed,
    _model_info,
    _frames,
    _OutputDir,
    check_output_dir,
    decode_errors,
    load_model,
    overlay_image,
)
from mosegpipe.track import KLTTracker
from mosegpipe.types import Trajectories

log = logging.getLogger(__name__)

_FALLBACK_FPS = 10.0  # frame folders carry no rate; the overlay video needs one
_MIN_SHARE = 0.5  # a cluster continues a global label only if most of its shared tracks carried it


@dataclass
class LabelBook:
    """Global motion labels across windows, with reuse once the uint8 mask range is spent.

    Attributes:
        next_label: the next never-used label.
        last_window: label -> the last window that used it.
        num_reused: how many times a label was handed out again (only after 255 labels).
        max_label: largest label a mask can hold (mask value = label + 1 <= 255).
    """

    next_label: int = 0
    last_window: dict[int, int] = field(default_factory=dict)
    num_reused: int = 0
    max_label: int = MAX_LABEL

    def new_label(self, busy: set[int]) -> int:
        """A label for a motion that continues none seen before: the next unused one, else the least
        recently used label that is not in `busy`."""
        if self.next_label <= self.max_label:
            self.next_label += 1
            return self.next_label - 1
        free = [lab for lab in self.last_window if lab not in busy]
        if not free:
            raise InputError(f"more than {self.max_label + 1} motions live at once; masks cannot hold them")
        self.num_reused += 1
        return min(free, key=lambda lab: self.last_window[lab])


def match_labels(
    prev: dict[int, int],
    ids: npt.NDArray[np.int64],
    clusters: npt.NDArray[np.int64],
    k: int,
    book: LabelBook,
    window: int = 0,
) -> npt.NDArray[np.int64]:
    """Maps this window's clusters to global labels through the tracks shared with the previous window.

    Clusters and previous labels are paired by the Hungarian method on their overlap counts
    (maximum total overlap, one-to-one). A pair is kept only when at least half of the cluster's
    shared tracks carried that label, so a new object that happens to share a few mislabelled
    tracks with an old one does not inherit its label.

    Args:
        prev: track id -> global label from the previous labelled window.
        ids: (N,) int64 track ids of this window's trajectories.
        clusters: (N,) int64 cluster of each, in 0..k-1.
        k: number of clusters in this window.
        book: the global label state (updated).
        window: index of this window (for least-recently-used label reuse).

    Returns:
        (N,) int64 global labels.
    """
    old = np.array([prev.get(int(i), -1) for i in ids], dtype=np.int64)
    shared = old >= 0
    mapping: dict[int, int] = {}
    if shared.any():
        olds = np.unique(old[shared])
        overlap = np.zeros((k, olds.size), dtype=np.int64)
        np.add.at(overlap, (clusters[shared], np.searchsorted(olds, old[shared])), 1)
        per_cluster = overlap.sum(axis=1)
        rows, cols = linear_sum_assignment(-overlap)
        for r, c in zip(rows, cols):
            if overlap[r, c] > 0 and overlap[r, c] >= _MIN_SHARE * per_cluster[r]:
                mapping[int(r)] = int(olds[c])
    busy = set(mapping.values()) | set(prev.values())
    for c in range(k):
        if c not in mapping:
            mapping[c] = book.new_label(busy)
            busy.add(mapping[c])
    for lab in mapping.values():
        book.last_window[lab] = window
    return np.array([mapping[int(c)] for c in clusters], dtype=np.int64)


class _OverlayVideo:
    """MJPG .avi of overlay frames, opened on the first frame (its size is not known before)."""

    def __init__(self, path: Path, fps: float) -> None:
        self.path = path
        self.fps = fps
        self._writer: cv2.VideoWriter | None = None

    def write(self, rgb: npt.NDArray[np.uint8]) -> None:
        if self._writer is None:
            size_wh = (rgb.shape[1], rgb.shape[0])
            self._writer = cv2.VideoWriter(str(self.path), cv2.VideoWriter_fourcc(*"MJPG"), self.fps, size_wh)
            if not self._writer.isOpened():
                raise OSError(f"{self.path}: OpenCV could not open an MJPG video writer")
        self._writer.write(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))

    def __enter__(self) -> _OverlayVideo:
        return self

    def __exit__(self, *exc: Any) -> None:
        if self._writer is not None:
            self._writer.release()


_Frame = tuple[int, npt.NDArray[np.uint8], npt.NDArray[np.int64], npt.NDArray[np.float32]]


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

    Output folder (built atomically; see docs/OUTPUTS.md): masks/NNNNNN.png for every frame (palette
    PNG, value = global motion label + 1, 0 = unknown), overlay.avi (MJPG), labels.npz, summary.json
    and recording.rrd.

    Args:
        path: video file or frame folder.
        out_dir: output folder.
        cfg: pipeline settings; cfg.frames is the window length F (>= 2).
        model: the model (None = shipped default for cfg.frames).
        overwrite: replace an existing moseg output folder.
        rrd: also write a Rerun recording (frames downscaled to keep it small).
        max_frames: stop after this many frames (None = whole video).

    Returns:
        The summary dict written to summary.json.

    Raises:
        InputError: unreadable input, fewer than F frames, F < 2 or max_frames < 1.
        TooFewTracksError: no window had cfg.min_tracks tracks through all its frames.
        OutputExistsError: out_dir holds results and overwrite is False.
    """
    f = cfg.frames
    if f < 2:
        raise InputError(f"--frames {f}: whole-video mode needs windows of at least 2 frames")
    if max_frames is not None and max_frames < 1:
        raise InputError(f"--max-frames {max_frames} must be >= 1")
    check_output_dir(out_dir, overwrite)
    model = model or load_model(f)
    with decode_errors(path):
        info = video_info(path)
    fps = float(info.get("fps") or 0.0) or _FALLBACK_FPS
    tracker = KLTTracker(replace(cfg.track, reseed=True, reseed_every=f - 1))
    palette = default_palette()
    book = LabelBook()
    t_start = time.perf_counter()
    windows: list[dict[str, Any]] = []
    label_ids: list[npt.NDArray[np.int64]] = []
    label_vals: list[npt.NDArray[np.int64]] = []
    label_win: list[npt.NDArray[np.int64]] = []
    prev: dict[int, int] = {}
    num_frames = 0

    with _OutputDir(Path(out_dir), overwrite) as tmp:
        (tmp / "masks").mkdir()
        with ExitStack() as stack:
            overlay = stack.enter_context(_OverlayVideo(tmp / "overlay.avi", fps))
            recorder = None
            if rrd:
                from mosegpipe.viz import VideoRecorder

                recorder = stack.enter_context(VideoRecorder(tmp / "recording.rrd"))

            def label_window(window: list[_Frame]) -> dict[int, int]:
                """Clusters the tracks live through the whole window; returns track id -> global label."""
                nonlocal prev
                common = window[0][2]
                for _, _, ids, _ in window[1:]:
                    common = np.intersect1d(common, ids)
                k = 0
                labels_by_id: dict[int, int] = {}
                if common.size >= max(cfg.min_tracks, 2):
                    data = np.concatenate([xy[np.searchsorted(ids, common)] for _, _, ids, xy in window], axis=1)
                    emb = _embed(model, Trajectories(data=data.astype(np.float32), track_ids=common))
                    forced = None if cfg.k is None else min(cfg.k, common.size)
                    clustering = cluster_auto_k(emb, cfg.cluster, k=forced)
                    k = clustering.k
                    glob = match_labels(prev, common, clustering.labels, k, book, len(windows))
                    labels_by_id = {int(i): int(g) for i, g in zip(common, glob)}
                    label_ids.append(common)
                    label_vals.append(glob)
                    label_win.append(np.full(common.size, len(windows), dtype=np.int64))
                    prev = labels_by_id
                else:
                    log.warning("frames %d-%d: only %d tracks; left unlabelled", window[0][0], window[-1][0], common.size)
                log.info("frames %d-%d: %d tracks, K = %d", window[0][0], window[-1][0], common.size, k)
                windows.append({"start": window[0][0], "frames": len(window), "num_tracks": int(common.size), "k": k})
                return labels_by_id

            def write_frames(window: list[_Frame], labels_by_id: dict[int, int]) -> None:
                for t, img, ids, xy in window:
                    lab = np.array([labels_by_id.get(int(i), -1) for i in ids], dtype=np.int64)
                    keep = lab >= 0
                    mask = labels_to_mask(xy[keep], lab[keep], img.shape[:2], cfg.mask)
                    write_palette_png(tmp / "masks" / f"{t:06d}.png", mask, palette)
                    overlay.write(overlay_image(img, mask, xy[keep], lab[keep]))
                    if recorder is not None:
                        recorder.log_frame(t, img, xy[keep], ids[keep], lab[keep], mask)

            window: list[_Frame] = []
            frames_iter = iter_video(path, max_frames=max_frames)
            while True:
                with decode_errors(path):
                    item = next(frames_iter, None)
                if item is None:
                    break
                t, frame = item
                ids, xy = tracker.step(frame)
                window.append((t, frame, ids, xy))
                num_frames += 1
                if len(window) == f:
                    first = not windows
                    labels_by_id = label_window(window)
                    # Later windows start on the previous one's last frame, written with its labels.
                    write_frames(window if first else window[1:], labels_by_id)
                    window = [window[-1]]
            if not windows:
                raise InputError(f"{path}: only {_frames(num_frames)} could be read; --frames needs {f}")
            if len(window) > 1:
                write_frames(window[1:], label_window(window))
        if not label_ids:
            raise TooFewTracksError(
                f"{path}: no window had at least {cfg.min_tracks} tracks through its {f} frames (textureless video?)"
            )
        claimed = info.get("num_frames")
        if max_frames is None and info["kind"] == "video" and claimed and num_frames < claimed:
            log.warning("%s: decoding stopped after %d of the %d frames the header lists", path, num_frames, claimed)
        write_npz(
            tmp / "labels.npz",
            track_ids=np.concatenate(label_ids),
            labels=np.concatenate(label_vals),
            window=np.concatenate(label_win),
        )
        seconds = time.perf_counter() - t_start
        summary = {
            "schema": SUMMARY_SCHEMA,
            "kind": "video",
            "source": str(path),
            "version": __version__,
            "frames": num_frames,
            "size_hw": list(info["size_hw"]),
            "video_fps": float(info.get("fps") or 0.0),
            "window_frames": f,
            "num_windows": len(windows),
            "num_windows_labelled": len(label_ids),
            "num_motions": book.next_label,
            "num_labels_reused": book.num_reused,
            "k_method": "fixed" if cfg.k is not None else cfg.cluster.method,
            "windows": windows,
            "seconds": round(seconds, 3),
            "processing_fps": round(num_frames / seconds, 3) if seconds > 0 else 0.0,
            "model": _model_info(model),
            "config": asdict(cfg),
        }
        write_json(tmp / "summary.json", summary)
    return summary
