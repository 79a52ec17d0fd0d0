"""Whole-video labels: a motion keeps its label through the windows it is missing from (LabelConfig)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import pytest

from mosegpipe.errors import ConfigError
from mosegpipe.pipeline import LabelBook, LabelConfig, PipelineConfig, match_labels

F = 5  # frames per window; windows share their boundary frame, so window w starts on frame 4w


@dataclass(frozen=True)
class Mover:
    """A group of tracks: ids first_id .. first_id + n - 1, spread over +-15 px around a centre that starts at
    x0_xy on frame 0 and moves v_xy pixels per frame."""

    first_id: int
    n: int
    x0_xy: tuple[float, float]
    v_xy: tuple[float, float]

    def ids(self) -> npt.NDArray[np.int64]:
        return np.arange(self.first_id, self.first_id + self.n, dtype=np.int64)

    def xy(self, window: int) -> npt.NDArray[np.float32]:
        """(n, F, 2) positions in the frames of `window`."""
        t = 4 * window + np.arange(F, dtype=np.float64)
        spread = np.random.default_rng(self.first_id).uniform(-15, 15, (self.n, 1, 2))
        centre = np.asarray(self.x0_xy) + np.outer(t, self.v_xy)
        return (centre[None] + spread).astype(np.float32)


WORLD_TRACKS = Mover(0, 60, (320, 240), (0, 0))


Cluster = Mover | tuple[Mover, ...]


def _window(
    book: LabelBook, prev: dict[int, int], window: int, clusters: list[Cluster]
) -> tuple[dict[int, int], dict[int, int]]:
    """One window whose cluster c holds the tracks of clusters[c] (a tuple: of several movers; cluster 0 the
    world). Returns (track id -> label, cluster -> label)."""
    groups = [c if isinstance(c, tuple) else (c,) for c in clusters]
    ids = np.concatenate([m.ids() for g in groups for m in g])
    cl = np.concatenate([np.full(m.n, c, np.int64) for c, g in enumerate(groups) for m in g])
    xy = np.concatenate([m.xy(window) for g in groups for m in g])
    labels = match_labels(prev, ids, cl, len(clusters), book, window, world=True, xy=xy, frame=4 * window)
    assert (labels[cl == 0] == 0).all(), "the world must stay 0"
    by_cluster = {c: int(labels[cl == c][0]) for c in range(len(clusters))}
    assert all(len(set(labels[cl == c].tolist())) == 1 for c in range(len(clusters)))
    return dict(zip(ids.tolist(), labels.tolist())), by_cluster


def _run(windows: list[list[Cluster]], cfg: LabelConfig = LabelConfig()) -> list[dict[int, int]]:
    book, prev, out = LabelBook(cfg=cfg), {}, []
    for w, clusters in enumerate(windows):
        prev, by_cluster = _window(book, prev, w, clusters)
        out.append(by_cluster)
    return out


def test_an_object_hidden_for_a_window_comes_back_with_its_label() -> None:
    a = Mover(100, 20, (100, 100), (5, 0))
    back = Mover(200, 20, (100, 100), (5, 0))  # the same object, new tracks (the old ones died behind something)
    windows = [[WORLD_TRACKS, a], [WORLD_TRACKS], [WORLD_TRACKS, back]]
    assert [w.get(1) for w in _run(windows)] == [1, None, 1]
    # Without the memory it is a new motion.
    assert [w.get(1) for w in _run(windows, LabelConfig(memory_windows=0))] == [1, None, 2]
    # Forgotten after memory_windows windows.
    assert (
        _run([[WORLD_TRACKS, a], [WORLD_TRACKS], [WORLD_TRACKS], [WORLD_TRACKS, back]], LabelConfig(memory_windows=1))[
            3
        ][1]
        == 2
    )


def test_a_motion_merged_for_a_window_splits_off_with_its_label() -> None:
    a, b = Mover(100, 25, (100, 100), (5, 0)), Mover(300, 20, (400, 300), (-5, 0))
    windows: list[list[Cluster]] = [[WORLD_TRACKS, a, b], [WORLD_TRACKS, (a, b)], [WORLD_TRACKS, b, a]]
    assert _run(windows)[2] == {0: 0, 1: 2, 2: 1}
    # Without the memory the piece that splits off keeps the merged label for a window, then gets a new one.
    plain = _run([*windows, [WORLD_TRACKS, b, a]], LabelConfig(memory_windows=0))
    assert plain[2] == {0: 0, 1: 1, 2: 1} and plain[3] == {0: 0, 1: 3, 2: 1}


def test_two_objects_crossing_keep_their_labels() -> None:
    # a moves right, b left; they cross on frames 8-12, where a hides b (b's tracks die) and comes out with new tracks.
    a = Mover(100, 20, (100, 200), (10, 0))
    b = Mover(300, 20, (300, 200), (-10, 0))
    b_after = Mover(400, 20, (300, 200), (-10, 0))
    windows = [[WORLD_TRACKS, a, b], [WORLD_TRACKS, b, a], [WORLD_TRACKS, a], [WORLD_TRACKS, b_after, a]]
    labels = _run(windows)
    assert labels[0] == {0: 0, 1: 1, 2: 2}
    assert labels[1] == {0: 0, 1: 2, 2: 1}  # clusters numbered anew: the labels follow the tracks
    assert labels[3] == {0: 0, 1: 2, 2: 1}  # b back where its motion carried it; a on its shared tracks


def test_a_new_object_gets_a_new_label() -> None:
    a = Mover(100, 20, (100, 100), (5, 0))
    elsewhere = Mover(200, 20, (500, 400), (0, -5))  # new tracks far from where a would be
    labels = _run([[WORLD_TRACKS, a], [WORLD_TRACKS], [WORLD_TRACKS, elsewhere]])
    assert labels[2] == {0: 0, 1: 2}
    # Two remembered labels, one cluster of new tracks near neither, one near the first: only that one returns.
    b = Mover(300, 20, (500, 100), (0, 5))
    near_a = Mover(400, 20, (100, 100), (5, 0))
    labels = _run([[WORLD_TRACKS, a, b], [WORLD_TRACKS], [WORLD_TRACKS, elsewhere, near_a]])
    assert labels[2] == {0: 0, 1: 3, 2: 1}


def test_a_small_new_object_is_labelled_from_the_settings_size() -> None:
    # 12 new tracks beside 600 of the world: under both default thresholds (15 tracks; 5 % = 31 tracks)
    world = Mover(0, 600, (320, 240), (0, 0))
    small = Mover(1000, 12, (100, 100), (5, 0))
    assert _run([[world, small]])[0] == {0: 0, 1: -1}
    assert _run([[world, small]], LabelConfig(new_tracks=10, new_share=0.0))[0] == {0: 0, 1: 1}
    assert _run([[world, small]], LabelConfig(new_tracks=10, new_share=0.05))[0] == {0: 0, 1: -1}


def test_a_shot_cut_forgets_every_label() -> None:
    book = LabelBook()
    a = Mover(100, 20, (100, 100), (5, 0))
    prev, _ = _window(book, {}, 0, [WORLD_TRACKS, a])
    book.forget()
    _, labels = _window(book, {}, 1, [WORLD_TRACKS, Mover(200, 20, (100, 100), (5, 0))])
    assert labels == {0: 0, 1: 2} and book.memory.keys() == {2}


def test_label_settings_are_checked() -> None:
    with pytest.raises(ConfigError, match="revive_share"):
        LabelConfig(revive_share=0.0)
    with pytest.raises(ConfigError, match="labels.gate"):
        PipelineConfig().with_settings(["labels.gate=-1"])
    cfg = PipelineConfig().with_settings(["labels.memory_windows=0"])
    assert PipelineConfig.from_dict({"labels": {"memory_windows": 0}}).labels == cfg.labels
