"""Sequential RANSAC for K curves of one kind (lines, circles or ellipses): the hypothesise-and-test baseline.

The classical multi-model fit the paper's sampling-imbalance figure argues against: draw minimal samples
uniformly (2 points for a line, 3 for a circle, 5 for an ellipse), fit a curve to each, keep the one with
the most inliers, refit it to its inliers, remove them and repeat K times; then give every point to the
curve it is nearest to. With K curves of similar size the chance that a minimal sample of m points lies
on one curve falls roughly as K^(1-m), which is what the study measures.

The baseline is given what the paper's baseline is given: the true K and the noise level (the inlier
threshold is `threshold_sigmas` times the generator's sigma). Distances are in the units of the points
(the unit-scale LCE curves): exact point-to-line and point-to-circle distances; for ellipse hypotheses the
Sampson distance |Q(x)| / |grad Q(x)| of the conic Q (a first-order approximation of the geometric
distance, exact to first order near the curve), and for fitted ellipses the distance to the nearest of
foot point found by Newton steps on the ellipse's angle parameter from the nearest of 64 points spread
evenly over it.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from mosegpipe.errors import InputError

log = logging.getLogger(__name__)

MIN_SAMPLE = {"line": 2, "circle": 3, "ellipse": 5}
"""Points in a minimal sample per curve kind."""

_ELLIPSE_SAMPLES = 64
"""Start angles on a fitted ellipse for its distance, each point refined from the nearest (see _ellipse_distance)."""


@dataclass(frozen=True)
class RansacConfig:
    """Settings of the sequential RANSAC baseline.

    Attributes:
        noise_sigma: the noise level of the points (same units), given to the baseline (LCE: 0.05).
        threshold_sigmas: inlier threshold in units of sigma; 2.5 sigma keeps ~99 % of the inliers of
            a curve when the noise is Gaussian across it.
        max_hypotheses: most minimal samples drawn per model (OpenCV's findHomography default, 2000).
        confidence: adaptive stop: stop drawing once an all-inlier sample of the best model so far
            would have been drawn with this probability.
        batch: hypotheses drawn and scored together (vectorised).
        refits: least-squares refits of the best hypothesis to its inliers (each kept only when it
            has at least as many inliers).
        seed: seed of the sampling.
    """

    noise_sigma: float = 0.05
    threshold_sigmas: float = 2.5
    max_hypotheses: int = 2000
    confidence: float = 0.99
    batch: int = 256
    refits: int = 2
    seed: int = 0

    def __post_init__(self) -> None:
        if not self.noise_sigma > 0 or not self.threshold_sigmas > 0:
            raise InputError(
                f"noise_sigma={self.noise_sigma}, threshold_sigmas={self.threshold_sigmas}: both must be > 0"
            )
        if self.max_hypotheses < 1 or self.batch < 1 or self.refits < 0:
            raise InputError(
                f"max_hypotheses={self.max_hypotheses}, batch={self.batch}, refits={self.refits}: "
                "need max_hypotheses >= 1, batch >= 1, refits >= 0"
            )
        if not 0.0 < self.confidence < 1.0:
            raise InputError(f"confidence={self.confidence} must lie in (0, 1)")

    @property
    def threshold(self) -> float:
        """The inlier threshold: threshold_sigmas * noise_sigma (units of the points)."""
        return self.threshold_sigmas * self.noise_sigma


@dataclass(frozen=True)
class CurveModel:
    """One fitted curve.

    Attributes:
        kind: "line", "circle" or "ellipse".
        params: float64; line (nx, ny, c): unit normal and offset, nx x + ny y + c = 0; circle
            (cx, cy, r); ellipse (cx, cy, a, b, angle): centre, semi-axes a >= b, angle (radians, in
            [0, pi)) of the major axis from the x axis.
    """

    kind: str
    params: npt.NDArray[np.float64]

    def distance(self, xy: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Distance of (N, 2) points to the curve: (N,) float64, units of the points (see the module docstring)."""
        pts = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        p = self.params
        if self.kind == "line":
            return np.asarray(np.abs(pts @ p[:2] + p[2]))
        if self.kind == "circle":
            return np.asarray(np.abs(np.linalg.norm(pts - p[:2], axis=1) - p[2]))
        return _ellipse_distance(p, pts)


@dataclass(frozen=True)
class RansacResult:
    """What sequential RANSAC found.

    Attributes:
        labels: (N,) int64 in 0..len(models)-1: the nearest model of every point (all 0 when no
            model was found).
        models: the fitted curves, in the order found (at most K: fewer when too few points remain).
        num_hypotheses: minimal samples drawn for each model.
        num_inliers: inliers of each model when it was found (among the points then remaining).
    """

    labels: npt.NDArray[np.int64]
    models: list[CurveModel] = field(default_factory=list)
    num_hypotheses: list[int] = field(default_factory=list)
    num_inliers: list[int] = field(default_factory=list)


def ellipse_points(params: npt.ArrayLike, count: int) -> npt.NDArray[np.float64]:
    """(count, 2) float64 points spread evenly in angle over the ellipse (cx, cy, a, b, angle)."""
    cx, cy, a, b, angle = np.asarray(params, dtype=np.float64)
    theta = np.linspace(0.0, 2 * np.pi, count, endpoint=False)
    c, s = math.cos(angle), math.sin(angle)
    u, v = a * np.cos(theta), b * np.sin(theta)
    return np.stack([cx + c * u - s * v, cy + s * u + c * v], axis=1)


def _ellipse_distance(params: npt.NDArray[np.float64], pts: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """(N,) distances of (N, 2) points to the ellipse (cx, cy, a, b, angle): the nearest of 64 points on it,
    refined by Newton steps on the angle theta of e(theta) = (a cos theta, b sin theta), never worse than that start."""
    cx, cy, a, b, angle = params
    c, s = math.cos(angle), math.sin(angle)
    dx, dy = pts[:, 0] - cx, pts[:, 1] - cy
    u, v = c * dx + s * dy, -s * dx + c * dy  # the points in the ellipse's own frame
    step = 2 * np.pi / _ELLIPSE_SAMPLES
    grid = np.arange(_ELLIPSE_SAMPLES) * step
    d2 = (a * np.cos(grid)[None] - u[:, None]) ** 2 + (b * np.sin(grid)[None] - v[:, None]) ** 2
    best = d2.argmin(axis=1)
    start = np.sqrt(d2[np.arange(pts.shape[0]), best])
    theta = grid[best]
    for _ in range(6):
        # g(theta) = |e(theta) - (u, v)|^2 / 2; g' and g'' in closed form; a step never leaves one grid spacing.
        ct, st = np.cos(theta), np.sin(theta)
        g1 = (b * b - a * a) * st * ct + a * u * st - b * v * ct
        g2 = (b * b - a * a) * (ct * ct - st * st) + a * u * ct + b * v * st
        newton = np.where(g2 > 1e-12, -g1 / np.maximum(g2, 1e-12), -np.sign(g1) * step)
        theta = theta + np.clip(newton, -step, step)
    refined = np.hypot(a * np.cos(theta) - u, b * np.sin(theta) - v)
    return np.asarray(np.minimum(refined, start))


def _check_points(xy: npt.ArrayLike) -> npt.NDArray[np.float64]:
    arr = np.asarray(xy, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise InputError(f"points of shape {arr.shape}: expected (N, 2) x, y")
    if not np.all(np.isfinite(arr)):
        raise InputError("points hold NaN or inf values")
    return arr


def _check_kind(kind: str) -> str:
    if kind not in MIN_SAMPLE:
        raise InputError(f"curve kind {kind!r}: choose from {', '.join(MIN_SAMPLE)}")
    return kind


# ---------------------------------------------------------------------------------------------
# Minimal-sample fits, vectorised over H hypotheses: (H, m, 2) points -> (H, P) parameters, (H,) valid


def lines_from_pairs(s: npt.NDArray[np.float64]) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.bool_]]:
    d = s[:, 1] - s[:, 0]
    length = np.linalg.norm(d, axis=1)
    valid = length > 1e-12
    n = np.stack([-d[:, 1], d[:, 0]], axis=1) / np.where(valid, length, 1.0)[:, None]
    c = -(n * s[:, 0]).sum(axis=1)
    return np.concatenate([n, c[:, None]], axis=1), valid


def circles_from_triples(s: npt.NDArray[np.float64]) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.bool_]]:
    # Circumcentre of the triangle (a, b, c); collinear triples (zero area) have none.
    a, b, c = s[:, 0], s[:, 1], s[:, 2]
    den = 2.0 * (a[:, 0] * (b[:, 1] - c[:, 1]) + b[:, 0] * (c[:, 1] - a[:, 1]) + c[:, 0] * (a[:, 1] - b[:, 1]))
    valid = np.abs(den) > 1e-12
    den = np.where(valid, den, 1.0)
    sa, sb, sc = (a**2).sum(1), (b**2).sum(1), (c**2).sum(1)
    ux = (sa * (b[:, 1] - c[:, 1]) + sb * (c[:, 1] - a[:, 1]) + sc * (a[:, 1] - b[:, 1])) / den
    uy = (sa * (c[:, 0] - b[:, 0]) + sb * (a[:, 0] - c[:, 0]) + sc * (b[:, 0] - a[:, 0])) / den
    r = np.hypot(a[:, 0] - ux, a[:, 1] - uy)
    return np.stack([ux, uy, r], axis=1), valid & np.isfinite(r)


