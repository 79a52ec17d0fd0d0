"""Wall-clock speed of the pipeline on this machine, printed as Markdown tables.

    python benchmarks/speed.py [--model PATH] [--data-root ../shared/data] [--video-frames 200]

(a) `moseg run` on 5 frames at 640x480 (a rendered clip and the first frames of vtest.avi resized),
    stage by stage: the first (cold) call after the imports, then the median of --repeats calls
    after one warm-up call. "write" is masks + overlays + labels + summary, "rrd" the recording.
(b) whole-video mode (`moseg run --whole`, mosegpipe.apps.outputs.write_video_outputs) on --video-frames frames
    of a rendered 640x480 video (~900 tracks) and of vtest.avi resized to 640x480 (~400 tracks):
    frames per second, vtest.avi with and without the Rerun recording.
(c) embedding + automatic K for the 22 KT3DMoSeg test clips (the datasets' own trajectories).
(e) whole-video mode at 854x480 (DAVIS' size; vtest.avi resized) with each dense-mask method, against
    a bare DIS loop (medium preset, forward flow only, full resolution, one thread) and the bare KLT
    loop of (b) on the same frames, measured right before each run. `--dense-methods motion@0.75 ...`
    runs the motion masks with their mask steps at another work scale (MotionMaskConfig.work_scale).
(d) start-up: `moseg run` on 5 frames (samples/rendered/frames) from the shell, fresh processes with
    the commands interleaved, against `python -c "import numpy, cv2"` and `python -c "import torch"`
    measured in the same rounds; then the same steps stamped one by one in a fresh process (interpreter,
    imports, model, stages, files, recording, exit). `--startup-against OTHER/.venv/bin/moseg` runs another
    checkout's `moseg run` in the same rounds and prints the per-round ratios.

(b) also times a bare OpenCV KLT loop on the same frames (same corners, no checks) right before each
run and prints the pipeline's frames/s as a multiple of it: on these shared machines absolute
times vary from run to run, the ratio much less.

Everything runs on one thread (mosegpipe.runtime.set_threads(1)), as `moseg` does by default.
Without --model the shipped 5-frame weights are used, or, when there are none, an untrained
SubspaceNet of the same size: the timings hold, the segmentations do not.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

_T_START = time.perf_counter()

import cv2  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

from mosegpipe.apps.outputs import write_clip_outputs  # noqa: E402
from mosegpipe.embed.model import ModelConfig, SubspaceNet  # noqa: E402
from mosegpipe.embed.numpy_net import Embedder, NumpySubspaceNet  # noqa: E402
from mosegpipe.group.cluster import cluster_auto_k  # noqa: E402
from mosegpipe.pipeline import PipelineConfig, segment_clip  # noqa: E402
from mosegpipe.runtime import set_threads  # noqa: E402

_IMPORT_S = time.perf_counter() - _T_START
_DEFAULT_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
_SAMPLE_FRAMES = Path(__file__).resolve().parents[1] / "samples" / "rendered" / "frames"
STAGES = ("read", "track", "embed", "cluster", "masks", "write", "rrd")


def machine_info() -> str:
    """One line: CPU model, cores, torch threads and versions, load average."""
    model = "unknown CPU"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    load = " / ".join(f"{v:.2f}" for v in os.getloadavg()) if hasattr(os, "getloadavg") else "n/a"
    return (
        f"{model} · nproc {usable} (cpu_count {os.cpu_count()}) · torch {torch.__version__} with "
        f"{torch.get_num_threads()} thread(s) · OpenCV {cv2.__version__} with {cv2.getNumThreads()} thread(s) · "
        f"Python {platform.python_version()} · load average {load}"
    )


def load_model(path: Path | None, frames: int = 5) -> tuple[Embedder, str]:
    """The model to time and a description of it: in NumPy, as the single-clip commands run it."""
    if path is not None:
        t0 = time.perf_counter()
        net = SubspaceNet.from_checkpoint(path)
        what = f"checkpoint {path} (loaded in {1000 * (time.perf_counter() - t0):.0f} ms)"
    else:
        try:
            net, what = SubspaceNet.default(frames=frames), f"shipped weights for {frames} frames"
        except Exception:  # noqa: BLE001 - any failure means: no usable shipped weights
            torch.manual_seed(0)
            net = SubspaceNet(ModelConfig(in_dim=2 * frames)).eval()
            what = "untrained SubspaceNet (no shipped weights; accuracy meaningless)"
    if net.cfg.arch != "subspacenet":
        return net, f"{what}, torch inference"
    return NumpySubspaceNet.from_torch(net), f"{what}, NumPy inference (as moseg run)"


def write_video(frames: list[np.ndarray], path: Path, fps: float = 10.0) -> Path:
    """RGB frames (H, W, 3) uint8 to an MJPG .avi."""
    h, w = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (w, h))
    if not writer.isOpened():
        sys.exit(f"speed.py: cannot write {path}")
    for f in frames:
        writer.write(cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
    writer.release()
    return path


def resized_frames(video: Path, count: int, size_wh: tuple[int, int] = (640, 480)) -> list[np.ndarray]:
    """The first `count` frames of a video, resized, RGB."""
    from mosegpipe.io.read import iter_video

    return [cv2.resize(f, size_wh, interpolation=cv2.INTER_AREA) for _, f in iter_video(video, max_frames=count)]


def run_once(clip: Path, out: Path, model: Embedder, cfg: PipelineConfig) -> tuple[dict[str, float], dict[str, Any]]:
    """One `moseg run` (segment_clip + write_clip_outputs with the recording): seconds per stage."""
    t0 = time.perf_counter()
    result = segment_clip(clip, cfg, model)
    t1 = time.perf_counter()
    summary = write_clip_outputs(result, out, cfg, overwrite=True, rrd=True)
    t2 = time.perf_counter()
    times = {k: result.timings.get(k, 0.0) for k in ("read", "track", "embed", "cluster", "masks")}
    times["rrd"] = float(summary["timings_s"].get("rrd", 0.0))
    times["write"] = (t2 - t1) - times["rrd"]
    times["total"] = t2 - t0
    return times, summary


def clip_table(clips: dict[str, Path], model: Embedder, repeats: int, work: Path) -> str:
    cfg = PipelineConfig(frames=5)
    cols = [*STAGES, "total"]
    lines = [
        "| input | call | tracks | K | " + " | ".join(f"{c} ms" for c in cols) + " |",
        "|" + "---|" * (len(cols) + 4),
    ]
    first = True
    for name, path in clips.items():
        out = work / f"out_{name}"
        cold, summary = run_once(path, out, model, cfg)
        if first:
            label = "cold (1st call in process)"
        else:
            label = "1st call on this input"
        runs = [run_once(path, out, model, cfg)[0] for _ in range(repeats)]
        warm = {c: statistics.median(r[c] for r in runs) for c in cols}
        info = f"{summary['num_tracks_segmented']} | {summary['k']}"
        for lab, t in ((label, cold), (f"warm, median of {repeats}", warm)):
            lines.append(f"| {name} | {lab} | {info} | " + " | ".join(f"{1000 * t[c]:.0f}" for c in cols) + " |")
        first = False
    return "\n".join(lines)


def bare_klt_fps(video: Path) -> float:
    """Frames/s of a bare OpenCV KLT loop on the decoded frames of `video`: the same corner settings
    (TrackConfig defaults), forward LK only, no checks, no re-seeding. The reference of (b)."""
    from mosegpipe.io.read import iter_video
    from mosegpipe.points.klt import TrackConfig

    c = TrackConfig()
    grays = [cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for _, f in iter_video(video)]
    t0 = time.perf_counter()
    pts = cv2.goodFeaturesToTrack(grays[0], c.max_corners, c.quality_level, c.min_distance_px, blockSize=c.block_size)
    win = (c.win_size_px, c.win_size_px)
    for a, b in zip(grays, grays[1:]):
        pts, _, _ = cv2.calcOpticalFlowPyrLK(a, b, pts, None, winSize=win, maxLevel=c.max_level)
    return (len(grays) - 1) / (time.perf_counter() - t0)


def video_table(runs: list[tuple[str, Path, bool]], model: Embedder, work: Path) -> str:
    """Whole-video mode on each (name, video, with recording) run, against bare KLT on the same frames
    measured just before it (timings on shared machines drift: the ratio is the figure to compare)."""
    from mosegpipe.apps.outputs import write_video_outputs
    from mosegpipe.pipeline import segment_video

    cfg = PipelineConfig(frames=5)
    lines = [
        "| input | recording | frames | windows | mean tracks / window | motion labels | wall s | frames/s "
        "| bare KLT frames/s | x bare KLT | CPU ms / frame (all threads) | at most on 2 cores, frames/s "
        "| tracking thread alone, frames/s |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for i, (name, video, rrd) in enumerate(runs):
        ref = bare_klt_fps(video)
        t0, c0 = time.perf_counter(), time.process_time()
        s = write_video_outputs(video, work / f"video_{i}", cfg, model, overwrite=True, rrd=rrd)
        seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
        # The thread that reads, tracks and clusters, on its own (no masks, no files): the bound that
        # a second core cannot lift.
        t0 = time.perf_counter()
        for _ in segment_video(video, cfg, model, masks=False):
            pass
        alone = s["frames"] / (time.perf_counter() - t0)
        tracks = np.mean([w["num_tracks"] for w in s["windows"]])
        fps = s["frames"] / seconds
        cpu_ms = 1000 * cpu / s["frames"]
        lines.append(
            f"| {name} | {'yes' if rrd else 'no'} | {s['frames']} | {s['num_windows']} | {tracks:.0f} | "
            f"{s['num_motions']} | {seconds:.2f} | {fps:.1f} | {ref:.0f} | {fps / ref:.3f} | {cpu_ms:.0f} | "
            f"{2000 / cpu_ms:.1f} | {alone:.1f} |"
        )
    return "\n".join(lines)


def bare_dis_fps(video: Path) -> float:
    """Frames/s of a bare OpenCV DIS loop (medium preset, forward flow only, full resolution) on the
    decoded frames of `video`: the reference of (e), the flow that the "motion" masks compute twice."""
    from mosegpipe.io.read import iter_video

    grays = [cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for _, f in iter_video(video)]
    dis = cv2.DISOpticalFlow.create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    t0 = time.perf_counter()
    for a, b in zip(grays, grays[1:]):
        dis.calc(a, b, None)
    return (len(grays) - 1) / (time.perf_counter() - t0)


def dense_table(video: Path, model: Embedder, work: Path, methods: tuple[str, ...] = ("motion", "watershed")) -> str:
    """Whole-video mode (no recording) with each mask method, against bare DIS and KLT loops measured just before."""
    from dataclasses import replace

    from mosegpipe.apps.outputs import write_video_outputs
    from mosegpipe.masks import MaskConfig

    lines = [
        "| mask method | frames | wall s | frames/s | bare DIS frames/s | x bare DIS | bare KLT frames/s | x bare KLT "
        "| CPU ms / frame (all threads) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for i, method in enumerate(methods):
        dis, klt = bare_dis_fps(video), bare_klt_fps(video)
        name, _, scale = method.partition("@")
        mask = MaskConfig(method=name)
        if scale:
            mask = replace(mask, motion=replace(mask.motion, work_scale=float(scale)))
        cfg = replace(PipelineConfig(frames=5), mask=mask)
        t0, c0 = time.perf_counter(), time.process_time()
        s = write_video_outputs(video, work / f"dense_{i}", cfg, model, overwrite=True, rrd=False)
        seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
        fps = s["frames"] / seconds
        lines.append(
            f"| {method} | {s['frames']} | {seconds:.2f} | {fps:.1f} | {dis:.1f} | {fps / dis:.2f} | {klt:.0f} | "
            f"{fps / klt:.3f} | {1000 * cpu / s['frames']:.0f} |"
        )
    return "\n".join(lines)


# The steps of `moseg run CLIP --frames 5` (cli/clip.py `run`) in a fresh interpreter, each stamped
# with the wall clock (time.time(), comparable with the parent's): the breakdown of table (d).
_STARTUP_PROBE = """
import json, sys, time
marks = {"started": time.time()}
from mosegpipe.cli import main as cli
from mosegpipe.cli.app import setup_run
from mosegpipe.cli.options import ClusterOptions, pipeline_cfg
marks["cli_imported"] = time.time()
setup_run(1, False, "mosegpipe.apps.outputs")
marks["setup"] = time.time()
from mosegpipe.apps.outputs import write_clip_outputs
from mosegpipe.embed.numpy_net import load_embedder
from mosegpipe.pipeline import segment_clip
from mosegpipe.cli.clip import _import_ahead
cfg = pipeline_cfg(5, ClusterOptions())
_import_ahead(cfg)
model = load_embedder(5)
marks["model"] = time.time()
result = segment_clip(sys.argv[1], cfg, model)
marks["segmented"] = time.time()
summary = write_clip_outputs(result, sys.argv[2], cfg, rrd=True)
marks["written"] = time.time()
print(json.dumps({"marks": marks, "timings": result.timings, "rrd": summary["timings_s"].get("rrd", 0.0)}))
"""
STARTUP_PHASES = (
    ("interpreter", "Python itself, up to the first line"),
    ("CLI import", "mosegpipe.cli.main: Typer, NumPy"),
    ("imports + setup", "OpenCV, mosegpipe; thread settings (SciPy, PyAV, Rerun: on a thread of their own)"),
    ("model", "the shipped weights (their NumPy copy; torch only on a checkpoint's first run)"),
    ("read", "5 frames"),
    ("flow", "the clip's dense flow (the motion masks', the world's evidence)"),
    ("track", "KLT"),
    ("embed", "SubspaceNet"),
    ("cluster", "automatic K, the rigid-motion check, the world (with any wait for SciPy's import)"),
    ("masks", "dense masks"),
    ("files", "masks, overlays, labels, summary"),
    ("rrd", "the recording (with any wait for Rerun's import)"),
    ("exit", "interpreter teardown"),
)


def _timed_process(cmd: list[str], env: dict[str, str]) -> tuple[float, float, str]:
    """(start time.time(), wall s, stdout) of one fresh process, run from the temporary folder."""
    import subprocess

    started = time.time()
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=tempfile.gettempdir(), check=False)
    seconds = time.perf_counter() - t0
    if proc.returncode != 0:
        sys.exit(f"speed.py: {' '.join(cmd)} failed:\n{proc.stderr}")
    return started, seconds, proc.stdout


_COLD = "moseg run CLIP --frames 5 --no-rrd, first run of the weights"


def startup_tables(clip: Path, work: Path, repeats: int = 5, against: Path | None = None) -> str:
    """(d): wall and CPU time of fresh processes from the shell, `repeats` rounds, the commands
    interleaved within each round (the load of a shared machine drifts; interleaving spreads it
    evenly); then the breakdown of `moseg run` on 5 frames into its steps (_STARTUP_PROBE). With `against`
    (another checkout's `moseg`, e.g. main's) its `moseg run` runs in the same rounds, and the table adds the
    median of the per-round ratios."""
    import resource
    import shutil

    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    moseg = str(Path(sys.executable).with_name("moseg"))
    out = work / "startup"
    commands = {
        "python -c pass": [sys.executable, "-c", "pass"],
        'python -c "import numpy, cv2"': [sys.executable, "-c", "import numpy, cv2"],
        'python -c "import torch"': [sys.executable, "-c", "import torch"],
        "moseg --help": [moseg, "--help"],
        "moseg run CLIP --frames 5 --no-rrd": [moseg, "run", str(clip), "--frames", "5", "--no-rrd", "--out", str(out)],
        "moseg run CLIP --frames 5": [moseg, "run", str(clip), "--frames", "5", "--out", str(out)],
        # The first run of a checkpoint loads it with torch and keeps its NumPy copy (inference.py).
        _COLD: [moseg, "run", str(clip), "--frames", "5", "--no-rrd", "--out", str(out)],
        "breakdown probe": [sys.executable, "-c", _STARTUP_PROBE, str(clip), str(out)],
    }
    if against is not None:
        commands["OTHER run CLIP --frames 5 --no-rrd"] = [
            str(against),
            *commands["moseg run CLIP --frames 5 --no-rrd"][1:],
        ]
        commands["OTHER run CLIP --frames 5"] = [str(against), *commands["moseg run CLIP --frames 5"][1:]]
    wall: dict[str, list[float]] = {k: [] for k in commands}
    cpu: dict[str, list[float]] = {k: [] for k in commands}
    phases: dict[str, list[float]] = {name: [] for name, _ in STARTUP_PHASES}
    for _ in range(repeats):
        for name, cmd in commands.items():
            shutil.rmtree(out, ignore_errors=True)
            shutil.rmtree(work / "cold-cache", ignore_errors=True)
            cmd_env = {**env, "MOSEG_CACHE": str(work / "cold-cache")} if name == _COLD else env
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            started, seconds, stdout = _timed_process(cmd, cmd_env)
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            wall[name].append(seconds)
            cpu[name].append((after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime))
            if name == "breakdown probe":
                rec = json.loads(stdout.strip().splitlines()[-1])
                m, t = rec["marks"], rec["timings"]
                stages = {k: float(t.get(k, 0.0)) for k in ("read", "flow", "track", "embed", "cluster", "masks")}
                write_s = m["written"] - m["segmented"]
                values = {
                    "interpreter": m["started"] - started,
                    "CLI import": m["cli_imported"] - m["started"],
                    "imports + setup": m["setup"] - m["cli_imported"],
                    "model": m["model"] - m["setup"],
                    **stages,
                    "files": write_s - rec["rrd"],
                    "rrd": rec["rrd"],
                    "exit": started + seconds - m["written"],
                }
                for key, value in values.items():
                    phases[key].append(value)
    ref = statistics.median(wall['python -c "import numpy, cv2"'])
    torch_s = statistics.median(wall['python -c "import torch"'])
    lines = [
        f"Fresh processes, {repeats} interleaved rounds; CLIP = {clip}. CPU = user + system time of the process.\n",
        "| command | wall s (median) | min–max | CPU s (median) | x `import numpy, cv2` | x `import torch` |",
        "|---|---|---|---|---|---|",
    ]
    for name in commands:
        if name == "breakdown probe":
            continue
        w = statistics.median(wall[name])
        lines.append(
            f"| `{name}` | {w:.2f} | {min(wall[name]):.2f}–{max(wall[name]):.2f} | {statistics.median(cpu[name]):.2f} "
            f"| {w / ref:.1f} | {w / torch_s:.2f} |"
        )
    if against is not None:
        lines.insert(0, f"OTHER = {against}.\n")
        for rrd in ("", " --no-rrd"):
            ours, other = f"moseg run CLIP --frames 5{rrd}", f"OTHER run CLIP --frames 5{rrd}"
            w = statistics.median(a / b for a, b in zip(wall[ours], wall[other], strict=True))
            c = statistics.median(a / b for a, b in zip(cpu[ours], cpu[other], strict=True))
            lines.append(f"\n`{ours}` / `{other}` in the same round, median: wall {w:.2f}×, CPU {c:.2f}×")
    total = statistics.median(wall["breakdown probe"])
    lines += [
        "",
        f"Where the time of `moseg run CLIP --frames 5` goes (the same steps in a fresh process; medians of {repeats}; "
        f"wall {total:.2f} s, CPU {statistics.median(cpu['breakdown probe']):.2f} s):\n",
        "| step | what | ms (median) | share of the wall time |",
        "|---|---|---|---|",
    ]
    for key, what in STARTUP_PHASES:
        ms = 1000 * statistics.median(phases[key])
        lines.append(f"| {key} | {what} | {ms:.0f} | {ms / 10 / total:.0f} % |")
    return "\n".join(lines)


def kt3d_line(data_root: Path, model: Embedder) -> str:
    from mosegpipe.data.kt3dmoseg import kt3d_test_clips

    clips = kt3d_test_clips(data_root, frames=5)
    cluster_auto_k(model.embed(clips[0].traj))  # one-off costs out of the timing
    per = []
    for clip in clips:
        t0 = time.perf_counter()
        cluster_auto_k(model.embed(clip.traj))
        per.append(time.perf_counter() - t0)
    n = sum(c.num_points for c in clips)
    return (
        f"| {len(clips)} KT3DMoSeg test clips | {n} | {sum(per):.3f} | {1000 * statistics.median(per):.1f} | "
        f"{1000 * max(per):.1f} |"
    )


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--model", type=Path, default=None, help="5-frame checkpoint (default: shipped weights or untrained)"
    )
    ap.add_argument("--data-root", type=Path, default=Path(os.environ.get("MOSEG_DATA", _DEFAULT_DATA)))
    ap.add_argument("--video-frames", type=int, default=200, help="frames of the videos in whole-video mode")
    ap.add_argument("--repeats", type=int, default=3, help="warm calls per input in (a)")
    ap.add_argument(
        "--dense-methods",
        nargs="+",
        default=["motion", "watershed"],
        help="rows of (e): mask methods, motion@SCALE for the motion masks at another work scale",
    )
    ap.add_argument("--skip", nargs="*", default=[], choices=["clip", "video", "dense", "kt3d", "startup"])
    ap.add_argument("--startup-clip", type=Path, default=_SAMPLE_FRAMES, help="input of the start-up table (d)")
    ap.add_argument("--startup-repeats", type=int, default=5, help="rounds of the start-up table (d)")
    ap.add_argument("--startup-against", type=Path, default=None, help="(d): another checkout's moseg, same rounds")
    args = ap.parse_args(argv)

    set_threads(1)
    model, model_desc = load_model(args.model)
    vtest = args.data_root / "videos" / "vtest.avi"
    print("# mosegpipe speed\n")
    print(f"machine: {machine_info()}\n")
    print(f"model: {model_desc}\n")
    print(f"imports (cv2, numpy, torch, mosegpipe pipeline): {_IMPORT_S:.2f} s\n")
    with tempfile.TemporaryDirectory(prefix="moseg_speed_") as tmp:
        work = Path(tmp)
        if "clip" not in args.skip:
            from mosegpipe.synth.render import RenderConfig, render_clip, write_clip

            rendered = render_clip(
                RenderConfig(size_hw=(480, 640), frames=5, num_objects=2, seed=0, camera_motion="handheld")
            )
            clips = {"rendered": write_clip(rendered, work / "rendered", video=True) / "clip.avi"}
            if vtest.is_file():
                clips["vtest.avi"] = write_video(resized_frames(vtest, 5), work / "vtest5.avi")
            print("## (a) `moseg run` on 5 frames at 640x480 (stage times in ms)\n")
            print(clip_table(clips, model, args.repeats, work) + "\n")
        if "video" not in args.skip:
            from mosegpipe.synth.render import RenderConfig, render_clip

            n = args.video_frames
            long_clip = render_clip(
                RenderConfig(size_hw=(480, 640), frames=n, num_objects=3, seed=1, camera_motion="handheld")
            )
            runs = [
                (f"rendered {n} frames 640x480", write_video(list(long_clip.frames), work / "rendered_long.avi"), False)
            ]
            if vtest.is_file():
                video = write_video(resized_frames(vtest, n), work / "vtest_long.avi")
                runs += [
                    (f"vtest.avi {n} frames 640x480", video, False),
                    (f"vtest.avi {n} frames 640x480", video, True),
                ]
            print("## (b) whole-video mode (`moseg run --whole`, windows of 5 frames)\n")
            print(video_table(runs, model, work) + "\n")
        if "dense" not in args.skip and vtest.is_file():
            video = write_video(resized_frames(vtest, args.video_frames, (854, 480)), work / "vtest_854.avi")
            print("## (e) whole-video mode at 854x480 by dense-mask method (no recording)\n")
            print(dense_table(video, model, work, tuple(args.dense_methods)) + "\n", flush=True)
        if "startup" not in args.skip:
            print("## (d) start-up: `moseg run` on 5 frames from the shell\n")
            print(startup_tables(args.startup_clip.resolve(), work, args.startup_repeats, args.startup_against) + "\n")
        if "kt3d" not in args.skip:
            if (args.data_root / "kt3dmoseg").is_dir():
                print("## (c) embedding + automatic K on the KT3DMoSeg test clips (one thread)\n")
                print("| clips | points | total s | median ms / clip | max ms / clip |\n|---|---|---|---|---|")
                print(kt3d_line(args.data_root, model) + "\n")
            else:
                print(f"(c) skipped: {args.data_root / 'kt3dmoseg'} not found\n")


if __name__ == "__main__":
    main()
