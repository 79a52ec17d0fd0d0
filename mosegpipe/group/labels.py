"""Motion labels kept across the windows of a whole video: `LabelBook` (the global labels handed out, and a
memory of the labels seen lately) and `match_labels` (a window's clusters -> global labels through the tracks
it shares with the window before; Hungarian matching on the overlap counts, splits confirmed over two windows;
a motion that was missing for a few windows takes its label back: `LabelConfig`)."""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from mosegpipe.configs import LabelConfig
from mosegpipe.errors import InputError
from mosegpipe.group.label_shapes import LabelShape, label_shapes, labels_under, shape_holds
from mosegpipe.masks import MAX_LABEL

_MIN_SHARE = 0.5  # a cluster continues a global label only if most of its shared tracks carried it
_MIN_CONTINUED = 0.25  # a cluster continues a label only if this share of its tracks carried labels before


@dataclass
class LabelTrace:
    """What is remembered of a moving label (LabelBook.memory).

    Attributes:
        tracks: track id -> the last window in which it held the label.
        window: the last window in which the label was given.
        frame: the last frame of that window (source index).
        centre_xy: (2,) float64 mean position of its tracks in that frame, pixels.
        velocity_xy: (2,) float64 their mean motion per frame over that window, pixels.
        radius_px: twice the RMS distance of its tracks from their centre in that frame, pixels.
    """

    tracks: dict[int, int]
    window: int
    frame: int
    centre_xy: npt.NDArray[np.float64]
    velocity_xy: npt.NDArray[np.float64]
    radius_px: float


@dataclass
class LabelBook:
    """Global motion labels across windows, with reuse once the uint8 mask range is spent.

    Attributes:
        next_label: the next never-used label.
        last_window: label -> the last window that used it.
        num_reused: how many times a label was handed out again (only after 255 labels).
        max_label: largest label a mask can hold (mask value = label <= 253; 254 = a moving region no clustered
            motion reaches, 255 = unknown).
        pending: track id -> split candidate of the last window: the tracks of a cluster that
            split off a known motion, which kept that motion's label (see match_labels).
        cfg: how labels are remembered.
        memory: moving label -> what is remembered of it (the labels of the last cfg.memory_windows windows).
        shapes: moving label -> its pixels in the last mask that showed it (with cfg.carry_masks; the labels
            in `memory` only).
        last_mask: (H, W) uint8 the last labelled frame's final mask (with cfg.carry_masks), or None.
        mask_frame: that frame's source index (-1: none).
        dense: the labels the dense stage gave to moving regions no clustered motion reached
            (`dense_label`) that no cluster has continued yet.
        born: moving label -> the window that first gave it to a cluster (`pipeline.merge_back`).
    """

    next_label: int = 0
    last_window: dict[int, int] = field(default_factory=dict)
    num_reused: int = 0
    max_label: int = MAX_LABEL - 1  # MAX_LABEL is the unclustered mover's value (masks.MOVING_UNCLUSTERED)
    pending: dict[int, int] = field(default_factory=dict)
    cfg: LabelConfig = field(default_factory=LabelConfig)
    memory: dict[int, LabelTrace] = field(default_factory=dict)
    shapes: dict[int, LabelShape] = field(default_factory=dict)
    last_mask: npt.NDArray[np.uint8] | None = None
    mask_frame: int = -1
    dense: set[int] = field(default_factory=set)
    born: dict[int, int] = field(default_factory=dict)

    def forget(self) -> None:
        """Forgets every remembered label (a shot cut: no motion of the new shot continues one before it)."""
        self.memory.clear()
        self.dense.clear()
        self.pending.clear()
        self.shapes.clear()
        self.last_mask, self.mask_frame = None, -1

    def remember_mask(self, mask: npt.NDArray[np.uint8], frame: int) -> None:
        """Keeps a window's last labelled frame's final mask: the next window (which starts on that frame)
        reads the labels under its new tracks there, and each moving label it shows its shape (for when it
        goes missing). Nothing without cfg.carry_masks.

        Args:
            mask: (H, W) uint8 the frame's final mask.
            frame: its source index.
        """
        if not self.cfg.carry_masks:
            return
        self.last_mask, self.mask_frame = mask, frame
        self.shapes.update(label_shapes(mask, frame))
        self.shapes = {lab: shape for lab, shape in self.shapes.items() if lab in self.memory}

    def retire(self, label: int, into: int) -> None:
        """`label` merged back into `into` (`pipeline.merge_back`): it is remembered no more, and the last mask
        shows `into` where it showed `label`."""
        for store in (self.memory, self.shapes, self.born):
            store.pop(label, None)
        self.dense.discard(label)
        if self.last_mask is not None and label < 256 and (self.last_mask == label).any():
            self.last_mask = np.where(self.last_mask == label, np.uint8(into), self.last_mask)

    def remembered(self) -> dict[int, npt.NDArray[np.float64]]:
        """The moving labels remembered from the last windows (`memory`) -> the centre (x, y) of their last mask,
        pixels (those whose shape is known: with cfg.carry_masks)."""
        out = {}
        for lab, shape in self.shapes.items():
            if lab in self.memory:
                ys, xs = np.nonzero(shape.crop)
                out[lab] = shape.origin_xy + np.array([xs.mean(), ys.mean()])
        return out

    def dense_label(self) -> int:
        """A new label for a moving region of the masks that no clustered motion reaches
        (`masks.compose.name_unclustered`); new tracks on it in the next window count as its (`_known_labels`)."""
        label = self.new_label(self.dense)
        self.dense.add(label)
        return label

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
        label = min(free, key=lambda lab: self.last_window[lab])
        for store in (self.memory, self.shapes, self.born):
            store.pop(label, None)
        return label


