"""moseg live: segment a camera, a stream, a file played in real time or frames piped on stdin as they
arrive, shown in a Rerun viewer; parse the options, open the viewer's sinks, one library call, print."""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Annotated, Any

import typer

from mosegpipe.cli.app import STOP_SIGNALS, Terminated, click_api, friendly, report_stopped, setup_run
from mosegpipe.cli.common import check_model_path, lock_out, print_total, print_video_summary, stop_child
from mosegpipe.cli.options import (
    RIGID_CHECK,
    ClusterOptions,
    MaskOptions,
    MaxSide,
    Method,
    MethodChoice,
    ModelOpt,
    NoRrd,
    Overwrite,
    Preset,
    PresetChoice,
    Quiet,
    RigidCheck,
    Threads,
    TrackerOptions,
    Verbose,
    option_blocks,
    pipeline_cfg,
)
from mosegpipe.errors import InputError, MosegError
from mosegpipe.settings import MAX_FRAME_INDEX, MAX_FRAMES
from mosegpipe.types import SEGMENT_METHODS

DEFAULT_VIEWER_URL = "rerun+http://127.0.0.1:9876/proxy"
"""Where a Rerun viewer started on its own (`rerun`) listens: --connect's default, --viewer's port."""

SERVER_MEMORY = "512MiB"
"""What the --serve server keeps for a browser that connects late (the oldest data goes first)."""


def _check_connect_url(url: str) -> tuple[str, int]:
    """(host, port) of a viewer's gRPC URL, checked as Rerun checks it."""
    from urllib.parse import urlsplit

    expected = f"--connect {url}: expected rerun+http://HOST:PORT/proxy (the URL a Rerun viewer prints)"
    try:
        parts = urlsplit(url)
        hostname = parts.hostname
    except ValueError:  # urllib's own complaint ("Invalid IPv6 URL")
        raise InputError(expected) from None
    if parts.scheme not in ("rerun", "rerun+http", "rerun+https") or parts.path != "/proxy" or not hostname:
        raise InputError(expected)
    try:
        port = parts.port or (443 if parts.scheme == "rerun+https" else 9876)
    except ValueError:
        raise InputError(f"--connect {url}: the port is not a number in 1..65535") from None
    return hostname, port


_HTTP2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + bytes([0, 0, 0, 4, 0, 0, 0, 0, 0])
"""A client's HTTP/2 connection preface and an empty SETTINGS frame (RFC 9113, 3.4 and 6.5)."""


def _speaks_grpc(host: str, port: int, timeout_s: float = 2.0) -> bool:
    """Whether what listens at host:port answers as a gRPC server (a Rerun viewer) does: HTTP/2, its
    first frame a SETTINGS frame (type 4). A web server, say, answers in HTTP/1 or not at all;
    Rerun's SDK would then print its own errors for each frame sent."""
    import socket

    try:
        with socket.create_connection((host, port), timeout=timeout_s) as sock:
            sock.sendall(_HTTP2_PREFACE)
            head = b""
            while len(head) < 9:
                chunk = sock.recv(9 - len(head))
                if not chunk:
                    break
                head += chunk
    except OSError:
        return False
    return len(head) == 9 and head[3] == 4


def _listening(host: str, port: int, timeout_s: float = 2.0) -> bool:
    import socket

    try:
        socket.create_connection((host, port), timeout=timeout_s).close()
        return True
    except OSError:
        return False


def _wait_listening(host: str, port: int, timeout_s: float, proc: Any = None) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc is not None and proc.poll() is not None:
            return False
        if _listening(host, port, 0.5):
            return True
        time.sleep(0.05)
    return False


