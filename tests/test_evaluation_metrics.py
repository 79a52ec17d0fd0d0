from __future__ import annotations

import numpy as np
import pytest

from mosegpipe.evaluation.metrics import (
    boundary_f,
    boundary_map,
    contingency,
    correct_k_rate,
    error_summary,
    fbms_prf,
    jaccard,
    mask_scores,
    match_masks,
    misclassification_error,
    nmi,
)

# --- misclassification error ---------------------------------------------------------------------


def test_renamed_partition_has_zero_error() -> None:
    assert misclassification_error([0, 0, 1, 1, 1], [1, 1, 0, 0, 0]) == 0.0


def test_one_error_in_five() -> None:
    assert misclassification_error([0, 0, 1, 1, 0], [0, 0, 1, 1, 1]) == pytest.approx(0.2)


def test_more_predicted_clusters_than_groups() -> None:
    # p0 -> g0 (2 points) and p2 -> g1 (2 points); p1 is unmatched: 2 of 6 wrong
    assert misclassification_error([0, 0, 1, 1, 2, 2], [0, 0, 0, 1, 1, 1]) == pytest.approx(1 / 3)


def test_fewer_predicted_clusters_than_groups() -> None:
    # one cluster matches the largest group (3 points); the other 3 are errors
    assert misclassification_error([5, 5, 5, 5, 5, 5], [0, 0, 0, 1, 1, 2]) == pytest.approx(0.5)


def test_one_to_one_matching_on_a_mixed_table() -> None:
    # table [[2, 1], [1, 1]]: p0 -> g0 and p1 -> g1 agree on 3 of 5 points
    assert misclassification_error([0, 0, 0, 1, 1], [0, 0, 1, 0, 1]) == pytest.approx(2 / 5)


def test_error_is_invariant_to_renaming_and_point_order() -> None:
    rng = np.random.default_rng(0)
    gt = rng.integers(0, 4, 200)
    pred = np.where(rng.random(200) < 0.8, gt, rng.integers(0, 5, 200))
    base = misclassification_error(pred, gt)
    renamed = np.array([3, 0, 4, 1, 2])[pred]
    order = rng.permutation(200)
    assert misclassification_error(renamed, gt) == pytest.approx(base)
    assert misclassification_error(pred[order], gt[order]) == pytest.approx(base)
    assert misclassification_error(gt, pred) == pytest.approx(base)  # symmetric
    assert 0.0 < base < 0.3


def test_contingency_counts() -> None:
    table = contingency([7, 7, 2, 2, 2], [0, 1, 1, 1, 0])
    # rows: pred ids sorted (2, 7); columns: gt ids sorted (0, 1)
    np.testing.assert_array_equal(table, [[1, 2], [1, 1]])


# --- validation ----------------------------------------------------------------------------------


def test_shape_mismatch_names_both_shapes() -> None:
    with pytest.raises(ValueError, match=r"pred has shape \(3,\) but gt has shape \(4,\)"):
        misclassification_error([0, 1, 1], [0, 1, 1, 0])


def test_empty_input_is_rejected() -> None:
    with pytest.raises(ValueError, match="empty"):
        misclassification_error([], [])


def test_two_dimensional_labels_are_rejected() -> None:
    with pytest.raises(ValueError, match=r"1-D.*\(2, 2\)"):
        nmi(np.zeros((2, 2), int), np.zeros((2, 2), int))


def test_fractional_labels_are_rejected() -> None:
    with pytest.raises(ValueError, match="integer"):
        misclassification_error([0.5, 1.0], [0, 1])


def test_integral_float_labels_are_accepted() -> None:
    assert misclassification_error(np.array([0.0, 1.0]), [1, 0]) == 0.0


# --- NMI -----------------------------------------------------------------------------------------


def test_nmi_known_values() -> None:
    assert nmi([0, 0, 1, 1], [1, 1, 0, 0]) == pytest.approx(1.0)
    assert nmi([0, 1, 0, 1], [0, 0, 1, 1]) == pytest.approx(0.0, abs=1e-12)  # independent


# --- FBMS P/R/F ----------------------------------------------------------------------------------


