from __future__ import annotations

import math

import numpy as np
import pytest

from mosegpipe.errors import InputError
from mosegpipe.evaluation.metrics import misclassification_error
from mosegpipe.studies.ransac_curves import (
    CurveModel,
    RansacConfig,
    circles_from_triples,
    conic_to_ellipse,
    conics_from_quintuples,
    ellipse_points,
    fit_curve,
    lines_from_pairs,
    sequential_ransac,
)
from mosegpipe.synth.lce import LCEConfig, SingleKindDataset


def _circle(cx: float, cy: float, r: float, n: int, rng: np.random.Generator, sigma: float = 0.0) -> np.ndarray:
    theta = rng.uniform(0, 2 * np.pi, n)
    return np.stack([cx + r * np.cos(theta), cy + r * np.sin(theta)], 1) + rng.normal(0, sigma, (n, 2))


def _angle_diff(a: float, b: float) -> float:
    """Distance of two axis angles modulo pi."""
    d = (a - b) % math.pi
    return min(d, math.pi - d)


def test_minimal_fits_are_exact() -> None:
    # Line through (0, 1) and (2, 1): y = 1, normal (0, +-1), offset -+1.
    params, valid = lines_from_pairs(np.array([[[0.0, 1.0], [2.0, 1.0]], [[3.0, 3.0], [3.0, 3.0]]]))
    assert valid.tolist() == [True, False]
    assert abs(params[0, 0]) < 1e-12 and abs(params[0, 1]) == pytest.approx(1.0)
    assert params[0, 2] * params[0, 1] == pytest.approx(-1.0)
    # Circle through three points of the circle centred (1, -2) with radius 3; collinear points have none.
    pts = np.array([[4.0, -2.0], [1.0, 1.0], [-2.0, -2.0]])
    circles, ok = circles_from_triples(np.stack([pts, np.array([[0.0, 0], [1, 1], [2, 2]])]))
    assert ok.tolist() == [True, False]
    np.testing.assert_allclose(circles[0], [1.0, -2.0, 3.0], atol=1e-12)
    # Ellipse through five points of a known ellipse: the conic gives back its parameters.
    truth = np.array([0.3, -0.2, 0.9, 0.4, 0.7])
    five = ellipse_points(truth, 5)
    conics, good = conics_from_quintuples(five[None])
    assert good.tolist() == [True]
    got = conic_to_ellipse(conics[0])
    assert got is not None
    np.testing.assert_allclose(got[:4], truth[:4], atol=1e-9)
    assert _angle_diff(got[4], truth[4]) < 1e-9
    # Five points of a hyperbola x y = 1 are no ellipse; five points on a line are no hypothesis.
    hyper = np.array([[t, 1.0 / t] for t in (0.5, 1.0, 2.0, -1.0, -3.0)])
    line5 = np.stack([np.linspace(0, 1, 5), np.linspace(0, 2, 5)], 1)
    assert conics_from_quintuples(np.stack([hyper, line5]))[1].tolist() == [False, False]


def test_least_squares_fits_recover_known_curves() -> None:
    rng = np.random.default_rng(0)
    t = rng.uniform(-1.5, 1.5, 200)
    angle = 0.6
    line_pts = np.array([0.2, -0.4]) + t[:, None] * np.array([math.cos(angle), math.sin(angle)])
    line = fit_curve("line", line_pts + rng.normal(0, 0.005, line_pts.shape))
    assert line is not None and line.kind == "line"
    normal = line.params[:2]
    assert abs(normal @ [math.cos(angle), math.sin(angle)]) < 1e-2  # normal is perpendicular to the line
    assert line.distance([[0.2, -0.4]])[0] < 5e-3

    circle = fit_curve("circle", _circle(-0.5, 0.7, 0.8, 200, rng, sigma=0.005))
    assert circle is not None
    np.testing.assert_allclose(circle.params, [-0.5, 0.7, 0.8], atol=5e-3)
    # A short arc (a quarter circle): the geometric steps keep the radius right.
    theta = rng.uniform(0, np.pi / 2, 100)
    arc = np.stack([0.6 * np.cos(theta), 0.6 * np.sin(theta)], 1) + rng.normal(0, 0.003, (100, 2))
    short = fit_curve("circle", arc)
    assert short is not None and short.params[2] == pytest.approx(0.6, abs=0.01)

    truth = np.array([0.1, 0.3, 0.95, 0.45, 2.4])
    dense = ellipse_points(truth, 300)
    ellipse = fit_curve("ellipse", dense + rng.normal(0, 0.005, dense.shape))
    assert ellipse is not None
    np.testing.assert_allclose(ellipse.params[:4], truth[:4], atol=0.01)
    assert _angle_diff(ellipse.params[4], truth[4]) < 0.02
    # Too few points: no fit.
    assert fit_curve("ellipse", dense[:4]) is None and fit_curve("line", dense[:1]) is None


