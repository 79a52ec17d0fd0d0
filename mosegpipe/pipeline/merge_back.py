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
    """Labels merged back into others: label -> (the label it joined, the first frame of the window that merged it).

    A label stands for the one it joined only in the windows that start at or before that frame: once it has
    merged, no later window gives it (the label book forgets it), and should the book hand the number out again to
    a new motion (`LabelBook` reuses labels once the mask range is spent), that motion's windows keep it.
    """

    to: dict[int, tuple[int, int]] = field(default_factory=dict)

    def add(self, label: int, into: int, frame: int) -> None:
        """`label` is `into` in every window that starts at or before `frame`."""
        self.to[label] = (into, frame)

    def resolve(self, label: int, start: int) -> int:
        """The label `label` stands for in a window starting at frame `start` (chains followed)."""
        seen = set()
        while label in self.to and label not in seen and start <= self.to[label][1]:
            seen.add(label)
            label = self.to[label][0]
        return label

    def _live(self, start: int) -> list[int]:
        return [a for a, (_, until) in self.to.items() if start <= until]

    def relabel_mask(self, mask: npt.NDArray[np.uint8] | None, start: int) -> npt.NDArray[np.uint8] | None:
        """The mask of a window starting at frame `start` with every merged label written as the one it joined (the
        mask itself when none shows)."""
        live = [a for a in self._live(start) if a < 256]
        if mask is None or not live or not np.isin(mask, live).any():
            return mask
        lut = np.arange(256, dtype=np.uint8)
        for a in live:
            lut[a] = self.resolve(a, start)
        return lut[mask]

    def relabel(self, labels: npt.NDArray[np.int64], start: int) -> npt.NDArray[np.int64]:
        """Track labels of a window starting at frame `start` with every merged label replaced."""
        live = self._live(start)
        if not live or labels.size == 0:
            return labels
        out = labels.copy()
        for a in live:
            out[labels == a] = self.resolve(a, start)
        return out

    def window(self, result: WindowResult) -> WindowResult:
        """A window's result with every merged label replaced (masks and tracks)."""
        at = result.start
        if not self._live(at):
            return result
        frames = tuple(
            replace(fr, labels=self.relabel(fr.labels, at), mask=self.relabel_mask(fr.mask, at)) for fr in result.frames
        )
        return replace(result, labels=self.relabel(result.labels, at), frames=frames)

    def drop_before(self, start: int) -> None:
        """Forgets the aliases no window starting at `start` or later needs (those windows have left)."""
        self.to = {a: v for a, v in self.to.items() if v[1] >= start}


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
            aliases.drop_before(held[0].start if held else result.start + 1)
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