@contextlib.contextmanager
def _sinks(viewer: bool, connect: str | None, serve: bool) -> Any:
    """The Rerun sinks of --viewer, --connect and --serve (a list; empty when none was asked for).

    --viewer spawns the native viewer (or finds one already listening on port 9876); --serve runs
    the web viewer and its gRPC server on 127.0.0.1, free ports, as a child of this process in a
    session of its own (a Ctrl-C does not reach it), ended with it. A --connect URL where nothing listens is an error before any work.
    """
    import subprocess

    import rerun as rr

    from mosegpipe.cli.view import VIEWER_START_S, find_viewer, has_display, reserve_ports

    sinks: list[Any] = []
    child = None
    try:
        if connect is not None:
            host, port = _check_connect_url(connect)
            if not _listening(host, port):
                raise InputError(f"--connect {connect}: no Rerun viewer listens there (start one with `rerun`)")
            if not _speaks_grpc(host, port):
                raise InputError(
                    f"--connect {connect}: something listens there, but not a Rerun viewer (no gRPC answer)"
                )
            sinks.append(rr.GrpcSink(connect))
        if viewer:
            if not has_display():
                raise InputError("--viewer needs a display (none here: $DISPLAY is unset); use --serve")
            if not _listening("127.0.0.1", 9876, 0.5):
                rr.spawn(port=9876, connect=False, hide_welcome_screen=True)
                if not _wait_listening("127.0.0.1", 9876, VIEWER_START_S):
                    raise InputError(f"the Rerun viewer did not start listening in {VIEWER_START_S:.0f} s")
            elif not _speaks_grpc("127.0.0.1", 9876):
                raise InputError("--viewer: port 9876 is taken by something that is not a Rerun viewer")
            if connect is None or _check_connect_url(connect)[1] != 9876:
                sinks.append(rr.GrpcSink(DEFAULT_VIEWER_URL))
        if serve:
            from urllib.parse import quote

            exe = find_viewer()
            if exe is None:
                raise InputError("--serve: the `rerun` program of rerun-sdk is not installed")
            web_port, grpc_port = reserve_ports("127.0.0.1", [("--serve", 0, 0), ("--serve", 0, 0)])
            args = [exe, "--web-viewer", "--bind", "127.0.0.1", "--port", str(grpc_port)]
            args += ["--web-viewer-port", str(web_port), "--server-memory-limit", SERVER_MEMORY]
            # A session of its own: Ctrl-C (SIGINT to the terminal's whole process group) must not end the server
            # before the last frames are flushed to it; Rerun's client printed two ERROR lines when it did.
            child = subprocess.Popen(
                args,
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
                start_new_session=True,
            )
            if not _wait_listening("127.0.0.1", grpc_port, VIEWER_START_S, child):
                raise InputError(f"--serve: the Rerun web viewer did not start listening in {VIEWER_START_S:.0f} s")
            url = f"rerun+http://127.0.0.1:{grpc_port}/proxy"
            sinks.append(rr.GrpcSink(url))
            typer.echo(f"open http://127.0.0.1:{web_port}/?url={quote(url, safe='')} in a browser")
        yield sinks
    finally:
        if child is not None:
            stop_child(child)


def _stdin_size_value(value: str | None) -> str | None:
    """--stdin-size checked as the option is parsed: a bad one is a usage error (exit code 2)."""
    if value is not None:
        from mosegpipe.apps.live.run import parse_size  # here: parsing any other live command line stays light

        try:
            parse_size(value)
        except InputError as exc:  # "--stdin-size '...': why"; the option and value are named by the usage line
            raise typer.BadParameter(str(exc).partition(": ")[2]) from None
    return value


class _Signals:
    """Ctrl-C, SIGTERM and SIGHUP set `stop` once (the run ends cleanly, its outputs complete); the
    handlers before (cli/app.py's policy) are back from then on, so a second one aborts at once."""

    def __init__(self, stop: threading.Event) -> None:
        self.stop = stop
        self.signum: int | None = None
        self._previous: dict[int, Any] = {}

    def _caught(self, signum: int, frame: Any) -> None:
        self.signum = signum
        self.stop.set()
        self.restore()

    def restore(self) -> None:
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)
        self._previous.clear()

    def __enter__(self) -> _Signals:
        with contextlib.suppress(ValueError):  # not the main thread: no handlers
            for signum in STOP_SIGNALS:
                self._previous[signum] = signal.signal(signum, self._caught)
        return self

    def __exit__(self, *exc: object) -> None:
        self.restore()


def _status_line(stats: Any) -> str:
    return (
        f"live: {stats.frames_shown} frames · {stats.fps:.1f} frames/s · latency {stats.last_latency_s:.2f} s "
        f"(median {stats.latency_quantile(0.5):.2f}) · dropped {stats.frames_dropped} ({100 * stats.dropped_share:.1f} %)"
    )


_END_LINES = {
    "stalled": "no frame for {timeout:g} s: the source stalled; stopped",
    "ended": "the stream ended",
}


LIVE_PRESET = "fast"
"""Live mode's preset unless --preset is given: the fastest that keeps the motion masks (docs/RESULTS.md, "Speed")."""


