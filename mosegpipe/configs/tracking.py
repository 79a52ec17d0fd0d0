"""Settings of the stages that make points: the KLT tracker, the dense flow, the flow tracker and SIFT matching.

Light on purpose (standard library and mosegpipe.settings / types only): the CLI takes its defaults from
these classes without importing OpenCV. Re-exported by the modules that use them (mosegpipe.points.klt, flow,
flow_tracks, match).
"""

from __future__ import annotations

from dataclasses import dataclass

from mosegpipe.settings import MAX_CORNERS, MAX_MIN_DISTANCE_PX, MAX_THREADS, MAX_WIN_SIZE_PX, Check, check_fields
from mosegpipe.types import CAMERA_FIT_NAMES, DIS_PRESET_NAMES, MATCHERS, CameraFit, DisPreset, Matcher


@dataclass(frozen=True)
class TrackConfig:
    """Settings of the KLT tracker, one line each; how the values were chosen is in docs/HISTORY.md ("Where the
    defaults come from", "TrackConfig"), what they give end to end in docs/RESULTS.md ("End to end on our own tracks").

    Attributes:
        max_corners: corners detected in the first frame (SubspaceNet works on a few hundred to a thousand).
        quality_level: Shi-Tomasi threshold relative to the strongest corner; low keeps weakly textured areas.
        min_distance_px: minimum spacing between corners, so that points cover the whole image.
        block_size: neighbourhood of the corner response, pixels.
        win_size_px: Lucas-Kanade window, pixels.
        max_level: pyramid levels above the full image (3: motions up to about 4 * win_size_px per frame).
        fb_threshold_px: forward-backward check: a point tracked there and back must land this near its start (None: off).
        min_eig: minimum eigenvalue of the LK structure tensor (OpenCV's minEigThreshold).
        max_iter: Lucas-Kanade iterations per pyramid level.
        epsilon_px: Lucas-Kanade stops when an update is smaller than this.
        border_px: a point closer than this to the image border has left the image.
        reseed: KLTTracker only: detect new corners in areas without live tracks (long videos).
        reseed_every: re-seed every this many frames.
    """

    max_corners: int = 1000
    quality_level: float = 0.01
    min_distance_px: float = 7.0
    block_size: int = 7
    win_size_px: int = 21
    max_level: int = 3
    fb_threshold_px: float | None = 1.0
    min_eig: float = 1e-4
    max_iter: int = 30
    epsilon_px: float = 0.01
    border_px: float = 10.0
    reseed: bool = False
    reseed_every: int = 5

    def __post_init__(self) -> None:
        check_fields(self, _TRACK_CHECKS)


_TRACK_CHECKS: tuple[Check, ...] = (
    ("max_corners", lambda v: 1 <= v <= MAX_CORNERS, f"lie in 1..{MAX_CORNERS}"),
    ("win_size_px", lambda v: 3 <= v <= MAX_WIN_SIZE_PX, f"lie in 3..{MAX_WIN_SIZE_PX}"),
    ("min_distance_px", lambda v: 0 <= v <= MAX_MIN_DISTANCE_PX, f"lie in [0, {MAX_MIN_DISTANCE_PX:g}]"),
    ("quality_level", lambda v: 0 < v <= 1, "lie in (0, 1]"),
    ("max_level", lambda v: v >= 0, "be >= 0"),
    ("fb_threshold_px", lambda v: v > 0, "be > 0 (or None: no check)"),
    ("reseed_every", lambda v: v >= 1, "be >= 1"),
)
"""TrackConfig's checks: (field, test, what it must be)."""


@dataclass(frozen=True)
class FlowConfig:
    """Settings of the dense flow and the camera fit, one line each; how the values were chosen is in
    docs/HISTORY.md ("How the motion masks work, and what each step bought", "The camera's homography by RANSAC
    instead of MAGSAC", "Where the defaults come from"), their speed in docs/RESULTS.md ("Presets").

    Attributes:
        preset: DIS preset (types.DisPreset); medium is the most accurate of the three.
        scale: the flow is computed on images resized by this (0 < scale <= 1); residuals come back at full size.
        grid_step_px: the camera fit samples one pixel every this many (at the flow's scale).
        fb_max_px: samples whose forward and backward flows disagree by more (flow-scale pixels) are left out of the fit.
        ransac_px: inlier threshold of the camera's homography, pixels at the flow's scale.
        camera_fit: the robust fit of the camera's homography (types.CameraFit): OpenCV's RANSAC or USAC MAGSAC.
        workers: threads computing a stack's flows and fits (OpenCV releases the GIL; each thread has its own DIS).
        patch_stride: DIS patch stride, pixels (None: the preset's, 3 for medium).
        refinement_iterations: DIS variational refinement iterations (None: the preset's, 5 for medium).
        both_directions: a frame between two others takes, per pixel, the smaller residual of its flows forward and back.
    """

    preset: DisPreset = "medium"
    scale: float = 1.0
    grid_step_px: int = 8
    fb_max_px: float = 1.0
    ransac_px: float = 1.0
    camera_fit: CameraFit = "ransac"
    workers: int = 2
    patch_stride: int | None = None
    refinement_iterations: int | None = None
    both_directions: bool = True

    def __post_init__(self) -> None:
        check_fields(self, _FLOW_CHECKS)


