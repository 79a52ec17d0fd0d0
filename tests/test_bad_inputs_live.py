"""The bad-input matrix of issue 40: live, batch discovery and decoder noise.

Each case failed before its fix: a hang (live waiting for a first frame that never comes, a batch
walking a symbolic link loop), an abort after the right error line, a traceback, counts that were
wrong or unsaid, Rerun's or OpenCV's own lines on stderr, or a message that named the wrong thing.
"""

from __future__ import annotations

import errno
import http.server
import json
import logging
import os
import signal
import struct
import subprocess
import sys
import tempfile
import threading
import time
import zlib
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt
import pytest

from mosegpipe.errors import InputError

from helpers import moseg, one_error_line, write_frames

W, H = 160, 120


def frames_text(n: int, size_wh: tuple[int, int] = (W, H)) -> list[npt.NDArray[np.uint8]]:
    """RGB frames: a textured square moving over a textured, static background."""
    w, h = size_wh
    rng = np.random.default_rng(0)
    background = cv2.GaussianBlur(rng.integers(0, 256, (h, w, 3), dtype=np.uint8), (3, 3), 0)
    square = cv2.GaussianBlur(rng.integers(0, 256, (40, 40, 3), dtype=np.uint8), (3, 3), 0)
    frames = []
    for t in range(n):
        frame = background.copy()
        x, y = 20 + t % 60, 40 + t % 10
        frame[y : y + 40, x : x + 40] = square
        frames.append(frame)
    return frames


def _raw(frames: list[npt.NDArray[np.uint8]]) -> bytes:
    """The frames as ffmpeg's `-f rawvideo -pix_fmt bgr24` writes them."""
    return b"".join(cv2.cvtColor(f, cv2.COLOR_RGB2BGR).tobytes() for f in frames)