def test_distances_are_geometric() -> None:
    circle = CurveModel("circle", np.array([0.0, 0.0, 1.0]))
    np.testing.assert_allclose(circle.distance([[2.0, 0.0], [0.0, 0.5], [0.0, 0.0]]), [1.0, 0.5, 1.0])
    # An ellipse with equal axes is that circle; the sampled distance is accurate to ~1e-5.
    round_ellipse = CurveModel("ellipse", np.array([0.0, 0.0, 1.0, 1.0, 0.3]))
    np.testing.assert_allclose(
        round_ellipse.distance([[2.0, 0.0], [0.0, 0.5], [0.3, -0.4]]), [1.0, 0.5, 0.5], atol=1e-4
    )
    # Distance to an ellipse along its minor axis: b - y.
    flat = CurveModel("ellipse", np.array([1.0, 1.0, 2.0, 0.5, 0.0]))
    assert flat.distance([[1.0, 1.2]])[0] == pytest.approx(0.3, abs=1e-4)
    line = CurveModel("line", np.array([0.0, 1.0, -1.0]))  # y = 1
    np.testing.assert_allclose(line.distance([[5.0, 3.0], [-2.0, 1.0]]), [2.0, 0.0])


@pytest.mark.parametrize("kind", ["line", "circle", "ellipse"])
def test_two_models_recovered_on_low_noise_data(kind: str) -> None:
    data = SingleKindDataset(kind, 10, 2, seed=5, split="ransac-test", cfg=LCEConfig(noise_sigma=0.005))
    cfg = RansacConfig(noise_sigma=0.005)
    errors = []
    for i, clip in enumerate(data):
        fit = sequential_ransac(clip.traj, kind, 2, RansacConfig(noise_sigma=0.005, seed=i))
        assert fit.labels.shape == clip.labels.shape and fit.labels.dtype == np.int64
        assert len(fit.models) == 2 and all(m.kind == kind for m in fit.models)
        assert all(1 <= h <= cfg.max_hypotheses for h in fit.num_hypotheses)
        errors.append(misclassification_error(fit.labels, clip.labels))
    # Only points near a crossing of the two curves are ambiguous at this noise level.
    assert float(np.median(errors)) < 0.02 and float(np.mean(errors)) < 0.08, errors


def test_separate_circles_exactly_and_seeded() -> None:
    rng = np.random.default_rng(1)
    pts = np.concatenate([_circle(-2, 0, 1, 40, rng, 0.02), _circle(2, 0, 0.5, 30, rng, 0.02)])
    labels = np.repeat([0, 1], [40, 30])
    fit = sequential_ransac(pts, "circle", 2, RansacConfig(noise_sigma=0.02, seed=3))
    assert misclassification_error(fit.labels, labels) == 0.0
    found = sorted(fit.models, key=lambda m: m.params[0])
    np.testing.assert_allclose(found[0].params, [-2, 0, 1], atol=0.02)
    np.testing.assert_allclose(found[1].params, [2, 0, 0.5], atol=0.02)
    again = sequential_ransac(pts, "circle", 2, RansacConfig(noise_sigma=0.02, seed=3))
    np.testing.assert_array_equal(again.labels, fit.labels)
    assert again.num_hypotheses == fit.num_hypotheses


def test_too_few_points_and_bad_inputs() -> None:
    rng = np.random.default_rng(2)
    five = _circle(0, 0, 1, 5, rng)
    # K = 3 circles asked of 5 points: the first takes them all, the others cannot be drawn.
    fit = sequential_ransac(five, "circle", 3)
    assert len(fit.models) == 1 and fit.labels.tolist() == [0] * 5
    # Fewer points than a minimal sample: no model, every point in group 0.
    none = sequential_ransac(five[:4], "ellipse", 2)
    assert none.models == [] and none.labels.tolist() == [0, 0, 0, 0]
    with pytest.raises(InputError, match="expected \\(N, 2\\)"):
        sequential_ransac(np.zeros((4, 3)), "line", 1)
    with pytest.raises(InputError, match="NaN"):
        sequential_ransac(np.array([[0.0, np.nan], [1.0, 1.0]]), "line", 1)
    with pytest.raises(InputError, match="curve kind 'parabola'"):
        sequential_ransac(five, "parabola", 1)
    with pytest.raises(InputError, match="k=0"):
        sequential_ransac(five, "line", 0)
    with pytest.raises(InputError, match="noise_sigma"):
        RansacConfig(noise_sigma=0.0)
    with pytest.raises(InputError, match="confidence"):
        RansacConfig(confidence=1.0)
    with pytest.raises(InputError, match="max_hypotheses"):
        RansacConfig(max_hypotheses=0)
    assert RansacConfig().threshold == pytest.approx(0.125)