def test_fbms_hand_computed() -> None:
    # Region 0 = background (6 points), region 1 = object (4 points).
    # Cluster A: 5 background + 1 object; cluster B: 1 background + 3 object.
    # A<->background: P = R = 5/6;  B<->object: P = R = 3/4 (F = 0.75, not > 0.75).
    gt = [0, 0, 0, 0, 0, 0, 1, 1, 1, 1]
    pred = [0, 0, 0, 0, 0, 1, 1, 1, 1, 0]
    p, r, f, objects = fbms_prf(pred, gt)
    assert p == pytest.approx(19 / 24)
    assert r == pytest.approx(19 / 24)
    assert f == pytest.approx(19 / 24)
    assert objects == 0
    assert fbms_prf(pred, gt, object_threshold=0.7)[3] == 1
    # with no background, the background region counts as an object too (F = 5/6)
    assert fbms_prf(pred, gt, background=None, object_threshold=0.7)[3] == 2


def test_fbms_over_segmentation_ignores_extra_clusters() -> None:
    # The object is split in two halves: the unmatched half is ignored, recall of the object 1/2.
    p, r, f, objects = fbms_prf([0, 0, 0, 0, 1, 1, 2, 2], [0, 0, 0, 0, 1, 1, 1, 1])
    assert (p, r) == pytest.approx((1.0, 0.75))
    assert f == pytest.approx(2 * 0.75 / 1.75)
    assert objects == 0  # F(object) = 2/3


def test_fbms_under_segmentation_counts_missing_regions() -> None:
    # One cluster for three regions: matched to the background (F = 2/3); the two object
    # regions get no cluster and count P = 1, R = 0.
    p, r, f, objects = fbms_prf([4, 4, 4, 4, 4, 4], [0, 0, 0, 1, 1, 2])
    assert p == pytest.approx((0.5 + 1 + 1) / 3)
    assert r == pytest.approx(1 / 3)
    assert f == pytest.approx(10 / 21)
    assert objects == 0


def test_fbms_perfect_and_unlabelled_points() -> None:
    gt = np.array([0, 0, 1, 1, 2, 2, -1, -1, -1])
    pred = np.array([2, 2, 0, 0, 1, 1, 0, 1, 2])  # unlabelled points assigned anywhere
    assert fbms_prf(pred, gt) == pytest.approx((1.0, 1.0, 1.0, 2))


def test_fbms_rejects_all_unlabelled() -> None:
    with pytest.raises(ValueError, match="no labelled point"):
        fbms_prf([0, 1], [-1, -1])


# --- summaries -----------------------------------------------------------------------------------


def test_correct_k_rate() -> None:
    assert correct_k_rate([2, 3, 4], [2, 3, 5]) == pytest.approx(2 / 3)
    with pytest.raises(ValueError, match=r"\(2,\).*\(3,\)"):
        correct_k_rate([2, 3], [2, 3, 4])
    with pytest.raises(ValueError, match="empty"):
        correct_k_rate([], [])


def test_error_summary() -> None:
    summary = error_summary([0.1, 0.0, 0.5])
    assert summary == pytest.approx({"mean": 0.2, "median": 0.1, "max": 0.5, "count": 3.0})
    with pytest.raises(ValueError, match="non-empty"):
        error_summary([])
    with pytest.raises(ValueError, match="NaN"):
        error_summary([0.1, float("nan")])


def _square(size_hw: tuple[int, int], x0: int, y0: int, side: int) -> np.ndarray:
    m = np.zeros(size_hw, dtype=bool)
    m[y0 : y0 + side, x0 : x0 + side] = True
    return m


# ---------------------------------------------------------------- J and boundary F


def test_jaccard_of_shifted_square_is_hand_computed() -> None:
    a = _square((40, 40), 10, 10, 10)
    b = _square((40, 40), 13, 10, 10)  # shifted 3 px right: overlap 7 x 10, union 130
    assert jaccard(b, a) == pytest.approx(70 / 130)
    assert jaccard(a, a) == 1.0
    assert jaccard(np.zeros((4, 4), bool), np.zeros((4, 4), bool)) == 1.0
    assert jaccard(a, np.zeros_like(a)) == 0.0


