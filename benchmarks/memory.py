"""Peak memory of whole-video mode against video length: it should stay flat.

    python benchmarks/memory.py [--lengths 50 200 400] [--size 1280x720] [--rrd] [--model PATH] [--max-side N]
    python benchmarks/memory.py --minutes 10 [--size 1920x1080] [--fps 30] [--video PATH] [--rrd]

Length sweep (the default): writes one synthetic video (a textured background panning back and
forth and two textured rectangles moving across it, MJPG) as long as the longest length, then
segments its first L frames in a fresh subprocess per length (mosegpipe.apps.video_outputs.write_video_outputs,
as `moseg run --whole`, with the model loaded as `moseg run` loads it: NumPy, no torch; the parent
loads it once first so that the copy exists). Each subprocess reports its peak resident set size (resource.getrusage
ru_maxrss) right after the imports and the model (the baseline) and after the run. Flat memory means
the peak does not grow with L. One thread throughout.

Long video (--minutes M): streams an M-minute synthetic video of the same kind, H.264 in an .mp4
(mosegpipe.io.read.write_video, frame by frame, so that writing it holds one frame), or takes --video;
then runs the real command, `moseg run VIDEO --whole --no-rrd` (or with the recording: --rrd), and
samples the child's /proc/PID/status (VmRSS, VmHWM) every --interval seconds. Progress is the
number of masks/NNNNNN.png files in the command's temporary output folder, one per finished frame.
The table gives the peak so far (VmHWM) when 10 %, 25 %, 50 %, 75 % of the frames are done and the
child's final ru_maxrss (os.wait4) at 100 %: flat memory means the column stops growing after the
first windows. --samples CSV keeps every sample.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any


def _maxrss_mib() -> float:
    import resource

    # Linux reports ru_maxrss in KiB.
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def synthetic_frames(frames: int, size_wh: tuple[int, int], seed: int = 0) -> Iterator[Any]:
    """(H, W, 3) uint8 frames: a textured background panning on a slow ellipse and two textured
    rectangles bouncing across it at 3 and 5 px / frame (textures: random colour blocks, about 8 px)."""
    import cv2
    import numpy as np

    rng = np.random.default_rng(seed)
    w, h = size_wh
    margin = 64

    def texture(tw: int, th: int) -> np.ndarray:
        small = rng.integers(0, 256, (th // 8 + 1, tw // 8 + 1, 3), dtype=np.uint8)
        return cv2.resize(small, (tw, th), interpolation=cv2.INTER_NEAREST)

    background = texture(w + 2 * margin, h + 2 * margin)
    objects = [texture(w // 5, h // 4), texture(w // 6, h // 5)]
    for t in range(frames):
        # The camera pans on a slow ellipse so that the background stays inside its margin.
        dx = int(margin + 0.8 * margin * np.sin(2 * np.pi * t / 150))
        dy = int(margin + 0.5 * margin * np.cos(2 * np.pi * t / 150))
        frame = background[dy : dy + h, dx : dx + w].copy()
        for i, obj in enumerate(objects):
            oh, ow = obj.shape[:2]
            # Each object bounces horizontally across the frame at its own speed (px / frame).
            span = w - ow
            x = int(abs((t * (3 + 2 * i) + i * span // 2) % (2 * span) - span))
            y = int((h - oh) * (0.25 + 0.5 * i))
            frame[y : y + oh, x : x + ow] = obj
        yield frame


def make_video(path: Path, frames: int, size_wh: tuple[int, int], seed: int = 0) -> Path:
    """A synthetic MJPG video (see synthetic_frames)."""
    import cv2

    w, h = size_wh
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (w, h))
    if not writer.isOpened():
        sys.exit(f"memory.py: cannot write {path}")
    for frame in synthetic_frames(frames, size_wh, seed):
        writer.write(frame)  # channel order does not matter for the benchmark
    writer.release()
    return path


def make_h264_video(path: Path, frames: int, size_wh: tuple[int, int], fps: float, seed: int = 0) -> Path:
    """A synthetic H.264 .mp4 (see synthetic_frames), streamed: one frame is held at a time."""
    from mosegpipe.io.read import write_video

    write_video(path, synthetic_frames(frames, size_wh, seed), fps)
    return path


def child(video: Path, frames: int, rrd: bool, model_path: Path | None, max_side: int | None = None) -> None:
    """Runs in the subprocess: segments the first `frames` frames, prints one JSON line."""
    from mosegpipe.apps.video_outputs import write_video_outputs
    from mosegpipe.embed.numpy_net import load_embedder
    from mosegpipe.pipeline import PipelineConfig
    from mosegpipe.runtime import set_threads

    set_threads(1)
    # As `moseg run` loads it: the NumPy copy that the parent made sure of (no torch in the child).
    model = load_embedder(5, model_path)
    if rrd:
        import rerun  # noqa: F401 - imported here so that the baseline includes it, as the run will

    baseline = _maxrss_mib()
    with tempfile.TemporaryDirectory(prefix="moseg_mem_") as tmp:
        t0 = time.perf_counter()
        summary = write_video_outputs(
            video, Path(tmp) / "out", PipelineConfig(frames=5, max_side=max_side), model, rrd=rrd, max_frames=frames
        )
        seconds = time.perf_counter() - t0
    tracks = [w["num_tracks"] for w in summary["windows"]]
    print(
        json.dumps(
            {
                "frames": summary["frames"],
                "baseline_mib": baseline,
                "peak_mib": _maxrss_mib(),
                "seconds": seconds,
                "mean_tracks": sum(tracks) / max(len(tracks), 1),
            }
        )
    )


def _proc_status_mib(pid: int) -> dict[str, float]:
    """VmRSS and VmHWM of a live process in MiB ({} once it has gone)."""
    try:
        text = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return {}
    values = {}
    for line in text.splitlines():
        key, _, rest = line.partition(":")
        if key in ("VmRSS", "VmHWM"):
            values[key] = int(rest.split()[0]) / 1024.0  # kB
    return values


def _count_files(folder: Path) -> int:
    try:
        with os.scandir(folder) as it:
            return sum(1 for _ in it)
    except OSError:
        return 0


CHECKPOINTS = (0.10, 0.25, 0.50, 0.75)
TABLE_HEAD = (
    "| done | frames | elapsed s | frames/s so far | RSS now (MiB) | peak RSS so far (MiB) |\n|---|---|---|---|---|---|"
)


def summary_row(label: str, frames: float, t_s: float, rss: str, peak: str) -> str:
    return f"| {label} | {frames:.0f} | {t_s:.0f} | {frames / max(t_s, 1e-9):.1f} | {rss} | {peak} |"


def sample_run(
    cmd: list[str],
    masks_dir: Path,
    total_frames: int,
    interval_s: float,
    env: dict[str, str],
    deadline_s: float | None = None,
    samples_csv: Path | None = None,
) -> tuple[list[dict[str, float]], dict[str, float], int | None, str]:
    """Runs `cmd`, sampling its memory and progress every `interval_s` until it exits (or until
    `deadline_s`, when it is stopped with SIGTERM). A table row is printed as each checkpoint
    fraction of `total_frames` is passed, so that a run cut short still reports what it reached.

    Returns:
        (samples, final, returncode or None when stopped at the deadline, stderr tail): samples hold
        t_s, frames_done, rss_mib, hwm_mib; final holds wall_s and the child's ru_maxrss in MiB.
    """
    fields = ["t_s", "frames_done", "rss_mib", "hwm_mib"]
    t0 = time.perf_counter()
    pending = list(CHECKPOINTS)
    stopped = False
    print(TABLE_HEAD, flush=True)
    with tempfile.TemporaryFile(mode="w+") as err, open(samples_csv or os.devnull, "w", newline="") as csv_fh:
        writer = csv.DictWriter(csv_fh, fieldnames=fields)
        writer.writeheader()
        child = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=err)
        samples: list[dict[str, float]] = []
        while True:
            pid, status, usage = os.wait4(child.pid, os.WNOHANG)
            if pid:
                break
            now = time.perf_counter() - t0
            mem = _proc_status_mib(child.pid)
            if mem:
                sample = {
                    "t_s": now,
                    "frames_done": float(_count_files(masks_dir)),
                    "rss_mib": mem.get("VmRSS", 0.0),
                    "hwm_mib": mem.get("VmHWM", 0.0),
                }
                samples.append(sample)
                writer.writerow({k: round(v, 2) for k, v in sample.items()})
                csv_fh.flush()
                while pending and sample["frames_done"] >= pending[0] * total_frames:
                    label = f"{100 * pending.pop(0):.0f} %"
                    rss, hwm = f"{sample['rss_mib']:.0f}", f"{sample['hwm_mib']:.0f}"
                    print(summary_row(label, sample["frames_done"], now, rss, hwm), flush=True)
            if deadline_s is not None and now > deadline_s and not stopped:
                stopped = True
                if samples:
                    last = samples[-1]
                    pct = 100 * last["frames_done"] / total_frames
                    rss, hwm = f"{last['rss_mib']:.0f}", f"{last['hwm_mib']:.0f}"
                    print(
                        summary_row(f"{pct:.0f} % (stopped at the deadline)", last["frames_done"], now, rss, hwm),
                        flush=True,
                    )
                child.terminate()
            time.sleep(interval_s)
        err.seek(0)
        tail = err.read()[-2000:]
    final = {"wall_s": time.perf_counter() - t0, "maxrss_mib": usage.ru_maxrss / 1024.0}
    return samples, final, None if stopped else os.waitstatus_to_exitcode(status), tail


def long_video(args: argparse.Namespace) -> None:
    """--minutes: a long H.264 video through the real `moseg run --whole`, memory sampled over time."""
    w, h = (int(v) for v in args.size.lower().split("x"))
    frames = int(round(args.minutes * 60 * args.fps))
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    moseg = shutil.which("moseg", path=str(Path(sys.executable).parent)) or "moseg"
    with tempfile.TemporaryDirectory(prefix="moseg_mem_long_", dir=args.work) as tmp:
        work = Path(tmp)
        if args.video is not None and args.video.is_file():
            video = args.video
            made = f"reused {video} ({video.stat().st_size / 2**20:.0f} MiB)"
        else:
            video = args.video or work / "synthetic.mp4"
            t0 = time.perf_counter()
            make_h264_video(video, frames, (w, h), args.fps)
            made = (
                f"wrote {frames} frames ({args.minutes:g} min at {args.fps:g} fps, {w}x{h}, H.264, "
                f"{video.stat().st_size / 2**20:.0f} MiB) in {time.perf_counter() - t0:.0f} s"
            )
        out = work / "out"
        cmd = [moseg, "run", str(video), "--whole", "--frames", "5", "--out", str(out), "--threads", "1"]
        cmd += [] if args.rrd else ["--no-rrd"]
        cmd += [] if args.max_side is None else ["--max-side", str(args.max_side)]
        print(f"# whole-video peak memory over a long video: {w}x{h}, {frames} frames\n")
        print(
            f"machine: {platform.processor() or platform.machine()}, nproc {len(os.sched_getaffinity(0))}, "
            f"load average {' / '.join(f'{v:.2f}' for v in os.getloadavg())}\n"
        )
        print(f"video: {made}\n")
        print(f"command: `{' '.join(['moseg', *cmd[1:]])}`, sampled every {args.interval:g} s\n", flush=True)
        masks_dir = out.with_name(f".{out.name}.partial") / "masks"
        deadline = None if args.deadline_min is None else 60 * args.deadline_min
        samples, final, code, tail = sample_run(cmd, masks_dir, frames, args.interval, env, deadline, args.samples)
        summary_path = out / "summary.json"
        done = json.loads(summary_path.read_text())["frames"] if summary_path.is_file() else None
    if code == 0:
        last_rss = f"{samples[-1]['rss_mib']:.0f} (last sample)" if samples else "n/a"
        print(
            summary_row("100 % (exit)", done or 0, final["wall_s"], last_rss, f"{final['maxrss_mib']:.0f} (ru_maxrss)")
        )
    elif code is not None:
        print(f"\nthe command failed (exit {code}) after {final['wall_s']:.0f} s:\n{tail}")
    if samples:
        first = next((s for s in samples if s["frames_done"] >= CHECKPOINTS[0] * frames), samples[0])
        last = samples[-1]
        peak = final["maxrss_mib"] if code == 0 else last["hwm_mib"]
        until = "the end" if code == 0 else f"{last['frames_done']:.0f} frames"
        print(
            f"\npeak RSS {peak:.0f} MiB; growth of the peak from {first['frames_done']:.0f} frames to {until}: "
            f"{peak - first['hwm_mib']:+.0f} MiB; highest RSS sampled {max(s['rss_mib'] for s in samples):.0f} MiB"
        )


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--lengths", type=int, nargs="+", default=[50, 200, 400], help="video lengths in frames")
    ap.add_argument("--size", default="1280x720", help="WxH of the synthetic video")
    ap.add_argument("--rrd", action="store_true", help="also write the Rerun recording")
    ap.add_argument("--model", type=Path, default=None, help="5-frame checkpoint (default: the shipped weights)")
    ap.add_argument("--minutes", type=float, default=None, help="long-video mode: this many minutes of video")
    ap.add_argument("--fps", type=float, default=30.0, help="long-video mode: frames per second of the video")
    ap.add_argument("--video", type=Path, default=None, help="long-video mode: use (or keep) this .mp4")
    ap.add_argument("--interval", type=float, default=1.0, help="long-video mode: seconds between samples")
    ap.add_argument("--samples", type=Path, default=None, help="long-video mode: write every sample to this CSV")
    ap.add_argument(
        "--deadline-min", type=float, default=None, help="long-video mode: stop the run after this many minutes"
    )
    ap.add_argument("--work", type=Path, default=None, help="long-video mode: folder for the temporary files")
    ap.add_argument("--max-side", type=int, default=None, help="segment frames shrunk to this longer side (--max-side)")
    ap.add_argument("--child", type=Path, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--frames", type=int, default=0, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child is not None:
        child(args.child, args.frames, args.rrd, args.model, args.max_side)
        return
    if args.minutes is not None:
        if args.size == "1280x720" and "--size" not in (argv if argv is not None else sys.argv[1:]):
            args.size = "1920x1080"
        long_video(args)
        return

    w, h = (int(v) for v in args.size.lower().split("x"))
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    print(f"# whole-video peak memory, {w}x{h} MJPG, windows of 5 frames, recording {'on' if args.rrd else 'off'}\n")
    from mosegpipe.embed.numpy_net import load_embedder

    load_embedder(5, args.model)  # makes the NumPy copy that the children load, as a second `moseg run` does
    print(f"model: {args.model or 'the shipped 5-frame weights'}, NumPy inference (no torch in the children)\n")
    rows = []
    with tempfile.TemporaryDirectory(prefix="moseg_mem_video_") as tmp:
        video = Path(tmp) / "synthetic.avi"
        t0 = time.perf_counter()
        make_video(video, max(args.lengths), (w, h))
        print(
            f"wrote {max(args.lengths)} frames ({video.stat().st_size / 2**20:.0f} MiB) in {time.perf_counter() - t0:.1f} s\n"
        )
        for n in args.lengths:
            cmd = [sys.executable, __file__, "--child", str(video), "--frames", str(n)]
            cmd += ["--rrd"] if args.rrd else []
            cmd += ["--model", str(args.model)] if args.model else []
            cmd += [] if args.max_side is None else ["--max-side", str(args.max_side)]
            out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
            if out.returncode != 0:
                sys.exit(f"memory.py: the run on {n} frames failed:\n{out.stderr}")
            rows.append(json.loads(out.stdout.strip().splitlines()[-1]))
    print(
        "| frames | mean tracks / window | peak RSS after imports + model (MiB) | peak RSS after the run (MiB) | growth (MiB) | wall s | frames/s |"
    )
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['frames']} | {r['mean_tracks']:.0f} | {r['baseline_mib']:.0f} | {r['peak_mib']:.0f} | "
            f"{r['peak_mib'] - r['baseline_mib']:.0f} | {r['seconds']:.1f} | {r['frames'] / r['seconds']:.1f} |"
        )
    if len(rows) > 1:
        first, last = rows[0], rows[-1]
        slope = (last["peak_mib"] - first["peak_mib"]) / max(last["frames"] - first["frames"], 1)
        print(
            f"\npeak growth from {first['frames']} to {last['frames']} frames: {last['peak_mib'] - first['peak_mib']:+.1f} MiB "
            f"({1024 * slope:+.1f} KiB per frame; one {w}x{h} RGB frame is {w * h * 3 / 2**10:.0f} KiB)"
        )


if __name__ == "__main__":
    main()