@friendly
@option_blocks
def live(
    ctx: typer.Context,
    source: Annotated[
        str,
        typer.Argument(
            help="A camera index (0), a stream URL (rtsp://, http://, ...), a video file, or - for raw BGR frames "
            "on stdin (ffmpeg ... -f rawvideo -pix_fmt bgr24 -, with --stdin-size).",
            show_default=False,
        ),
    ],
    viewer: Annotated[bool, typer.Option("--viewer", help="Spawn the Rerun viewer (needs a display).")] = False,
    connect: Annotated[
        str | None,
        typer.Option(
            "--connect",
            help=f"Stream to a Rerun viewer already running at this gRPC URL (a viewer started with `rerun` "
            f"listens at {DEFAULT_VIEWER_URL}).",
            show_default=False,
        ),
    ] = None,
    serve: Annotated[
        bool,
        typer.Option("--serve", help="Serve the web viewer on 127.0.0.1 (free ports; the URL is printed)."),
    ] = False,
    out: Annotated[
        Path | None,
        typer.Option("--out", "-o", help="Also write the output folder of `moseg run --whole` (docs/OUTPUTS.md)."),
    ] = None,
    realtime: Annotated[
        bool,
        typer.Option(
            "--realtime",
            help="A video file is played at its own frame rate, frames dropped when the machine falls behind "
            "(default: read as fast as segmented, none dropped).",
        ),
    ] = False,
    stdin_size: Annotated[
        str | None,
        typer.Option(
            "--stdin-size",
            callback=_stdin_size_value,
            help="WIDTHxHEIGHT of the raw frames on stdin (SOURCE -).",
            show_default=False,
        ),
    ] = None,
    fps: Annotated[
        float | None,
        typer.Option(
            "--fps",
            min=0.001,
            max=1000.0,
            help="Frame rate of the source (default: what it states, else 25): pacing of --realtime, the outputs' rate.",
            show_default=False,
        ),
    ] = None,
    stall_timeout: Annotated[
        float,
        typer.Option(
            "--stall-timeout", min=0.1, max=86400.0, help="End the run when no frame came for this many seconds."
        ),
    ] = 10.0,
    drop: Annotated[
        bool | None,
        typer.Option(
            "--drop/--no-drop",
            help="When the machine falls behind: drop the oldest frames (default for a camera, a stream and "
            "--realtime) or wait for it (default for a file and stdin; a pipe then blocks its writer).",
            show_default=False,
        ),
    ] = None,
    buffer: Annotated[
        int,
        typer.Option(
            "--buffer",
            min=1,
            max=1000,
            help="Frames held for the segmenter; when it falls behind a live source the oldest is dropped.",
        ),
    ] = 4,
    max_frames: Annotated[
        int | None,
        typer.Option("--max-frames", min=1, max=MAX_FRAME_INDEX, help="Stop after this many frames from the source."),
    ] = None,
    frames: Annotated[
        int,
        typer.Option("--frames", "-f", min=2, max=MAX_FRAMES, help=f"Window length, 2..{MAX_FRAMES}."),
    ] = 5,
    shot_cuts: Annotated[
        bool,
        typer.Option("--shot-cuts/--no-shot-cuts", help="Start tracking and windows afresh at a shot cut."),
    ] = True,
    clustering: ClusterOptions = ClusterOptions(),
    method: Method = MethodChoice(SEGMENT_METHODS[0]),
    rigid_check: RigidCheck = RIGID_CHECK,
    tracker: TrackerOptions = TrackerOptions(),
    masks: MaskOptions = MaskOptions(),
    preset: Preset = PresetChoice(LIVE_PRESET),
    max_side: MaxSide = None,
    model: ModelOpt = None,
    overwrite: Overwrite = False,
    no_rrd: NoRrd = False,
    quiet: Quiet = False,
    threads: Threads = 1,
    verbose: Verbose = False,
) -> None:
    """Segment SOURCE live, window by window as its frames arrive, and show it in the Rerun viewer.

    Each frame, its mask, its tracks and each window's K go to the viewer (--viewer, --connect,
    --serve) as soon as they are ready; --out also writes the output folder of `moseg run --whole`.
    When the machine falls behind a live source, whole frames are dropped (counted), never queued.
    A status line (frames/s, latency, dropped frames) is drawn on stderr when it is a terminal; a
    summary is printed at the end. The run ends when the source ends or stalls (--stall-timeout),
    after --max-frames, or on Ctrl-C: the window in hand is finished and the outputs are complete
    (exit code 130 after Ctrl-C, 143 after SIGTERM, 129 after SIGHUP; a second one aborts at once). The masks are
    the motion masks with --preset fast unless --preset or --mask-method say otherwise.
    """
    started = time.perf_counter()
    src = _live_source(ctx, source, stdin_size, realtime, fps, drop, viewer, connect, serve, out, no_rrd)
    check_model_path(model)
    setup_run(threads, verbose, "mosegpipe.apps.outputs")
    from mosegpipe.apps.live.run import LiveView, run_live
    from mosegpipe.apps.outputs import check_output_dir
    from mosegpipe.embed.numpy_net import load_embedder

    cfg = pipeline_cfg(
        frames,
        clustering,
        segment_method=method,
        rigid_check=rigid_check,
        shot_cuts=shot_cuts,
        tracker=tracker,
        masks=masks,
        preset=preset,
        max_side=max_side,
    )
    if out is not None:
        lock_out(out)
        check_output_dir(out, overwrite)
    net = load_embedder(frames, model)
    status = sys.stderr.isatty() and not quiet

    def on_status(stats: Any) -> None:
        sys.stderr.write("\r" + _status_line(stats) + "\x1b[K")
        sys.stderr.flush()

    stop = threading.Event()
    with _Signals(stop) as signals, _sinks(viewer, connect, serve) as sinks:
        view = LiveView(sinks, margins=cfg.k is None) if sinks else None
        try:
            result = run_live(
                src,
                cfg,
                net,
                view,
                out_dir=out,
                overwrite=overwrite,
                rrd=not no_rrd,
                stall_timeout_s=stall_timeout,
                buffer_frames=buffer,
                max_frames=max_frames,
                stop=stop,
                on_status=on_status if status else None,
            )
        except MosegError:
            if signals.signum is not None:  # stopped before a window's worth of frames: not the source's fault
                _stop_line(signals.signum)
            raise
        finally:
            if status:
                sys.stderr.write("\r\x1b[K")
            if view is not None:
                view.close()
    _print_live_summary(src.name, result)
    if result.summary is not None and out is not None:
        print_video_summary(result.summary, out, not no_rrd)
    print_total(started)
    if signals.signum is None:
        _warn_end(src, result, stdin_size, stall_timeout)
    if signals.signum is not None:
        _stop_line(signals.signum)


