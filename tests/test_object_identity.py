"""Per-video and per-frame J per object and identity switches (evaluation.metrics), on hand-made label arrays."""

from __future__ import annotations

import numpy as np
import pytest

from mosegpipe.evaluation.identities import identity_switches, match_objects_video, object_identities, object_j


def _video() -> tuple[np.ndarray, np.ndarray]:
    """4 frames of 1x4 pixels: object 1 on pixels 0-1, object 2 on pixel 3; the prediction gives object 1
    label 5 in frames 0-2 and label 6 in frame 3, object 2 label 7 throughout (0 = world)."""
    gt = np.array([[[1, 1, 0, 2]]] * 4)
    pred = np.array([[[5, 5, 0, 7]]] * 3 + [[[6, 6, 0, 7]]])
    return pred, gt


def test_per_video_matching_charges_the_switch_and_per_frame_forgives_it() -> None:
    pred, gt = _video()
    assert match_objects_video(pred, gt, [1, 2]) == {1: 5, 2: 7}
    # per video: object 1 is label 5, J 1 in frames 0-2 and 0 in frame 3 -> 0.75
    assert object_j(pred, gt, [1, 2]) == pytest.approx({1: 0.75, 2: 1.0})
    # per frame: frame 3 matches object 1 to label 6 -> 1
    assert object_j(pred, gt, [1, 2], per_video=False) == pytest.approx({1: 1.0, 2: 1.0})
    assert identity_switches(pred, gt, [1, 2]) == {1: 1, 2: 0}


def test_one_label_for_two_objects_goes_to_one_of_them() -> None:
    gt = np.array([[[1, 1, 2, 2]]] * 2)
    pred = np.array([[[3, 3, 3, 0]]] * 2)  # label 3: IoU 2/3 with object 1, 1/4 with object 2
    assert match_objects_video(pred, gt, [1, 2]) == {1: 3, 2: None}
    assert object_j(pred, gt, [1, 2]) == pytest.approx({1: 2 / 3, 2: 0.0})


def test_world_and_unknown_are_no_identity() -> None:
    gt = np.array([[[1, 1, 0, 0]]] * 5)
    # frame 0: label 4; frame 1: world (not a switch); frame 2: unknown; frame 3: 4 again; frame 4: 9
    pred = np.array([[[4, 4, 0, 0]], [[0, 0, 0, 0]], [[255, 255, 0, 0]], [[4, 0, 0, 0]], [[9, 9, 0, 0]]])
    assert object_identities(pred, gt, [1]) == {1: [4, 4, 9]}
    assert identity_switches(pred, gt, [1]) == {1: 1}
    assert match_objects_video(pred, gt, [1]) == {1: 4}
    # per video: J 1, 0, 0, 0.5, 0 -> 0.3
    assert object_j(pred, gt, [1]) == pytest.approx({1: 0.3})


def test_switching_back_and_forth_counts_each_change() -> None:
    gt = np.ones((4, 1, 2), dtype=np.int64)
    pred = np.array([[[2, 2]], [[3, 3]], [[2, 2]], [[2, 3]]])  # frame 3: a tie 2/3 -> the smaller label, 2
    assert identity_switches(pred, gt, [1]) == {1: 2}


def test_a_label_on_too_little_of_the_object_is_no_identity() -> None:
    gt = np.ones((2, 1, 10), dtype=np.int64)
    pred = np.zeros((2, 1, 10), dtype=np.int64)
    pred[0, 0, :5] = 1
    pred[1, 0, 0] = 2  # 1 pixel of 10: under share 0.2
    assert identity_switches(pred, gt, [1], share=0.2) == {1: 0}
    assert identity_switches(pred, gt, [1], share=0.1) == {1: 1}


def test_an_absent_object_scores_one_where_nothing_claims_it() -> None:
    gt = np.array([[[1, 0]], [[0, 0]]])
    pred = np.array([[[1, 0]], [[0, 0]]])
    assert object_j(pred, gt, [1]) == {1: 1.0}
    assert object_j(pred, gt, [1], per_video=False) == {1: 1.0}


def test_shapes_must_agree() -> None:
    with pytest.raises(ValueError, match="shape"):
        object_j(np.zeros((2, 2, 2)), np.zeros((2, 2, 3)), [1])