def test_boundary_map_is_inner_contour_without_image_border() -> None:
    sq = boundary_map(_square((20, 20), 5, 5, 4))
    assert sq.sum() == 12  # 4 x 4 square: 16 pixels, 2 x 2 interior
    assert not sq[6:8, 6:8].any()
    # A mask covering the whole image has no contour: the image border is not a boundary.
    assert not boundary_map(np.ones((10, 10), bool)).any()


def test_boundary_f_of_shifted_square_is_hand_computed() -> None:
    gt = _square((100, 100), 10, 10, 10)
    pred = _square((100, 100), 13, 10, 10)
    # Each contour has 36 pixels. Within 2 px of the other contour: 9 of 10 on the top row, 9 on
    # the bottom row, 4 of the 8 inner pixels of the near side column, none on the far column.
    p, r, f = boundary_f(pred, gt, tolerance=2)
    assert (p, r) == (pytest.approx(22 / 36), pytest.approx(22 / 36))
    assert f == pytest.approx(22 / 36)
    # 0.008 of the 100 x 100 diagonal (1.13 px) rounds up to the same 2 px.
    assert boundary_f(pred, gt, tolerance=0.008) == (p, r, f)
    # With 3 px the whole shifted contour is within reach.
    assert boundary_f(pred, gt, tolerance=3)[2] == pytest.approx(1.0)
    assert boundary_f(gt, gt) == (1.0, 1.0, 1.0)


def test_boundary_f_empty_cases() -> None:
    empty = np.zeros((30, 30), bool)
    sq = _square((30, 30), 5, 5, 6)
    assert boundary_f(empty, empty) == (1.0, 1.0, 1.0)
    assert boundary_f(empty, sq) == (1.0, 0.0, 0.0)
    assert boundary_f(sq, empty) == (0.0, 1.0, 0.0)
    with pytest.raises(ValueError, match="shape"):
        boundary_f(sq, sq[:-1])


# ---------------------------------------------------------------- label permutation


def _scene() -> np.ndarray:
    """(2, 40, 60) ground truth: background 0, object 1 (left square), object 2 (right square)."""
    g = np.zeros((2, 40, 60), dtype=np.uint8)
    g[:, 5:15, 5:15] = 1
    g[:, 20:30, 35:50] = 2
    return g


def test_permuted_labels_score_perfectly() -> None:
    gt = _scene()
    pred = np.choose(gt, [2, 3, 1]).astype(np.uint8)  # background -> 2, object 1 -> 3, object 2 -> 1
    assert match_masks(pred, gt) == {0: 2, 1: 3, 2: 1}
    s = mask_scores(pred, gt)
    assert (s.j, s.f) == (1.0, 1.0)
    assert set(s.j_per_group) == {1, 2}  # the background is matched but not averaged
    assert mask_scores(pred, gt, background=None).j_per_group.keys() == {0, 1, 2}


def test_hungarian_keeps_background_cluster_from_the_object() -> None:
    gt = _scene()
    pred = np.full(gt.shape, 1, dtype=np.uint8)  # one cluster covers everything ...
    pred[:, 20:30, 35:42] = 2  # ... except half of object 2, with a second cluster
    pred[:, 0:2, :] = 0  # a strip of unknown pixels never matches anything
    # Object 2 overlaps cluster 1 more (80 px) than cluster 2 (70 px), but cluster 1 is worth
    # more to the background; object 1 is left without a cluster.
    assert match_masks(pred, gt) == {0: 1, 1: None, 2: 2}
    s = mask_scores(pred, gt, tolerance=1)
    assert s.j_per_group[1] == 0.0 and s.f_per_group[1] == 0.0
    assert s.j_per_group[2] == pytest.approx(70 / 150)
    assert s.j == pytest.approx((0 + 70 / 150) / 2)


def test_object_absent_from_a_frame_counts_as_one_there() -> None:
    gt = _scene()
    gt[1][gt[1] == 2] = 0  # object 2 leaves in frame 2
    pred = gt.copy() + 1  # exact, shifted ids (0 would be "unknown")
    s = mask_scores(pred, gt)
    assert s.j_per_group == {1: 1.0, 2: 1.0}
