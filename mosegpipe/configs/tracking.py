"""Settings of the stages that make points: the KLT tracker, the dense flow, the flow tracker and SIFT matching.

Light on purpose (standard library and mosegpipe.settings / types only): the CLI takes its defaults from
these classes without importing OpenCV. Re-exported by the modules that use them (mosegpipe.track, flow,
flow_tracks, match).
"""

from __future__ import annotations

from dataclasses import dataclass

from mosegpipe.settings import MAX_CORNERS, MAX_MIN_DISTANCE_PX, MAX_THREADS, MAX_WIN_SIZE_PX, Check, check_fields
from mosegpipe.types import CAMERA_FIT_NAMES, DIS_PRESET_NAMES, MATCHERS, CameraFit, DisPreset, Matcher


@dataclass(frozen=True)
class TrackConfig:
    """Settings of the KLT tracker.

    Attributes:
        max_corners: corners detected in the first frame; SubspaceNet works on a few hundred to
            a thousand trajectories (KT3DMoSeg clips hold 158-1018).
        quality_level: Shi-Tomasi threshold relative to the strongest corner; 0.01 keeps weakly
            textured areas (road, walls) that still track well over a few frames.
        min_distance_px: minimum spacing between corners, so points cover the whole image rather
            than clustering on the most textured object.
        block_size: neighbourhood of the corner response; 7 px is robust to JPEG noise.
        win_size_px: Lucas-Kanade window; 21 px tolerates the small blur and noise of real video.
        max_level: pyramid levels above the full image; 3 levels (1/8 scale) handle motions up to
            about 8 * win_size_px / 2 px per frame.
        fb_threshold_px: forward-backward check: a point tracked to the next frame and back must
            land within this distance of where it started, else it is dropped (occlusions,
            drift on edges). None disables the check and roughly halves the cost.
        min_eig: minimum eigenvalue of the LK structure tensor (OpenCV's minEigThreshold);
            rejects points that became textureless (e.g. moved onto sky).
        max_iter: Lucas-Kanade iterations per pyramid level.
        epsilon_px: Lucas-Kanade stops when an update is smaller than this.
        border_px: a point closer than this to the image border counts as having left the image.
            About win_size_px / 2: nearer the border the LK window reads padded pixels; on a
            translated texture the error there reached ~1 px, against < 0.002 px inside.
        reseed: KLTTracker only: detect new corners in areas without live tracks, for long videos.
        reseed_every: re-seed every this many frames (detection, ~6 ms at 640x480, costs about
            half a tracking step).
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
    """Settings of the dense flow and the camera fit.

    Attributes:
        preset: DIS preset ("ultrafast", "fast" or "medium"); medium is the most accurate of the three.
        scale: flow is computed on images resized by this factor (0 < scale <= 1); residuals are
            returned at full resolution in full-resolution pixels.
        grid_step_px: the camera fit samples one pixel every this many pixels (at the flow's scale);
            8 fits as well as 4 (DAVIS dev J 0.646 either way) at a quarter of the fit's time.
        fb_max_px: a sample whose forward flow and the backward flow at its end point disagree by
            more than this (pixels, at the flow's scale) is left out of the camera fit (occlusions,
            flow failures).
        ransac_px: RANSAC inlier threshold of the homography, in pixels at the flow's scale.
        camera_fit: the robust fit of the camera's homography (CAMERA_FITS): "ransac" (OpenCV's RANSAC,
            the inliers' fit refined by Levenberg-Marquardt) or "magsac" (OpenCV's USAC MAGSAC, the
            choice before). MAGSAC weighs samples by a soft score up to its threshold and beyond: an
            object moving 2-3 px against the camera, over a third of the frame, pulls its fit off the
            background (median background residual 0.2-0.7 px where a least-squares fit of the true
            background leaves 0.05-0.08; rendered clips, seeds 12 and 17), and the noise floor then hides
            slow movers. RANSAC leaves 0.04 there, in half MAGSAC's time (2.5 against 4.9 ms for 5 400
            samples). DAVIS dev, whole video J / F 0.750 / 0.714 -> 0.759 / 0.726 (elephant 0.67 -> 0.81;
            ransac_px 0.5 0.751, 2.0 0.754), first 5 frames 0.707 / 0.672 -> 0.718 / 0.683.
        workers: threads that compute the flows and fits of a stack (`frame_motion`); OpenCV releases
            the GIL, so two threads use both cores of a small machine (each thread has its own DIS).
        patch_stride: DIS patch stride in pixels (None = the preset's: 3 for medium).
        refinement_iterations: DIS variational refinement iterations (None = the preset's: 5 for medium).
        both_directions: a frame between two others takes, per pixel, the smaller camera residual and
            the smaller forward-backward error of its flow to the next frame and its flow to the one
            before (each with its own camera fit). A band beside a moving object is occluded in one
            of its neighbours only, so one of the two flows is right there: the band's residual (the
            flow smoothed across the object's border) drops out, the object's own stays (it moves
            in both). DAVIS dev J of the moving masks (25 frames pooled) 0.676 -> 0.713; False =
            the next frame's flow only.
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
    """Settings of `track_flow`.

    Attributes:
        max_points: the grid holds about this many seeds (its step is sqrt(H * W / max_points) pixels,
            at least `min_step_px`).
        min_step_px: the grid's smallest step, pixels.
        border_px: a point closer than this to the image border is lost.
        fb_rel: forward-backward check, relative part (see the module docstring).
        fb_abs_px: forward-backward check, absolute part, pixels.
        boundary_rel: motion-boundary check: a point is lost where |grad u|^2 + |grad v|^2 exceeds
            boundary_rel |w|^2 + boundary_abs (a negative boundary_rel = no check).
        boundary_abs: absolute part of the motion-boundary check (flow gradient squared, per pixel).
        max_brightness: brightness check, grey levels (0-255) of the images smoothed by a Gaussian of
            sigma 1 px (0 = no check).
        min_texture: seeds whose smallest structure-tensor eigenvalue is below this share of the
            frame's mean are left out (0 = every grid point is seeded).
        klt_distance_px: "klt+flow": flow points nearer than this to a KLT corner in the first
            frame are dropped.
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
    """Settings of SIFT detection and matching.

    Attributes:
        nfeatures: keypoints kept per image, strongest first (0 = all). Caps the quadratic
            matching cost: ~2.5k keypoints per 640x480 image took 180 ms to detect and 250 ms
            to brute-force match both ways on one core.
        n_octave_layers: SIFT layers per octave (Lowe's 3).
        contrast_threshold: SIFT's DoG contrast threshold (OpenCV default 0.04); lower finds
            more keypoints in low-contrast images at the cost of weaker ones.
        edge_threshold: SIFT's edge-response threshold (OpenCV default 10).
        sigma: Gaussian blur of the base octave (Lowe's 1.6).
        ratio: Lowe's ratio test: keep a match when best distance < ratio * second best; 0.8
            is Lowe's value, rejecting ~90 % of false matches and ~5 % of true ones.
        cross_check: keep a match only if it is also the best match from image 2 back to
            image 1 (mutual nearest neighbours); otherwise only the best-ratio match per
            keypoint of image 2 survives.
        matcher: "bf" (exact brute force, deterministic) or "flann" (approximate KD-trees;
            measured ~3x faster matching at 2.5k keypoints, with the same matches to within 0.5 %).
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
