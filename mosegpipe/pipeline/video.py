"""Whole videos: `segment_video` walks a video as a stream of F-frame window results.

Windows share their boundary frame (window w covers frames w(F-1) .. w(F-1)+F-1) and the tracker
re-seeds corners at every window start, so tracks run on from one window into the next. A window's
clusters take the global label of the previous window's cluster they share most tracks with
(Hungarian matching on the overlap counts); a cluster of new tracks starts a new global label, a
cluster that split off a known motion only once it splits off in two windows running
(`mosegpipe.group.labels`). On a near tie of the automatic-K scores a window keeps the previous
window's K. A shot cut (`_is_cut`) ends a window early and starts tracking afresh. Only the current
window's frames (at most F images) are held.

The steps: `_read_windows` reads and tracks the frames and cuts them into windows, `_label_window`
clusters one window (`_cluster_window`) and labels its frames, `_report_video_end` checks and logs
what the whole run found.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from mosegpipe.embed.numpy_net import Embedder, load_model
from mosegpipe.errors import InputError, TooFewTracksError
from mosegpipe.group.cluster import ClusterConfig, cluster_auto_k
from mosegpipe.group.joint import geometry_supported
from mosegpipe.group.labels import LabelBook, match_labels, small_guard
from mosegpipe.group.refine import group_window
from mosegpipe.io.read import iter_video, video_info
from mosegpipe.masks import (
    MOVING_UNCLUSTERED,
    UNKNOWN,
    WORLD,
    MaskConfig,
)
from mosegpipe.masks.compose import MaskSequence
from mosegpipe.masks.learned.probability import check_mask_networks
from mosegpipe.masks.learned.which import window_features
from mosegpipe.masks.moving_pixels import ColourMemory
from mosegpipe.masks.rigid_tracks import WindowTracks
from mosegpipe.pipeline.common import (
    decode_errors,
    frames_text,
)
from mosegpipe.pipeline.config import PipelineConfig
from mosegpipe.pipeline.merge_back import Aliases, WindowLabels, held_back, merged_back
from mosegpipe.pipeline.resize import dense_sized, shrink_factor, shrunk_stream, small_size
from mosegpipe.pipeline.window import FrameTracks, VideoFrame, WindowResult, at_input_size, frame_mask
from mosegpipe.points.flow import FlowStream, FrameMotion, flow_fits
from mosegpipe.points.klt import KLTTracker, tracks_from_steps
from mosegpipe.points.trajectories import build_trajectories
from mosegpipe.runtime import run_ahead, warnings_held
from mosegpipe.types import FLOW_MASK_METHODS, Trajectories

log = logging.getLogger("mosegpipe.pipeline.video")

MIN_VIDEO_SIDE_PX = 12
"""Smallest frame width and height whole-video mode takes: OpenCV's DIS flow (the motion masks)
refuses a smaller image, and no window of a smaller one holds enough tracks to segment."""


def check_video_settings(cfg: PipelineConfig, max_frames: int | None) -> None:
    """Fails early on settings a whole-video run cannot use.

    Raises:
        InputError: cfg.frames < 2 or max_frames < 1.
        CheckpointError: a mask network the settings ask for cannot be used (`check_mask_networks`).
    """
    if cfg.frames < 2:
        raise InputError(f"--frames {cfg.frames}: whole-video mode needs windows of at least 2 frames")
    if max_frames is not None and max_frames < 1:
        raise InputError(f"--max-frames {max_frames} must be >= 1")
    check_mask_networks(cfg.mask)


def video_frames_to_read(path: str | Path, cfg: PipelineConfig, max_frames: int | None = None) -> int | None:
    """How many frames segment_video will read: for a progress bar's total (None when not known).

    A frame folder knows its length; a video file only what its container header claims (which
    may be wrong for a truncated file: the run then ends early). Unreadable input gives None here:
    segment_video reports it.
    """
    try:
        with decode_errors(path):
            claimed = video_info(path)["num_frames"]
    except InputError:
        return None
    if claimed is None:
        return max_frames
    available = max(0, int(claimed) - cfg.start)
    return available if max_frames is None else min(available, max_frames)


def segment_video(
    path: str | Path,
    cfg: PipelineConfig = PipelineConfig(),
    model: Embedder | None = None,
    max_frames: int | None = None,
    masks: bool = True,
    frames: Iterable[tuple[int, npt.NDArray[np.uint8]]] | None = None,
) -> Iterator[WindowResult]:
    """Segments a whole video window by window, streamed: yields each window as soon as it is labelled.

    Args:
        path: video file or frame folder.
        cfg: pipeline settings; cfg.frames is the window length F (>= 2).
        model: the model (None = shipped default for cfg.frames).
        max_frames: stop after this many frames (None = whole video).
        masks: compute each frame's dense mask; False leaves VideoFrame.mask None for the caller
            to compute with `frame_mask` (e.g. on another thread, as video_outputs.write_video_outputs does),
            except with the motion masks: their labels depend on the frame before's mask (its regions
            that no clustered motion reaches keep the label they had there, `masks.carry_unclustered`, and
            the next window keeps the weaker regions of the motions shown, `MotionMaskConfig.anchor_tracks`),
            so those are always computed here, in order.
        frames: the frames themselves, (index, (H, W, 3) uint8 RGB) in increasing index order, read
            in place of `path`, which then only names the source in messages (a live source:
            mosegpipe.apps.live.run); cfg.start and max_frames do not apply, and the caller checks the frame
            size.

    Yields:
        WindowResult per window, in order; together their `frames` cover every frame read once.

    Raises:
        InputError: unreadable input, frames smaller than MIN_VIDEO_SIDE_PX on a side, fewer than F
            frames, F < 2 or max_frames < 1.
        TooFewTracksError: no window had cfg.min_tracks tracks through all its frames (raised once
            the video is exhausted).

    Only the tracks live through a whole window are clustered; one that ends inside it (leaving the view,
    occluded) keeps the label it had in the window before for its last frames.

    A shot cut (fewer than cfg.video_cut_survival of a frame's tracks survive into the next frame)
    ends the window on the frame before it, however short; tracking restarts on the cut frame
    (`KLTTracker.restart`), which starts the next window (WindowResult.shot_start), so no track and
    no window spans two shots. The motions of the new shot get labels of their own, the dominant one 0.

    Automatic K keeps the previous window's K when that K scores within cfg.cluster.ambiguity_margin of the best
    (`cluster_auto_k`'s prefer_k) and tries K only up to it + cfg.video_k_step. Its ambiguity warning is logged
    once, after the last window ("K was ambiguous in 3 of 40 windows: ..."); each window keeps its note.

    Each window is yielded cfg.labels.merge_back_windows windows after it is labelled: a label born in them
    that merges back into a motion beside it is written as that motion's throughout (`pipeline.merge_back`).
    """
    check_video_settings(cfg, max_frames)
    model = model or load_model(cfg.frames)
    info: dict[str, Any] = {"kind": "stream"}
    if frames is None:
        with decode_errors(path):
            info = video_info(path)
    size_hw = info.get("size_hw")
    if size_hw is not None and min(size_hw) < MIN_VIDEO_SIDE_PX:
        height, width = size_hw
        raise InputError(
            f"{path}: frames of {width}x{height} px are too small to track "
            f"(whole-video mode needs at least {MIN_VIDEO_SIDE_PX}x{MIN_VIDEO_SIDE_PX})"
        )
    if size_hw is not None:  # the dense stage at most at mask.motion.max_side_px (a live stream's size is not known)
        cfg = dense_sized(cfg, small_size(size_hw, shrink_factor(size_hw, cfg.max_side)))
    memory, book = cfg.mask.motion.colour_memory, LabelBook(cfg=cfg.labels)
    colour, named = (ColourMemory(memory) if memory > 0 else None), cfg.labels.name_unclustered
    run = _VideoRun(book, masks=MaskSequence(cfg.mask, True, colour, namer=book if named else None, name_share=named))
    with contextlib.ExitStack() as stack:
        # The motion masks' flows start as each frame is read (FlowStream's threads), and reading runs a
        # window ahead of the clustering and masks (its own thread): the stages overlap on two cores.
        stream = stack.enter_context(FlowStream(cfg.flow)) if cfg.mask.method in FLOW_MASK_METHODS else None
        windows = stack.enter_context(
            contextlib.closing(
                run_ahead(_read_windows(path, cfg, run, max_frames, frames, stream), 1, "moseg-read", strict=True)
            )
        )
        labelled = _labelled(windows, cfg, model, run, masks, stream)
        yield from held_back(labelled, cfg.labels.merge_back_windows, run.aliases)
    _report_video_end(path, cfg, info, run, max_frames)


def _labelled(
    windows: Iterable[tuple[list[FrameTracks], bool, int | None]],
    cfg: PipelineConfig,
    model: Embedder,
    run: _VideoRun,
    masks: bool,
    stream: FlowStream | None,
) -> Iterator[WindowResult]:
    """Each window read (`_read_windows`) labelled and masked (`_label_window`), at the input's size."""
    for window, first_labelled, after in windows:
        result = _label_window(window, first_labelled, cfg, model, run, masks, stream, after)
        yield at_input_size(result, run.originals) if run.originals is not None else result
        del window, result  # from here on its frames live only in the result: a few windows' frames are held


@dataclass
class _VideoRun:
    """What one segment_video run carries from window to window.

    Attributes:
        book: the global labels handed out so far.
        prev: track id -> global label in the last labelled window (a track that ends inside the next
            window keeps its label there).
        prev_k: K of the last labelled window as the embedding found it, before the rigid-motion check
            (the next window's preferred K; 0 = none yet).
        num_windows: windows yielded so far.
        num_labelled: windows labelled so far.
        num_frames: frames read so far (by the reading thread, which runs a window ahead).
        num_done: frames of the windows labelled so far.
        cuts: frames that start a new shot.
        ambiguous: (first, last) frame of each window whose K was ambiguous.
        masks: the video's mask sequence: the last labelled frame's mask (the moving regions no clustered motion
            reached take the label they had there) and the motion masks' colour model of the shot so far.
        frame_before: the frame before the last motion-masked window's last frame (whose flows the stream
            keeps: the next window's first frame takes its flow back to it), or None.
        last: the shot's last labelled window's labels (None: none yet).
        aliases: the labels merged back into others (`pipeline.merge_back`).
    """

    book: LabelBook = field(default_factory=LabelBook)
    prev: dict[int, int] = field(default_factory=dict)
    prev_k: int = 0
    num_windows: int = 0
    num_labelled: int = 0
    num_frames: int = 0
    num_done: int = 0
    cuts: set[int] = field(default_factory=set)
    ambiguous: list[tuple[int, int]] = field(default_factory=list)
    masks: MaskSequence = field(default_factory=lambda: MaskSequence(MaskConfig(), video=True))
    frame_before: int | None = None
    originals: dict[int, npt.NDArray[np.uint8]] | None = None
    last: WindowLabels | None = None
    aliases: Aliases = field(default_factory=Aliases)


def _read_windows(
    path: str | Path,
    cfg: PipelineConfig,
    run: _VideoRun,
    max_frames: int | None,
    frames: Iterable[tuple[int, npt.NDArray[np.uint8]]] | None = None,
    stream: FlowStream | None = None,
) -> Iterator[tuple[list[FrameTracks], bool, int | None]]:
    """Reads and tracks the frames and cuts them into windows, each as soon as it is complete.

    Each frame is handed to `stream` (when given and the frames are large enough for dense flow),
    which starts its flows to and from the frame before at once (not across a shot cut).

    With a `stream`, a full window is held until the next frame is read: its flows to and from the
    window's last frame give that frame the evidence of both directions (FlowConfig.both_directions),
    as the window's other frames have it.

    Yields:
        (the window's frames, whether its first frame was labelled by the window before: windows
        share their boundary frame, except across a shot cut; the index of the frame after the
        window's last in the same shot, whose flows are in `stream`, or None).

    Raises:
        InputError: unreadable input or fewer than cfg.frames frames.
    """
    f = cfg.frames
    tracker = KLTTracker(replace(cfg.track, reseed=True, reseed_every=f - 1))
    window: list[FrameTracks] = []
    first_done = False  # whether window[0] was labelled by the window before (it starts on its last frame)
    held: tuple[list[FrameTracks], bool] | None = None  # a full window waiting for the next frame's flows
    frames_iter = iter_video(path, start=cfg.start, max_frames=max_frames) if frames is None else iter(frames)
    if cfg.max_side is not None:
        run.originals = {}
        frames_iter = shrunk_stream(frames_iter, cfg.max_side, run.originals)
    while True:
        with decode_errors(path):
            item = next(frames_iter, None)
        if item is None:
            break
        t, frame = item
        ids, xy = tracker.step(frame)
        run.num_frames += 1
        if stream is not None and not flow_fits(frame.shape[:2], stream.cfg):
            stream = None
        cut = bool(window) and _is_cut(window[-1][2], ids, cfg)
        if stream is not None:
            stream.add(t, frame if tracker.gray is None else tracker.gray, new_shot=cut)  # the grey KLT made
        if held is not None:
            yield *held, None if cut or stream is None else t
            held = None
        if cut:
            # A shot cut: the window ends on the frame before, a new one starts on this frame with
            # tracks detected afresh (the few that survived the cut landed on unrelated content).
            run.cuts.add(t)
            ids, xy = tracker.restart(frame)
            if not first_done or len(window) > 1:
                yield window, first_done, None
            window, first_done = [], False
        window.append((t, frame, ids, xy))
        if len(window) == f:
            # Later windows start on the previous one's last frame, already labelled there.
            if stream is not None and stream.cfg.both_directions:
                held = (window, first_done)
            else:
                yield window, first_done, None
            window, first_done = [window[-1]], True
    if held is not None:
        yield *held, None
    if run.num_frames < f:
        raise InputError(f"{path}: only {frames_text(run.num_frames)} could be read; --frames needs {f}")
    if not first_done or len(window) > 1:
        yield window, first_done, None


def _is_cut(before: npt.NDArray[np.int64], after: npt.NDArray[np.int64], cfg: PipelineConfig) -> bool:
    """Whether fewer than cfg.video_cut_survival of the track ids `before` (one frame) live on `after`."""
    if cfg.video_cut_survival is None or before.size < 2 * cfg.min_tracks:
        return False
    survived = np.count_nonzero(np.isin(before, after, assume_unique=True))
    return bool(survived < cfg.video_cut_survival * before.size)


def _window_sweep(cfg: PipelineConfig, prev_k: int) -> ClusterConfig:
    """cfg.cluster, trying K only up to the previous window's K + cfg.video_k_step (prev_k 0: no window yet)."""
    sweep = cfg.cluster
    if prev_k and cfg.video_k_step is not None:
        sweep = replace(sweep, k_max=max(sweep.k_min, min(sweep.k_max, prev_k + cfg.video_k_step)))
    return sweep


def _cluster_window(
    window: list[FrameTracks], cfg: PipelineConfig, model: Embedder, run: _VideoRun, motion: FrameMotion | None = None
) -> tuple[npt.NDArray[np.int64], WindowLabels]:
    """Clusters the tracks live through the whole window (by cfg.method) and maps the clusters to global labels,
    the world's motion to 0 (told by where its tracks lie, the window's dense flow `motion` when given, and
    which tracks were the world in the window before: `mosegpipe.group.world`).

    Returns:
        (tracker ids of the tracks live through the whole window, their global labels; k = 0 when
        the window is a single frame or holds fewer than cfg.min_tracks such tracks).
    """
    tracks, row_ids = tracks_from_steps([(ids, xy) for _, _, ids, xy in window], window[0][1].shape[:2])
    traj = build_trajectories(tracks)
    common = row_ids[traj.track_ids]  # tracker ids of the tracks live through the whole window
    if len(window) < 2:
        log.info("frame %d: a shot of one frame; left unlabelled", window[0][0])
        return common, WindowLabels()
    if common.size < max(cfg.min_tracks, 2):
        log.warning("frames %d-%d: only %d tracks; left unlabelled", window[0][0], window[-1][0], common.size)
        return common, WindowLabels()
    forced = None if cfg.k is None else min(cfg.k, common.size)
    before = np.array([run.prev.get(int(i), -1) for i in common], np.int64)
    # automatic K's ambiguity warnings are reported once for the video, not per window
    with warnings_held(logging.getLogger(cluster_auto_k.__module__)):
        grouped = group_window(
            Trajectories(data=traj.data, track_ids=common),
            tracks.size_hw,
            cfg,
            model,
            k=forced,
            sweep=_window_sweep(cfg, run.prev_k),
            prefer_k=run.prev_k or None,
            was_world=before == WORLD,
            known=before >= 0,
            motion=motion,
        )
    clustering, sweep_k = grouped.clustering, grouped.sweep_k  # the next window's preferred K: the embedding's
    glob = np.full(common.size, -1, np.int64)
    kept = clustering.labels >= 0  # method "joint" leaves out the tracks no model explains (-1)
    xy_all = traj.data.reshape(common.size, len(window), 2)
    glob[kept] = match_labels(
        run.prev,
        common[kept],
        clustering.labels[kept],
        clustering.k,
        run.book,
        run.num_windows,
        world=cfg.world.enabled,
        xy=xy_all[kept],
        frame=window[0][0],
        supported=small_rigid(clustering.labels[kept], traj.data[kept], cfg),
    )
    keep = glob >= 0
    found = WindowLabels(clustering.k, clustering.note, dict(clustering.scores), common[keep], glob[keep], xy_all[keep])
    _merge_back(window, found, cfg, run)
    run.prev, run.prev_k, run.last = found.by_id(), sweep_k, found
    run.num_labelled += 1
    return common, found


def _merge_back(window: list[FrameTracks], found: WindowLabels, cfg: PipelineConfig, run: _VideoRun) -> None:
    """The labels of the window before, born within the windows held back, that merged back into another motion
    in `found` (`pipeline.merge_back`) are that motion's from their start: aliased for the held windows, forgotten
    by the label book and the carried mask."""
    held = cfg.labels.merge_back_windows
    if held <= 0 or run.last is None:
        return
    merged = merged_back(run.last, found.track_ids, found.labels, run.book.born, run.num_windows - held, cfg.joint)
    for lab, into in merged.items():
        log.info("frames %d-%d: label %d merged back into %d", window[0][0], window[-1][0], lab, into)
        run.aliases.add(lab, into, window[0][0])
        run.book.retire(lab, into)
    if merged:
        run.masks.last_mask = run.aliases.relabel_mask(run.masks.last_mask, window[0][0])


def small_rigid(labels: npt.NDArray[np.int64], points: npt.NDArray[np.float32], cfg: PipelineConfig) -> list[int]:
    """Method "joint" with cfg.joint.new_rigid_tracks: the moving clusters (not 0) smaller than the label matching's
    guard, of at least that many tracks, that geometry shows to be a rigid motion of their own
    (`joint.geometry_supported`); match_labels labels them whatever their size. Else none."""
    least = cfg.joint.new_rigid_tracks
    if cfg.method != "joint" or least is None or labels.size == 0:
        return []
    sizes = np.bincount(labels, minlength=1)
    guard = small_guard(cfg.labels, labels.size)
    small = [c for c in range(1, sizes.size) if least <= sizes[c] < guard]
    return geometry_supported(points, labels, small, cfg.joint) if small else []


def _label_window(
    window: list[FrameTracks],
    first_labelled: bool,
    cfg: PipelineConfig,
    model: Embedder,
    run: _VideoRun,
    masks: bool,
    stream: FlowStream | None = None,
    after: int | None = None,
) -> WindowResult:
    """Clusters one window and labels its frames (all but the first when the window before labelled that one).

    With the motion masks, the window's flows come from `stream` (handed every frame by `_read_windows`),
    and those between its last frame and the frame `after` it (when not None).
    """
    before = run.prev  # the last labelled window's labels: tracks that end inside this window keep theirs
    if not first_labelled:  # a shot starts here: no mask to carry over, its colours are new, no motion returns
        run.book.forget()
        run.masks.new_shot()
        run.frame_before, run.last = None, None
    motion = None
    if stream is not None and len(window) >= 2 and flow_fits(window[0][1].shape[:2], stream.cfg):
        # a window that starts on the one before's last frame gives that frame the flow back to the frame before it too
        motion = stream.motion([t for t, _, _, _ in window], after=after, before=run.frame_before)
        # the next window starts on this one's last frame and takes the pair before it: the rest is in `motion`
        stream.forget(window[-2][0])
        run.frame_before = window[-2][0]
    common, found = _cluster_window(window, cfg, model, run, motion)
    note = found.note
    log.info(
        "frames %d-%d: %d tracks, K = %d%s", window[0][0], window[-1][0], common.size, found.k, note and f"; {note}"
    )
    by_id = found.by_id()
    skip = 1 if first_labelled else 0
    # each frame's tracks: this window's labels, else the window before's (tracks that end inside it), else -1
    labs = [
        np.array([by_id.get(int(i), before.get(int(i), -1)) for i in ids], np.int64) for _, _, ids, _ in window[skip:]
    ]
    moving, which, motion = _window_pixels(window, skip, labs, cfg, run, motion, found)
    labelled = []
    seen = [(ids, xy) for _, _, ids, xy in window]
    for at, (item, lab, moved) in enumerate(zip(window[skip:], labs, moving), start=skip):
        # the motion masks need the frame before's mask: computed here, in order, whatever `masks` says
        frame = _labelled_frame(item, lab, cfg.mask, masks or moved is not None, moved)
        if frame.mask is not None:
            feats = None if which is None else which[at - skip]
            frame = replace(frame, mask=run.masks.finish(frame.mask, at, seen, lab, motion, feats))
        labelled.append(frame)
    if labelled and labelled[-1].mask is not None:  # the next window starts on this frame: its labels carry on
        run.book.remember_mask(labelled[-1].mask, labelled[-1].index)
    run.num_windows += 1
    run.num_done += len(labelled)
    result = WindowResult(
        start=window[0][0],
        num_frames=len(window),
        num_tracks=int(common.size),
        k=found.k,
        track_ids=found.track_ids,
        labels=found.labels,
        frames=tuple(labelled),
        num_motions=run.book.next_label,
        num_labels_reused=run.book.num_reused,
        num_frames_read=run.num_done,
        k_note=note,
        k_scores=found.scores,
        shot_start=window[0][0] in run.cuts,
    )
    if result.is_k_ambiguous:
        run.ambiguous.append((window[0][0], window[-1][0]))
    return result


def _window_pixels(
    window: list[FrameTracks],
    skip: int,
    labs: list[npt.NDArray[np.int64]],
    cfg: PipelineConfig,
    run: _VideoRun,
    motion: FrameMotion | None,
    found: WindowLabels,
) -> tuple[npt.NDArray[np.bool_] | list[None], npt.NDArray[np.float32] | None, FrameMotion | None]:
    """The moving pixels of frames skip.. of a window (None each without the motion masks' flows), the per-motion
    network's inputs when it has something to choose (`window_features`), and the window's flow evidence (the
    world's parallax explained for the "motion" masks)."""
    moving: npt.NDArray[np.bool_] | list[None] = [None] * (len(window) - skip)
    which = None
    if motion is None:
        return moving, which, motion
    indices = [t for t, _, _, _ in window]
    images = np.stack([img for _, img, _, _ in window])
    shown = _shown_motions(run.masks.last_mask)
    anchors = [(item[3], lab, WORLD, shown) for item, lab in zip(window[skip:], labs)]
    # the world's 3D structure: its parallax is not motion
    parallax = (found.xy, found.labels, cfg.world) if found.track_ids.size else None
    tracks = None
    if labs and run.masks.history is not None:  # the long-span test (MaskConfig.rigid) follows the tracks back
        tracks = WindowTracks(indices, [(ids, xy) for _, _, ids, xy in window], labs[-1], found.track_ids)
    moving, motion = run.masks.moving(images, motion, first=skip, parallax=parallax, anchors=anchors, tracks=tracks)
    which = window_features(images, motion, cfg.mask, labs, skip)
    return moving, which, motion


def _shown_motions(mask: npt.NDArray[np.uint8] | None) -> npt.NDArray[np.int64]:
    """The moving motions a frame's mask shows: its labels but the world, the unclustered and unknown."""
    if mask is None:
        return np.zeros(0, np.int64)
    counts = np.bincount(mask.ravel(), minlength=256)
    counts[np.array([WORLD, MOVING_UNCLUSTERED, UNKNOWN])] = 0
    return np.flatnonzero(counts).astype(np.int64)


def _labelled_frame(
    item: FrameTracks,
    labels: npt.NDArray[np.int64],
    cfg: MaskConfig,
    masks: bool,
    moving: npt.NDArray[np.bool_] | None = None,
) -> VideoFrame:
    """One frame with its tracks' labels and its mask."""
    t, img, ids, xy = item
    frame = VideoFrame(t, img, ids, xy, labels, None, moving)
    return replace(frame, mask=frame_mask(frame, cfg)) if masks else frame


def _report_video_end(
    path: str | Path, cfg: PipelineConfig, info: dict[str, Any], run: _VideoRun, max_frames: int | None
) -> None:
    """Logs the shot cuts, a decoder that stopped early and the windows whose K was ambiguous.

    Raises:
        TooFewTracksError: no window was labelled.
    """
    cuts = sorted(run.cuts)
    if cuts:
        shown = ", ".join(str(c) for c in cuts[:5]) + (f" and {len(cuts) - 5} more" if len(cuts) > 5 else "")
        log.info("shot cuts at frames %s: tracking started afresh there", shown)
    if run.num_labelled == 0:
        raise TooFewTracksError(
            f"{path}: no window had at least {cfg.min_tracks} tracks through its {cfg.frames} frames (textureless video?)"
        )
    claimed = info.get("num_frames")
    if max_frames is None and info["kind"] == "video" and claimed and run.num_frames < claimed - cfg.start:
        log.warning(
            "%s: decoding stopped after %d of the %d frames the header lists", path, cfg.start + run.num_frames, claimed
        )
    if run.ambiguous:
        log.warning(
            "K was ambiguous in %d of %d windows: %s (runner-up within %g; summary.json windows[].k_ambiguous); "
            "pass --k to decide",
            len(run.ambiguous),
            run.num_windows,
            _ranges(run.ambiguous),
            cfg.cluster.ambiguity_margin,
        )


def _ranges(spans: list[tuple[int, int]], shown: int = 3) -> str:
    """`frames 0-4, 8-12, 16-20 and 4 more`: the first `shown` of some (first, last) frame ranges."""
    listed = ", ".join(f"{first}-{last}" for first, last in spans[:shown])
    more = f" and {len(spans) - shown} more" if len(spans) > shown else ""
    return f"frames {listed}{more}"
