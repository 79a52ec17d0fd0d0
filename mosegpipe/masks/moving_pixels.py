"""Dense masks of what moves, from the flow the camera's motion does not explain.

Per frame, the camera residual (`mosegpipe.points.flow`) says how far each pixel's flow is from the camera's
motion. The steps:

1. The score: log(residual + eps) minus a weight times the local log forward-backward error (flow that does
   not hold up both ways: water, smoke, occlusions) and the flow's local spread (flow that varies from pixel
   to pixel is not one object's motion).
2. Carried along the flow: each frame's score is averaged with its neighbours' at the pixels the flow leads
   to, twice (two frames either side count), so a mover that one frame's flow misses keeps its evidence.
3. Colour: RGB histograms of the confidently moving and confidently static pixels of the clip (in whole
   videos also of the shot's earlier windows, decayed: `ColourMemory`) add their log ratio to the score; and
   a pixel nearer the mean colour of the moving pixels around it than of the static ones gains, else loses
   (a cast shadow has the colours of the ground beside it).
4. Edges: a guided filter with the grey frame as guide moves the score's edges onto the image's, then a fast
   global smoother with the colour frame as guide spreads it within regions of like colour (OpenCV
   ximgproc). Superpixels (SLIC, scikit-image) are an option, off.
5. The split: Otsu's threshold per frame (movers are slow in some clips and fast in others); components
   weaker than a share (0.3) of the strongest are dropped, a component's strength being its area times the
   square of its mean residual (a small fast mover outweighs a large slowly drifting texture, and two
   movers at different speeds both stay); a pixel whose residual is under 3 times the frame's median is
   never moving (the background's own noise). In whole videos a motion the frame before showed keeps its
   weaker regions where its tracks are (`MotionMaskConfig.anchor_tracks`).

Each step and the values above were chosen on the 20 dev clips of DAVIS-2016 train; the measurements are in
docs/RESULTS.md ("Real video") and docs/HISTORY.md. `mosegpipe.masks.compose` then gives the moving pixels the
labels of the tracks' motions.
"""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe.configs.masks import MotionMaskConfig
from mosegpipe.points.flow import FrameMotion, frame_motion, pixel_points


def _resize(x: npt.NDArray[np.float32], hw: tuple[int, int]) -> npt.NDArray[np.float32]:
    if x.shape[:2] == hw:
        return x
    return cv2.resize(x, (hw[1], hw[0]), interpolation=cv2.INTER_LINEAR)


def _colour_index(image: npt.NDArray[np.uint8], bins: int) -> npt.NDArray[np.int64]:
    q = (image.astype(np.int64) * bins) >> 8
    return (q[..., 0] * bins + q[..., 1]) * bins + q[..., 2]