def _live_source(
    ctx: typer.Context,
    source: str,
    stdin_size: str | None,
    realtime: bool,
    fps: float | None,
    drop: bool | None,
    viewer: bool,
    connect: str | None,
    serve: bool,
    out: Path | None,
    no_rrd: bool,
) -> Any:
    """The parsed SOURCE (mosegpipe.apps.live.run.LiveSource), once the options that go with it are checked."""
    from mosegpipe.apps.live.run import parse_size, parse_source

    if (source == "-") != (stdin_size is not None):
        raise click_api.exceptions.UsageError(
            "SOURCE '-' (raw frames on stdin) needs --stdin-size WIDTHxHEIGHT"
            if source == "-"
            else "--stdin-size only applies to SOURCE '-' (raw frames on stdin)",
            ctx=ctx,
        )
    src = parse_source(source, realtime, None if stdin_size is None else parse_size(stdin_size), fps, drop)
    if not (viewer or connect or serve or out):
        raise InputError("nothing to show or write: pass --viewer, --connect URL, --serve or --out DIR")
    if no_rrd and out is None:
        raise InputError("--no-rrd only applies with --out (the recording is written into the output folder)")
    if connect is not None:
        _check_connect_url(connect)
    return src


def _warn_end(src: Any, result: Any, stdin_size: str | None, stall_timeout: float) -> None:
    """The warning line of a run that ended on the source's side: a camera or a stream that ended or
    stalled, any stalled source, or a last raw frame cut short on stdin."""
    line = _END_LINES.get(result.end) if src.kind in ("camera", "url") or result.end == "stalled" else None
    if result.partial_bytes:
        line = (
            f"the stream ended inside a frame ({result.partial_bytes} bytes of it, dropped; "
            f"is --stdin-size {stdin_size} right?)"
        )
    if line is not None:
        typer.echo(
            f"moseg: warning: {src.name}: {line.format(timeout=stall_timeout)} after {result.stats.frames_read} frames",
            err=True,
        )


def _stop_line(signum: int) -> None:
    """The signal's line and exit code, as cli/app.py gives them (130 Ctrl-C, 143 SIGTERM, 129 SIGHUP)."""
    report_stopped(KeyboardInterrupt() if signum == signal.SIGINT else Terminated(signum))


def _print_live_summary(name: str, result: Any) -> None:
    stats = result.stats
    rec = stats.record()
    typer.echo(
        f"live {name}: {stats.frames_shown} frames segmented of {stats.frames_read} read in {rec['seconds']:.1f} s "
        f"({rec['fps']:.1f} frames/s), {stats.frames_dropped} dropped ({100 * stats.dropped_share:.1f} %), "
        f"{result.num_windows} windows"
    )
    typer.echo(
        f"latency from arrival to mask: median {rec['latency_median_s']:.2f} s, 95 % {rec['latency_p95_s']:.2f} s"
    )
