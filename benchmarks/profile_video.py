"""Where a whole-video run's CPU goes, stage by stage, against bare DIS and KLT loops of the same run.

    python benchmarks/profile_video.py                          # 3 DAVIS dev clips at 854x480, vtest.avi at 640x480
    python benchmarks/profile_video.py --preset fast --set mask.motion.work_scale=0.5
    python benchmarks/profile_video.py --clips bear,tennis --video-frames 100 --rounds 2

Each input is run through `write_video_outputs` (what `moseg run --whole` does; no recording, one
thread per stage as the CLI runs it) with every stage function wrapped by a timer of the CPU time of
the thread it runs on (`time.thread_time`), nested calls subtracted from the caller: each row is the
stage's own CPU ms per frame, summed over the threads (reader, segmenter, the flow workers, writer),
and its share of the process's CPU over the run. "other" is what no wrapped function claims (queues,
Python glue, the wrappers themselves). Nothing in the library is changed: the wrappers are installed on
the module attributes the pipeline looks up, and removed afterwards.

Before each input, in the same process and on the same decoded frames: a bare KLT loop (TrackConfig's
corners, forward LK only, no checks, no re-seeding), a bare DIS loop with the pipeline's flow settings
(one flow per frame) and the issue's minimal classical loop (DIS ultrafast forward and backward, a
RANSAC homography on a 16-px grid of the flow, the residual thresholded). Their ms per frame (wall and
CPU) are printed beside the run's, and the run's frames/s and CPU per frame as multiples of each: on the
shared 2-core machine absolute times drift, the same-run ratios much less (the CPU ratio least: another
process on the cores stretches wall time, not CPU time). The references run on one thread.

The inputs: DAVIS-2016 train clips (854x480, 25 frames; the dev clips only by default) from
--data-root, and the first --video-frames frames of videos/vtest.avi resized to 640x480 into a
temporary folder (JPEG, as the DAVIS clips are stored).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import statistics
import tempfile
import threading
import time
from collections import defaultdict
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np

import mosegpipe.apps.outputs as outputs_mod
import mosegpipe.masks.moving_pixels as motion_mod
import mosegpipe.pipeline.video as video_mod
import mosegpipe.pipeline.window as window_mod
import mosegpipe.points.flow as flow_mod
import mosegpipe.points.klt as track_mod
from mosegpipe.embed.numpy_net import load_embedder
from mosegpipe.io.read import iter_video
from mosegpipe.pipeline import PipelineConfig
from mosegpipe.runtime import set_threads

_DEFAULT_DATA = Path(os.environ.get("MOSEG_DATA", Path(__file__).resolve().parents[1].parent / "shared" / "data"))
_DEFAULT_CLIPS = ("bear", "dance-jump", "motocross-bumps")

# (owner, attribute, stage): the functions timed; a stage may collect several functions.
_WRAPPED: list[tuple[Any, str, str]] = [
    (track_mod.KLTTracker, "_lk", "KLT: LK passes (forward + back check)"),
    (track_mod.KLTTracker, "_seed", "KLT: corners (re-seeding)"),
    (track_mod.KLTTracker, "step", "KLT: the rest (grey, bookkeeping)"),
    (track_mod.KLTTracker, "restart", "KLT: the rest (grey, bookkeeping)"),
    (flow_mod, "to_gray", "flow: grey (+ resize) per frame"),
    (flow_mod, "forward_backward_error", "flow: forward-backward error"),
    (flow_mod, "fit_camera", "camera fit (homography)"),
    (flow_mod, "camera_residual", "camera residual"),
    (flow_mod.FlowStream, "motion", "flow: window evidence (min of both directions)"),
    (motion_mod, "_flow_spread", "mask: flow spread"),
    (motion_mod, "_flow_maps", "mask: carried along the flow"),
    (motion_mod, "_carried_along_flow", "mask: carried along the flow"),
    (motion_mod, "colour_log_ratio", "mask: colour model (histograms)"),
    (motion_mod, "local_colour_contrast", "mask: local colour contrast"),
    (motion_mod, "keep_strong", "mask: components (strength test)"),
    (motion_mod, "_add_anchored", "mask: anchored regions"),
    (video_mod, "moving_from_motion", "mask: the rest (resizes, logs, fb blur, floor)"),
    (window_mod, "moving_to_labels", "labels onto moving pixels"),
    (video_mod, "carry_unclustered", "labels: carried unclustered regions"),
    (window_mod, "labels_to_mask", "labels onto pixels (other mask methods)"),
    (video_mod, "tracks_from_steps", "trajectories"),
    (video_mod, "build_trajectories", "trajectories"),
    (video_mod, "embed_at_model_frames", "embedding"),
    (video_mod, "cluster_auto_k", "automatic K"),
    (video_mod, "group_geometric", "automatic K"),
    (video_mod, "check_rigid", "rigid-motion check"),
    (video_mod, "world_to_zero", "world (label 0)"),
    (video_mod, "explain_parallax", "world: parallax (epipolar residual)"),
    (video_mod, "match_labels", "label matching"),
    (video_mod, "_label_window", "window bookkeeping"),
    (outputs_mod, "write_mask_png", "write: mask PNG"),
    (outputs_mod, "overlay_image", "write: overlay image"),
    (outputs_mod, "write_video", "write: overlay video encoding"),
    (outputs_mod, "write_npz", "write: labels.npz, summary"),
    (outputs_mod, "write_json", "write: labels.npz, summary"),
]
_DIS_FLOW = "flow: DIS {} (each direction)"
_FILTERS = [
    ("guidedFilter", "mask: guided filter"),
    ("fastGlobalSmootherFilter", "mask: fast global smoother"),
]
_ORDER = [
    "decode",
    "KLT: LK passes (forward + back check)",
    "KLT: corners (re-seeding)",
    "KLT: the rest (grey, bookkeeping)",
    "flow: grey (+ resize) per frame",
    _DIS_FLOW.format("forward"),
    _DIS_FLOW.format("backward"),
    "flow: forward-backward error",
    "camera fit (homography)",
    "camera residual",
    "flow: pair glue",
    "flow: window evidence (min of both directions)",
    "mask: the rest (resizes, logs, fb blur, floor)",
    "mask: flow spread",
    "mask: Otsu threshold",
    "mask: carried along the flow",
    "mask: colour model (histograms)",
    "mask: local colour contrast",
    "mask: guided filter",
    "mask: fast global smoother",
    "mask: components (strength test)",
    "mask: anchored regions",
    "labels onto moving pixels",
    "labels: carried unclustered regions",
    "labels onto pixels (other mask methods)",
    "trajectories",
    "embedding",
    "automatic K",
    "rigid-motion check",
    "world (label 0)",
    "world: parallax (epipolar residual)",
    "label matching",
    "window bookkeeping",
    "write: mask PNG",
    "write: overlay image",
    "write: overlay video encoding",
    "write: labels.npz, summary",
]


_GROUPS = {
    "decode": "decode",
    "KLT": "KLT (LK both ways, corners, bookkeeping)",
    "flow: DIS forward": "DIS flow, forward",
    "flow: DIS backward": "DIS flow, backward",
    "flow: forward-backward error": "forward-backward error (both directions)",
    "camera": "camera fit + residual (both directions)",
    "flow:": "flow: grey, pair glue, window evidence",
    "mask: colour model": "mask: colour model + local colour contrast",
    "mask: local colour": "mask: colour model + local colour contrast",
    "mask: guided": "mask: guided filter + global smoother",
    "mask: fast global": "mask: guided filter + global smoother",
    "mask: carried": "mask: carried along the flow",
    "mask:": "mask: the other steps (resizes, logs, spread, Otsu, components)",
    "labels": "labels onto the moving pixels",
    "write": "writing (mask PNG, overlay, video encoding)",
}
"""--grouped: a stage's row by the first prefix of its name listed here; the rest are clustering."""


