"""`moseg view --web`: free ports, two viewers at once, the viewer ends with the command, one error line."""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import pytest

from helpers import moseg, one_error_line

LINUX = sys.platform.startswith("linux")

# `moseg view` as a shell starts it in the foreground: Ctrl-C raises KeyboardInterrupt (a background
# job of a non-interactive shell, such as a test run, would otherwise inherit SIGINT ignored).
VIEW = (
    "import signal, sys\n"
    "signal.signal(signal.SIGINT, signal.default_int_handler)\n"
    "from mosegpipe.cli.main import app\n"
    "sys.argv[0] = 'moseg'\n"
    "app()\n"
)


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    import rerun as rr

    path = tmp_path_factory.mktemp("view") / "recording.rrd"
    rec = rr.RecordingStream("mosegpipe-test")
    rec.save(str(path))
    rec.log("points", rr.Points2D([[0.0, 0.0], [1.0, 1.0]]))
    rec.flush()
    rec.disconnect()
    return path


def _children(pid: int) -> list[int]:
    """The processes whose parent is `pid` (from /proc)."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue
        if int(fields[1]) == pid:
            found.append(int(stat.parent.name))
    return found


def _ended(pid: int, within: float = 5.0) -> bool:
    """Whether process `pid` is gone (or a zombie nobody reaps yet) within `within` seconds."""
    deadline = time.monotonic() + within
    while True:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except (OSError, IndexError):
            return True
        if state in ("Z", "X"):
            return True
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)


class Viewer:
    """A `moseg view --web` process, its printed address and its viewer child."""

    def __init__(self, recording: Path, cwd: Path, *args: str) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-c", VIEW, "view", "--web", *args, str(recording)],
            cwd=cwd,  # outside the source tree: the installed package, as a user runs it
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        assert self.proc.stdout is not None
        self.line = self.proc.stdout.readline()  # printed once the viewer listens
        assert self.line.startswith(f"serving {recording} at http://127.0.0.1:"), (self.line, self.stop(0.0))
        self.port = int(self.line.split("http://127.0.0.1:")[1].split("/")[0])
        self.viewers = _children(self.proc.pid) if LINUX else []

    def stop(self, grace: float = 10.0) -> tuple[int, str]:
        """(exit code, stderr) once it ended by itself within `grace` seconds, or was killed."""
        try:
            _, err = self.proc.communicate(timeout=grace)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            _, err = self.proc.communicate(timeout=10)
        return self.proc.returncode, err


@pytest.fixture
def viewers(recording: Path, tmp_path: Path) -> Iterator[list[Viewer]]:
    started: list[Viewer] = []
    yield started
    for viewer in started:
        viewer.stop(grace=0.0)
        for pid in viewer.viewers:
            if not _ended(pid, 0.0):
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)


def test_two_viewers_at_once_and_each_ends_with_its_command(
    recording: Path, tmp_path: Path, viewers: list[Viewer]
) -> None:
    for _ in range(2):
        viewers.append(Viewer(recording, tmp_path))
    ports = [v.port for v in viewers]
    assert len(set(ports)) == 2, ports  # the second finds 9090 (or another port) taken
    for port in ports:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=5) as page:
            assert page.status == 200
    if LINUX:
        assert all(len(v.viewers) == 1 for v in viewers), [v.viewers for v in viewers]

    viewers[0].proc.send_signal(signal.SIGTERM)  # kill PID
    viewers[1].proc.send_signal(signal.SIGINT)  # Ctrl-C
    code, err = viewers[0].stop()
    assert code == 143 and one_error_line(err) == "moseg: error: terminated (SIGTERM)"
    code, err = viewers[1].stop()
    assert code == 130 and one_error_line(err) == "moseg: error: interrupted"
    for viewer in viewers:
        assert all(_ended(pid) for pid in viewer.viewers), viewer.viewers


def test_a_port_given_is_used_a_taken_one_is_one_error_line_and_the_viewer_dies_with_it(
    recording: Path, tmp_path: Path, viewers: list[Viewer]
) -> None:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        free = sock.getsockname()[1]
    viewers.append(Viewer(recording, tmp_path, "--web-port", str(free), "--bind", "localhost"))
    assert viewers[0].port == free
    for option in ("--web-port", "--grpc-port"):
        code, out, err = moseg("view", "--web", option, free, recording)
        assert code == 1 and out == "", err
        assert one_error_line(err) == (
            f"moseg: error: {option} {free}: the port is taken on 127.0.0.1 (another viewer or server listens "
            f"there); pass another port, or {option} 0 for any free one"
        )
    if LINUX:
        assert len(viewers[0].viewers) == 1
        viewers[0].proc.send_signal(signal.SIGKILL)  # no clean-up of its own: the viewer goes with it
        viewers[0].stop()
        assert _ended(viewers[0].viewers[0])


@pytest.mark.parametrize(
    ("bind", "code", "message"),
    [
        (
            "example.org",
            2,
            "--bind example.org: not an IP address (e.g. 127.0.0.1, 0.0.0.0 or ::) (see 'moseg view --help')",
        ),
        (
            "999.1.1.1",
            2,
            "--bind 999.1.1.1: not an IP address (e.g. 127.0.0.1, 0.0.0.0 or ::) (see 'moseg view --help')",
        ),
        (
            "192.0.2.1",
            1,
            "--bind 192.0.2.1: cannot listen there (Cannot assign requested address)",
        ),  # not this machine's
    ],
)
def test_a_bad_bind_is_one_error_line(recording: Path, bind: str, code: int, message: str) -> None:
    got, out, err = moseg("view", "--web", "--bind", bind, recording)
    assert got == code and out == ""
    if code == 1 and not LINUX:
        assert one_error_line(err).startswith(f"moseg: error: --bind {bind}: cannot listen there (")
    else:
        assert one_error_line(err) == f"moseg: error: {message}"
