"""Dense optical flow (OpenCV DIS) and the camera's motion fitted to it.

Every pixel gets a displacement to the next frame (DIS, Kroeger et al. 2016, as OpenCV ships it); a
homography fitted robustly to a grid of those displacements is the camera's motion (the dominant
planar motion: a rotating or zooming camera, or a distant scene); what it does not explain is each
pixel's *camera residual*, the evidence that the pixel moves on its own. `mosegpipe.masks.moving_pixels` turns
residuals into dense masks of the moving objects.

Measured on the 20 dev clips of DAVIS-2016 train (docs/RESULTS.md, "Real video"): the flow at full
resolution separates objects from background clearly better than at half resolution (mask J 0.57 vs
0.52 with the same mask stage) because DIS's smoothing spills less across object boundaries; finer
patches or a weaker smoothness term at half resolution did not help.
"""

from __future__ import annotations

import functools
import threading
from collections.abc import Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe.configs.tracking import FlowConfig
from mosegpipe.group.twoview import robust_fit
from mosegpipe.types import DisPreset

DIS_PRESETS: dict[DisPreset, int] = {
    "ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST,
    "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
    "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM,
}
"""The DIS presets `FlowConfig.preset` accepts."""

MIN_FLOW_SIDE_PX = 16
"""OpenCV's DIS refuses images under 12 px a side; smaller frames (after FlowConfig.scale) get no flow."""


def flow_fits(size_hw: tuple[int, int], cfg: FlowConfig) -> bool:
    """Whether frames of this (H, W) are large enough for dense flow at cfg.scale."""
    return min(size_hw) * cfg.scale >= MIN_FLOW_SIDE_PX


"""The robust fits of the camera's homography (FlowConfig.camera_fit) and their OpenCV methods."""


def to_gray(image: npt.NDArray[np.uint8], scale: float) -> npt.NDArray[np.uint8]:
    """(H, W, 3) RGB or (H, W) gray uint8 -> gray uint8 resized by `scale` (area interpolation)."""
    gray = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
    if scale == 1:
        return np.ascontiguousarray(gray)
    return cv2.resize(gray, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)


class DenseFlow:
    """DIS optical flow between gray images, one OpenCV instance reused (it keeps its buffers)."""

    def __init__(self, cfg: FlowConfig = FlowConfig()) -> None:
        self.cfg = cfg
        self._dis = cv2.DISOpticalFlow.create(DIS_PRESETS[cfg.preset])
        if cfg.patch_stride is not None:
            self._dis.setPatchStride(cfg.patch_stride)
        if cfg.refinement_iterations is not None:
            self._dis.setVariationalRefinementIterations(cfg.refinement_iterations)

    def __call__(self, gray0: npt.NDArray[np.uint8], gray1: npt.NDArray[np.uint8]) -> npt.NDArray[np.float32]:
        """(h, w, 2) float32 displacement (dx, dy) of each pixel of gray0 to gray1, in pixels of these images."""
        return self._dis.calc(gray0, gray1, None)


@functools.lru_cache(maxsize=4)
def pixel_grid(h: int, w: int) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
    """(x, y) float32 coordinates of every pixel of an (h, w) image, read-only (cached: a video's frames share them)."""
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    xs.flags.writeable = False
    ys.flags.writeable = False
    return xs, ys