def _group(stage: str) -> str:
    return next(
        (group for prefix, group in _GROUPS.items() if stage.startswith(prefix)),
        "clustering (trajectories, embedding, K, rigid check, world, matching)",
    )


class StageTimer:
    """CPU time per stage, each wrapped call's own (its wrapped callees subtracted), over all threads."""

    def __init__(self) -> None:
        self.ms: dict[str, float] = defaultdict(float)
        self._lock = threading.Lock()
        self._local = threading.local()

    def _stack(self) -> list[float]:
        if not hasattr(self._local, "stack"):
            self._local.stack = []
        stack: list[float] = self._local.stack
        return stack

    @contextlib.contextmanager
    def stage(self, name: str) -> Iterator[None]:
        stack = self._stack()
        t0 = time.thread_time()
        stack.append(0.0)
        try:
            yield
        finally:
            spent = time.thread_time() - t0
            children = stack.pop()
            if stack:
                stack[-1] += spent
            with self._lock:
                self.ms[name] += 1000 * (spent - children)

    def wrap(self, fn: Callable[..., Any], name: str | Callable[[], str]) -> Callable[..., Any]:
        def timed(*args: Any, **kwargs: Any) -> Any:
            with self.stage(name if isinstance(name, str) else name()):
                return fn(*args, **kwargs)

        return timed


