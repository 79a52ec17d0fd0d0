"""Live mode: the bounded reader, a live source through the whole-video pipeline, what a viewer receives,
and how a run ends (stall, end inside a frame, Ctrl-C)."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt
import pytest

from mosegpipe.apps.live.run import Capture, FrameBuffer, LiveFrames, RawCapture, SourceReader, parse_source
from mosegpipe.errors import InputError

from helpers import moseg, one_error_line

W, H, T = 160, 120, 40


def frames_text(n: int = T) -> list[npt.NDArray[np.uint8]]:
    """RGB frames: a textured square moving over a textured, static background."""
    rng = np.random.default_rng(0)
    background = cv2.GaussianBlur(rng.integers(0, 256, (H, W, 3), dtype=np.uint8), (3, 3), 0)
    square = cv2.GaussianBlur(rng.integers(0, 256, (40, 40, 3), dtype=np.uint8), (3, 3), 0)
    frames = []
    for t in range(n):
        frame = background.copy()
        x, y = 20 + 2 * t, 40 + t % 10
        frame[y : y + 40, x : x + 40] = square
        frames.append(frame)
    return frames


@pytest.fixture(scope="module")
def video(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """40 frames of 160x120 at 25 frames/s (1.6 s when played in real time)."""
    path = tmp_path_factory.mktemp("live") / "square.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (W, H))
    for frame in frames_text():
        writer.write(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    writer.release()
    return path


def _raw(frames: list[npt.NDArray[np.uint8]]) -> bytes:
    """The frames as ffmpeg's `-f rawvideo -pix_fmt bgr24` writes them."""
    return b"".join(cv2.cvtColor(f, cv2.COLOR_RGB2BGR).tobytes() for f in frames)


# ---------------------------------------------------------------------------------------------
# The bounded hand-over
# ---------------------------------------------------------------------------------------------


def test_a_full_buffer_drops_its_oldest_frames_and_counts_them() -> None:
    buffer = FrameBuffer(capacity=3, drop=True)
    image = np.zeros((2, 2, 3), np.uint8)
    for i in range(10):
        assert buffer.put((i, image, 0.0))
    assert len(buffer) == 3 and buffer.dropped == 7
    buffer.close()
    got = [buffer.get(0.0) for _ in range(4)]
    assert [g[0] for g in got[:3] if g] == [7, 8, 9]  # the newest frames are the ones kept
    assert got[3] is False  # closed and empty


class _CountingCapture(Capture):
    """`n` frames as fast as asked for; records how many frames the buffer held at each read."""

    def __init__(self, n: int, buffer_of: list[FrameBuffer]) -> None:
        self.left = n
        self.held: list[int] = []
        self._buffer_of = buffer_of

    def read(self) -> npt.NDArray[np.uint8] | None:
        self.held.append(len(self._buffer_of[0]))
        if self.left == 0:
            return None
        self.left -= 1
        return np.full((4, 4, 3), self.left % 256, np.uint8)


def test_a_slow_consumer_makes_frames_drop_not_the_queue_grow() -> None:
    # The consumer takes nothing until the reader has read all 500 frames: the slowest consumer there is.
    buffer = FrameBuffer(capacity=4, drop=True)
    box = [buffer]
    capture = _CountingCapture(500, box)
    stop = threading.Event()
    reader = SourceReader(capture, buffer, stop, name="fake")
    reader.start()
    reader.join(timeout=30)
    assert not reader.is_alive() and reader.end == "ended"
    assert max(capture.held) <= 4  # never more than the buffer's frames held
    assert reader.frames_read == 500 and buffer.dropped == 496
    got = [index for index, _ in LiveFrames(reader, stall_timeout_s=5.0)]
    assert got == [496, 497, 498, 499]  # the newest frames, with their source indices


def test_a_file_read_as_fast_as_possible_loses_no_frame() -> None:
    buffer = FrameBuffer(capacity=2, drop=False)
    capture = _CountingCapture(50, [buffer])
    reader = SourceReader(capture, buffer, threading.Event(), name="fake")
    reader.start()
    got = [index for index, _ in LiveFrames(reader, stall_timeout_s=5.0)]
    assert got == list(range(50)) and buffer.dropped == 0 and max(capture.held) <= 2


def test_raw_frames_on_stdin_are_bgr24_and_a_partial_last_frame_is_dropped() -> None:
    import io

    frames = frames_text(3)
    capture = RawCapture(io.BytesIO(_raw(frames) + b"\x00" * 100), (W, H))
    got = [capture.read() for _ in range(4)]
    assert all(np.array_equal(g, f) for g, f in zip(got, frames)) and got[3] is None
    assert capture.partial_bytes == 100