def _length(vectors: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
    """(h, w) float32 lengths of (h, w, 2) vectors (numpy: exactly rounded, whatever the memory alignment,
    which cv2.magnitude's vector code is not; 6x faster than np.hypot)."""
    length: npt.NDArray[np.float32] = np.sqrt(np.square(vectors[..., 0]) + np.square(vectors[..., 1]))
    return length


@functools.lru_cache(maxsize=4)
def pixel_points(h: int, w: int) -> npt.NDArray[np.float32]:
    """(h, w, 2) float32 (x, y) of every pixel of an (h, w) image, read-only (cached)."""
    xs, ys = pixel_grid(h, w)
    points = np.stack([xs, ys], axis=-1)
    points.flags.writeable = False
    return points


def forward_backward_error(
    forward: npt.NDArray[np.float32], backward: npt.NDArray[np.float32]
) -> npt.NDArray[np.float32]:
    """(h, w) float32: |forward(p) + backward(p + forward(p))| in pixels; inf where forward leaves the image.

    Small where the two flows agree; large at occlusions, flow failures and dynamic textures (water,
    smoke), whose flow is not a consistent motion.
    """
    h, w = forward.shape[:2]
    xs, ys = pixel_grid(h, w)
    x1, y1 = xs + forward[..., 0], ys + forward[..., 1]
    back = cv2.remap(backward, x1, y1, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    loop = forward + back
    err: npt.NDArray[np.float32] = _length(loop)
    err[(x1 < 0) | (x1 > w - 1) | (y1 < 0) | (y1 > h - 1)] = np.inf
    return err


def fit_camera(
    flow: npt.NDArray[np.float32], usable: npt.NDArray[np.bool_] | None, cfg: FlowConfig = FlowConfig()
) -> npt.NDArray[np.float64]:
    """The homography that explains most of a flow field (the camera's motion), fitted robustly (cfg.camera_fit).

    Args:
        flow: (h, w, 2) float32 displacements.
        usable: (h, w) bool, pixels the fit may sample (None = all).
        cfg: grid step and inlier threshold.

    Returns:
        (3, 3) float64 homography mapping a pixel of the first image to the second; the identity
        when too few samples are usable or the fit fails (the flow is then taken as all residual).
    """
    h, w = flow.shape[:2]
    step = cfg.grid_step_px
    rows, cols = np.arange(step // 2, h, step), np.arange(step // 2, w, step)
    if usable is None:
        at_row, at_col = np.divmod(np.arange(rows.size * cols.size), cols.size)
    else:  # the grid's usable samples, row by row (no full-size temporaries)
        at_row, at_col = np.nonzero(usable[step // 2 :: step, step // 2 :: step])
    ys, xs = rows[at_row], cols[at_col]
    if xs.size < 8:
        return np.eye(3)
    p = np.stack([xs, ys], axis=1).astype(np.float32)
    q = p + flow[ys, xs]
    hom, _ = robust_fit("homography", p, q, cfg.camera_fit, cfg.ransac_px)
    return np.eye(3) if hom is None else hom


def camera_residual(flow: npt.NDArray[np.float32], hom: npt.NDArray[np.float64]) -> npt.NDArray[np.float32]:
    """(h, w) float32: |flow - the displacement the homography predicts| per pixel, in pixels."""
    h, w = flow.shape[:2]
    points = pixel_points(h, w)
    # The homography rounded to float32: fits that differ below that (the robust fit's last bits) give the same residual.
    hom32 = hom.astype(np.float32).astype(np.float64)
    predicted = cv2.perspectiveTransform(points.reshape(-1, 1, 2), hom32).reshape(h, w, 2)
    miss = points + flow - predicted
    return _length(miss)


@dataclass(frozen=True)
class FrameMotion:
    """Per-frame flow evidence of a stack of T frames, at the flow's scale (h, w).

    Attributes:
        residual: (T, h, w) float32 camera residual (`camera_residual`), pixels.
        fb_error: (T, h, w) float32 forward-backward disagreement (`forward_backward_error`), pixels;
            inf where the flow leaves the image.
        scale: the flow's scale (h / H).
        forward: (T-1, h, w, 2) float32 flow from frame t to t+1, pixels (None when not kept).
        backward: (T-1, h, w, 2) float32 flow from frame t+1 to t, pixels (None when not kept).
    """

    residual: npt.NDArray[np.float32]
    fb_error: npt.NDArray[np.float32]
    scale: float
    forward: npt.NDArray[np.float32] | None = None
    backward: npt.NDArray[np.float32] | None = None

    def frames(self, a: int, b: int) -> FrameMotion:
        """The evidence of frames a..b-1 (and the flows between them) of this stack."""
        return FrameMotion(
            self.residual[a:b],
            self.fb_error[a:b],
            self.scale,
            None if self.forward is None else self.forward[a : b - 1],
            None if self.backward is None else self.backward[a : b - 1],
        )


def _evidence(
    forward: npt.NDArray[np.float32], backward: npt.NDArray[np.float32], cfg: FlowConfig
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
    """(camera residual, forward-backward error) of the first image of a pair from its two flows."""
    err = forward_backward_error(forward, backward)
    return camera_residual(forward, fit_camera(forward, err < cfg.fb_max_px, cfg)), err


@dataclass(frozen=True)
class _Pair:
    """Frames t and t+1 of one shot: the flows both ways, frame t's evidence from the forward flow and
    (with FlowConfig.both_directions; else None, see `back_evidence`) frame t+1's from the backward one."""

    forward: npt.NDArray[np.float32]
    backward: npt.NDArray[np.float32]
    residual: npt.NDArray[np.float32]
    fb_error: npt.NDArray[np.float32]
    back_residual: npt.NDArray[np.float32] | None = None
    back_fb_error: npt.NDArray[np.float32] | None = None

    def back_evidence(self, cfg: FlowConfig) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
        """Frame t+1's (camera residual, forward-backward error) from the backward flow."""
        if self.back_residual is not None and self.back_fb_error is not None:
            return self.back_residual, self.back_fb_error
        return _evidence(self.backward, self.forward, cfg)


class FlowStream:
    """The flows of a stream of frames and each frame's evidence, computed on worker threads as frames arrive.

    `add` hands each frame over as it is read: the flows to and from the frame before (one job per
    pair of frames, `cfg.workers` threads, each with its own DIS) start at once, so they overlap with
    whatever the caller does next (tracking the next frames, clustering the window before). `motion`
    then collects a run of consecutive frames' evidence: exactly what `frame_motion` computes on the
    same frames. Pairs are kept until `forget`; use it as a context manager (the threads end on exit).
    """

    def __init__(self, cfg: FlowConfig = FlowConfig()) -> None:
        self.cfg = cfg
        self._pool = ThreadPoolExecutor(max_workers=cfg.workers, thread_name_prefix="moseg-flow")
        self._local = threading.local()
        self._pairs: dict[int, tuple[int, Future[_Pair]]] = {}  # frame -> (the next frame, their pair)
        self._last: tuple[int, npt.NDArray[np.uint8]] | None = None
        self._lock = threading.Lock()  # frames are added on one thread, collected and forgotten on another

    def __enter__(self) -> FlowStream:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Ends the worker threads (pending jobs are cancelled) and drops every pair."""
        self._pool.shutdown(wait=True, cancel_futures=True)
        with self._lock:
            self._pairs.clear()
        self._last = None

    def _flow(self, gray0: npt.NDArray[np.uint8], gray1: npt.NDArray[np.uint8]) -> npt.NDArray[np.float32]:
        if not hasattr(self._local, "flow"):
            self._local.flow = DenseFlow(self.cfg)  # one DIS per thread (it keeps its buffers)
        flow: npt.NDArray[np.float32] = self._local.flow(gray0, gray1)
        return flow

    def _pair(self, gray0: npt.NDArray[np.uint8], gray1: npt.NDArray[np.uint8]) -> _Pair:
        forward, backward = self._flow(gray0, gray1), self._flow(gray1, gray0)
        # Frame t+1's evidence from the flow back: every frame's with both directions, else only a
        # window's last frame needs it (computed then, by `motion`).
        back = _evidence(backward, forward, self.cfg) if self.cfg.both_directions else (None, None)
        return _Pair(forward, backward, *_evidence(forward, backward, self.cfg), *back)

    def add(self, index: int, image: npt.NDArray[np.uint8], new_shot: bool = False) -> None:
        """Hands over the next frame.

        Args:
            index: the frame's index, larger than the frame before's (a stream that drops frames may
                skip indices: the flow then runs from the frame before to this one).
            image: (H, W, 3) uint8 RGB or (H, W) gray.
            new_shot: the frame starts a new shot: no flow to the frame before (a shot cut).
        """
        gray = to_gray(image, self.cfg.scale)
        if self._last is not None and not new_shot:
            before, gray0 = self._last
            if index <= before:
                raise ValueError(f"frame {index} follows frame {before}: frames must come in increasing order")
            job = self._pool.submit(self._pair, gray0, gray)
            with self._lock:
                self._pairs[before] = (index, job)
        self._last = (index, gray)

    def motion(self, indices: Sequence[int], after: int | None = None, before: int | None = None) -> FrameMotion:
        """FrameMotion of successive frames (at least 2, added one after the other in one shot), waiting for their flows.

        Frame t uses its flow to the next frame (checked by the flow back); the last frame its flow
        back to the frame before (checked by the flow forward); with `cfg.both_directions` the frames
        between take the smaller of both, as `frame_motion` does, and so do the last frame when
        `after` names the frame added after it and the first frame when `before` names the frame
        added before it (their flows are used for that, not returned).
        """
        if len(indices) < 2:
            raise ValueError(f"motion needs at least 2 frames, got {len(indices)}")
        lead = [] if before is None else [before]
        frames = [*lead, *indices, *([] if after is None else [after])]
        steps = list(zip(frames[:-1], frames[1:]))
        with self._lock:
            jobs = [self._pairs.get(a, (None, None)) for a, _ in steps]
        for (following, job), (a, b) in zip(jobs, steps):
            if following != b or job is None:
                raise ValueError(f"no flow from frame {a} to frame {b} (not added in turn, forgotten or a shot cut)")
        pairs = [job.result() for _, job in jobs if job is not None]
        inside = pairs[len(lead) : len(lead) + len(indices) - 1]
        last = inside[-1].back_evidence(self.cfg)
        residual = np.stack([p.residual for p in inside] + [last[0]])
        fb_error = np.stack([p.fb_error for p in inside] + [last[1]])
        if self.cfg.both_directions:
            for t in range(1, len(pairs)):  # frame t: pair t's forward flow and pair t-1's flow back
                back_residual, back_fb_error = pairs[t - 1].back_evidence(self.cfg)
                own = t - len(lead)  # the frame's place in `indices`
                np.minimum(pairs[t].residual, back_residual, out=residual[own])
                np.minimum(pairs[t].fb_error, back_fb_error, out=fb_error[own])
        return FrameMotion(
            residual,
            fb_error,
            self.cfg.scale,
            np.stack([p.forward for p in inside]),
            np.stack([p.backward for p in inside]),
        )

    def forget(self, before: int) -> None:
        """Drops the pairs that start before frame `before` (a window done with them)."""
        with self._lock:
            for t in [t for t in self._pairs if t < before]:
                self._pairs.pop(t)[1].cancel()


def frame_motion(images: npt.NDArray[np.uint8], cfg: FlowConfig = FlowConfig()) -> FrameMotion:
    """The camera residual and flow consistency of every frame of a stack.

    Frame t < T-1 uses its flow to frame t+1 (checked by the flow back); the last frame its flow back
    to frame T-2 (checked by the flow forward); with `cfg.both_directions` (the default) frames
    0 < t < T-1 take the smaller residual and forward-backward error of both.

    Args:
        images: (T, H, W, 3) uint8 RGB, T >= 2.
        cfg: flow settings.

    Returns:
        FrameMotion at the flow's scale.
    """
    if images.shape[0] < 2:
        raise ValueError(f"frame_motion needs at least 2 frames, got {images.shape[0]}")
    with FlowStream(cfg) as stream:
        for t, image in enumerate(images):
            stream.add(t, image)
        return stream.motion(range(images.shape[0]))