class ColourMemory:
    """The colour model's histograms carried from window to window of a video (`moving_from_motion`).

    Each window's counts of confidently moving and static pixels are added to the memory's, which are
    first multiplied by `decay`: an object's colours learnt while it moved still count in a later window
    where part of it stands still. `reset` at a shot cut (the new shot's colours are not the old one's).
    """

    def __init__(self, decay: float) -> None:
        if not 0 <= decay < 1:
            raise ValueError(f"decay={decay} must be in [0, 1)")
        self.decay = decay
        self.moving: npt.NDArray[np.float64] | None = None
        self.static: npt.NDArray[np.float64] | None = None

    def reset(self) -> None:
        self.moving = self.static = None

    def add(
        self, moving: npt.NDArray[np.float64], static: npt.NDArray[np.float64]
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """The remembered counts after adding one window's."""
        if self.moving is None or self.static is None:
            self.moving, self.static = moving.copy(), static.copy()
        else:
            self.moving = self.decay * self.moving + moving
            self.static = self.decay * self.static + static
        return self.moving, self.static


def colour_log_ratio(
    images: list[npt.NDArray[np.uint8]],
    scores: list[npt.NDArray[np.float32]],
    cfg: MotionMaskConfig,
    memory: ColourMemory | None = None,
) -> list[npt.NDArray[np.float32]]:
    """Per frame, log p(colour | moving) - log p(colour | static), from the confident pixels of all frames
    (and, with a memory, of the windows before)."""
    nbins = cfg.colour_bins**3
    moving = np.zeros(nbins)
    static = np.zeros(nbins)
    index = [_colour_index(im, cfg.colour_bins) for im in images]
    for idx, z in zip(index, scores):
        moving += np.bincount(idx[z > cfg.colour_margin], minlength=nbins)
        static += np.bincount(idx[z < -cfg.colour_margin], minlength=nbins)
    if memory is not None:
        moving, static = memory.add(moving, static)
    moving, static = moving + 1.0, static + 1.0
    ratio = np.clip(np.log(moving / moving.sum()) - np.log(static / static.sum()), -5.0, 5.0).astype(np.float32)
    return [ratio[idx] for idx in index]


def local_colour_contrast(
    image: npt.NDArray[np.uint8], score: npt.NDArray[np.float32], margin: float, box_px: int
) -> npt.NDArray[np.float32]:
    """(h, w) float32 in (-1, 1): (d_static - d_moving) / (d_static + d_moving + 10), where d_moving (d_static)
    is the RGB distance from a pixel's colour to the mean colour of the pixels scoring above `margin` (below
    -`margin`) in the `box_px` box around it; 0 where the box holds under 2 % of either class.

    Computed at half the size of `image` and resized back (4 against 17 ms per 640x360 frame; DAVIS dev,
    whole video J / F 0.767 / 0.742 against 0.768 / 0.745 at full size)."""
    h, w = score.shape
    half = (max(1, round(w / 2)), max(1, round(h / 2)))
    colour = cv2.resize(image, half, interpolation=cv2.INTER_AREA).astype(np.float32)
    small = cv2.resize(score, half, interpolation=cv2.INTER_AREA)
    side = max(3, round(box_px / 2) | 1)
    ones = np.ones((1, 3), np.float32)
    dist, share = [], []
    for chosen in (small > margin, small < -margin):
        weight = chosen.astype(np.float32)
        frac = cv2.blur(weight, (side, side))
        mean = cv2.blur(colour * weight[..., None], (side, side)) / np.maximum(frac, np.float32(1e-3))[..., None]
        diff = colour - mean
        dist.append(cv2.sqrt(cv2.transform(diff * diff, ones)))  # per-pixel RGB distance
        share.append(frac)
    moving, static = dist
    contrast = (static - moving) / (static + moving + np.float32(10.0))
    contrast[(share[0] < 0.02) | (share[1] < 0.02)] = 0.0
    resized: npt.NDArray[np.float32] = cv2.resize(contrast, (w, h), interpolation=cv2.INTER_LINEAR)
    return resized


def _superpixel_mean(
    image: npt.NDArray[np.uint8], score: npt.NDArray[np.float32], cfg: MotionMaskConfig
) -> npt.NDArray[np.float32]:
    from skimage.segmentation import slic

    seg = slic(
        image,
        n_segments=cfg.superpixels,
        compactness=cfg.compactness,
        max_num_iter=cfg.superpixel_iterations,
        start_label=0,
    )
    sums = np.bincount(seg.ravel(), score.ravel().astype(np.float64))
    counts = np.maximum(np.bincount(seg.ravel()), 1)
    return (sums / counts).astype(np.float32)[seg]


def _flow_spread(flow: npt.NDArray[np.float32], box_px: int) -> npt.NDArray[np.float32]:
    """(h, w) float32: the standard deviation of the flow vectors in a box around each pixel, pixels."""
    box = (box_px, box_px)
    mean = cv2.blur(flow, box)
    var = cv2.blur(flow * flow, box) - mean * mean
    spread: npt.NDArray[np.float32] = cv2.sqrt(np.maximum(var[..., 0] + var[..., 1], 0))
    return spread


Anchors = tuple[npt.NDArray[np.float32], npt.NDArray[np.int64], int, npt.NDArray[np.int64]]
"""One video frame's tracked points as the clustering labelled them: xy (N, 2) float32 full-resolution pixels,
labels (N,) int64 (-1 = unlabelled), the background motion's label, and the moving motions the frame
before showed in its mask."""


def keep_strong(
    mask: npt.NDArray[np.bool_], residual: npt.NDArray[np.float32], share: float, power: float
) -> npt.NDArray[np.bool_]:
    """The connected regions of `mask` whose area x mean(residual)^power is >= share x the strongest's."""
    n, comp, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    if n <= 2 or share <= 0:
        return mask
    strength = stats[1:, cv2.CC_STAT_AREA].astype(np.float64)
    inside = comp[mask]  # the regions' pixels only (a tenth of the frame or less), in the frame's order
    if power > 0:
        mean = np.bincount(inside, residual[mask].astype(np.float64), minlength=n)[1:] / strength
        strength *= mean**power
    keep = np.zeros(n, bool)
    keep[1:] = strength >= share * strength.max()
    kept = np.zeros_like(mask)
    kept[mask] = keep[inside]
    return kept


def _region_motions(regions: npt.NDArray[np.int32], n: int, anchors: Anchors, min_points: int) -> npt.NDArray[np.int64]:
    """Per region (ids 0..n-1 of `regions`, 0 = outside every region): the moving motion of `anchors` that has
    at least `min_points` points in it and more than any other motion (the background included), else -1."""
    xy, labels, background, _ = anchors
    h, w = regions.shape
    ij = np.round(xy).astype(np.int64)
    ok = (labels >= 0) & (ij[:, 0] >= 0) & (ij[:, 0] < w) & (ij[:, 1] >= 0) & (ij[:, 1] < h)
    owner = np.full(n, -1, np.int64)
    if not ok.any():
        return owner
    motions, which = np.unique(labels[ok], return_inverse=True)
    counts = np.zeros((n, motions.size), np.int64)  # counts[r, m]: points of motion m in region r
    np.add.at(counts, (regions[ij[ok, 1], ij[ok, 0]], which), 1)
    best = counts.argmax(axis=1)
    held = (counts[np.arange(n), best] >= min_points) & (motions[best] != background)
    held[0] = False
    owner[held] = motions[best[held]]
    return owner


def _add_anchored(
    kept: npt.NDArray[np.bool_], candidates: npt.NDArray[np.bool_], anchors: Anchors, min_points: int
) -> npt.NDArray[np.bool_]:
    """`kept` (whole regions of `candidates`, as `keep_strong` gives them) and the other regions of
    `candidates` that a moving motion holds (`_region_motions`) which the frame before showed (`anchors`)
    and no kept region holds: its weaker regions, which the strength test dropped although its tracks go on."""
    allowed = anchors[3]
    if allowed.size == 0 or np.array_equal(kept, candidates):  # nothing to add, or nothing dropped
        return kept
    n, regions = cv2.connectedComponents(candidates.astype(np.uint8), connectivity=8)
    owner = _region_motions(regions, n, anchors, min_points)
    is_kept = np.zeros(n, bool)
    is_kept[regions[kept]] = True
    add = (owner >= 0) & np.isin(owner, allowed) & ~np.isin(owner, owner[is_kept]) & ~is_kept
    add[0] = False
    added: npt.NDArray[np.bool_] = kept | add[regions]
    return added


_Maps = list[npt.NDArray[np.float32]]
"""Per flow, the (h, w, 2) (x, y) remap coordinates of every work-scale pixel's end point."""


def _flow_maps(flows: list[npt.NDArray[np.float32]]) -> _Maps:
    """Remap coordinates of each (work-scale) flow's end points: built once, used by every pass (one
    two-channel map per flow: one addition instead of two strided ones, the same remap)."""
    points = pixel_points(*flows[0].shape[:2])
    return [points + f for f in flows]


def _carried_along_flow(
    scores: list[npt.NDArray[np.float32]], forward: _Maps, backward: _Maps, weight: float
) -> list[npt.NDArray[np.float32]]:
    """Each score averaged with the previous and next frames' scores at the pixels the flow leads to."""

    def sample(score: npt.NDArray[np.float32], to: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
        moved: npt.NDArray[np.float32] = cv2.remap(score, to, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        return moved

    out = []
    for t, z in enumerate(scores):
        total, norm = z.copy(), 1.0
        if t + 1 < len(scores):
            total += np.float32(weight) * sample(scores[t + 1], forward[t])
            norm += weight
        if t > 0:
            total += np.float32(weight) * sample(scores[t - 1], backward[t - 1])
            norm += weight
        out.append((total / np.float32(norm)).astype(np.float32))
    return out


def moving_from_motion(
    images: npt.NDArray[np.uint8],
    motion: FrameMotion,
    cfg: MotionMaskConfig = MotionMaskConfig(),
    first: int = 0,
    colour: ColourMemory | None = None,
    anchors: list[Anchors] | None = None,
) -> npt.NDArray[np.bool_]:
    """Masks of the moving pixels from the frames' flow evidence (steps 1-5 of the module docstring).

    Args:
        images: (T, H, W, 3) uint8 RGB.
        motion: camera residuals and forward-backward errors of the T frames (`flow.frame_motion`).
        cfg: mask settings.
        first: masks of frames first..T-1 only; the frames before are evidence (their scores are
            carried along the flow and train the colour model) but get no mask of their own: a whole
            video's window starts on a frame the window before already masked.
        colour: the colour model of the windows before (a video's), updated with this window's (None =
            this window's frames only).
        anchors: per masked frame (T - first), the points the clustering labelled and the motions the
            frame before showed (`Anchors`): a region step 5 drops survives when cfg.anchor_tracks points
            of such a motion hold it and no kept region shows that motion (None = none known: clips).

    Returns:
        (T - first, H, W) bool, True = moving.
    """
    from skimage.filters import threshold_otsu

    num, height, width = images.shape[:3]
    if not 0 <= first < num:
        raise ValueError(f"first={first} must be in 0..{num - 1}")
    to_full = np.float32(1.0 / motion.scale)
    to_work = np.float32(cfg.work_scale / motion.scale)
    hw = (max(1, round(height * cfg.work_scale)), max(1, round(width * cfg.work_scale)))
    small = [cv2.resize(im, (hw[1], hw[0]), interpolation=cv2.INTER_LINEAR) for im in images]
    res = [_resize(r * to_full, hw) for r in motion.residual]
    logs = [np.log(r + np.float32(cfg.eps_px)) for r in res]
    if cfg.fb_weight > 0:
        box = (cfg.fb_box_px, cfg.fb_box_px)
        for t, err in enumerate(motion.fb_error):
            inconsistency = np.log1p(np.minimum(_resize(np.minimum(err, 1e3) * to_work, hw), 50.0))
            logs[t] = logs[t] - np.float32(cfg.fb_weight) * cv2.blur(inconsistency, box)
    forward: list[npt.NDArray[np.float32]] = []
    backward: list[npt.NDArray[np.float32]] = []
    uses_flows = cfg.spread_weight > 0 or cfg.temporal_weight > 0
    if uses_flows and motion.forward is not None and motion.backward is not None and num > 1:
        forward = [_resize(f, hw) * to_work for f in motion.forward]
        backward = [_resize(f, hw) * to_work for f in motion.backward]
    if cfg.spread_weight > 0 and forward:
        for t in range(num):
            # the flow away from the frame (into it, for the last)
            spread = _flow_spread(forward[t] if t < num - 1 else backward[t - 1], cfg.fb_box_px)
            logs[t] = logs[t] - np.float32(cfg.spread_weight) * np.log1p(spread)
    scores = []
    for lg in logs:
        sample = lg[::2, ::2]
        thr = threshold_otsu(sample) if np.ptp(sample) > 0 else float(sample.max())
        scores.append((lg - np.float32(thr)).astype(np.float32))
    if cfg.temporal_weight > 0 and forward:
        to_next, to_previous = _flow_maps(forward), _flow_maps(backward)
        for _ in range(cfg.temporal_passes):
            scores = _carried_along_flow(scores, to_next, to_previous, cfg.temporal_weight)
    if cfg.colour_weight > 0:
        ratios = colour_log_ratio(small, scores, cfg, colour)
        scores = [z + np.float32(cfg.colour_weight) * a for z, a in zip(scores, ratios)]
    small, scores, res = small[first:], scores[first:], res[first:]
    scores = refined_scores(small, scores, cfg)
    return _moving_masks(scores, res, cfg, anchors, hw, (height, width))


def refined_scores(
    small: list[npt.NDArray[np.uint8]], scores: list[npt.NDArray[np.float32]], cfg: MotionMaskConfig
) -> list[npt.NDArray[np.float32]]:
    """The scores refined on the (work-size) images: local colour contrast, superpixel means, the
    guided filter and the global smoother, each when its setting is on."""
    if cfg.local_colour_weight > 0:
        weight = np.float32(cfg.local_colour_weight)
        scores = [
            z + weight * local_colour_contrast(im, z, cfg.colour_margin, cfg.local_colour_box_px)
            for im, z in zip(small, scores)
        ]
    if cfg.superpixels > 0:
        scores = [_superpixel_mean(im, z, cfg) for im, z in zip(small, scores)]
    if cfg.guided_radius > 0:
        eps = cfg.guided_eps * 255.0**2
        guides = [cv2.cvtColor(im, cv2.COLOR_RGB2GRAY) for im in small]
        scores = [cv2.ximgproc.guidedFilter(g, z, cfg.guided_radius, eps) for g, z in zip(guides, scores)]
    if cfg.smooth_lambda > 0:
        scores = [
            cv2.ximgproc.fastGlobalSmootherFilter(im, z, cfg.smooth_lambda, cfg.smooth_sigma)
            for im, z in zip(small, scores)
        ]
    return scores


def _moving_masks(
    scores: list[npt.NDArray[np.float32]],
    res: list[npt.NDArray[np.float32]],
    cfg: MotionMaskConfig,
    anchors: list[Anchors] | None,
    hw: tuple[int, int],
    size_hw: tuple[int, int],
) -> npt.NDArray[np.bool_]:
    """(T, H, W) bool masks at full size from the masked frames' scores and residuals (work size): a
    pixel moves where its score is positive and its residual above the floor, in a strong enough
    component or one its anchors hold."""
    height, width = size_hw
    to_small = np.array([hw[1] / width, hw[0] / height], np.float32)
    masks = np.zeros((len(scores), height, width), bool)
    for t, (z, r) in enumerate(zip(scores, res)):
        moving = z > 0
        floor = max(cfg.min_residual_px, cfg.noise_factor * float(np.median(r)))
        if floor > 0:
            moving &= cv2.dilate((r >= floor).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
        kept = keep_strong(moving, r, cfg.min_component, cfg.component_power)
        if anchors is not None and cfg.anchor_tracks > 0:
            xy, labels, background, shown_before = anchors[t]
            kept = _add_anchored(kept, moving, (xy * to_small, labels, background, shown_before), cfg.anchor_tracks)
        masks[t] = cv2.resize(kept.astype(np.uint8), (width, height), interpolation=cv2.INTER_NEAREST) > 0
    return masks


def stack_motion(
    images: npt.NDArray[np.uint8],
    cfg: MotionMaskConfig = MotionMaskConfig(),
    before: npt.NDArray[np.uint8] | None = None,
    after: npt.NDArray[np.uint8] | None = None,
) -> FrameMotion:
    """The flow evidence of a stack of frames as `moving_masks` uses it (the flows between its frames kept).

    Args:
        images: (T, H, W, 3) uint8 RGB, T >= 2.
        cfg: flow settings (cfg.flow).
        before, after: the source's frames just before and after the stack (or None): with
            cfg.flow.both_directions, their flows give the stack's end frames the evidence of both
            directions too, as its inner frames have it; they take no other part (DAVIS dev, the
            first 5 frames with the 6th as `after`: J 0.643 -> 0.668 in the harness of docs/RESULTS.md).

    Returns:
        FrameMotion of the T frames (forward / backward: the T - 1 flows between them).
    """
    if not cfg.flow.both_directions or (before is None and after is None):
        return frame_motion(images, cfg.flow)
    lead = 0 if before is None else 1
    wide = np.concatenate([s for s in ([before], images, [after]) if s[0] is not None])
    full = frame_motion(wide, cfg.flow)
    end = lead + images.shape[0]
    return full.frames(lead, end)


def moving_masks(
    images: npt.NDArray[np.uint8],
    cfg: MotionMaskConfig = MotionMaskConfig(),
    first: int = 0,
    before: npt.NDArray[np.uint8] | None = None,
    after: npt.NDArray[np.uint8] | None = None,
    motion: FrameMotion | None = None,
) -> npt.NDArray[np.bool_]:
    """Masks of what moves against the camera's motion in a stack of frames.

    Args:
        images: (T, H, W, 3) uint8 RGB, T >= 2.
        cfg: flow and mask settings.
        first: masks of frames first..T-1 only (`moving_from_motion`).
        before, after: the source's frames next to the stack, as evidence (`stack_motion`).
        motion: `stack_motion` of these frames, if already computed (e.g. for the flow points).

    Returns:
        (T - first, H, W) bool, True = moving.
    """
    if motion is None:
        motion = stack_motion(images, cfg, before, after)
    return moving_from_motion(images, motion, cfg, first)
