"""A label born within the held-back windows that merges back into a motion beside it (`pipeline.merge_back`)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from mosegpipe.group.labels import LabelBook
from mosegpipe.pipeline.merge_back import Aliases, WindowLabels, held_back, merged_back
from mosegpipe.pipeline.window import VideoFrame, WindowResult

T = 5  # frames per window


def _tracks(n: int, start_xy: tuple[float, float], v_xy: tuple[float, float], jitter: float, seed: int) -> npt.NDArray:
    """(n, T, 2) float32 tracks around start_xy moving v_xy px per frame, each frame jittered by up to `jitter` px."""
    rng = np.random.default_rng(seed)
    xy0 = np.asarray(start_xy) + rng.uniform(-40, 40, (n, 1, 2))
    steps = np.arange(T)[None, :, None] * np.asarray(v_xy)[None, None, :]
    return (xy0 + steps + rng.uniform(-jitter, jitter, (n, T, 2))).astype(np.float32)


def _window_before(piece_v: tuple[float, float], piece_jitter: float) -> WindowLabels:
    """A still world (label 0, 60 tracks), a mover (label 1, 30 tracks) and a piece beside it (label 2, 20)."""
    xy = np.concatenate(
        [
            _tracks(60, (320, 240), (0.0, 0.0), 0.2, 1) + np.random.default_rng(9).uniform(-250, 250, (60, 1, 2)),
            _tracks(30, (200, 200), (4.0, 0.0), 0.2, 2),
            _tracks(20, (220, 300), piece_v, piece_jitter, 3),
        ]
    ).astype(np.float32)
    labels = np.repeat([0, 1, 2], [60, 30, 20]).astype(np.int64)
    return WindowLabels(3, track_ids=np.arange(110, dtype=np.int64), labels=labels, xy=xy)


def _now_merged(ids: npt.NDArray[np.int64]) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """This window: the same tracks, the piece's now in the mover's cluster (label 1)."""
    return ids, np.repeat([0, 1], [60, 50]).astype(np.int64)


def test_a_non_rigid_piece_that_merges_back_takes_the_label_it_joined() -> None:
    before = _window_before((4.0, 0.0), 6.0)  # moves with the mover, limbs flailing: no rigid motion of its own
    ids, labels = _now_merged(before.track_ids)
    assert merged_back(before, ids, labels, {1: 0, 2: 0}, since=0) == {2: 1}


def test_a_rigid_piece_keeps_its_label_when_the_grouping_merges_it() -> None:
    before = _window_before((-3.0, 2.0), 0.2)  # one rigid motion of its own: an object the grouping merged
    ids, labels = _now_merged(before.track_ids)
    assert merged_back(before, ids, labels, {1: 0, 2: 0}, since=0) == {}


def test_only_labels_born_within_the_held_windows_merge_back() -> None:
    before = _window_before((4.0, 0.0), 6.0)
    ids, labels = _now_merged(before.track_ids)
    assert merged_back(before, ids, labels, {1: 0, 2: 0}, since=1) == {}
    # a piece whose tracks ended (left the view) merged into nothing
    keep = np.arange(94)  # 4 of its tracks left: too few to say where it went
    assert merged_back(before, ids[keep], labels[keep], {1: 0, 2: 0}, since=0) == {}
    # a piece still labelled in this window did not merge
    still = labels.copy()
    still[90:] = 2
    assert merged_back(before, ids, still, {1: 0, 2: 0}, since=0) == {}


def test_aliases_resolve_chains_and_relabel_masks_and_tracks() -> None:
    aliases = Aliases()
    aliases.add(3, 2, 8)
    aliases.add(2, 1, 12)
    assert aliases.resolve(3, 4) == 1 and aliases.resolve(2, 4) == 1 and aliases.resolve(4, 4) == 4
    mask = np.array([[0, 1, 2], [3, 254, 255]], np.uint8)
    assert aliases.relabel_mask(mask, 4).tolist() == [[0, 1, 1], [1, 254, 255]]
    untouched = np.array([[0, 4]], np.uint8)
    assert aliases.relabel_mask(untouched, 4) is untouched
    assert aliases.relabel(np.array([3, -1, 0, 2, 5]), 4).tolist() == [1, -1, 0, 1, 5]


def test_a_merged_label_handed_out_again_later_is_the_new_motions() -> None:
    """A label merges at frame 8 and the label book hands the number out again at frame 20 (labels are reused
    once the mask range is spent): the windows up to frame 8 show the label it joined, the later ones keep it."""
    aliases = Aliases()
    aliases.add(3, 1, 8)
    assert aliases.resolve(3, 8) == 1 and aliases.resolve(3, 20) == 3
    mask = np.array([[3, 0]], np.uint8)
    assert aliases.relabel_mask(mask, 4).tolist() == [[1, 0]]
    assert aliases.relabel_mask(mask, 20) is mask
    assert aliases.relabel(np.array([3, 0]), 20).tolist() == [3, 0]
    aliases.drop_before(9)  # every window up to frame 8 has left
    assert aliases.to == {} and aliases.resolve(3, 4) == 3


def _result(start: int, label: int) -> WindowResult:
    mask = np.full((4, 4), label, np.uint8)
    frame = VideoFrame(
        start, np.zeros((4, 4, 3), np.uint8), np.array([7]), np.zeros((1, 2), np.float32), np.array([label]), mask
    )
    return WindowResult(start, T, 1, 2, np.array([7]), np.array([label]), (frame,), 3, 0, start + 4)


def test_held_back_windows_are_relabelled_by_a_merge_found_later() -> None:
    for windows, relabelled in ((2, [1, 1, 1]), (1, [2, 1, 1]), (0, [2, 2, 1])):
        aliases = Aliases()

        def results(aliases: Aliases = aliases) -> object:
            yield _result(0, 2)
            yield _result(4, 2)
            aliases.add(2, 1, 8)  # found while labelling the third window
            yield _result(8, 1)

        out = list(held_back(results(), windows, aliases))  # type: ignore[arg-type]
        assert [int(r.frames[0].mask[0, 0]) for r in out] == relabelled
        assert [int(r.labels[0]) for r in out] == relabelled
        assert [r.start for r in out] == [0, 4, 8]


def test_a_retired_label_is_forgotten_and_its_last_mask_shows_the_label_it_joined() -> None:
    book = LabelBook()
    book.born = {1: 0, 2: 0}
    book.dense = {2}
    book.last_mask = np.array([[0, 2, 1]], np.uint8)
    book.retire(2, 1)
    assert 2 not in book.born and 2 not in book.dense
    assert book.last_mask.tolist() == [[0, 1, 1]]
