"""Two-view geometry on hand-made scenes: a translating camera before two planes needs F, a plane needs only H."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from mosegpipe.group import twoview

FOCAL, CX, CY = 500.0, 320.0, 240.0


def _project(points: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """(N, 2) pixels of (N, 3) world points seen by an unrotated camera at `centre`."""
    rel = points - centre
    return np.stack([FOCAL * rel[:, 0] / rel[:, 2] + CX, FOCAL * rel[:, 1] / rel[:, 2] + CY], axis=1)


def _two_planes(n: int = 300, seed: int = 0) -> np.ndarray:
    """(2n, 3) points on a near plane (Z = 4) and a far one (Z = 20), both across the view."""
    rng = np.random.default_rng(seed)
    near = np.column_stack([rng.uniform(-2, 2, n), rng.uniform(-1.5, 1.5, n), np.full(n, 4.0)])
    far = np.column_stack([rng.uniform(-10, 10, n), rng.uniform(-7, 7, n), np.full(n, 20.0)])
    return np.concatenate([near, far])


def test_fundamental_explains_two_planes_seen_by_a_translating_camera_and_homography_does_not() -> None:
    scene = _two_planes()
    move = np.array([0.3, 0.05, 0.1])
    p, q = _project(scene, np.zeros(3)), _project(scene, move)
    q = q + np.random.default_rng(1).normal(0, 0.2, q.shape)
    fun, f_in = twoview.fit_with_inliers("fundamental", p, q, 1.0)
    hom, h_in = twoview.fit_with_inliers("homography", p, q, 2.0)
    assert fun is not None and hom is not None
    assert f_in.mean() > 0.95 and np.median(twoview.sampson_px(fun, p, q)) < 0.5
    assert h_in.mean() < 0.6  # one plane at most
    assert twoview.gric(np.square(twoview.sampson_px(fun, p, q)), 0.3, 3, 7) < twoview.gric(
        np.square(twoview.transfer_px(hom, p, q)), 0.3, 2, 8
    )
    # the epipole is the image of the first camera's centre in the second image
    e = twoview.epipole(fun)
    expected = _project(np.zeros((1, 3)), move)[0]
    assert e[:2] / e[2] == pytest.approx(expected, rel=0.02)


def test_gric_prefers_the_homography_on_a_planar_scene_and_a_rotating_camera() -> None:
    rng = np.random.default_rng(2)
    plane = np.column_stack([rng.uniform(-10, 10, 400), rng.uniform(-7, 7, 400), np.full(400, 20.0)])
    p, q = _project(plane, np.zeros(3)), _project(plane, np.array([0.5, 0.0, 0.2]))
    q = q + rng.normal(0, 0.3, q.shape)
    fun, _ = twoview.fit_with_inliers("fundamental", p, q, 1.0)
    hom, _ = twoview.fit_with_inliers("homography", p, q, 2.0)
    assert fun is not None and hom is not None
    assert twoview.gric(np.square(twoview.transfer_px(hom, p, q)), 0.3, 2, 8) < twoview.gric(
        np.square(twoview.sampson_px(fun, p, q)), 0.3, 3, 7
    )


def test_plane_parallax_keeps_one_depth_for_the_static_world_and_not_for_a_mover_along_its_epipolar_line() -> None:
    scene = _two_planes(200)
    ref = _project(scene, np.zeros(3))
    step = np.array([0.2, 0.0, 0.0])  # sideways: the epipolar lines are the image rows
    views = [_project(scene, step * k) for k in (2, 4)]
    # a mover on the far plane that slides along its rows, at a speed that changes between the frames
    mover = np.arange(200, 230)
    views[0][mover, 0] += 6.0
    views[1][mover, 0] -= 9.0
    parallax, basis = [], []
    for q in views:
        fun, _ = twoview.fit_with_inliers("fundamental", ref, q, 0.5)
        hom, h_in = twoview.fit_with_inliers("homography", ref, q, 1.0)
        assert fun is not None and hom is not None
        plane = twoview.compatible_homography(fun, hom, ref[h_in], q[h_in])
        mapped, v = twoview.parallax_basis(plane, twoview.epipole(fun), ref)
        parallax.append(q - mapped)
        basis.append(v)
        assert np.median(twoview.sampson_px(fun, ref[mover], q[mover])) < 0.5  # each F alone holds it
    g_ref = np.sum(parallax[0] * basis[0], axis=1) / np.sum(basis[0] ** 2, axis=1)
    static = np.setdiff1d(np.arange(len(scene)), mover)
    scale = twoview.depth_scale(parallax[1][static], basis[1][static], g_ref[static])
    assert abs(scale) == pytest.approx(
        2.0, rel=0.05
    )  # twice the baseline, twice the parallax (the epipole: either sign)
    _, residual = twoview.shared_depth_residual(parallax, basis, [1.0, scale])
    assert np.percentile(residual[static], 95) < 0.5
    assert np.median(residual[mover]) > 3.0


def test_fits_refuse_too_few_points_and_gric_caps_outliers() -> None:
    p = np.zeros((3, 2))
    assert twoview.fit_with_inliers("homography", p, p, 1.0)[0] is None
    assert not twoview.fit_with_inliers("fundamental", p, p, 1.0)[1].any()
    # GRIC's robust cost caps each outlier: one wild residual costs as much as a merely bad one
    assert twoview.gric(np.square([100.0]), 1.0, 2, 8) == twoview.gric(np.square([10.0]), 1.0, 2, 8)


def test_a_fit_that_opencv_refuses_with_an_assertion_is_no_fit(monkeypatch: pytest.MonkeyPatch) -> None:
    # USAC asserts (cv2.error) on some degenerate samples; a caller gets "no model", as for any failed fit
    def refuse(*args: object, **kwargs: object) -> None:
        raise cv2.error("!model.empty()")

    monkeypatch.setattr(cv2, "findFundamentalMat", refuse)
    monkeypatch.setattr(cv2, "findHomography", refuse)
    p = np.random.default_rng(0).uniform(0, 100, (30, 2))
    for kind in ("fundamental", "homography"):
        assert twoview.robust_fit(kind, p, p + 1, "magsac", 1.0) == (None, None)
        model, inliers = twoview.fit_with_inliers(kind, p, p + 1, 1.0)
        assert model is None and not inliers.any()