def _conic_rows(xy: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    x, y = xy[..., 0], xy[..., 1]
    return np.stack([x * x, x * y, y * y, x, y, np.ones_like(x)], axis=-1)


def conics_from_quintuples(s: npt.NDArray[np.float64]) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.bool_]]:
    # The conic A x^2 + B xy + C y^2 + D x + E y + F = 0 through 5 points is the null vector of the
    # (5, 6) design matrix; it is an ellipse when 4AC - B^2 > 0 (it is real: it passes through the points).
    _, sv, vh = np.linalg.svd(_conic_rows(s))
    conic = vh[:, -1, :]
    disc = 4.0 * conic[:, 0] * conic[:, 2] - conic[:, 1] ** 2
    # A rank below 5 (repeated or 4 collinear points) leaves a family of conics: no hypothesis.
    rank_ok = sv[:, -1] > 1e-10 * sv[:, 0]
    return conic, (disc > 1e-12) & rank_ok


def _sampson(conics: npt.NDArray[np.float64], xy: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """(H, N) Sampson distances of N points to H conics."""
    A, B, C, D, E, F = (conics[:, i : i + 1] for i in range(6))
    x, y = xy[None, :, 0], xy[None, :, 1]
    q = A * x * x + B * x * y + C * y * y + D * x + E * y + F
    gx = 2 * A * x + B * y + D
    gy = B * x + 2 * C * y + E
    return np.asarray(np.abs(q) / np.maximum(np.hypot(gx, gy), 1e-12))


def conic_to_ellipse(conic: npt.ArrayLike) -> npt.NDArray[np.float64] | None:
    """(cx, cy, a, b, angle) of the ellipse A x^2 + B xy + C y^2 + D x + E y + F = 0, or None if it is not one.

    Args:
        conic: (6,) coefficients (A, B, C, D, E, F), any scale and sign.

    Returns:
        (5,) float64: centre, semi-axes a >= b (units of the points), major-axis angle in [0, pi).
    """
    A, B, C, D, E, F = np.asarray(conic, dtype=np.float64)
    m = np.array([[A, B / 2], [B / 2, C]])
    det = 4 * A * C - B * B
    if det <= 0:
        return None
    centre = np.linalg.solve(2 * m, [-D, -E])
    value = A * centre[0] ** 2 + B * centre[0] * centre[1] + C * centre[1] ** 2 + D * centre[0] + E * centre[1] + F
    lam, vec = np.linalg.eigh(m)  # ascending: the smaller |lambda| is the longer axis when both share a sign
    axes2 = -value / lam
    if not np.all(axes2 > 0):
        return None
    order = np.argsort(-axes2)
    a, b = np.sqrt(axes2[order])
    major = vec[:, order[0]]
    angle = math.atan2(major[1], major[0]) % math.pi
    return np.array([centre[0], centre[1], a, b, angle])


# ---------------------------------------------------------------------------------------------
# Least-squares refits on inliers


def fit_curve(kind: str, xy: npt.ArrayLike) -> CurveModel | None:
    """Least-squares fit of one curve to (M, 2) points; None when the points do not determine one.

    Lines: total least squares (cv2.fitLine, L2). Circles: the algebraic (Kasa) fit followed by
    Gauss-Newton steps on the geometric distance. Ellipses: cv2.fitEllipse (algebraic, needs M >= 5).

    Args:
        kind: "line", "circle" or "ellipse".
        xy: (M, 2) points; M >= 2, 3 or 5.

    Returns:
        The curve (see CurveModel for its parameters), or None (too few or degenerate points).
    """
    import cv2

    _check_kind(kind)
    pts = _check_points(xy)
    if pts.shape[0] < MIN_SAMPLE[kind]:
        return None
    if kind == "line":
        vx, vy, x0, y0 = cv2.fitLine(pts.astype(np.float32), cv2.DIST_L2, 0, 0.01, 0.01).ravel().astype(np.float64)
        n = np.array([-vy, vx])
        norm = float(np.linalg.norm(n))
        if not norm > 0 or not np.all(np.isfinite(n)):
            return None
        n /= norm
        return CurveModel("line", np.array([n[0], n[1], -(n[0] * x0 + n[1] * y0)]))
    if kind == "circle":
        return _fit_circle(pts)
    (cx, cy), (w, h), deg = cv2.fitEllipse(pts.astype(np.float32).reshape(-1, 1, 2))
    angle = math.radians(deg)
    a, b = w / 2.0, h / 2.0
    if b > a:  # OpenCV's width runs along `angle`; keep a as the major semi-axis
        a, b, angle = b, a, angle + math.pi / 2
    params = np.array([cx, cy, a, b, angle % math.pi], dtype=np.float64)
    if not np.all(np.isfinite(params)) or not b > 0:
        return None
    return CurveModel("ellipse", params)


def _fit_circle(pts: npt.NDArray[np.float64]) -> CurveModel | None:
    design = np.column_stack([pts, np.ones(len(pts))])
    sol, *_ = np.linalg.lstsq(design, -(pts**2).sum(1), rcond=None)
    centre = -sol[:2] / 2
    r2 = float(centre @ centre - sol[2])
    if not r2 > 0:
        return None
    params = np.array([centre[0], centre[1], math.sqrt(r2)])
    # The Kasa fit is biased towards small circles on short arcs; a few geometric steps remove that.
    for _ in range(5):
        diff = pts - params[:2]
        dist = np.maximum(np.linalg.norm(diff, axis=1), 1e-12)
        jac = np.column_stack([-diff / dist[:, None], -np.ones(len(pts))])
        step, *_ = np.linalg.lstsq(jac, -(dist - params[2]), rcond=None)
        params = params + step
        if float(np.abs(step).max()) < 1e-10:
            break
    if not np.all(np.isfinite(params)) or not params[2] > 0:
        return None
    params[2] = abs(params[2])
    return CurveModel("circle", params)


# ---------------------------------------------------------------------------------------------
# Sequential RANSAC


def _distinct_samples(rng: np.random.Generator, n: int, m: int, count: int) -> npt.NDArray[np.int64]:
    """(count', m) index samples without a repeated index inside a row (rows with repeats are dropped)."""
    idx = rng.integers(0, n, size=(count, m))
    srt = np.sort(idx, axis=1)
    ok = np.all(srt[:, 1:] != srt[:, :-1], axis=1)
    return idx[ok]


def _hypotheses(
    kind: str, samples: npt.NDArray[np.float64], pts: npt.NDArray[np.float64]
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """(valid hypotheses (H', P), their (H', N) distances to `pts`) for (H, m, 2) minimal samples."""
    if kind == "line":
        params, valid = lines_from_pairs(samples)
        params = params[valid]
        return params, np.abs(params[:, :2] @ pts.T + params[:, 2:3])
    if kind == "circle":
        params, valid = circles_from_triples(samples)
        params = params[valid]
        d = np.sqrt(((pts[None] - params[:, None, :2]) ** 2).sum(-1))
        return params, np.abs(d - params[:, 2:3])
    params, valid = conics_from_quintuples(samples)
    params = params[valid]
    return params, _sampson(params, pts)


def _hypothesis_model(kind: str, params: npt.NDArray[np.float64]) -> CurveModel | None:
    if kind != "ellipse":
        return CurveModel(kind, params.copy())
    ellipse = conic_to_ellipse(params)
    return None if ellipse is None else CurveModel("ellipse", ellipse)


def _best_model(
    pts: npt.NDArray[np.float64], kind: str, cfg: RansacConfig, rng: np.random.Generator
) -> tuple[CurveModel | None, int]:
    """The hypothesis with the most inliers among adaptively many minimal samples, and how many were drawn."""
    n, m = pts.shape[0], MIN_SAMPLE[kind]
    thr = cfg.threshold
    best: tuple[int, float] | None = None  # (inliers, -sum of inlier distances): larger is better
    best_params: npt.NDArray[np.float64] | None = None
    drawn = 0
    needed = cfg.max_hypotheses
    while drawn < min(needed, cfg.max_hypotheses):
        count = min(cfg.batch, cfg.max_hypotheses - drawn)
        drawn += count
        idx = _distinct_samples(rng, n, m, count)
        if idx.shape[0] == 0:
            continue
        params, dist = _hypotheses(kind, pts[idx], pts)
        if params.shape[0] == 0:
            continue
        inl = dist <= thr
        counts = inl.sum(axis=1)
        spread = np.where(inl, dist, 0.0).sum(axis=1)
        i = int(np.lexsort((spread, -counts))[0])
        score = (int(counts[i]), -float(spread[i]))
        if best is None or score > best:
            best, best_params = score, params[i]
            w = best[0] / n
            # Samples needed to draw one all-inlier sample of this model with probability `confidence`.
            p_good = w**m
            needed = 0 if p_good >= 1.0 else math.ceil(math.log(1 - cfg.confidence) / math.log1p(-p_good))
    if best_params is None:
        return None, drawn
    return _hypothesis_model(kind, best_params), drawn


def _refine(model: CurveModel, pts: npt.NDArray[np.float64], cfg: RansacConfig) -> tuple[CurveModel, int]:
    """Refits the model to its inliers up to cfg.refits times; returns the best and its inlier count."""
    thr = cfg.threshold
    best, best_count = model, int((model.distance(pts) <= thr).sum())
    current = model
    for _ in range(cfg.refits):
        inl = current.distance(pts) <= thr
        refit = fit_curve(model.kind, pts[inl])
        if refit is None:
            break
        count = int((refit.distance(pts) <= thr).sum())
        if count < best_count:
            break
        best, best_count, current = refit, count, refit
    return best, best_count


def sequential_ransac(xy: npt.ArrayLike, kind: str, k: int, cfg: RansacConfig = RansacConfig()) -> RansacResult:
    """Fits K curves of one kind one after another (RANSAC, then inlier removal) and labels every point.

    Args:
        xy: (N, 2) points (units of the curves; the LCE generators' unit scale).
        kind: "line", "circle" or "ellipse".
        k: the number of curves K (given, as to the paper's baseline).
        cfg: threshold (from the given noise sigma), sampling budget, seed.

    Returns:
        RansacResult: labels (N,) int64, the nearest fitted curve of each point by the distances of
        the module docstring; fewer than K models when fewer than a minimal sample of points remain.

    Raises:
        InputError: points not (N, 2) finite numbers, unknown kind, or K < 1.
    """
    pts = _check_points(xy)
    _check_kind(kind)
    if k < 1:
        raise InputError(f"k={k}: RANSAC needs at least one model")
    rng = np.random.default_rng(cfg.seed)
    remaining = np.arange(pts.shape[0])
    models: list[CurveModel] = []
    drawn_per_model: list[int] = []
    inliers_per_model: list[int] = []
    for _ in range(k):
        if remaining.size < MIN_SAMPLE[kind]:
            break
        sub = pts[remaining]
        model, drawn = _best_model(sub, kind, cfg, rng)
        if model is None:
            break
        model, count = _refine(model, sub, cfg)
        models.append(model)
        drawn_per_model.append(drawn)
        inliers_per_model.append(count)
        remaining = remaining[model.distance(sub) > cfg.threshold]
    if not models:
        return RansacResult(np.zeros(pts.shape[0], dtype=np.int64))
    dist = np.stack([mdl.distance(pts) for mdl in models], axis=1)
    labels = np.argmin(dist, axis=1).astype(np.int64)
    return RansacResult(labels, models, drawn_per_model, inliers_per_model)
