"""A label that lives a window or two and then merges back into a motion beside it is that motion's from its start.

K-means often cuts one non-rigid mover in two where a video's first window sees it (a rider and his bike, a
player's legs and torso), and in the next window or the one after one cluster holds both pieces again: the label
matching keeps the older label, but the frames already written show two labels on one object. `segment_video`
holds its last `LabelConfig.merge_back_windows` windows back before yielding them; when a label born within them
merges back (`merged_back`), every held window is relabelled with the label it joined (`Aliases`), so the object
carries one label throughout. Geometry decides what a piece is: a piece that is one rigid motion of its own
(`joint.geometry_supported`) is an object that the grouping merged with another, and keeps its label.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field, replace

import numpy as np
import numpy.typing as npt

from mosegpipe.configs import JointConfig
from mosegpipe.group.joint import geometry_supported
from mosegpipe.pipeline.window import WindowResult

_MIN_SHARED = 5  # a label whose tracks this window shares fewer of says nothing about where it went
_MIN_SHARE = 0.5  # ... and most of those must carry the one label it joins


@dataclass
class Aliases:
    """Labels merged back into others: label -> the label it is now (resolved through chains)."""

    to: dict[int, int] = field(default_factory=dict)

    def add(self, label: int, into: int) -> None:
        """`label` is `into` from now on, and was from its start."""
        self.to[label] = self.resolve(into)
        self.to = {a: self.resolve(b) for a, b in self.to.items()}

    def resolve(self, label: int) -> int:
        """The label `label` stands for now."""
        seen = set()
        while label in self.to and label not in seen:
            seen.add(label)
            label = self.to[label]
        return label

    def table(self) -> npt.NDArray[np.uint8]:
        """(256,) uint8 lookup table of mask values."""
        lut = np.arange(256, dtype=np.uint8)
        for a in self.to:
            if a < 256:
                lut[a] = self.resolve(a)
        return lut

    def relabel_mask(self, mask: npt.NDArray[np.uint8] | None) -> npt.NDArray[np.uint8] | None:
        """The mask with every merged label written as the one it joined (the mask itself when none shows)."""
        if mask is None or not self.to or not np.isin(mask, list(self.to)).any():
            return mask
        return self.table()[mask]

    def relabel(self, labels: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
        """Track labels with every merged label replaced."""
        if not self.to or labels.size == 0:
            return labels
        out = labels.copy()
        for a in self.to:
            out[labels == a] = self.resolve(a)
        return out

    def window(self, result: WindowResult) -> WindowResult:
        """A window's result with every merged label replaced (masks and tracks)."""
        if not self.to:
            return result
        frames = tuple(
            replace(fr, labels=self.relabel(fr.labels), mask=self.relabel_mask(fr.mask)) for fr in result.frames
        )
        return replace(result, labels=self.relabel(result.labels), frames=frames)


def _no_labels() -> npt.NDArray[np.int64]:
    return np.zeros(0, dtype=np.int64)


@dataclass(frozen=True)
class WindowLabels:
    """One window's clusters as global labels (k = 0: the window was left unlabelled).

    Attributes:
        k: motions found (after the rigid-motion check).
        note: automatic K's note.
        scores: automatic K's score per candidate K.
        track_ids: (N,) int64 ids of the labelled tracks.
        labels: (N,) int64 their global labels (>= 0).
        xy: (N, T, 2) float32 their positions in the window's frames, pixels.
    """

    k: int = 0
    note: str = ""
    scores: dict[int, float] = field(default_factory=dict)
    track_ids: npt.NDArray[np.int64] = field(default_factory=_no_labels)
    labels: npt.NDArray[np.int64] = field(default_factory=_no_labels)
    xy: npt.NDArray[np.float32] = field(default_factory=lambda: np.zeros((0, 0, 2), np.float32))

    def by_id(self) -> dict[int, int]:
        """Track id -> global label."""
        return {int(i): int(g) for i, g in zip(self.track_ids, self.labels)}


def held_back(results: Iterable[WindowResult], windows: int, aliases: Aliases) -> Iterator[WindowResult]:
    """`results` yielded `windows` windows late, each relabelled by `aliases` as it stood when it left."""
    held: deque[WindowResult] = deque()
    for result in results:
        held.append(result)
        while len(held) > windows:
            yield aliases.window(held.popleft())
    while held:
        yield aliases.window(held.popleft())


def merged_back(
    before: WindowLabels,
    ids: npt.NDArray[np.int64],
    labels: npt.NDArray[np.int64],
    born: dict[int, int],
    since: int,
    cfg: JointConfig = JointConfig(),
) -> dict[int, int]:
    """The moving labels of the window before that merged back into another motion in this window.

    A label merged back when it was born in window `since` or later, this window gives it to none of its
    tracks, at least _MIN_SHARED of its tracks are here and most of them carry one other moving label that the
    window before showed too, and geometry does not show it to be a rigid motion of its own there
    (`joint.geometry_supported` on the window before's tracks).

    Args:
        before: the window before's labels.
        ids: (N,) int64 this window's track ids.
        labels: (N,) int64 their global labels (-1: none).
        born: label -> the window it was first given in.
        since: the earliest birth window still held back.
        cfg: the geometry's thresholds.

    Returns:
        {label: the label it joined}.
    """
    ids_b, labels_b, xy_b = before.track_ids, before.labels, before.xy
    now = dict(zip(ids.tolist(), labels.tolist()))
    alive = set(labels.tolist())
    shown = set(labels_b.tolist())
    found: dict[int, int] = {}
    for lab in sorted(shown - alive):
        if lab <= 0 or born.get(lab, -1) < since:
            continue
        went = np.array([now.get(i, -1) for i in ids_b[labels_b == lab].tolist()], np.int64)
        went = went[went >= 0]
        if went.size < _MIN_SHARED:
            continue
        values, counts = np.unique(went, return_counts=True)
        into = int(values[counts.argmax()])
        if into <= 0 or into not in shown or counts.max() < _MIN_SHARE * went.size:
            continue
        found[lab] = into
    if not found or xy_b.shape[1] < 2:
        return found
    groups = np.unique(labels_b, return_inverse=True)
    index = {int(v): g for g, v in enumerate(groups[0])}
    points = xy_b.reshape(xy_b.shape[0], -1).astype(np.float64)
    rigid = geometry_supported(points, groups[1], [index[lab] for lab in found], cfg)
    return {lab: into for lab, into in found.items() if index[lab] not in rigid}