@contextlib.contextmanager
def installed(timer: StageTimer) -> Iterator[None]:
    """The timers on the pipeline's stage functions while the block runs."""
    saved: list[tuple[Any, str, Any]] = []

    def put(owner: Any, attr: str, value: Any) -> None:
        saved.append((owner, attr, getattr(owner, attr)))
        setattr(owner, attr, value)

    for owner, attr, name in _WRAPPED:
        put(owner, attr, timer.wrap(getattr(owner, attr), name))
    for attr, name in _FILTERS:
        put(cv2.ximgproc, attr, timer.wrap(getattr(cv2.ximgproc, attr), name))
    import skimage.filters

    put(skimage.filters, "threshold_otsu", timer.wrap(skimage.filters.threshold_otsu, "mask: Otsu threshold"))
    # The pair job computes the flow forward, then back, on one thread: the n-th flow of the job names its direction.
    local = threading.local()
    pair, flow = flow_mod.FlowStream._pair, flow_mod.FlowStream._flow

    def counted_pair(self: Any, *args: Any) -> Any:
        local.n = 0
        return pair(self, *args)

    def direction() -> str:
        local.n = getattr(local, "n", 0) + 1
        return _DIS_FLOW.format("forward" if local.n == 1 else "backward")

    put(flow_mod.FlowStream, "_flow", timer.wrap(flow, direction))
    put(flow_mod.FlowStream, "_pair", timer.wrap(counted_pair, "flow: pair glue"))

    def timed_frames(*args: Any, **kwargs: Any) -> Iterator[Any]:
        frames = iter_video(*args, **kwargs)
        while True:
            with timer.stage("decode"):
                item = next(frames, None)
            if item is None:
                return
            yield item

    put(video_mod, "iter_video", timed_frames)
    try:
        yield
    finally:
        for owner, attr, value in reversed(saved):
            setattr(owner, attr, value)


def _grays(folder: Path) -> list[np.ndarray]:
    return [cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for _, f in iter_video(folder)]


def _clocks() -> tuple[float, float]:
    return time.perf_counter(), time.thread_time()


def _per_frame(start: tuple[float, float], frames: int) -> tuple[float, float]:
    """(wall ms, CPU ms) per frame since `start`."""
    wall, cpu = _clocks()
    return 1000 * (wall - start[0]) / frames, 1000 * (cpu - start[1]) / frames


def bare_klt_ms(grays: list[np.ndarray], cfg: PipelineConfig) -> tuple[float, float]:
    """ms per frame of a bare KLT loop: the pipeline's corner settings, forward LK only, no checks, no re-seeding."""
    c = cfg.track
    t0 = _clocks()
    pts = cv2.goodFeaturesToTrack(grays[0], c.max_corners, c.quality_level, c.min_distance_px, blockSize=c.block_size)
    win = (c.win_size_px, c.win_size_px)
    for a, b in zip(grays, grays[1:]):
        pts, _, _ = cv2.calcOpticalFlowPyrLK(a, b, pts, None, winSize=win, maxLevel=c.max_level)
    return _per_frame(t0, len(grays) - 1)


def bare_dis_ms(grays: list[np.ndarray], cfg: PipelineConfig) -> tuple[float, float]:
    """ms per frame of a bare DIS loop with the pipeline's flow settings (preset, scale, stride, iterations), one flow a frame."""
    fc = cfg.mask.motion.flow
    dis = flow_mod.DenseFlow(fc)
    small = [flow_mod.to_gray(g, fc.scale) for g in grays]
    t0 = _clocks()
    for a, b in zip(small, small[1:]):
        dis(a, b)
    return _per_frame(t0, len(grays) - 1)