def match_labels(
    prev: dict[int, int],
    ids: npt.NDArray[np.int64],
    clusters: npt.NDArray[np.int64],
    k: int,
    book: LabelBook,
    window: int = 0,
    world: bool = False,
    xy: npt.NDArray[np.float32] | None = None,
    frame: int = 0,
    supported: Collection[int] = (),
) -> npt.NDArray[np.int64]:
    """Maps this window's clusters to global labels through the tracks shared with the previous window.

    1. Clusters and previous labels are paired by the Hungarian method on their overlap counts
       (maximum total overlap, one-to-one). A pair is kept only when at least half of the cluster's
       shared tracks carried that label and at least a quarter of its tracks carried a label at all
       (across a camera cut the few tracks that survive it say nothing about the new shot).
    2. A cluster left over whose tracks are known (that quarter carried labels) is a piece of the
       motions they carried: K-means split a motion (over-segmentation) or joined two. It takes the
       label most of its shared tracks carried, as in the window before, and becomes a split
       candidate. Only when a candidate splits off again in the next window (at least half of the
       cluster's shared tracks were one candidate's) does it get a new label: a motion that
       separates from another is labelled one window late, a split that comes and goes never.
    With `world`, cluster 0 is the world's motion (`mosegpipe.group.world`): it takes label 0 whatever its
    tracks carried, and no other cluster continues label 0 in step 1 (a cluster most of whose tracks
    were the world is a piece of it, step 2: it stays 0 until it splits off twice). Without it, the
    cluster that continues label 0 is the world, and after a shot cut cluster 0 takes 0.
    3. A cluster that would start a new label (steps 2 and 4), a leftover piece of a known motion or new
       tracks, takes back a moving label that this window does not continue but `book` remembers
       (`LabelConfig`): the one most of its tracks held lately, else (new tracks only) the one whose last
       motion carries it to where the cluster lies (`xy`). A motion that merged into another for a window
       and splits off again, or that was hidden, keeps its label.
       With LabelConfig.carry_masks the labels travel with the masks too (`_known_labels`, `_predicted_share`).
    4. The remaining clusters are new tracks (objects entering the view, a new shot): a new label,
       unless the cluster is too small to trust (fewer than LabelConfig.new_tracks tracks, or a quarter of
       the window's, and under LabelConfig.new_share of the window's), which stays unlabelled (-1). The clusters
       `supported` pass whatever their size (steps 2-4): rigid motions of their own (method "joint").

    Args:
        prev: track id -> global label from the previous labelled window.
        ids: (N,) int64 track ids of this window's trajectories.
        clusters: (N,) int64 cluster of each, in 0..k-1.
        k: number of clusters in this window.
        book: the global label state (updated, its split candidates included).
        window: index of this window (for least-recently-used label reuse and the label memory).
        world: cluster 0 is the world's motion and takes label 0.
        xy: (N, T, 2) float32 positions of the tracks in this window's frames, pixels (None: the memory
            matches by shared tracks only, and remembers no position).
        frame: the source index of this window's first frame.
        supported: clusters exempt from the size guard (`small_guard`).

    Returns:
        (N,) int64 global labels.
    """
    old, tracked = _known_labels(prev, ids, book, xy, frame)
    candidate = np.array([book.pending.get(int(i), -1) for i in ids], dtype=np.int64)
    sizes = np.bincount(clusters, minlength=k)
    small = np.where(np.isin(np.arange(k), list(supported)), 0.0, small_guard(book.cfg, clusters.size))
    mapping, splits = _continued_labels(old, tracked, candidate, clusters, k, sizes, small, world)
    takes_zero = world or (0 not in mapping and 0 not in mapping.values())
    reopen = [
        c for c in range(k) if (c not in mapping or c in splits) and sizes[c] >= small[c] and (c or not takes_zero)
    ]
    for c, lab in _revived_labels(book, ids, clusters, old, reopen, set(mapping.values()), window, xy, frame).items():
        mapping[c] = lab
        splits.pop(c, None)
    book.pending = {int(i): int(c) for i, c in zip(ids, clusters) if int(c) in splits}
    # The world takes label 0 (with `world`: cluster 0, always); without it, the dominant motion takes 0
    # when no cluster carries 0 on, e.g. after a camera cut.
    if world or (0 not in mapping and 0 not in mapping.values() and book.next_label > 0):
        mapping[0] = 0
        book.next_label = max(book.next_label, 1)
    _new_labels(mapping, sizes, small, book, set(mapping.values()) | set(prev.values()))
    book.last_window.update({lab: window for lab in mapping.values() if lab >= 0})
    book.born.update({lab: window for lab in mapping.values() if lab > 0 and lab not in book.born})
    book.dense -= set(mapping.values())  # a name a cluster continues is a motion's label like any other
    labels = np.array([mapping[int(c)] for c in clusters], dtype=np.int64)
    _remember(book, ids, labels, window, xy, frame)
    return labels