_FLOW_CHECKS: tuple[Check, ...] = (
    ("preset", lambda v: v in DIS_PRESET_NAMES, f"be one of {', '.join(DIS_PRESET_NAMES)}"),
    ("scale", lambda v: 0 < v <= 1, "lie in (0, 1]"),
    ("grid_step_px", lambda v: v >= 1, "be >= 1"),
    ("workers", lambda v: 1 <= v <= MAX_THREADS, f"lie in 1..{MAX_THREADS}"),
    ("patch_stride", lambda v: 1 <= v <= 8, "lie in 1..8 (the patches are 8 px; or None: the preset's)"),
    ("refinement_iterations", lambda v: 0 <= v <= 100, "lie in 0..100 (or None: the preset's)"),
    ("camera_fit", lambda v: v in CAMERA_FIT_NAMES, f"be one of {', '.join(CAMERA_FIT_NAMES)}"),
    ("fb_max_px", lambda v: v > 0, "be > 0"),
    ("ransac_px", lambda v: v > 0, "be > 0"),
)
"""FlowConfig's checks: (field, test, what it must be)."""


@dataclass(frozen=True)
class FlowTrackConfig:
    """Settings of `track_flow`, one line each (the checks: the module docstring); how they were chosen is in
    docs/HISTORY.md ("Points from the dense flow").

    Attributes:
        max_points: the grid holds about this many seeds (step sqrt(H * W / max_points) px, at least min_step_px).
        min_step_px: the grid's smallest step, pixels.
        border_px: a point closer than this to the image border is lost.
        fb_rel: forward-backward check, relative part.
        fb_abs_px: forward-backward check, absolute part, pixels.
        boundary_rel: motion-boundary check, relative part (a negative value: no check).
        boundary_abs: motion-boundary check, absolute part (flow gradient squared, per pixel).
        max_brightness: brightness check, grey levels of the images smoothed by a 1 px Gaussian (0: no check).
        min_texture: seeds whose smallest structure-tensor eigenvalue is below this share of the frame's mean are left out.
        klt_distance_px: "klt+flow": flow points nearer than this to a KLT corner in the first frame are dropped.
    """

    max_points: int = 2000
    min_step_px: int = 4
    border_px: float = 4.0
    fb_rel: float = 0.01
    fb_abs_px: float = 0.7
    boundary_rel: float = 0.01
    boundary_abs: float = 0.002
    max_brightness: float = 20.0
    min_texture: float = 0.0
    klt_distance_px: float = 4.0

    def __post_init__(self) -> None:
        check_fields(self, _FLOW_TRACK_CHECKS)


_FLOW_TRACK_CHECKS: tuple[Check, ...] = (
    ("max_points", lambda v: 1 <= v <= MAX_CORNERS, f"lie in 1..{MAX_CORNERS}"),
    ("min_step_px", lambda v: v >= 1, "be >= 1"),
    ("fb_rel", lambda v: v >= 0, "be >= 0"),
    ("fb_abs_px", lambda v: v >= 0, "be >= 0"),
    ("border_px", lambda v: v >= 0, "be >= 0"),
    ("klt_distance_px", lambda v: v >= 0, "be >= 0"),
    ("min_texture", lambda v: v >= 0, "be >= 0"),
    ("max_brightness", lambda v: v >= 0, "be >= 0"),
)
"""FlowTrackConfig's checks: (field, test, what it must be)."""


@dataclass(frozen=True)
class MatchConfig:
    """Settings of SIFT detection and matching (image pairs), one line each; how the values were chosen is in
    docs/HISTORY.md ("Where the defaults come from", "MatchConfig").

    Attributes:
        nfeatures: keypoints kept per image, strongest first (0 = all); caps the quadratic matching cost.
        n_octave_layers: SIFT layers per octave (Lowe's 3).
        contrast_threshold: SIFT's DoG contrast threshold (OpenCV's default).
        edge_threshold: SIFT's edge-response threshold (OpenCV's default).
        sigma: Gaussian blur of the base octave (Lowe's 1.6).
        ratio: Lowe's ratio test: keep a match when best distance < ratio * second best.
        cross_check: keep only mutual nearest neighbours (else the best-ratio match per keypoint of image 2).
        matcher: types.Matcher: "bf" (exact, deterministic) or "flann" (approximate KD-trees, faster).
    """

    nfeatures: int = 4000
    n_octave_layers: int = 3
    contrast_threshold: float = 0.04
    edge_threshold: float = 10.0
    sigma: float = 1.6
    ratio: float = 0.8
    cross_check: bool = True
    matcher: Matcher = "bf"

    def __post_init__(self) -> None:
        check_fields(self, _MATCH_CHECKS)


_MATCH_CHECKS: tuple[Check, ...] = (
    ("ratio", lambda v: 0 < v <= 1, "lie in (0, 1]"),
    ("matcher", lambda v: v in MATCHERS, f"be one of {', '.join(MATCHERS)}"),
    ("nfeatures", lambda v: v >= 0, "be >= 0"),
)
"""MatchConfig's checks: (field, test, what it must be)."""