def minimal_loop_ms(grays: list[np.ndarray]) -> tuple[float, float]:
    """ms per frame of the issue's minimal classical loop: DIS ultrafast forward and backward, a RANSAC
    homography on a 16-px grid of the forward flow, the residual thresholded at 1 px."""
    dis = cv2.DISOpticalFlow.create(cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST)
    h, w = grays[0].shape
    ys, xs = np.mgrid[8:h:16, 8:w:16]
    p = np.stack([xs.ravel(), ys.ravel()], 1).astype(np.float32)
    gx, gy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    pts = np.stack([gx, gy], -1).reshape(-1, 1, 2)
    t0 = _clocks()
    for a, b in zip(grays, grays[1:]):
        fwd = dis.calc(a, b, None)
        dis.calc(b, a, None)
        hom, _ = cv2.findHomography(p, p + fwd[p[:, 1].astype(int), p[:, 0].astype(int)], cv2.RANSAC, 1.0)
        if hom is None:
            continue
        pred = cv2.perspectiveTransform(pts, hom).reshape(h, w, 2)
        res = np.linalg.norm(pts.reshape(h, w, 2) + fwd - pred, axis=-1)
        _ = res > 1.0
    return _per_frame(t0, len(grays) - 1)


def vtest_640(data_root: Path, frames: int, folder: Path) -> Path:
    """The first `frames` frames of vtest.avi resized to 640x480, as JPEGs in `folder`."""
    folder.mkdir(parents=True, exist_ok=True)
    for t, rgb in iter_video(data_root / "videos" / "vtest.avi", max_frames=frames):
        small = cv2.resize(rgb, (640, 480), interpolation=cv2.INTER_AREA)
        cv2.imwrite(str(folder / f"{t:05d}.jpg"), small[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, 95])
    return folder


def profile(name: str, folder: Path, cfg: PipelineConfig, model: Any, work: Path) -> dict[str, Any]:
    """References, then the timed run, on one input."""
    grays = _grays(folder)
    refs = {"KLT": bare_klt_ms(grays, cfg), "DIS": bare_dis_ms(grays, cfg), "minimal": minimal_loop_ms(grays)}
    timer = StageTimer()
    with installed(timer):
        t0, c0 = time.perf_counter(), time.process_time()
        summary = outputs_mod.write_video_outputs(folder, work / name, cfg, model, overwrite=True, rrd=False)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    n = summary["frames"]
    return {
        "name": name,
        "size": f"{grays[0].shape[1]}x{grays[0].shape[0]}",
        "frames": n,
        "wall": wall,
        "cpu_ms": 1000 * cpu / n,
        "stages": {k: v / n for k, v in timer.ms.items()},
        "refs": refs,
    }