@pytest.fixture(scope="module")
def video(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("live40") / "square.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (W, H))
    for frame in frames_text(20):
        writer.write(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    writer.release()
    return path


def _live_stdin(tmp: Path, data: bytes, *args: str) -> tuple[int, str, str]:
    """`moseg live - --stdin-size 160x120 --no-rrd --out OUT ARGS` in-process, `data` on stdin."""
    from typer.testing import CliRunner

    from mosegpipe.cli.main import app

    result = CliRunner(env={"COLUMNS": "200"}).invoke(
        app, ["live", "-", "--stdin-size", f"{W}x{H}", "--no-rrd", "--out", str(tmp / "out"), *args], input=data
    )
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        raise result.exception
    return result.exit_code, result.stdout, result.stderr


def _script(*args: str, **popen: object) -> subprocess.Popen[str]:
    """`moseg ARGS` as a process of its own, outside the checkout (the installed package)."""
    code = "import sys; from mosegpipe.cli.main import app; sys.argv[0] = 'moseg'; app()"
    return subprocess.Popen(
        [sys.executable, "-c", code, *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "COLUMNS": "200", "OMP_NUM_THREADS": "1"},
        **popen,  # type: ignore[call-overload]
    )


# ---------------------------------------------------------------------------------------------
# 2. Waiting for the first frame: a signal or the stall timeout ends it
# ---------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_no_first_frame_ends_at_the_stall_timeout(tmp_path: Path) -> None:
    """A pipe held open with no data (a FIFO whose writer sleeps): one line after --stall-timeout."""
    read_end, write_end = os.pipe()
    try:
        proc = _script(
            "live", "-", "--stdin-size", f"{W}x{H}", "--stall-timeout", "1", "--out", "o", stdin=read_end, cwd=tmp_path
        )
        started = time.monotonic()
        try:
            _, stderr = proc.communicate(timeout=60)
        finally:
            proc.kill()
    finally:
        os.close(read_end)
        os.close(write_end)
    assert proc.returncode == 1 and time.monotonic() - started < 30
    assert "-: no frame came in 1 s (--stall-timeout)" in one_error_line(stderr)
    assert sorted(p.name for p in tmp_path.iterdir()) == []


@pytest.mark.slow
@pytest.mark.skipif(sys.platform == "win32", reason="signals to a process")
def test_a_signal_ends_the_wait_for_the_first_frame(tmp_path: Path) -> None:
    read_end, write_end = os.pipe()
    try:
        proc = _script(
            *("live", "-", "--stdin-size", f"{W}x{H}", "--stall-timeout", "120", "--out", "o", "-v"),
            stdin=read_end,
            cwd=tmp_path,
        )
        assert proc.stderr is not None
        lines: list[str] = []
        reader = threading.Thread(target=lambda: lines.extend(proc.stderr or []), daemon=True)
        reader.start()
        deadline = time.monotonic() + 60
        while not any("waiting for the first frame" in line for line in lines):  # -v: the library says so
            assert time.monotonic() < deadline and proc.poll() is None, lines
            time.sleep(0.05)
        proc.send_signal(signal.SIGTERM)
        sent = time.monotonic()
        try:
            proc.wait(timeout=60)
        finally:
            proc.kill()
        reader.join(10)
    finally:
        os.close(read_end)
        os.close(write_end)
    assert proc.returncode == 143 and time.monotonic() - sent < 10, lines
    assert lines[-1].rstrip("\n") == "moseg: error: terminated (SIGTERM)"
    assert sorted(p.name for p in tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------------------------
# 3. An output folder that cannot be written: the reader thread is stopped before the process ends
# ---------------------------------------------------------------------------------------------


def test_a_failed_run_leaves_no_reader_thread_behind(
    tmp_path: Path, video: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A reader still inside OpenCV when Python exits aborted the process (rc 134) after the right line."""
    from mosegpipe.apps import outputs
    from mosegpipe.apps.live.run import parse_source, run_live
    from mosegpipe.embed.numpy_net import load_embedder
    from mosegpipe.pipeline import PipelineConfig

    def read_only(self: object) -> None:
        raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(tmp_path / "o"))

    monkeypatch.setattr(outputs._OutputDir, "__enter__", read_only)
    with pytest.raises(OSError, match="Read-only file system"):
        run_live(parse_source(str(video)), PipelineConfig(frames=5), load_embedder(5), out_dir=tmp_path / "o")
    assert [t for t in threading.enumerate() if t.name == "moseg-source"] == []


@pytest.mark.slow
def test_a_read_only_output_folder_is_one_line_and_no_abort(tmp_path: Path, video: Path) -> None:
    code = f"""
import errno, os, sys
from mosegpipe.apps import outputs
def read_only(self):
    raise OSError(errno.EROFS, os.strerror(errno.EROFS), {str(tmp_path / "o")!r})
outputs._OutputDir.__enter__ = read_only
from mosegpipe.cli.main import app
sys.argv[0] = "moseg"
app()
"""
    proc = subprocess.run(
        [sys.executable, "-c", code, "live", str(video), "--out", str(tmp_path / "o"), "--no-rrd"],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=tempfile.gettempdir(),
        env={**os.environ, "OMP_NUM_THREADS": "1"},
    )
    assert proc.returncode == 1, proc.stderr
    assert one_error_line(proc.stderr).endswith("o: Read-only file system")


# ---------------------------------------------------------------------------------------------
# 4. Batch discovery: symbolic link loops and links that lead nowhere
# ---------------------------------------------------------------------------------------------


def _find_clips_within(root: Path, seconds: float = 30.0) -> list[Path]:
    from mosegpipe.apps.batch.run import find_clips

    found: list[list[Path]] = []
    walker = threading.Thread(target=lambda: found.append(find_clips(root)), daemon=True)
    walker.start()
    walker.join(seconds)
    assert found, "discovery did not finish: it followed a symbolic link loop"
    return found[0]


@pytest.mark.skipif(sys.platform == "win32", reason="symbolic links")
def test_batch_discovery_searches_each_folder_once(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    root = tmp_path / "bt"
    write_frames(root / "sub", np.zeros((2, 8, 8, 3), np.uint8))
    (root / "sub" / "loop").symlink_to(".")
    (root / "sub" / "loop2").symlink_to("../sub")
    (root / "dangling.avi").symlink_to("nowhere.avi")
    (root / "a").symlink_to("b")  # a loop of two links: neither leads anywhere
    (root / "b").symlink_to("a")
    with caplog.at_level(logging.WARNING, logger="mosegpipe.apps.batch.run"):
        assert _find_clips_within(root) == [root / "sub"]
    said = caplog.text
    assert "dangling.avi: a broken symbolic link (to nowhere.avi); skipped" in said
    assert "loop: the same folder as" in said and "loop2: the same folder as" in said


@pytest.mark.skipif(sys.platform == "win32", reason="symbolic links")
def test_a_linked_folder_outside_the_root_is_still_searched(tmp_path: Path) -> None:
    write_frames(tmp_path / "elsewhere", np.zeros((2, 8, 8, 3), np.uint8))
    (tmp_path / "bt").mkdir()
    (tmp_path / "bt" / "linked").symlink_to(tmp_path / "elsewhere")
    assert _find_clips_within(tmp_path / "bt") == [tmp_path / "bt" / "linked"]


# ---------------------------------------------------------------------------------------------
# 5 and 10. Live's options: one line, not a traceback; usage errors exit with 2
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("args", "code", "expected"),
    [
        (["2147483648", "--out", "o"], 1, "camera index 2147483648: too large"),
        (
            ["-", "--stdin-size", "2147483647x2147483647", "--out", "o"],
            2,
            "--stdin-size 2147483647x2147483647: too large",
        ),
        (["-", "--stdin-size", "99999x99999", "--out", "o"], 2, "--stdin-size 99999x99999: too large"),
        (["-", "--stdin-size", "16384x16384", "--out", "o"], 2, "64 Mi pixels a frame"),
        (["-", "--stdin-size", "160by120", "--out", "o"], 2, "--stdin-size 160by120: expected WIDTHxHEIGHT"),
        (["-", "--stdin-size", "0x120", "--out", "o"], 2, "at least 1 pixel"),
        (["-", "--out", "o"], 2, "SOURCE '-' (raw frames on stdin) needs --stdin-size"),
        (["SQUARE", "--stdin-size", "160x120", "--out", "o"], 2, "--stdin-size only applies to SOURCE '-'"),
        (["SQUARE", "--connect", "rerun+http://[::1/proxy"], 1, "expected rerun+http://HOST:PORT/proxy"),
        (["FOLDER", "--out", "o"], 1, "is a folder; SOURCE is a camera index, a URL, a video file or '-'"),
    ],
)
def test_bad_live_options_are_one_line(
    tmp_path: Path, video: Path, monkeypatch: pytest.MonkeyPatch, args: list[str], code: int, expected: str
) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "frames").mkdir()
    named = {"SQUARE": str(video), "FOLDER": "frames"}
    got, out, err = moseg("live", *[named.get(a, a) for a in args])
    assert got == code and expected in one_error_line(err) and out == ""
    assert not (tmp_path / "o").exists()


def test_a_huge_stdin_size_is_refused_before_a_frame_is_allocated() -> None:
    from mosegpipe.apps.live.run import parse_source

    with pytest.raises(InputError, match="too large"):
        parse_source("-", stdin_size=(99_999, 99_999))  # 30 GB a frame
    with pytest.raises(InputError, match="camera index"):
        parse_source(str(2**31))


# ---------------------------------------------------------------------------------------------
# 7. Live's counts
# ---------------------------------------------------------------------------------------------


def test_a_pipe_loses_no_frame_and_the_counts_are_in_the_summary(tmp_path: Path) -> None:
    """40 frames piped at once: all read, none dropped (a pipe's writer waits), all shown."""
    code, stdout, stderr = _live_stdin(tmp_path, _raw(frames_text(40)))
    assert code == 0, stderr
    assert "40 frames segmented of 40 read" in stdout and "0 dropped" in stdout
    live = json.loads((tmp_path / "out" / "summary.json").read_text())["live"]
    assert live["frames_read"] == 40 and live["frames_dropped"] == 0 and live["frames_shown"] == 40
    assert live["source_kind"] == "stdin" and live["end"] == "ended"
    assert 0 < live["latency_median_s"] <= live["latency_p95_s"]


def test_replay_of_a_stdin_live_run_says_stdin_cannot_be_replayed(tmp_path: Path) -> None:
    out = tmp_path / "out"
    out.mkdir()
    (out / "summary.json").write_text(
        json.dumps(
            {
                "schema": "mosegpipe.summary/2",
                "kind": "video",
                "source": "-",
                "source_identity": None,
                "model": {"model_frames": 5},
                "live": {"source_kind": "stdin"},
            }
        )
    )
    code, _, err = moseg("replay", out / "summary.json", "--out", tmp_path / "again")
    assert code == 1 and "a live run of frames piped on stdin (-) cannot be replayed" in one_error_line(err)


def test_frames_read_faster_than_real_time_are_not_dropped_before_the_pipeline_started(tmp_path: Path) -> None:
    """--drop with 200 frames piped at once: the first window is whole (it was 4 frames and an error),
    then most frames are dropped, which a warning says."""
    code, stdout, stderr = _live_stdin(tmp_path, _raw(frames_text(200)), "--drop")
    assert code == 0, stderr
    live = json.loads((tmp_path / "out" / "summary.json").read_text())["live"]
    assert live["frames_read"] == 200 and live["frames_shown"] >= 5
    assert live["frames_shown"] + live["frames_dropped"] == 200
    if live["dropped_share"] > 0.5:  # the usual case; a fast machine may keep up with part of it
        assert f"{live['frames_dropped']} of 200 frames dropped" in stderr and stderr.startswith("moseg: warning:")


def test_frames_of_another_size_than_declared_are_named(tmp_path: Path) -> None:
    """200x150 frames declared as 160x120 (25 declared frames = 16 real ones, no partial frame left)."""
    code, _, stderr = _live_stdin(tmp_path, _raw(frames_text(16, (200, 150))))
    assert "the frames do not look 160x120" in stderr and "(frames 200 px wide?); is --stdin-size right?" in stderr
    # a run that ends warns; a failure (too few tracks on the sheared frames) carries the same words in its error line
    said = "moseg: warning: -: the frames do not look" if code == 0 else "moseg: error: -: "
    assert code in (0, 1) and any(
        line.startswith(said) and "do not look 160x120" in line for line in stderr.splitlines()
    )


def test_the_size_check_passes_frames_of_the_declared_size() -> None:
    from mosegpipe.apps.live.run import stdin_size_suspect
    from mosegpipe.io.read import read_image

    photo = read_image(Path(__file__).resolve().parents[1] / "samples" / "basketball1.png")
    h, w = photo.shape[:2]
    assert stdin_size_suspect(photo) == "" and stdin_size_suspect(frames_text(1)[0]) == ""
    raw = photo.tobytes()
    narrower = np.frombuffer(raw[: (w - 24) * h * 3], np.uint8).reshape(h, w - 24, 3)
    assert f"(frames {w} px wide?)" in stdin_size_suspect(narrower)
    half = np.frombuffer(raw, np.uint8).reshape(2 * h, w // 2, 3)  # read as half as wide
    assert "every other row lines up" in stdin_size_suspect(half)


# ---------------------------------------------------------------------------------------------
# 8. --connect to something that is not a Rerun viewer
# ---------------------------------------------------------------------------------------------


@pytest.fixture
def web_server() -> Iterator[int]:
    """A plain HTTP server (what `python -m http.server` is) on a free port of 127.0.0.1."""

    class Quiet(http.server.SimpleHTTPRequestHandler):
        def log_message(self, *args: object) -> None:
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Quiet)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield int(server.server_address[1])
    finally:
        server.shutdown()
        server.server_close()


def test_connect_to_a_web_server_is_one_line(tmp_path: Path, video: Path, web_server: int) -> None:
    url = f"rerun+http://127.0.0.1:{web_server}/proxy"
    code, _, err = moseg("live", video, "--connect", url, "--out", tmp_path / "o")
    assert code == 1 and f"--connect {url}: something listens there, but not a Rerun viewer" in one_error_line(err)
    assert not (tmp_path / "o").exists()


# ---------------------------------------------------------------------------------------------
# 9. Decoder noise on failing runs: OpenCV's, FFmpeg's and libpng's own lines kept off stderr
# ---------------------------------------------------------------------------------------------


def _png_claiming(path: Path, width: int, height: int) -> Path:
    """A PNG whose header claims width x height (CRC right) over the data of a small image: libpng's
    "Not enough image data", as from a huge image cut short."""
    ok, encoded = cv2.imencode(".png", np.zeros((16, 16, 3), np.uint8))
    assert ok
    data = bytearray(encoded.tobytes())
    data[16:24] = struct.pack(">II", width, height)
    data[29:33] = struct.pack(">I", zlib.crc32(bytes(data[12:29])) & 0xFFFFFFFF)
    path.write_bytes(bytes(data))
    return path


@pytest.mark.slow
def test_failing_runs_print_only_their_error_lines(tmp_path: Path, video: Path) -> None:
    """In one process, live first (it imports OpenCV before the CLI's set-up quiets it)."""
    frames = write_frames(tmp_path / "frames", np.stack(frames_text(6)))
    (frames / "000003.png").write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\x00\x0dIHDX")  # "IHDR chunk shall be first"
    huge = _png_claiming(tmp_path / "huge.png", 20_000, 20_000)
    runs = [
        ["live", "9", "--out", "o1"],  # no such camera: OpenCV's V4L and FFmpeg warnings
        ["live", "rtsp://127.0.0.1:1/x", "--stall-timeout", "2", "--out", "o2"],  # a closed port
        ["run", str(frames), "--out", "o3"],
        ["pair", str(huge), str(huge), "--out", "o4"],
    ]
    code = f"""
import sys
from mosegpipe.cli.main import app
for args in {runs!r}:
    try:
        app(args, prog_name="moseg")
    except SystemExit as exc:
        assert exc.code == 1, (args, exc.code)
"""
    env = {k: v for k, v in os.environ.items() if k not in ("OPENCV_FFMPEG_LOGLEVEL", "OPENCV_LOG_LEVEL")}
    proc = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        timeout=180,
        cwd=tmp_path,
        env={**env, "OMP_NUM_THREADS": "1"},
    )
    assert proc.returncode == 0, proc.stderr
    lines = proc.stderr.splitlines()
    assert len(lines) == 4 and all(line.startswith("moseg: error: ") for line in lines), proc.stderr
    assert "000003.png: not a readable image" in lines[2] and "huge.png: not a readable image" in lines[3]


def test_stderr_is_muted_only_after_the_cli_asked_and_comes_back(
    capfd: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    from mosegpipe import runtime

    monkeypatch.setattr(runtime, "_quiet_native", [False])  # the library alone: no side effect
    with runtime.native_stderr_muted():
        os.write(2, b"seen\n")
    monkeypatch.setattr(runtime, "_quiet_native", [True])  # after quiet_native_logs
    with runtime.native_stderr_muted(), runtime.native_stderr_muted():
        os.write(2, b"hidden\n")
    os.write(2, b"after\n")
    assert capfd.readouterr().err == "seen\nafter\n"


# ---------------------------------------------------------------------------------------------
# 10. Wording
# ---------------------------------------------------------------------------------------------


def test_view_warns_of_a_recording_cut_short(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import rerun as rr

    from mosegpipe.cli import view

    served: list[Path] = []
    monkeypatch.setattr(view, "_serve_web", lambda exe, recording, *args: served.append(recording))
    monkeypatch.setattr(view, "find_viewer", lambda: "rerun")
    path = tmp_path / "rec.rrd"
    rec = rr.RecordingStream("mosegpipe-test")
    rec.save(path)
    rec.log("points", rr.Points2D([[0.0, 0.0]]))
    rec.flush()
    rec.disconnect()
    code, _, err = moseg("view", "--web", path)
    assert code == 0 and err == ""
    data = path.read_bytes()
    cut = tmp_path / "cut.rrd"
    cut.write_bytes(data[: len(data) * 2 // 3])
    code, _, err = moseg("view", "--web", cut)
    assert code == 0 and served == [path, cut]
    assert err.startswith(f"moseg: warning: {cut}: cut short") and len(err.splitlines()) == 1


def test_tracks_start_beyond_the_tracks_names_start(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    np.savez(tmp_path / "t.npz", xy=rng.uniform(0, 100, (50, 8, 2)).astype(np.float32))
    code, _, err = moseg("tracks", tmp_path / "t.npz", "--start", "20", "--out", tmp_path / "o")
    line = one_error_line(err).rpartition("t.npz: ")[2]  # the message, not the temporary path (pytest-12...)
    assert code == 1 and "start=20: must lie in 0..6 (the tracks span 8 frames)" in line and "-12" not in line
