"""Whole-video labels carried by the masks (LabelConfig.carry_masks): synthetic windows of tracks on moving
rectangles, each window's last frame masked with the labels its clusters got, as the video's masks would be."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from mosegpipe.group.label_shapes import label_shapes, labels_under, shape_holds
from mosegpipe.pipeline import LabelBook, LabelConfig, match_labels

F = 5  # frames per window; windows share their boundary frame, so window w covers frames 4w .. 4w + 4
SIZE_HW = (480, 640)
CARRY = LabelConfig(carry_masks=True)


@dataclass(frozen=True)
class Body:
    """A rectangle of half size half_wh whose centre starts at x0_xy on frame 0 and moves v_xy px per frame."""

    x0_xy: tuple[float, float]
    v_xy: tuple[float, float]
    half_wh: tuple[float, float] = (30.0, 30.0)

    def centre(self, t: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        return np.asarray(self.x0_xy) + np.outer(t, self.v_xy)

    def paint(self, mask: npt.NDArray[np.uint8], t: int, label: int) -> None:
        (cx, cy), (hw, hh) = self.centre(np.array([t]))[0], self.half_wh
        mask[int(cy - hh) : int(cy + hh) + 1, max(int(cx - hw), 0) : int(cx + hw) + 1] = label


@dataclass(frozen=True)
class Patch:
    """n tracks (ids first_id ..) on a part of a body: x from part[0] to part[1] half widths off its centre, y
    within half a half height."""

    body: Body
    first_id: int
    n: int = 20
    part: tuple[float, float] = (-1.0, -0.3)

    def ids(self) -> npt.NDArray[np.int64]:
        return np.arange(self.first_id, self.first_id + self.n, dtype=np.int64)

    def xy(self, window: int) -> npt.NDArray[np.float32]:
        rng = np.random.default_rng(self.first_id)
        hw, hh = self.body.half_wh
        off = np.stack([rng.uniform(*self.part, self.n) * hw, rng.uniform(-0.5, 0.5, self.n) * hh], axis=1)
        centre = self.body.centre(4 * window + np.arange(F, dtype=np.float64))
        return (centre[None] + off[:, None]).astype(np.float32)


WORLD = Patch(Body((320, 240), (0, 0), (300, 220)), 0, 60, (-1.0, 1.0))  # never painted: the mask's 0

Cluster = Patch | tuple[Patch, ...]


def _run(windows: list[list[Cluster]], cfg: LabelConfig = CARRY) -> list[dict[int, int]]:
    """The windows in turn (window w's cluster c holds the tracks of windows[w][c], cluster 0 the world), each
    window's last frame masked with its clusters' labels (a cluster's bodies painted in order). Returns per
    window {cluster: label}."""
    book, prev, out = LabelBook(cfg=cfg), {}, []
    for w, clusters in enumerate(windows):
        groups = [c if isinstance(c, tuple) else (c,) for c in clusters]
        ids = np.concatenate([p.ids() for g in groups for p in g])
        cl = np.concatenate([np.full(p.n, c, np.int64) for c, g in enumerate(groups) for p in g])
        xy = np.concatenate([p.xy(w) for g in groups for p in g])
        labels = match_labels(prev, ids, cl, len(clusters), book, w, world=True, xy=xy, frame=4 * w)
        by_cluster = {c: int(labels[cl == c][0]) for c in range(len(clusters))}
        mask = np.zeros(SIZE_HW, np.uint8)
        for c, g in enumerate(groups[1:], start=1):
            for p in g:
                p.body.paint(mask, 4 * w + F - 1, max(by_cluster[c], 0))
        book.remember_mask(mask, 4 * w + F - 1)
        prev = dict(zip(ids.tolist(), labels.tolist()))
        out.append(by_cluster)
    return out


def test_an_object_lost_for_two_windows_comes_back_where_its_mask_is_predicted() -> None:
    body = Body((100, 150), (5, 0), (60, 30))
    before, after = Patch(body, 100), Patch(body, 200, part=(0.4, 1.0))  # new tracks on another part of it
    windows: list[list[Cluster]] = [[WORLD, before], [WORLD], [WORLD], [WORLD, after]]
    assert [w.get(1) for w in _run(windows)] == [1, None, None, 1]
    # by the tracks' centre alone (the label's radius) the new tracks lie too far: a new label
    assert _run(windows, LabelConfig(carry_masks=False))[3][1] == 2
    # no memory: nothing is reserved, the mask of three windows ago says nothing
    assert _run(windows, LabelConfig(carry_masks=True, memory_windows=1))[3][1] == 2


def test_a_merge_then_a_split_keeps_the_labels_the_overlap_gives() -> None:
    a, b = Body((150, 150), (5, 0)), Body((300, 300), (-5, 0))
    a1, b1 = Patch(a, 100, 25), Patch(b, 300)
    a2, b2 = Patch(a, 500, 25, (0.3, 1.0)), Patch(b, 600, part=(0.3, 1.0))  # after the split: new tracks only
    windows: list[list[Cluster]] = [[WORLD, a1, b1], [WORLD, (a1, b1)], [WORLD, b2, a2]]
    labels = _run(windows)
    assert labels[1] == {0: 0, 1: 1}  # merged: the larger motion's label, 2 reserved
    assert labels[2] == {0: 0, 1: 2, 2: 1}  # b's new tracks lie on 1 in the last mask, and on 2 predicted
    assert _run(windows, LabelConfig(carry_masks=False))[2] == {0: 0, 1: 3, 2: 1}
    # first found merged: the piece the overlap gives the label keeps it. The other, whose tracks are all new,
    # lies on that label in the mask too, but a label read off the mask never makes a split piece: a new label
    # at once (it kept the label for a window, on both objects).
    first = _run([[WORLD, (a1, b1)], [WORLD, b2, a2], [WORLD, b2, a2]])
    assert first[0] == {0: 0, 1: 1} and first[1] == {0: 0, 1: 2, 2: 1} and first[2] == {0: 0, 1: 2, 2: 1}
    # pieces whose own tracks carried the label split off a window late, as without the masks (a split that
    # comes and goes never gets a label)
    tracked = _run([[WORLD, (a1, b1)], [WORLD, b1, a1], [WORLD, b1, a1]])
    assert tracked[1] == {0: 0, 1: 1, 2: 1} and tracked[2] == {0: 0, 1: 2, 2: 1}


def test_two_objects_crossing_keep_their_labels() -> None:
    # a moves right, b left; they cross on frames 8-12, where a hides b (b's tracks die); b comes out with new tracks
    a, b = Body((150, 240), (15, 0), (30, 15)), Body((450, 240), (-15, 0), (30, 15))
    a1, b1, b_after = Patch(a, 100), Patch(b, 300), Patch(b, 400, part=(0.3, 1.0))
    windows: list[list[Cluster]] = [[WORLD, a1, b1], [WORLD, b1, a1], [WORLD, a1], [WORLD, b_after, a1]]
    labels = _run(windows)
    assert labels[1] == {0: 0, 1: 2, 2: 1}
    assert labels[3] == {0: 0, 1: 2, 2: 1}
    assert _run(windows, LabelConfig(carry_masks=False))[3] == {0: 0, 1: 3, 2: 1}


def test_new_tracks_on_a_labelled_object_continue_its_label() -> None:
    # all of a's tracks are new in the second window (a deforming object): the mask they start on says whose
    body = Body((200, 200), (8, 0), (60, 30))
    windows: list[list[Cluster]] = [[WORLD, Patch(body, 100)], [WORLD, Patch(body, 200, part=(0.4, 1.0))]]
    assert _run(windows)[1] == {0: 0, 1: 1}
    assert _run(windows, LabelConfig(carry_masks=False))[1] == {0: 0, 1: 2}


def test_a_new_object_entering_gets_a_new_label() -> None:
    a = Body((100, 100), (5, 0))
    entering = Body((640, 400), (-10, 0))  # enters on the right, far from where a is or is predicted
    windows: list[list[Cluster]] = [[WORLD, Patch(a, 100)], [WORLD, Patch(a, 100), Patch(entering, 200)]]
    assert _run(windows)[1] == {0: 0, 1: 1, 2: 2}
    # entering while a is missing: still new
    windows = [[WORLD, Patch(a, 100)], [WORLD], [WORLD, Patch(entering, 200)]]
    assert _run(windows)[2] == {0: 0, 1: 2}


def test_a_mover_the_masks_named_is_continued_by_the_cluster_on_it() -> None:
    # window 0 finds only the world; the dense stage named the moving region it saw (LabelBook.dense_label)
    body = Body((200, 200), (8, 0), (60, 30))
    old, new = Patch(body, 100, 5), Patch(body, 200, 30, (0.4, 1.0))  # most of its tracks are new
    ids0 = np.concatenate([WORLD.ids(), old.ids()])
    xy0 = np.concatenate([WORLD.xy(0), old.xy(0)])
    ids1 = np.concatenate([WORLD.ids(), old.ids(), new.ids()])
    xy1 = np.concatenate([WORLD.xy(1), old.xy(1), new.xy(1)])
    clusters = np.concatenate([np.zeros(WORLD.n, np.int64), np.ones(old.n + new.n, np.int64)])

    def second_window(where: Body) -> tuple[set[int], LabelBook]:
        book, mask = LabelBook(cfg=CARRY), np.zeros(SIZE_HW, np.uint8)
        first = match_labels({}, ids0, np.zeros(ids0.size, np.int64), 1, book, 0, world=True, xy=xy0, frame=0)
        where.paint(mask, F - 1, book.dense_label())
        book.remember_mask(mask, F - 1)
        prev = dict(zip(ids0.tolist(), first.tolist()))  # the object's old tracks were the world's
        labels = match_labels(prev, ids1, clusters, 2, book, 1, world=True, xy=xy1, frame=F - 1)
        return set(labels[clusters == 1].tolist()), book

    named, book = second_window(body)
    assert named == {1} and not book.dense and book.next_label == 2  # continued: a motion's label like any other
    # a name painted elsewhere (another mover) is not this object's: a new label, the name stays the dense stage's
    elsewhere, book = second_window(Body((500, 100), (0, 0), (30, 30)))
    assert elsewhere == {2} and book.dense == {1}


def test_shapes_and_the_labels_under_points() -> None:
    mask = np.zeros((4, 6), np.uint8)
    mask[1:3, 2:4] = 7
    mask[0, 5] = 254  # an unclustered mover: no label
    mask[3, 0] = 255
    shape = label_shapes(mask, 9)[7]
    assert label_shapes(mask, 9).keys() == {7}
    assert shape.frame == 9 and shape.origin_xy.tolist() == [2, 1] and shape.crop.all() and shape.crop.shape == (2, 2)
    pts = np.array([[2.2, 1.4], [5, 0], [0, 3], [-1, 0], [3, 2], [0, 0]])
    assert labels_under(mask, pts).tolist() == [7, -1, -1, -1, 7, -1]
    # moved 2 px right: (4, 1) is on it, (2, 1) no longer
    assert shape_holds(shape, np.array([[4.0, 1.0], [2.0, 1.0], [5.0, 2.0]]), np.array([2.0, 0.0])).tolist() == [
        True,
        False,
        True,
    ]