def _known_labels(
    prev: dict[int, int],
    ids: npt.NDArray[np.int64],
    book: LabelBook,
    xy: npt.NDArray[np.float32] | None,
    frame: int,
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """The labels the tracks are known by: ((N,) int64 known, (N,) int64 carried by the tracks themselves in the
    previous window), -1: none. With LabelConfig.carry_masks, a track that carried none is known by the moving
    label under its first position in the last labelled frame's mask when that frame is this window's first
    (`LabelBook.remember_mask`; windows share their boundary frame): new tracks on a labelled object count as
    that object's in match_labels' step 1 (a region the dense stage named too, `LabelBook.dense_label`). Without
    it, both arrays are the tracks' own labels."""
    tracked = np.array([prev.get(int(i), -1) for i in ids], dtype=np.int64)
    if book.cfg.carry_masks and book.last_mask is not None and book.mask_frame == frame and xy is not None:
        return np.where(tracked >= 0, tracked, labels_under(book.last_mask, xy[:, 0])), tracked
    return tracked, tracked


def small_guard(cfg: LabelConfig, num_tracks: int) -> float:
    """The fewest tracks a cluster needs to start a label or a split in a window of `num_tracks` tracks (the
    guard of match_labels' steps 2 and 4): LabelConfig.new_tracks (at most a quarter of the window), or
    new_share of the window when that is more."""
    return max(min(cfg.new_tracks, 0.25 * num_tracks), cfg.new_share * num_tracks)


def _new_labels(
    mapping: dict[int, int],
    sizes: npt.NDArray[np.int64],
    small: npt.NDArray[np.float64],
    book: LabelBook,
    busy: set[int],
) -> None:
    """Step 4 of match_labels: a new label for each cluster not in `mapping` (-1 for one too small to trust)."""
    k = sizes.size
    for c in range(k):
        if c in mapping:
            continue
        if sizes[c] < small[c] and k > 1:
            # Too few tracks to trust as a motion that just appeared: left unlabelled (-1).
            mapping[c] = -1
            continue
        mapping[c] = book.new_label(busy)
        busy.add(mapping[c])


def _revived_labels(
    book: LabelBook,
    ids: npt.NDArray[np.int64],
    clusters: npt.NDArray[np.int64],
    old: npt.NDArray[np.int64],
    reopen: list[int],
    used: set[int],
    window: int,
    xy: npt.NDArray[np.float32] | None,
    frame: int,
) -> dict[int, int]:
    """Step 3 of match_labels: cluster -> the remembered label it takes back, for the clusters `reopen` (those
    of new tracks, few of which carried a label `old`, also by position), among the labels not `used` here."""
    cfg = book.cfg
    absent = [lab for lab, tr in book.memory.items() if lab not in used and window - tr.window <= cfg.memory_windows]
    if not absent or not reopen:
        return {}
    share = np.zeros((len(reopen), len(absent)))
    for j, lab in enumerate(absent):
        held = np.isin(ids, np.fromiter(book.memory[lab].tracks, np.int64))
        share[:, j] = [np.count_nonzero(held & (clusters == c)) / np.count_nonzero(clusters == c) for c in reopen]
    share[share < cfg.revive_share] = 0
    if cfg.carry_masks and xy is not None:
        share = np.maximum(share, _predicted_share(book, absent, xy[:, 0], clusters, reopen, frame))
    out: dict[int, int] = {}
    from scipy.optimize import linear_sum_assignment  # on first use: see runtime.import_ahead

    rows, cols = linear_sum_assignment(-share)
    for r, j in zip(rows, cols):
        if share[r, j] > 0:
            out[reopen[r]] = absent[j]
    placed = [
        c
        for c in reopen
        if c not in out
        and np.count_nonzero((clusters == c) & (old >= 0)) < _MIN_CONTINUED * np.count_nonzero(clusters == c)
    ]
    left = [lab for lab in absent if lab not in out.values() and np.isfinite(book.memory[lab].radius_px)]
    if cfg.gate <= 0 or xy is None or not placed or not left:
        return out
    dist = np.full((len(placed), len(left)), np.inf)
    for j, lab in enumerate(left):
        tr = book.memory[lab]
        there = tr.centre_xy + tr.velocity_xy * (frame - tr.frame)
        for r, c in enumerate(placed):
            dist[r, j] = np.linalg.norm(xy[clusters == c, 0].mean(axis=0) - there) / tr.radius_px
    dist[dist > cfg.gate] = np.inf
    if not np.isfinite(dist).any():
        return out
    from scipy.optimize import linear_sum_assignment  # on first use: see runtime.import_ahead

    rows, cols = linear_sum_assignment(np.where(np.isfinite(dist), dist, 1e9))
    for r, j in zip(rows, cols):
        if np.isfinite(dist[r, j]):
            out[placed[r]] = left[j]
    return out


def _predicted_share(
    book: LabelBook,
    absent: list[int],
    start_xy: npt.NDArray[np.float32],
    clusters: npt.NDArray[np.int64],
    reopen: list[int],
    frame: int,
) -> npt.NDArray[np.float64]:
    """(len(reopen), len(absent)): the share of each cluster's tracks that start (`start_xy`, (N, 2) pixels in
    `frame`) on each remembered label's last shape moved on by its last motion; 0 under LabelConfig.mask_share."""
    share = np.zeros((len(reopen), len(absent)))
    for j, lab in enumerate(absent):
        shape = book.shapes.get(lab)
        if shape is None:
            continue
        trace = book.memory[lab]
        shift = trace.velocity_xy * (frame - shape.frame) if np.isfinite(trace.velocity_xy).all() else np.zeros(2)
        on = shape_holds(shape, start_xy, shift)
        share[:, j] = [np.count_nonzero(on & (clusters == c)) / np.count_nonzero(clusters == c) for c in reopen]
    share[share < book.cfg.mask_share] = 0
    return share


def _remember(
    book: LabelBook,
    ids: npt.NDArray[np.int64],
    labels: npt.NDArray[np.int64],
    window: int,
    xy: npt.NDArray[np.float32] | None,
    frame: int,
) -> None:
    """Updates the memory of the moving labels given in this window, and forgets those missing for too long."""
    cfg = book.cfg
    if cfg.memory_windows == 0:
        return
    for lab in np.unique(labels[labels > 0]).tolist():
        mine = labels == lab
        trace = book.memory.get(lab)
        tracks = {} if trace is None else {i: w for i, w in trace.tracks.items() if window - w <= cfg.memory_windows}
        tracks.update(dict.fromkeys(ids[mine].tolist(), window))
        centre, velocity, radius = np.full(2, np.nan), np.zeros(2), np.nan
        if xy is not None and xy.shape[1] > 0:
            pts = xy[mine].astype(np.float64)
            centre = pts[:, -1].mean(axis=0)
            velocity = (centre - pts[:, 0].mean(axis=0)) / max(xy.shape[1] - 1, 1)
            rms = np.sqrt(np.mean(np.sum((pts[:, -1] - centre) ** 2, axis=1)))
            radius = max(2.0 * rms, cfg.min_radius_px)
        book.memory[lab] = LabelTrace(
            tracks, window, frame + (0 if xy is None else xy.shape[1] - 1), centre, velocity, radius
        )
    for lab in [lab for lab, tr in book.memory.items() if window - tr.window > cfg.memory_windows]:
        del book.memory[lab]


def _continued_labels(
    old: npt.NDArray[np.int64],
    tracked: npt.NDArray[np.int64],
    candidate: npt.NDArray[np.int64],
    clusters: npt.NDArray[np.int64],
    k: int,
    sizes: npt.NDArray[np.int64],
    small: npt.NDArray[np.float64],
    world: bool,
) -> tuple[dict[int, int], dict[int, int]]:
    """Steps 1 and 2 of match_labels: (cluster -> the previous label it continues, cluster -> the label
    it split off), from the labels its tracks are known by (`old`, -1: none), the split candidates they
    were (`candidate`, -1: none) and, for step 2, the labels the tracks themselves carried (`tracked`, a
    subset of `old`): a label read off the mask continues a motion, but never makes a split piece (two
    objects merged under one label and then apart are two; the new tracks on the second would keep it
    on both for a window)."""
    shared = old >= 0
    mapping: dict[int, int] = {}
    splits: dict[int, int] = {}  # cluster -> the label it split off (it keeps that label for now)
    confirmed: set[int] = set()  # clusters that split off in two windows running: new labels
    if not shared.any():
        return mapping, splits
    olds = np.unique(old[shared])
    overlap = _overlap(old, clusters, k, olds)
    per_cluster = overlap.sum(axis=1)
    known = per_cluster >= _MIN_CONTINUED * sizes
    for r in range(k):
        mine = candidate[(clusters == r) & (candidate >= 0)]
        if known[r] and sizes[r] >= small[r] and mine.size and np.bincount(mine).max() >= _MIN_SHARE * per_cluster[r]:
            confirmed.add(r)
    if world:
        confirmed.discard(0)
    overlap[list(confirmed)] = 0  # a recurring split continues none of the labels
    if world:  # the world continues label 0, and only it
        mapping[0] = 0
        overlap[0] = 0
        overlap[:, olds == 0] = 0
    from scipy.optimize import linear_sum_assignment  # on first use: see runtime.import_ahead

    rows, cols = linear_sum_assignment(-overlap)
    for r, c in zip(rows, cols):
        if r in mapping:
            continue
        if known[r] and overlap[r, c] > 0 and overlap[r, c] >= _MIN_SHARE * per_cluster[r]:
            mapping[int(r)] = int(olds[c])
    carried = _overlap(tracked, clusters, k, olds)
    carried[list(confirmed)] = 0
    per_cluster = carried.sum(axis=1)
    known = per_cluster >= _MIN_CONTINUED * sizes
    for r in range(k):
        if r in mapping or r in confirmed or not known[r] or per_cluster[r] == 0:
            continue
        mapping[r] = int(olds[int(carried[r].argmax())])
        if sizes[r] >= small[r]:
            splits[r] = mapping[r]
    return mapping, splits


def _overlap(
    labels: npt.NDArray[np.int64], clusters: npt.NDArray[np.int64], k: int, olds: npt.NDArray[np.int64]
) -> npt.NDArray[np.int64]:
    """(k, olds.size) int64 how many of each cluster's tracks carry each label of `olds` (-1s not counted)."""
    on = labels >= 0
    out = np.zeros((k, olds.size), dtype=np.int64)
    np.add.at(out, (clusters[on], np.searchsorted(olds, labels[on])), 1)
    return out
