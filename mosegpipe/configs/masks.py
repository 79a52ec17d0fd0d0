"""Settings of the dense masks: the motion masks (flow residuals) and the methods that densify track labels.

Light on purpose (standard library and mosegpipe.settings / types only): the CLI takes its defaults from
these classes without importing OpenCV. Re-exported by mosegpipe.masks.moving_pixels and mosegpipe.masks.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from mosegpipe.configs.tracking import FlowConfig
from mosegpipe.settings import Check, SettingError, check_fields
from mosegpipe.types import MASK_METHODS


@dataclass(frozen=True)
class MotionMaskConfig:
    """Settings of the motion masks, one line each; how each value was chosen and what it bought on the
    DAVIS dev clips is in docs/HISTORY.md ("How the motion masks work, and what each step bought" and the
    sections after it).

    Attributes:
        flow: dense flow and camera fit (DIS medium, patch stride 4, 1 refinement iteration).
        work_scale: the mask steps run on images resized by this factor; masks are resized back (nearest).
        max_side_px: frames longer than this take both scales times max_side_px / their longer side (None = off).
        eps_px: residuals are compared as log(residual + eps_px), full-resolution pixels.
        min_residual_px: a pixel whose residual is below this (full-resolution pixels) is never moving.
        noise_factor: nor one whose residual is below this many times the frame's median residual.
        fb_weight: the score loses this times the local mean of log(1 + forward-backward error).
        fb_box_px: side of the box (work-scale pixels) averaging the forward-backward error and the spread.
        spread_weight: the score loses this times log(1 + the flow's local spread).
        guided_radius: radius of the guided filter of the score, grey frame as guide (0 = off).
        guided_eps: the guided filter's regulariser, (intensity / 255)^2.
        temporal_weight: weight of the neighbours' scores carried along the flow (0 = off).
        temporal_passes: how often that averaging is repeated (each pass reaches one frame further).
        colour_weight: weight of the colour model's log ratio (0 = off).
        colour_bins: histogram bins per RGB channel of the colour model.
        colour_margin: pixels this far (log units) above / below the threshold train the colour model.
        colour_memory: whole videos: decay of the colour counts of the windows before (0 = each window alone).
        local_colour_weight: weight of the local colour contrast (`local_colour_contrast`; 0 = off).
        local_colour_box_px: side of the box (work-scale pixels) of the local colour means.
        superpixels: approximate number of SLIC superpixels the score is averaged over (0 = off).
        compactness: SLIC compactness (colour vs distance).
        superpixel_iterations: SLIC's k-means iterations.
        min_component: moving regions weaker than this share of the frame's strongest are dropped.
        component_power: a region's strength is its area times its mean residual to this power.
        anchor_tracks: whole videos: a region step 5 would drop stays when this many tracks of a motion shown before lie in it.
        smooth_lambda: strength of the fast global smoother after the guided filter (0 = off).
        smooth_sigma: its colour scale (0-255 units): colours farther apart than this are an edge.
    """

    flow: FlowConfig = field(default_factory=lambda: FlowConfig(patch_stride=4, refinement_iterations=1))
    work_scale: float = 0.75
    max_side_px: int | None = 1280
    eps_px: float = 1.0
    min_residual_px: float = 0.5
    noise_factor: float = 3.0
    fb_weight: float = 0.75
    fb_box_px: int = 7
    spread_weight: float = 0.5
    guided_radius: int = 2
    guided_eps: float = 0.001
    temporal_weight: float = 1.0
    temporal_passes: int = 2
    colour_weight: float = 0.75
    colour_bins: int = 32
    colour_margin: float = 0.5
    colour_memory: float = 0.9
    local_colour_weight: float = 1.5
    local_colour_box_px: int = 61
    superpixels: int = 0
    compactness: float = 10.0
    superpixel_iterations: int = 4
    min_component: float = 0.3
    component_power: float = 2.0
    anchor_tracks: int = 3
    smooth_lambda: float = 16.0
    smooth_sigma: float = 5.0

    def __post_init__(self) -> None:
        check_fields(self, _MOTION_CHECKS)


_MOTION_CHECKS: tuple[Check, ...] = (
    ("work_scale", lambda v: 0 < v <= 1, "lie in (0, 1]"),
    ("max_side_px", lambda v: v is None or v >= 64, "be at least 64 pixels (or None: no limit)"),
    ("noise_factor", lambda v: v >= 0, "be >= 0"),
    ("eps_px", lambda v: v > 0, "be > 0"),
    ("min_residual_px", lambda v: v >= 0, "be >= 0"),
    ("colour_memory", lambda v: 0 <= v < 1, "lie in [0, 1)"),
    ("local_colour_weight", lambda v: v >= 0, "be >= 0"),
    ("local_colour_box_px", lambda v: v >= 3, "be >= 3"),
    ("colour_weight", lambda v: v >= 0, "be >= 0"),
    ("colour_bins", lambda v: 2 <= v <= 64, "lie in 2..64"),
    ("temporal_weight", lambda v: v >= 0, "be >= 0"),
    ("temporal_passes", lambda v: v >= 0, "be >= 0"),
    ("superpixel_iterations", lambda v: v >= 1, "be >= 1"),
    ("fb_weight", lambda v: v >= 0, "be >= 0"),
    ("fb_box_px", lambda v: v >= 1, "be >= 1"),
    ("spread_weight", lambda v: v >= 0, "be >= 0"),
    ("guided_radius", lambda v: v >= 0, "be >= 0"),
    ("guided_eps", lambda v: v > 0, "be > 0"),
    ("smooth_lambda", lambda v: v >= 0, "be >= 0"),
    ("smooth_sigma", lambda v: v > 0, "be > 0"),
    ("anchor_tracks", lambda v: v >= 0, "be >= 0"),
    ("superpixels", lambda v: v >= 0, "be >= 0"),
    ("min_component", lambda v: 0 <= v <= 1, "lie in [0, 1]"),
    ("component_power", lambda v: v >= 0, "be >= 0"),
)
"""MotionMaskConfig's checks, one field each: (field, test, what it must be)."""


@dataclass(frozen=True)
class LearnedMaskConfig:
    """Settings of the "learned" masks (`MaskConfig.learned`, mosegpipe.masks.learned); each default chosen end to end
    on development clips (docs/RESULTS.md, "Learned masks"; the threshold is the training recipe's own).

    Attributes:
        threshold: a pixel is moving where the network's probability of "not the world" is above this.
        scale: the network's input is the frame resized by this; its probability is resized back (linear).
        weights: checkpoint of the mask network ("" = the shipped one, mosegpipe/weights/masknet.pt).
        temporal_weight: each frame's probability is averaged with weight w with its neighbours' carried along the flow (0 = off).
        refine_scale: the probability goes to this scale of the frame through a guided filter and global smoother (0 = off).
        min_component: moving regions weaker (area x mean residual^2) than this share of the frame's strongest are dropped.
        which_weights: checkpoint of the per-motion network of `MaskConfig.which` "learned" ("" = the shipped whichnet.pt).
    """

    threshold: float = 0.3
    scale: float = 0.25
    weights: str = ""
    temporal_weight: float = 0.5
    refine_scale: float = 0.25
    min_component: float = 0.1
    which_weights: str = ""

    def __post_init__(self) -> None:
        check_fields(self, _LEARNED_CHECKS)


_LEARNED_CHECKS: tuple[Check, ...] = (
    ("threshold", lambda v: 0 < v < 1, "lie in (0, 1)"),
    ("scale", lambda v: 0.05 <= v <= 1, "lie in [0.05, 1]"),
    ("temporal_weight", lambda v: 0 <= v < 1, "lie in [0, 1)"),
    ("refine_scale", lambda v: 0 <= v <= 1, "lie in [0, 1]"),
    ("min_component", lambda v: 0 <= v <= 1, "lie in [0, 1]"),
)
"""LearnedMaskConfig's checks: (field, test, what it must be)."""


WHICH_METHODS = ("tracks", "learned")
"""`MaskConfig.which`: how a moving pixel chooses among a frame's moving motions."""


@dataclass(frozen=True)
class RigidTracksConfig:
    """Whole videos, "motion" masks: moving regions that tracks of the static world hold over a long span stay the
    world's (`mosegpipe.masks.rigid_tracks`), one line each.

    Attributes:
        enabled: judge the tracks (whole videos; the verdict serves `hold` and `guard`).
        hold: moving regions that the static world's tracks hold stay the world's (`rigid_tracks.static_held`).
        guard: with WorldConfig.rigid_scene, a pixel whose nearest judged track moves is not explained by the camera's
            3D motion, and a window without a verdict is not judged in 3D at all.
        span: the longest partner frame's distance back from the window's last frame (tracks seen there are known).
        partners: partner frames, evenly spaced back to `span` (`gaps`).
        residual_px: a static track's parallax stays within this of its one depth, per 4 frames of gap, full-resolution px.
        world_depth: least share of the world's tracks off the camera's homography and on its F at the longest gap.
        min_tracks: fewest tracks a fit needs.
        share: least share of a region's known tracks that must be static for it to stay the world's.
        region_tracks: fewest known tracks in such a region.
    """

    enabled: bool = False
    hold: bool = True
    guard: bool = True
    span: int = 12
    partners: int = 3
    residual_px: float = 1.0
    world_depth: float = 0.05
    min_tracks: int = 30
    share: float = 0.9
    region_tracks: int = 10

    def __post_init__(self) -> None:
        check_fields(self, _RIGID_TRACKS_CHECKS)
        if self.partners > self.span:
            raise SettingError("partners", f"{self.partners} must be at most span ({self.span})")

    @property
    def gaps(self) -> tuple[int, ...]:
        """The partner frames' distances back, ascending (the last is `span`)."""
        return tuple(sorted({round(self.span * (k + 1) / self.partners) for k in range(self.partners)}))


_RIGID_TRACKS_CHECKS: tuple[Check, ...] = (
    ("span", lambda v: 2 <= v <= 60, "lie in 2..60"),
    ("partners", lambda v: v >= 1, "be >= 1"),
    ("residual_px", lambda v: v > 0, "be > 0"),
    ("world_depth", lambda v: 0 <= v <= 1, "lie in [0, 1]"),
    ("min_tracks", lambda v: v >= 8, "be >= 8"),
    ("share", lambda v: 0 < v <= 1, "lie in (0, 1]"),
    ("region_tracks", lambda v: v >= 1, "be >= 1"),
)
"""RigidTracksConfig's checks: (field, test, what it must be)."""


@dataclass(frozen=True)
class MaskConfig:
    """Settings of densifying track labels, one line each (the methods: mosegpipe.masks); how the values were
    chosen is in docs/HISTORY.md ("Dense masks: densifiers compared", "Moving regions that no clustered motion
    explains", "Where the defaults come from"), what they give in docs/RESULTS.md ("Dense masks on rendered clips").

    Attributes:
        max_distance_px: pixels farther than this from every labelled track are unknown (255).
        method: types.MaskMethod: "motion", "watershed", "nearest", "vote" or "learned".
        vote_k: tracks consulted per pixel by "vote" (and by min_agree).
        vote_downsample: "vote" labels every n-th pixel and upsamples (nearest).
        median_px: odd size of a median filter over the label image (0 or 1 = off).
        min_agree: "watershed": a track seeds only when this many of its vote_k nearest tracks carry its label.
        blur_px: "watershed": odd Gaussian kernel applied to the image before flooding (0 or 1 = off).
        scale: "watershed" floods the image resized by this (0 < scale <= 1).
        extra_tracks: clips: up to this many more corners, tracked and labelled by motion for the masks only (0 = off).
        unexplained_px: "motion", clips: regions missing their motion's homography by more take 254 (`split_unexplained`; 0 = off).
        unexplained_area: smallest such region, as a share of the frame's pixels.
        unexplained_rigid: ... and the share of its pixels its own homography must explain (0 = no such test).
        reassign_ratio: a moving pixel takes the moving motion whose affine step misses its flow by < this x its own's (`reassign_by_flow`; 0 = off).
        missed_tracks: "motion"/"learned": a static region holding this many tracks of a moving motion the mask misses, whose flow the motion explains, takes it (`by_flow.missed_movers`; 0 = off).
        missed_ratio: ... when its affine step misses a pixel's flow by < this x the camera's miss, itself >= this x the flow.
        world_regions: "motion"/"learned": a moving region with world_region_tracks+ tracks, this share the world's, stays the world's (0 = off).
        world_region_tracks: that least number of tracks.
        which: "motion"/"learned" masks, frames with 2+ moving motions: "tracks" (nearest track, watershed) or "learned" (the per-motion network).
        motion: "motion": the flow and mask settings (mosegpipe.masks.moving_pixels); "learned": its flow settings.
        learned: "learned": the mask network's settings (mosegpipe.masks.learned).
        rigid: whole videos, "motion": regions held by tracks of the static world over a long span (RigidTracksConfig).
    """

    max_distance_px: float = 40.0
    method: str = "motion"
    vote_k: int = 5
    vote_downsample: int = 4
    median_px: int = 0
    min_agree: int = 1
    blur_px: int = 0
    scale: float = 1.0
    extra_tracks: int = 1000
    unexplained_px: float = 4.0
    unexplained_area: float = 0.002
    unexplained_rigid: float = 0.8
    reassign_ratio: float = 0.5
    missed_tracks: int = 3
    missed_ratio: float = 0.5
    world_regions: float = 0.0
    world_region_tracks: int = 5
    which: str = "tracks"
    motion: MotionMaskConfig = field(default_factory=MotionMaskConfig)
    learned: LearnedMaskConfig = field(default_factory=LearnedMaskConfig)
    rigid: RigidTracksConfig = field(default_factory=RigidTracksConfig)

    def __post_init__(self) -> None:
        check_fields(self, _MASK_CHECKS)
        if not self.min_agree <= self.vote_k:
            raise SettingError("min_agree", f"{self.min_agree} must lie in 1..vote_k ({self.vote_k})")


_MASK_CHECKS: tuple[Check, ...] = (
    ("method", lambda v: v in MASK_METHODS, f"be one of {', '.join(MASK_METHODS)}"),
    ("max_distance_px", lambda v: v > 0, "be > 0"),
    ("vote_k", lambda v: v >= 1, "be >= 1"),
    ("vote_downsample", lambda v: v >= 1, "be >= 1"),
    *(
        (name, lambda v: v in (0, 1) or (v >= 3 and v % 2 == 1), "be 0, 1 (off) or an odd number >= 3")
        for name in ("median_px", "blur_px")
    ),
    ("scale", lambda v: 0 < v <= 1, "lie in (0, 1]"),
    ("extra_tracks", lambda v: v >= 0, "be >= 0 (0 = off)"),
    ("unexplained_px", lambda v: v >= 0, "be >= 0 (0 = off)"),
    ("unexplained_area", lambda v: 0 < v <= 1, "lie in (0, 1]"),
    ("unexplained_rigid", lambda v: 0 <= v <= 1, "lie in [0, 1]"),
    ("reassign_ratio", lambda v: 0 <= v < 1, "lie in [0, 1) (0 = off)"),
    ("missed_tracks", lambda v: v >= 0, "be >= 0 (0 = off)"),
    ("missed_ratio", lambda v: 0 < v < 1, "lie in (0, 1)"),
    ("world_regions", lambda v: 0 <= v <= 1, "lie in [0, 1] (0 = off)"),
    ("world_region_tracks", lambda v: v >= 1, "be >= 1"),
    ("which", lambda v: v in WHICH_METHODS, f"be one of {', '.join(WHICH_METHODS)}"),
)
"""MaskConfig's checks: (field, test, what it must be)."""