def table(runs: list[dict[str, Any]], grouped: bool = False) -> str:
    """Markdown: one column per input, CPU ms per frame per stage (share of the run's CPU in brackets);
    grouped: the stages summed into a dozen rows (`_GROUPS`)."""
    if grouped:
        runs = [{**r, "stages": _grouped(r["stages"])} for r in runs]
    names = [r["name"] for r in runs]
    lines = [
        "| stage | " + " | ".join(names) + " |",
        "|---|" + "---|" * len(runs),
    ]
    seen = set().union(*(r["stages"] for r in runs))
    ranked = [_group(s) for s in _ORDER] if grouped else _ORDER
    order = list(dict.fromkeys(s for s in ranked if s in seen)) + sorted(seen - set(ranked))
    for stage in order:
        cells = []
        for r in runs:
            ms = r["stages"].get(stage, 0.0)
            cells.append(f"{ms:.1f} ({100 * ms / r['cpu_ms']:.0f} %)" if ms >= 0.05 else "")
        if any(cells):
            lines.append(f"| {stage} | " + " | ".join(cells) + " |")
    other = [r["cpu_ms"] - sum(r["stages"].values()) for r in runs]
    lines.append(
        "| other (queues, glue, timers) | "
        + " | ".join(f"{o:.1f} ({100 * o / r['cpu_ms']:.0f} %)" for o, r in zip(other, runs))
        + " |"
    )
    lines.append("| **CPU ms / frame, all threads** | " + " | ".join(f"**{r['cpu_ms']:.0f}**" for r in runs) + " |")
    lines.append("| frames/s (wall) | " + " | ".join(f"{r['frames'] / r['wall']:.1f}" for r in runs) + " |")
    lines.append(
        "| at most on 2 cores (2000 / CPU ms) | " + " | ".join(f"{2000 / r['cpu_ms']:.1f}" for r in runs) + " |"
    )
    for key, label in (
        ("KLT", "bare KLT loop, ms / frame: wall (CPU)"),
        ("DIS", "bare DIS loop (the pipeline's flow, one a frame), ms / frame: wall (CPU)"),
        ("minimal", "minimal classical loop (DIS ultrafast both ways, RANSAC), ms / frame: wall (CPU)"),
    ):
        lines.append(
            f"| {label} | " + " | ".join(f"{r['refs'][key][0]:.1f} ({r['refs'][key][1]:.1f})" for r in runs) + " |"
        )
    for key, label in (
        ("DIS", "× bare DIS: frames/s (CPU per frame)"),
        ("minimal", "× minimal loop: frames/s (CPU per frame)"),
        ("KLT", "× bare KLT: frames/s (CPU per frame)"),
    ):
        cells = []
        for r in runs:
            wall_ms, cpu_ms = r["refs"][key]
            cells.append(f"{wall_ms * r['frames'] / (1000 * r['wall']):.3f} ({cpu_ms / r['cpu_ms']:.3f})")
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _grouped(stages: dict[str, float]) -> dict[str, float]:
    out: dict[str, float] = defaultdict(float)
    for stage, ms in stages.items():
        out[_group(stage)] += ms
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data-root", type=Path, default=_DEFAULT_DATA)
    parser.add_argument("--clips", default=",".join(_DEFAULT_CLIPS), help="DAVIS-2016 train clips ('' for none)")
    parser.add_argument("--video-frames", type=int, default=200, help="frames of vtest.avi at 640x480 (0: none)")
    parser.add_argument("--preset", default=None, help="a named preset (PipelineConfig presets)")
    parser.add_argument("--set", dest="settings", action="append", default=[], help="dotted.path=value (repeatable)")
    parser.add_argument("--grouped", action="store_true", help="the stages summed into a dozen rows")
    parser.add_argument("--rounds", type=int, default=1, help="runs of each input; the table shows the median round")
    args = parser.parse_args()
    set_threads(1)
    # The library imports these on first use (`moseg run` on a thread of its own): here, before the timers,
    # so that no stage's first call pays for an import.
    import scipy.optimize  # noqa: F401
    import scipy.spatial  # noqa: F401
    import skimage.filters.thresholding  # noqa: F401

    options: dict[str, Any] = {"settings": args.settings}
    if args.preset is not None:
        options["preset"] = args.preset
    cfg = PipelineConfig.from_options(5, **options)
    model = load_embedder(cfg.frames)
    load = " / ".join(f"{v:.2f}" for v in os.getloadavg())
    with tempfile.TemporaryDirectory(prefix="moseg-profile-") as tmp:
        work = Path(tmp)
        inputs = [(c, args.data_root / "davis2016-train" / c / "frames") for c in args.clips.split(",") if c]
        if args.video_frames > 0:
            inputs.append(("vtest 640x480", vtest_640(args.data_root, args.video_frames, work / "vtest640")))
        runs = []
        for name, folder in inputs:
            rounds = [profile(name, folder, cfg, model, work) for _ in range(args.rounds)]
            runs.append(sorted(rounds, key=lambda r: r["cpu_ms"])[len(rounds) // 2])
    print(f"settings: preset {args.preset or '(default)'}, --set {' '.join(args.settings) or '(none)'}")
    print(f"load average at the start: {load}; at the end: {' / '.join(f'{v:.2f}' for v in os.getloadavg())}")
    print()
    print(table(runs, args.grouped))
    fps = [r["frames"] / r["wall"] for r in runs]
    print()
    print(f"median frames/s over the inputs: {statistics.median(fps):.1f}")


if __name__ == "__main__":
    main()
