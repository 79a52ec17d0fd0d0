"""`moseg live` for minutes on end: frames/s, dropped frames, latency and the process's memory over time.

    python benchmarks/live_memory.py --seconds 600            # 10 minutes, 640x480 at 25 frames/s

Feeds raw 640x480 BGR frames of a video (forward, then backward, looped) to `moseg live -` at a fixed
rate in real time, streams the result to a `rerun` gRPC sink that discards it (a stand-in for a
viewer), samples the resident memory of the moseg process every `--every` seconds and prints a table
of it with moseg's own summary (frames segmented and dropped, latency). Issue 22's target: memory
flat over 10 minutes at 25 frames/s, under 5 % dropped, median latency <= 0.5 s.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

_DEFAULT_VIDEO = Path(os.environ.get("MOSEG_DATA", Path(__file__).resolve().parents[1] / ".." / "shared" / "data"))
_DEFAULT_VIDEO = _DEFAULT_VIDEO / "videos" / "vtest.avi"


def frames_text(video: Path, size: tuple[int, int]) -> list[bytes]:
    """The video's frames resized, as raw BGR (what `moseg live -` reads), then the same backwards."""
    import cv2

    from mosegpipe.io.read import iter_video

    frames = [cv2.resize(rgb[..., ::-1], size, interpolation=cv2.INTER_AREA).tobytes() for _, rgb in iter_video(video)]
    if not frames:
        sys.exit(f"{video}: no frames")
    return frames + frames[::-1]


def _feed(pipe: object, frames: list[bytes], fps: float, seconds: float) -> None:
    """Writes the frames at `fps` in real time for `seconds`, then closes the pipe (the end of the stream)."""
    t0 = time.monotonic()
    i = 0
    try:
        while (now := time.monotonic() - t0) < seconds:
            if now < i / fps:
                time.sleep(i / fps - now)
            pipe.write(frames[i % len(frames)])  # type: ignore[attr-defined]
            i += 1
    except BrokenPipeError:
        pass
    finally:
        try:
            pipe.close()  # type: ignore[attr-defined]
        except BrokenPipeError:
            pass


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _rss_mib(pid: int) -> float | None:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        return None
    return None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--video", type=Path, default=_DEFAULT_VIDEO)
    ap.add_argument("--seconds", type=float, default=600.0)
    ap.add_argument("--fps", type=float, default=25.0)
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--every", type=float, default=60.0, help="seconds between memory samples in the table")
    ap.add_argument("moseg_args", nargs="*", help="more options for moseg live (after --)")
    args = ap.parse_args()
    width, height = (int(v) for v in args.size.split("x"))
    frames = frames_text(args.video, (width, height))
    rerun = shutil.which("rerun")
    if rerun is None:
        sys.exit("the `rerun` program of rerun-sdk is not on PATH")
    port = _free_port()
    sink = subprocess.Popen(  # its own process group: `rerun` is a wrapper that starts the real binary
        [rerun, "--port", str(port), "--save", os.devnull],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    time.sleep(2.0)
    live = subprocess.Popen(
        [
            "moseg",
            "live",
            "-",
            "--stdin-size",
            args.size,
            "--fps",
            str(args.fps),
            "--connect",
            f"rerun+http://127.0.0.1:{port}/proxy",
            "--drop",  # frames piped in real time: a live source, dropped when the machine falls behind
            *args.moseg_args,
        ],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=False,
    )
    feeder = threading.Thread(target=_feed, args=(live.stdin, frames, args.fps, args.seconds), daemon=True)
    feeder.start()
    samples: list[tuple[float, float]] = []
    t0 = time.monotonic()
    while live.poll() is None:
        rss = _rss_mib(live.pid)
        if rss is not None and rss > 50:  # None: gone; small: the interpreter still starting
            samples.append((time.monotonic() - t0, rss))
        time.sleep(1.0)
    summary = live.stdout.read().decode() if live.stdout is not None else ""
    os.killpg(sink.pid, signal.SIGTERM)
    sink.wait(timeout=10)
    print(f"# moseg live for {args.seconds:.0f} s, {args.size} at {args.fps:g} frames/s from {args.video.name}")
    print(summary.strip())
    print("\n| s | resident MiB |\n|---|---|")
    shown = -1e9
    for t, rss in samples:
        if t - shown >= args.every:
            print(f"| {t:.0f} | {rss:.0f} |")
            shown = t
    if samples:
        print(f"| {samples[-1][0]:.0f} (last) | {samples[-1][1]:.0f} |")
        tail = [r for t, r in samples if t >= samples[-1][0] / 2]
        print(f"\nsecond half: {min(tail):.0f}-{max(tail):.0f} MiB; peak {max(r for _, r in samples):.0f} MiB")


if __name__ == "__main__":
    main()