def test_sources_are_told_apart(tmp_path: Path, video: Path) -> None:
    assert parse_source("0").kind == "camera"
    assert parse_source("rtsp://example.org/cam").kind == "url"
    assert parse_source(str(video), realtime=True).drops
    assert not parse_source(str(video)).drops  # read as fast as possible: waited for, not dropped
    assert parse_source("-", stdin_size=(W, H)).kind == "stdin"
    assert not parse_source("-", stdin_size=(W, H)).drops  # a pipe's writer waits: nothing lost unless asked
    assert parse_source("-", stdin_size=(W, H), drop=True).drops and parse_source("0").drops
    with pytest.raises(InputError, match="--stdin-size"):
        parse_source("-")
    with pytest.raises(InputError, match="--realtime"):
        parse_source("0", realtime=True)
    with pytest.raises(InputError, match="no such file"):
        parse_source(str(tmp_path / "missing.avi"))


def test_segment_video_takes_the_frames_themselves(video: Path) -> None:
    """A live source is an iterator of frames in place of a path: the same windows and labels."""
    from mosegpipe.io.read import iter_video
    from mosegpipe.pipeline import segment_video

    from_file = list(segment_video(video))
    given = list(segment_video("a stream", frames=iter_video(video)))
    assert [(w.start, w.k) for w in given] == [(w.start, w.k) for w in from_file] and len(given) >= 5
    assert all(np.array_equal(a.labels, b.labels) for a, b in zip(given, from_file))
    assert [f.index for w in given for f in w.frames] == list(range(T))


# ---------------------------------------------------------------------------------------------
# The command
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["missing.avi", "--out", "o"], "no such file"),
        (["SQUARE"], "nothing to show or write"),
        (["SQUARE", "--connect", "http://127.0.0.1:1/"], "rerun+http://HOST:PORT/proxy"),
        (["SQUARE", "--connect", "rerun+http://127.0.0.1:1/proxy"], "no Rerun viewer listens there"),
    ],
)
def test_bad_live_input_is_one_error_line(
    tmp_path: Path, video: Path, monkeypatch: pytest.MonkeyPatch, args: list[str], expected: str
) -> None:
    monkeypatch.chdir(tmp_path)
    code, _, stderr = moseg("live", *[str(video) if a == "SQUARE" else a for a in args])
    assert code == 1 and expected in one_error_line(stderr)
    assert not (tmp_path / "o").exists()


def test_live_help_at_80_columns_reads_well() -> None:
    from typer.testing import CliRunner

    from mosegpipe.cli.main import app

    result = CliRunner(env={"COLUMNS": "80"}).invoke(app, ["live", "--help"])
    assert result.exit_code == 0
    usage = next(line for line in result.stdout.splitlines() if "Usage:" in line)
    assert usage.split() == ["Usage:", "moseg", "live", "[OPTIONS]", "SOURCE"] and "<bool>" not in result.stdout


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def _rerun_exe() -> str:
    from mosegpipe.cli.view import find_viewer

    exe = find_viewer()
    assert exe, "the rerun program of rerun-sdk is not installed"
    return exe


def _sink_rows(path: Path) -> dict[str, list[int]]:
    """Entity path -> the "frame" index of each of its rows, in the order they arrived."""
    import warnings

    from rerun.chunk import RrdReader

    rows: dict[str, list[int]] = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a saved stream has no footer: read as a stream
        chunks = list(RrdReader(path).stream().to_chunks())
    for chunk in chunks:
        batch = chunk.to_record_batch()
        if "frame" in batch.schema.names:
            rows.setdefault(str(chunk.entity_path), []).extend(batch.column("frame").to_pylist())
    return rows


