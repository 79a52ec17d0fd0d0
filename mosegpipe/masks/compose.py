"""The mask sequence (`MaskSequence`), used by clips, whole videos and live, and its steps after the moving pixels:
moving pixels labelled by the nearest track of a moving motion (`moving_to_labels`), then the steps the flow decides
(`mosegpipe.masks.by_flow`), an unclustered region given its label in the frame before (`carry_unclustered`);
`motion_masks`, a clip's "motion" or "learned" masks."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Protocol

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe.colours import WORLD
from mosegpipe.configs.grouping import WorldConfig
from mosegpipe.group.world import explain_parallax
from mosegpipe.masks.by_flow import common_step, missed_movers, reassign_by_flow, split_unexplained
from mosegpipe.masks.labels import (
    MOVING_UNCLUSTERED,
    UNKNOWN,
    MaskConfig,
    labels_to_mask,
    nearest_labels,
    without_held_regions,
)
from mosegpipe.masks.learned.probability import learned_moving
from mosegpipe.masks.learned.which import which_motion, window_features
from mosegpipe.masks.moving_pixels import Anchors, ColourMemory, moving_from_motion, moving_masks, stack_motion
from mosegpipe.masks.rigid_tracks import RigidTracks, Seen, TrackHistory, WindowTracks, rigid_tracks, static_held
from mosegpipe.masks.scene3d import explain_rigid_scene
from mosegpipe.points.flow import FrameMotion
from mosegpipe.types import Tracks


def label_moving_pixels(
    moving: npt.NDArray[np.bool_],
    xy: npt.NDArray[np.float32],
    labels: npt.NDArray[np.int64],
    background: int,
    new_label: int,
) -> npt.NDArray[np.uint8]:
    """One frame's label image: static pixels get the background label, moving ones a moving motion's.

    A moving pixel takes the label of the nearest track of a motion other than the background (the
    "nearest" partition of those tracks); with no such track in the frame it takes `new_label` (a
    motion the camera fit found that the tracks' clustering did not).

    Args:
        moving: (H, W) bool moving pixels.
        xy: (N, 2) float32 track positions in this frame (pixels).
        labels: (N,) int64 their motion labels (-1 = unlabelled, ignored).
        background: the background motion's label.
        new_label: label for moving pixels when no track of a moving motion is in the frame.

    Returns:
        (H, W) uint8 label image.
    """
    height, width = moving.shape
    out = np.full((height, width), max(background, 0), np.uint8)
    if not moving.any():
        return out
    keep = (labels >= 0) & (labels != background)
    pts = np.round(xy[keep]).astype(np.int64)
    inside = (pts[:, 0] >= 0) & (pts[:, 0] < width) & (pts[:, 1] >= 0) & (pts[:, 1] < height)
    if not inside.any():
        out[moving] = new_label
        return out
    present = np.unique(labels[keep][inside])
    if present.size == 1:  # one moving motion: it is every moving pixel's nearest
        out[moving] = present[0]
        return out
    nearest = nearest_labels(pts[inside], labels[keep][inside].astype(np.uint8), (height, width), np.inf)
    out[moving] = nearest[moving]
    return out


def world_held(
    moving: npt.NDArray[np.bool_],
    xy: npt.NDArray[np.float32],
    labels: npt.NDArray[np.int64],
    background: int,
    share: float,
    min_tracks: int,
) -> npt.NDArray[np.bool_]:
    """`moving` less its regions that the world's tracks hold: the tracks' grouping has the last word on a
    moving region full of tracks it calls static (parallax, a texture the flow gets wrong), in a frame where it
    found a mover of its own (at least `min_tracks` tracks of moving motions; else `moving` as it is).

    Args:
        moving: (H, W) bool moving pixels.
        xy: (N, 2) float32 the frame's track positions, pixels.
        labels: (N,) int64 their labels (-1 = unlabelled, not counted).
        background: the world's label.
        share: least share of a region's labelled tracks that are the world's.
        min_tracks: least number of labelled tracks in the region.

    Returns:
        (H, W) bool (`moving` itself when nothing changes).
    """
    height, width = moving.shape
    ij = np.round(xy).astype(np.int64)
    ok = (labels >= 0) & (ij[:, 0] >= 0) & (ij[:, 0] < width) & (ij[:, 1] >= 0) & (ij[:, 1] < height)
    ok[ok] = moving[ij[ok, 1], ij[ok, 0]]
    movers = (labels >= 0) & (labels != background)
    # a frame whose clustering found no mover of its own is left to the flow (a mover merged into the world)
    if ok.sum() < min_tracks or not (labels[ok] == background).any() or movers.sum() < min_tracks:
        return moving
    return without_held_regions(moving, ij[ok], labels[ok] == background, share, min_tracks)


def carry_unclustered(
    mask: npt.NDArray[np.uint8], previous: npt.NDArray[np.uint8] | None, min_share: float = 0.3
) -> npt.NDArray[np.uint8]:
    """A whole video's frame mask with its MOVING_UNCLUSTERED regions given the moving label they had.

    Each connected region of MOVING_UNCLUSTERED pixels (moving, but no track of a moving motion in
    the frame: the window's clustering merged the object into the background, or its tracks were
    lost) takes the moving label that covers most of it in the frame before, when that label covers at
    least `min_share` of it: an object keeps its identity through the windows where the clustering
    misses it, instead of turning into an anonymous mover. A label counts when it is neither this
    world (WORLD) nor MOVING_UNCLUSTERED or UNKNOWN.

    Args:
        mask: (H, W) uint8 label image of this frame (`moving_to_labels`).
        previous: the frame before's final mask, same shape (None: the first frame of a shot).
        min_share: least share of the region the label must cover in the frame before.

    Returns:
        (H, W) uint8: `mask` itself when nothing changes, else a relabelled copy.
    """
    unclustered = mask == MOVING_UNCLUSTERED
    if previous is None or previous.shape != mask.shape or not unclustered.any():
        return mask
    background = WORLD
    num, regions = cv2.connectedComponents(unclustered.astype(np.uint8), connectivity=8)
    before = previous.astype(np.int64)
    usable = (before != background) & (before != MOVING_UNCLUSTERED) & (before != UNKNOWN) & unclustered
    if not usable.any():
        return mask
    # counts[r, l]: pixels of region r that carried label l in the frame before
    counts = np.zeros((num, 256), np.int64)
    np.add.at(counts, (regions[usable], before[usable]), 1)
    sizes = np.bincount(regions[unclustered], minlength=num)
    best = counts.argmax(axis=1)
    take = counts[np.arange(num), best] >= min_share * np.maximum(sizes, 1)
    take[0] = False  # region 0: the pixels that are not MOVING_UNCLUSTERED
    if not take.any():
        return mask
    out = mask.copy()
    relabel = take[regions] & unclustered
    out[relabel] = best[regions[relabel]].astype(np.uint8)
    return out


def follow_flow(mask: npt.NDArray[np.uint8], backward: npt.NDArray[np.float32], scale: float) -> npt.NDArray[np.uint8]:
    """The frame before's mask moved to this frame along the flow: each pixel takes the label at the end of its
    backward flow (nearest pixel; off the frame, the nearest border pixel).

    Args:
        mask: (H, W) uint8 labels of the frame before.
        backward: (h, w, 2) float32 flow from this frame to the one before, at the flow's scale.
        scale: the flow's scale (h / H).
    """
    height, width = mask.shape
    flow = cv2.resize(backward, (width, height), interpolation=cv2.INTER_LINEAR) / np.float32(scale)
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float32)
    moved: npt.NDArray[np.uint8] = cv2.remap(
        mask, xs + flow[..., 0], ys + flow[..., 1], cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE
    )
    return moved


def _values(mask: npt.NDArray[np.uint8]) -> set[int]:
    """The values a uint8 mask holds."""
    return set(np.flatnonzero(np.bincount(mask.ravel(), minlength=256)).tolist())


class Namer(Protocol):
    """Hands out the labels of the moving regions no clustered motion reaches (`group.labels.LabelBook`)."""

    dense: set[int]

    def dense_label(self) -> int: ...

    def remembered(self) -> dict[int, npt.NDArray[np.float64]]: ...


def name_unclustered(
    mask: npt.NDArray[np.uint8],
    namer: Namer,
    min_share: float,
    previous: npt.NDArray[np.uint8] | None = None,
    gap: float = 0.02,
    gate: float = 0.25,
) -> npt.NDArray[np.uint8]:
    """A whole video's frame mask with each MOVING_UNCLUSTERED region left after `carry_unclustered` given a label of
    its own: a mover the flow shows but no clustered motion reaches (the window found only the world, or its
    cluster was too small to start a label) becomes an identity the next frames carry (`carry_unclustered`) and the
    next window's cluster continues (the new tracks on it read its label off the mask, `group.labels`), instead of
    an anonymous mover that turns into a label of its own a window later.

    Pieces closer than `gap` of the frame's diagonal are one region (a person's limbs). A region takes back a label
    that went missing, the nearest within `gate` of the diagonal: a name the frame before showed and the carry lost
    (a mover that jumped further than its size), or a motion the namer remembers from its last windows that this
    frame does not show (`Namer.remembered`: a rider the grouping gave to the world for a few windows, back in
    view); else a new label.

    Args:
        mask: (H, W) uint8 label image of the frame, after `carry_unclustered`.
        namer: hands out a label no motion holds, knows those it handed out (`LabelBook.dense_label`) and where
            the motions it remembers were last seen (`LabelBook.remembered`).
        min_share: the smallest region named, as a share of the frame's pixels (smaller ones stay unclustered).
        previous: (H, W) uint8 the frame before's mask (as `carry_unclustered` saw it), or None.
        gap, gate: shares of the frame's diagonal.

    Returns:
        (H, W) uint8: `mask` itself when nothing changes, else a relabelled copy.
    """
    unclustered = mask == MOVING_UNCLUSTERED
    if not unclustered.any():
        return mask
    diagonal = math.hypot(*mask.shape)
    radius = max(int(round(gap * diagonal / 2)), 1)
    joined = cv2.dilate(
        unclustered.astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1,) * 2)
    )
    num, regions = cv2.connectedComponents(joined, connectivity=8)
    regions[~unclustered] = 0
    sizes = np.bincount(regions.ravel(), minlength=num)
    big = [r for r in np.argsort(-sizes) if r > 0 and sizes[r] >= min_share * mask.size]
    if not big:
        return mask
    shown = _values(mask)
    # missing label -> where it was last seen: a motion remembered from the last windows, or a name the frame before showed
    lost = {lab: centre for lab, centre in namer.remembered().items() if lab not in shown}
    if previous is not None:
        for lab in (namer.dense & _values(previous)) - shown:
            ys, xs = np.nonzero(previous == lab)
            lost[lab] = np.array([xs.mean(), ys.mean()])
    out = mask.copy()
    for r in big:  # the largest region first
        on = regions == r
        ys, xs = np.nonzero(on)
        centre = np.array([xs.mean(), ys.mean()])
        near = min(lost, key=lambda lab: float(np.linalg.norm(lost[lab] - centre)), default=None)
        if near is not None and np.linalg.norm(lost[near] - centre) <= gate * diagonal:
            out[on] = near
            del lost[near]
        else:
            out[on] = namer.dense_label()
    return out


def moving_to_labels(
    moving: npt.NDArray[np.bool_],
    xy: npt.NDArray[np.float32],
    labels: npt.NDArray[np.int64],
    background: int = WORLD,
    image: npt.NDArray[np.uint8] | None = None,
    cfg: MaskConfig = MaskConfig(),
) -> npt.NDArray[np.uint8]:
    """One frame's "motion" mask from its moving pixels and labelled points.

    Static pixels take the background's label. A moving pixel takes the label the watershed of the
    labelled points gives it (edges between two moving motions follow the image) when that is a
    moving motion's, else the label of the nearest point of a moving motion, else MOVING_UNCLUSTERED.

    Args:
        moving: (H, W) bool moving pixels (`moving_pixels.moving_masks`).
        xy: (N, 2) float32 positions of the frame's points, pixels.
        labels: (N,) int64 their labels (-1 = unlabelled, ignored).
        background: the world's label (static pixels take it).
        image: (H, W, 3) uint8 RGB frame for the watershed (None = nearest points only).
        cfg: the watershed's settings (max_distance_px, scale, ...).

    Returns:
        (H, W) uint8: background label where static, a moving motion's label (or MOVING_UNCLUSTERED) where moving.
    """
    labels = np.asarray(labels, dtype=np.int64).reshape(-1)
    xy = np.asarray(xy, np.float32).reshape(-1, 2)
    if cfg.world_regions > 0:
        moving = world_held(moving, xy, labels, background, cfg.world_regions, cfg.world_region_tracks)
    out = label_moving_pixels(moving, xy, labels, background, MOVING_UNCLUSTERED)
    keep = labels >= 0
    # The flood only decides between two or more moving motions: with one, every moving pixel has its
    # label already (the nearest-track partition above).
    if image is not None and moving.any() and np.unique(labels[keep & (labels != background)]).size >= 2:
        # At the mask stage's scale: it only draws the border between two moving motions.
        flood_cfg = replace(cfg, method="watershed", scale=min(cfg.scale, cfg.motion.work_scale))
        flood = labels_to_mask(xy[keep], labels[keep], moving.shape, flood_cfg, image)
        take = moving & (flood != background) & (flood != UNKNOWN)
        out[take] = flood[take]
    return out


@dataclass
class MaskSequence:
    """The one mask sequence of clips, whole videos and live, and the state a video carries between frames.

    The steps, in order: the world's parallax explained in the flow evidence ("motion" masks,
    `explain_parallax`, and with WorldConfig.rigid_scene the camera's 3D motion, `explain_rigid_scene`) -> the moving pixels (the motion-mask chain `moving_from_motion`, or the mask network
    `learned_moving`) -> labelled by the tracks (`moving_to_labels`, by the caller, which also makes the other
    methods' masks) -> `finish`: the per-motion network's choice (`which_motion`), each moving pixel given the
    motion whose step explains its flow (`reassign_by_flow`), then in clips the regions no motion explains split
    off (`split_unexplained`), in both the static regions a moving motion's tracks hold and whose flow it explains
    given to it (`missed_movers`), in videos the unclustered regions given their label in the frame before
    (`carry_unclustered`) or, where they had none, a label of their own (`name_unclustered`).

    A clip makes one per clip (`motion_masks`); a whole video one for the video (`segment_video`), whose colour
    model of the shot and last final mask go from window to window.

    Attributes:
        cfg: mask settings.
        video: whole-video mode (the frame before's mask is carried).
        colour: the motion masks' colour model of the shot's windows so far (None = each stack alone).
        last_mask: the last finished frame's mask (None at the start of a shot).
        history: whole videos with MaskConfig.rigid: the tracks of the shot's last frames (`rigid_tracks`).
        namer: whole videos with LabelConfig.name_unclustered: hands out the label of an unclustered moving
            region (`name_unclustered`), None = such regions stay MOVING_UNCLUSTERED.
        name_share: the smallest region named so, as a share of the frame.
    """

    cfg: MaskConfig
    video: bool = False
    colour: ColourMemory | None = None
    last_mask: npt.NDArray[np.uint8] | None = None
    history: TrackHistory | None = None
    namer: Namer | None = None
    name_share: float = 0.0

    def __post_init__(self) -> None:
        if self.video and self.cfg.rigid.enabled and self.history is None:
            self.history = TrackHistory(max(self.cfg.rigid.gaps) + 1)

    def new_shot(self) -> None:
        """A shot starts: no mask to carry over, its colours are new, no track goes back beyond it."""
        self.last_mask = None
        if self.colour is not None:
            self.colour.reset()
        if self.history is not None:
            self.history.reset()

    def moving(
        self,
        images: npt.NDArray[np.uint8],
        motion: FrameMotion,
        first: int = 0,
        parallax: tuple[npt.NDArray[np.float32], npt.NDArray[np.int64], WorldConfig] | None = None,
        anchors: list[Anchors] | None = None,
        tracks: WindowTracks | None = None,
    ) -> tuple[npt.NDArray[np.bool_], FrameMotion]:
        """The moving pixels of frames first..T-1 of a stack, and the flow evidence they were judged on.

        Args:
            images: (T, H, W, 3) uint8 RGB.
            motion: the stack's flow evidence (`stack_motion` / the video's flow stream).
            first: the first frame to mask.
            parallax: (xy (N, T, 2), labels (N,), world settings) of the labelled tracks: with the "motion"
                masks the world's 3D structure is explained first (the mask network takes the camera residual
                it was trained on). None: not explained.
            anchors: whole videos: per masked frame, the tracks that keep a motion the frame before showed.
            tracks: whole videos: the window's tracks for MaskConfig.rigid (`rigid_tracks`); None: not judged.

        Returns:
            ((T - first, H, W) bool moving, the FrameMotion used).
        """
        rigid = self.cfg.rigid
        verdict = None
        if tracks is not None and self.history is not None:
            for index, frame in zip(tracks.indices, tracks.seen):
                self.history.add(index, frame)
            verdict = rigid_tracks(self.history, tracks.indices[-1], tracks.last_labels, rigid)
        if parallax is not None and self.cfg.method == "motion":
            motion = explain_parallax(motion, *parallax)
            if not (self.history is not None and rigid.guard):
                motion = explain_rigid_scene(motion, *parallax)
            elif verdict is not None and tracks is not None:  # guarded: judged in 3D only with a verdict
                motion = explain_rigid_scene(motion, *parallax, long_span=verdict.of(tracks.clustered))
        if self.cfg.method == "learned":
            return learned_moving(images, motion, self.cfg.learned, first=first), motion
        moving = moving_from_motion(images, motion, self.cfg.motion, first=first, colour=self.colour, anchors=anchors)
        if tracks is not None and verdict is not None and rigid.hold:
            moving = self._rigid_held(moving, first, tracks.seen, verdict)
        return moving, motion

    def _rigid_held(
        self, moving: npt.NDArray[np.bool_], first: int, seen: Sequence[Seen], verdict: RigidTracks
    ) -> npt.NDArray[np.bool_]:
        """The masked frames' moving pixels without the regions that tracks of the static world hold over a long
        span (MaskConfig.rigid.hold, `rigid_tracks`)."""
        rigid = self.cfg.rigid
        out = moving.copy()
        for f in range(first, len(seen)):
            known, static = verdict.of(seen[f][0])
            out[f - first] = static_held(moving[f - first], seen[f][1], known, static, rigid.share, rigid.region_tracks)
        return out

    def finish(
        self,
        mask: npt.NDArray[np.uint8],
        at: int,
        seen: Sequence[Seen],
        labels: npt.NDArray[np.int64],
        motion: FrameMotion | None,
        features: npt.NDArray[np.float32] | None = None,
        moving: npt.NDArray[np.bool_] | None = None,
    ) -> npt.NDArray[np.uint8]:
        """Frame `at` of a stack, labelled (`moving_to_labels`), through the sequence's last steps.

        Args:
            mask: (H, W) uint8 labels of the frame.
            at: its index in the stack (and in `motion`'s flows).
            seen: per frame of the stack, its labelled tracks (ids ascending, positions).
            labels: (M,) int64 the labels of frame `at`'s tracks.
            motion: the stack's flow evidence (None: the flow steps are skipped).
            features: the frame's per-motion network inputs (`window_features`), if it has something to choose.
            moving: (H, W) bool the frame's moving pixels (clips: the unexplained regions' split).
        """
        cfg = self.cfg
        ids, xy = seen[at]
        if features is not None:
            mask = which_motion(mask, features, xy, labels, cfg.learned.which_weights)
        if motion is not None and motion.forward is not None and motion.backward is not None:
            near = at + 1 if at < len(motion.forward) else at - 1
            flow = motion.forward[at] if near > at else motion.backward[near]
            here, step = common_step((ids, xy), seen[near])
            if cfg.reassign_ratio > 0 and here.size:
                mask = reassign_by_flow(mask, step, labels[here], flow, motion.scale, cfg.reassign_ratio)
            if not self.video and cfg.unexplained_px > 0 and moving is not None:
                mask = split_unexplained(mask, moving, step, labels[here], WORLD, flow, motion.scale, cfg)
            if cfg.missed_tracks > 0 and here.size:
                mask = missed_movers(mask, step, labels[here], flow, motion.residual[at], motion.scale, cfg)
        if self.video:
            if (mask == MOVING_UNCLUSTERED).any():  # nothing to carry or name otherwise
                mask = self._unclustered(mask, at, motion)
            self.last_mask = mask
        return mask

    def _unclustered(self, mask: npt.NDArray[np.uint8], at: int, motion: FrameMotion | None) -> npt.NDArray[np.uint8]:
        """A video frame's unclustered movers given the label they had in the frame before, whose mask is first
        moved along the flow (a fast mover has moved on), else, with a namer, a label of their own."""
        before = self.last_mask
        if before is not None and motion is not None and motion.backward is not None and at >= 1:
            before = follow_flow(before, motion.backward[at - 1], motion.scale)
        mask = carry_unclustered(mask, before)
        return mask if self.namer is None else name_unclustered(mask, self.namer, self.name_share, before)


def motion_masks(
    images: npt.NDArray[np.uint8],
    tracks: Tracks,
    track_ids: npt.NDArray[np.int64],
    labels: npt.NDArray[np.int64],
    cfg: MaskConfig = MaskConfig(),
    before: npt.NDArray[np.uint8] | None = None,
    after: npt.NDArray[np.uint8] | None = None,
    motion: FrameMotion | None = None,
    world: WorldConfig | None = None,
) -> npt.NDArray[np.uint8]:
    """The "motion" (or "learned") masks of a clip: moving pixels from the dense flow, labelled by the clip's tracks.

    Args:
        images: (T, H, W, 3) uint8 RGB, T >= 2.
        tracks: the clip's tracks.
        track_ids: (M,) int64 rows of `tracks` that carry labels, ascending.
        labels: (M,) int64 their labels; 0 is the world (WORLD, `mosegpipe.group.world`).
        cfg: mask settings (cfg.motion; cfg.learned when cfg.method is "learned"; the watershed's for the
            borders between moving motions).
        before, after: the source's frames next to the clip, as evidence (`moving_pixels.stack_motion`).
        motion: `stack_motion` of the clip, if already computed (None = computed here).
        world: the world's parallax settings: with a given `motion`, its 3D structure is explained first.

    Returns:
        (T, H, W) uint8 masks.
    """
    labels = np.asarray(labels, dtype=np.int64).reshape(-1)
    sequence = MaskSequence(cfg)
    parallax = None if world is None or motion is None else (tracks.xy[track_ids], labels, world)
    if motion is None and (
        cfg.unexplained_px > 0 or cfg.reassign_ratio > 0 or cfg.method == "learned" or cfg.which == "learned"
    ):
        motion = stack_motion(images, cfg.motion, before, after)  # its flows serve both steps
    if motion is None:
        moving = moving_masks(images, cfg.motion, before=before, after=after)
    else:
        moving, motion = sequence.moving(images, motion, parallax=parallax)
    visible = tracks.visible[track_ids]  # (M, T)
    seen = [(track_ids[visible[:, t]], tracks.xy[track_ids[visible[:, t]], t]) for t in range(len(moving))]
    out = np.empty(moving.shape, dtype=np.uint8)
    features = None if motion is None else window_features(images, motion, cfg, (labels[s] for s in visible.T))
    for t in range(len(moving)):
        lab = labels[visible[:, t]]
        out[t] = moving_to_labels(moving[t], seen[t][1], lab, WORLD, images[t], cfg)
        feats = None if features is None else features[t]
        out[t] = sequence.finish(out[t], t, seen, lab, motion, feats, moving[t])
    return out