def test_a_viewer_gets_frames_masks_and_k_in_order(tmp_path: Path, video: Path) -> None:
    """A real gRPC sink (the `rerun` program saving what it receives) as a viewer: `moseg live --connect`."""
    port = _free_port()
    saved = tmp_path / "received.rrd"
    sink = subprocess.Popen(
        [_rerun_exe(), "--port", str(port), "--save", str(saved)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    try:
        deadline = time.monotonic() + 30
        while True:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
                break
            except OSError:
                assert time.monotonic() < deadline and sink.poll() is None, "the sink did not start"
                time.sleep(0.05)
        out = tmp_path / "out"
        url = f"rerun+http://127.0.0.1:{port}/proxy"
        code, stdout, stderr = moseg("live", video, "--realtime", "--connect", url, "--out", out, "--no-rrd")
        assert code == 0, stderr
        # the sink may still be writing what it received last (under load): stop it once its file holds still
        size, still_since, deadline = -1, time.monotonic(), time.monotonic() + 15
        while time.monotonic() < deadline and time.monotonic() - still_since < 1.0:
            now = saved.stat().st_size if saved.exists() else -1
            if now != size:
                size, still_since = now, time.monotonic()
            time.sleep(0.1)
    finally:
        sink.terminate()
        sink.wait(timeout=30)
    summary = json.loads((out / "summary.json").read_text())
    written = sorted(int(p.stem) for p in (out / "masks").glob("*.png"))
    rows = _sink_rows(saved)
    # Every frame written reached the viewer once, in order, with its mask, points and tracks.
    assert rows["/video/frame"] == written and rows["/video/mask"] == written and rows["/video/points"] == written
    assert len(written) >= 2 * 5 and written[-1] == T - 1 and "dropped" in stdout
    # One K per window, at its first frame, in order.
    assert rows["/windows/k"] == [w["start"] for w in summary["windows"]]
    assert summary["num_windows"] >= 2 and summary["frames"] == len(written)
    # live's default: the motion masks with the fastest preset that keeps them
    assert (
        summary["config"]["mask"]["method"] == "motion" and summary["config"]["mask"]["motion"]["flow"]["scale"] == 0.5
    )


def _live_process(tmp_path: Path, *args: str) -> subprocess.Popen[bytes]:
    """`moseg live - --stdin-size 160x120 ...` as its own process, frames to be written to its stdin."""
    code = "import sys; from mosegpipe.cli.main import app; sys.argv[0] = 'moseg'; app()"
    return subprocess.Popen(
        [sys.executable, "-c", code, "live", "-", "--stdin-size", f"{W}x{H}", "--no-drop", "--out", "out", *args],
        cwd=tmp_path,  # outside the repository: the installed package, not the source tree
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env={**os.environ, "COLUMNS": "200"},
    )


def _complete_folder(out: Path, frames: int | None = None) -> int:
    """Checks the output folder holds every frame segmented (`frames`, when known); returns how many."""
    summary = json.loads((out / "summary.json").read_text())
    frames = summary["frames"] if frames is None else frames
    assert summary["frames"] == frames and summary["kind"] == "video"
    assert sorted(int(p.stem) for p in (out / "masks").glob("*.png")) == list(range(frames))
    assert (out / "overlay.mp4").stat().st_size > 0 and (out / "labels.npz").is_file()
    assert (out / "recording.rrd").is_file() and not list(out.parent.glob(".*partial"))
    return int(frames)


def test_a_stalled_source_gives_one_line_and_a_complete_output_folder(tmp_path: Path) -> None:
    # K forced: the one line asked for is the stall's, not automatic K's note on this tiny scene
    proc = _live_process(tmp_path, "--stall-timeout", "1", "--k", "2")
    assert proc.stdin is not None
    proc.stdin.write(_raw(frames_text(20)))  # then nothing more, the pipe left open: a stall
    proc.stdin.flush()
    try:
        proc.wait(timeout=120)  # stdin still open (communicate() would close it: an end, not a stall)
        assert proc.stdout is not None and proc.stderr is not None
        stdout, stderr = proc.stdout.read(), proc.stderr.read()
        assert b"20 frames segmented of 20 read" in stdout
    finally:
        proc.kill()
        proc.stdin.close()
    assert proc.returncode == 0, stderr
    lines = stderr.decode().splitlines()
    assert len(lines) == 1 and lines[0].startswith("moseg: warning: -: no frame for 1 s"), lines
    assert "stalled" in lines[0] and "after 20 frames" in lines[0]
    _complete_folder(tmp_path / "out", 20)


def test_a_stream_ending_inside_a_frame_gives_one_line_and_a_complete_output_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    data = _raw(frames_text(15)) + b"\x07" * 1000
    from typer.testing import CliRunner

    from mosegpipe.cli.main import app

    result = CliRunner(env={"COLUMNS": "200"}).invoke(
        app, ["live", "-", "--stdin-size", f"{W}x{H}", "--no-drop", "--out", "out", "--k", "2"], input=data
    )  # K forced, as above
    assert result.exit_code == 0, result.stderr
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and "ended inside a frame (1000 bytes" in lines[0], lines
    _complete_folder(tmp_path / "out", 15)


@pytest.mark.skipif(sys.platform == "win32", reason="signals to a process")
def test_ctrl_c_ends_the_run_with_its_outputs_complete(tmp_path: Path) -> None:
    """(SIGTERM and SIGHUP take the same path, with cli/app.py's lines and exit codes.)"""
    signum, code, line = signal.SIGINT, 130, "moseg: error: interrupted"
    proc = _live_process(tmp_path, "--stall-timeout", "60")
    assert proc.stdin is not None
    proc.stdin.write(_raw(frames_text(12)))
    proc.stdin.flush()
    deadline = time.monotonic() + 120
    while not list((tmp_path / ".out.partial" / "masks").glob("*.png")):  # segmenting: the frames arrived
        assert time.monotonic() < deadline and proc.poll() is None, proc.stderr.read() if proc.stderr else ""
        time.sleep(0.05)
    proc.send_signal(signum)
    try:
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == code, stderr
    assert stderr.decode().splitlines() == [line]
    # The window in hand was finished: at least the first window's frames, all of them written.
    segmented = _complete_folder(tmp_path / "out")
    assert 5 <= segmented <= 12 and f"{segmented} frames segmented".encode() in stdout
