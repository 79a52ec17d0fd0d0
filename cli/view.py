"""moseg replay (an earlier run again, from its summary.json) and moseg view (a recording in the Rerun
viewer)."""

from __future__ import annotations

import contextlib
import errno
import os
import signal
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Annotated, Any

import typer

from mosegpipe.cli.app import friendly, one_line, setup_run
from mosegpipe.cli.clip import read_tracks_file
from mosegpipe.cli.common import (
    default_out,
    frames_progress,
    lock_out,
    print_summary,
    print_total,
    print_tracks_summary,
    print_video_summary,
    stop_child,
)
from mosegpipe.cli.options import NoRrd, Overwrite, Quiet, Threads, Verbose
from mosegpipe.errors import InputError

REPLAY_KINDS = ("clip", "video", "pair", "tracks")
"""The summary.json kinds `moseg replay` re-runs (docs/OUTPUTS.md)."""


_LIVE_NOT_REPLAYABLE = {"stdin": "frames piped on stdin", "camera": "a camera", "url": "a stream"}
"""Live sources whose frames are gone once read (summary.json `live.source_kind`; "-" is stdin)."""


_RRF2_FOOTER = b"RRF2FOOT"
"""How a complete recording of the current .rrd format (its first bytes "RRF2") ends, but for a version
number: what Rerun's FileSink writes when the recording is closed."""

_RRF2_TAIL_BYTES = 64


def _read_run_summary(path: Path) -> dict[str, Any]:
    """A run's summary.json, checked enough to replay it (kind, source, model; config in the library).

    With a recorded `source_identity`, `source` is replaced by the identity's absolute path(s), checked
    to hold what the run read.
    """
    import json

    if not path.is_file():
        raise InputError(f"{path}: no such file")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        raise InputError(f"{path}: not a JSON file ({one_line(str(exc))})") from exc
    except RecursionError:  # json gives up on nesting deeper than Python's recursion limit
        raise InputError(f"{path}: not a moseg summary.json (nested too deeply to read)") from None
    if not isinstance(data, dict) or not str(data.get("schema", "")).startswith("mosegpipe.summary/"):
        if isinstance(data, dict) and "clips" in data or path.name == "batch_summary.json":
            raise InputError(f"{path}: a batch summary; replay one clip's OUT/NAME/summary.json, or re-run the batch")
        raise InputError(f"{path}: not a moseg summary.json (no 'schema': 'mosegpipe.summary/...')")
    kind = data.get("kind")
    if kind not in REPLAY_KINDS:
        raise InputError(f"{path}: kind {kind!r} cannot be replayed (kinds: {', '.join(REPLAY_KINDS)})")
    source = data.get("source")
    live = data.get("live")
    live_kind = live.get("source_kind") if isinstance(live, dict) else None
    if kind == "video" and (source == "-" or live_kind in _LIVE_NOT_REPLAYABLE):
        what = _LIVE_NOT_REPLAYABLE.get(str(live_kind), _LIVE_NOT_REPLAYABLE["stdin"])
        raise InputError(f"{path}: a live run of {what} ({source}) cannot be replayed: its frames were not kept")
    sources = source if kind == "pair" else [source]
    if not isinstance(sources, list) or not sources or not all(isinstance(s, str) and s for s in sources):
        raise InputError(f"{path}: 'source' is missing or not a path: {source!r}")
    identities = data.get("source_identity")
    # None: written before identities were recorded; [None, None]: a pair of images given from Python.
    if identities is None or identities == [None, None]:
        for s in sources:
            if not Path(s).exists():
                raise InputError(
                    f"{s}: no such file or folder (the source recorded in {path}, which has no absolute path: a "
                    "relative one is taken from this folder; replay from the folder the run was started in)"
                )
    else:
        recorded = identities if kind == "pair" else [identities]
        found = [_check_source_identity(path, identity) for identity in _source_identities(path, recorded, sources)]
        data["source"] = found if kind == "pair" else found[0]
    model = data.get("model")
    if not isinstance(model, dict) or not isinstance(model.get("model_frames"), int):
        raise InputError(f"{path}: 'model' is missing or has no 'model_frames'")
    checkpoint = model.get("checkpoint")
    if checkpoint is not None and not (isinstance(checkpoint, str) and Path(checkpoint).is_file()):
        raise InputError(f"{checkpoint}: the checkpoint recorded in {path} is not there")
    for key in ("frames", "start"):
        if kind in ("video", "tracks") and not isinstance(data.get(key, 0), int):
            raise InputError(f"{path}: {key!r} is not an integer: {data.get(key)!r}")
    return data


def _source_identities(path: Path, recorded: Any, sources: list[str]) -> list[dict[str, Any]]:
    """The recorded `source_identity` (one per source), checked to be what the summary builders write."""
    if not isinstance(recorded, list) or len(recorded) != len(sources):
        raise InputError(f"{path}: 'source_identity' does not match 'source': {recorded!r}")
    for identity in recorded:
        if not (
            isinstance(identity, dict) and isinstance(identity.get("path"), str) and os.path.isabs(identity["path"])
        ):
            raise InputError(f"{path}: 'source_identity' has no absolute 'path': {identity!r}")
    return recorded


def _check_source_identity(path: Path, recorded: dict[str, Any]) -> str:
    """The absolute path of a run's source, after checking it is still what the run read.

    Raises:
        InputError: the source is gone, or its size, first MiB or files differ from the recorded ones.
    """
    from mosegpipe.io.provenance import identity_differences, source_identity

    where = recorded["path"]
    now = source_identity(where)
    if now is None:
        raise InputError(f"{where}: no such file or folder (the source recorded in {path})")
    differ = identity_differences(recorded, now)
    if differ:
        what = f"it is {differ[0]}" if differ[0].startswith("a ") else " and ".join(differ)
        verb = "" if what.startswith("it ") else " differ" if len(differ) > 1 or differ == ["files"] else " differs"
        raise InputError(
            f"{path}: the source {where} changed since the run ({what}{verb}); replaying it would segment "
            "another input: restore the run's input, or segment this one with a new run"
        )
    return where


def _check_same_model(net: Any, recorded: dict[str, Any], where: Path) -> None:
    """The replay's weights must be the run's: same recipe and configuration (shipped weights may have changed)."""
    from mosegpipe.pipeline import model_info

    now = model_info(net)
    for key in ("recipe", "model_config"):
        if key in recorded and recorded[key] != now[key]:
            weights = recorded.get("checkpoint") or "the shipped weights"
            raise InputError(
                f"{where}: the run used a model with {key} {recorded[key]!r}; {weights} now hold {now[key]!r}"
            )


@friendly
def replay(
    summary: Annotated[
        Path,
        typer.Argument(
            help="The summary.json of an earlier moseg run, pair or tracks run (or of one clip of a batch)."
        ),
    ],
    out: Annotated[
        Path | None,
        typer.Option(
            "--out", "-o", help="Output folder (default: beside the run's folder, named after it + '_replay')."
        ),
    ] = None,
    overwrite: Overwrite = False,
    no_rrd: NoRrd = False,
    quiet: Quiet = False,
    threads: Threads = 1,
    verbose: Verbose = False,
) -> None:
    """Run an earlier segmentation again with the settings its summary.json recorded.

    Same input (the recorded absolute source path, refused when the file or folder changed since the
    run), the same frames (--start, --frames; whole-video mode and
    the frames it read), every pipeline setting (summary.json `config`: tracker, automatic K,
    masks, ...) and the same weights (the recorded --model file, or the shipped weights). Only the
    outputs (--out, --no-rrd) are chosen here. Prints whether K came out as recorded.
    """
    started = time.perf_counter()
    recorded = _read_run_summary(summary)
    setup_run(threads, verbose)
    from mosegpipe.apps.outputs import check_output_dir, write_clip_outputs, write_pair_outputs, write_tracks_outputs
    from mosegpipe.apps.video_outputs import write_video_outputs
    from mosegpipe.embed.numpy_net import load_embedder
    from mosegpipe.pipeline import PipelineConfig, segment_clip, segment_pair, segment_tracks, tracks_clip

    kind, source = recorded["kind"], recorded["source"]
    cfg = PipelineConfig.from_dict(recorded.get("config", {}), f"{summary}: config")
    out = out or default_out(summary.parent, "_replay")
    lock_out(out)
    check_output_dir(out, overwrite)
    net = load_embedder(recorded["model"]["model_frames"], recorded["model"].get("checkpoint"))
    _check_same_model(net, recorded["model"], summary)
    if kind == "video":
        clip = Path(source)
        read = recorded.get("frames")  # the frames the run read: the same ones again
        with frames_progress(clip, cfg, read, quiet) as on_window:
            result = write_video_outputs(
                clip, out, cfg, net, overwrite=overwrite, rrd=not no_rrd, max_frames=read, on_window=on_window
            )
        print_video_summary(result, out, not no_rrd)
        then = [w.get("k") for w in recorded.get("windows", [])]
        now = [w["k"] for w in result["windows"]]
        differ = sum(a != b for a, b in zip(then, now)) + abs(len(then) - len(now))
        typer.echo(
            f"replayed {summary}: K as recorded in all {len(now)} windows"
            if not differ
            else f"replayed {summary}: K differs from the recorded run in {differ} of {len(now)} windows"
        )
        print_total(started)
        return
    if kind == "clip":
        written = write_clip_outputs(segment_clip(source, cfg, net), out, cfg, overwrite=overwrite, rrd=not no_rrd)
        print_summary(written, out)
    elif kind == "pair":
        first, second = source
        written = write_pair_outputs(
            segment_pair(first, second, cfg, net),
            out,
            cfg,
            overwrite=overwrite,
            sources=(first, second),
            rrd=not no_rrd,
        )
        print_summary(written, out)
    else:
        xy, visible = read_tracks_file(Path(source))
        segmented = segment_tracks(xy, visible, cfg, net, start=recorded.get("start", 0), frames=recorded.get("frames"))
        views = None
        if isinstance(recorded.get("video"), str):  # run with --video: its masks, overlays and recording again
            video = recorded["video"]
            if isinstance(recorded.get("video_identity"), dict):
                video = _check_source_identity(summary, recorded["video_identity"])
            views = tracks_clip(segmented, video, cfg)
        written = write_tracks_outputs(
            segmented, out, cfg, source=source, overwrite=overwrite, clip=views, rrd=not no_rrd
        )
        print_tracks_summary(written, out)
    same = written["k"] == recorded.get("k")
    typer.echo(
        f"replayed {summary}: K = {written['k']} as recorded"
        if same
        else f"replayed {summary}: K = {written['k']}, the recorded run found K = {recorded.get('k')}"
    )
    print_total(started)


WEB_PORT = 9090
"""The web viewer's HTTP port when it is free (a free one otherwise): the port README's ssh line forwards."""

VIEWER_START_S = 30.0
"""How long `moseg view --web` waits for the viewer to listen before it reports a failure."""


def find_viewer() -> str | None:
    """The native `rerun` program: rerun-sdk's own binary (its `rerun` script is a Python wrapper that
    would outlive a SIGTERM), else `rerun` on PATH or beside this Python (a virtualenv not on PATH)."""
    import importlib.util
    import shutil

    spec = importlib.util.find_spec("rerun_cli")
    if spec is not None and spec.origin is not None:
        folder = Path(spec.origin).parent
        for name in ("Rerun.app/Contents/MacOS/Rerun", "rerun.exe" if os.name == "nt" else "rerun"):
            if (folder / name).is_file():
                return str(folder / name)
    beside = Path(sys.executable).with_name("rerun")
    return shutil.which("rerun") or (str(beside) if beside.is_file() else None)


def has_display() -> bool:
    if sys.platform.startswith("linux"):
        return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    return True


def _check_bind(value: str) -> str:
    """--bind: an IP address (the viewer takes no host names; `localhost` is 127.0.0.1)."""
    import ipaddress

    address = "127.0.0.1" if value == "localhost" else value
    try:
        ipaddress.ip_address(address)
    except ValueError:
        raise typer.BadParameter("not an IP address (e.g. 127.0.0.1, 0.0.0.0 or ::)") from None
    return address


def reserve_ports(bind: str, wanted: list[tuple[str, int | None, int]]) -> list[int]:
    """The ports the viewer will listen on, each checked free on `bind` now.

    `wanted` holds (option, port given or None, preferred port): a port given must be free (0 = any
    free port); without one the preferred port is taken when free, a free port otherwise. The
    sockets stay open until all ports are chosen, so no two coincide.

    Raises:
        InputError: a port given is taken, or nothing can listen on `bind` on this machine.
    """
    import socket

    family = socket.AF_INET6 if ":" in bind else socket.AF_INET
    held: list[socket.socket] = []
    ports: list[int] = []
    try:
        for option, given, preferred in wanted:
            tries = [given] if given is not None else [preferred, 0] if preferred else [0]
            for i, port in enumerate(tries):
                sock = socket.socket(family, socket.SOCK_STREAM)
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as the viewer's server binds
                try:
                    sock.bind((bind, port))
                except OSError as exc:
                    sock.close()
                    if exc.errno == errno.EADDRINUSE and i + 1 < len(tries):
                        continue
                    if exc.errno == errno.EADDRINUSE:
                        raise InputError(
                            f"{option} {port}: the port is taken on {bind} (another viewer or server listens "
                            f"there); pass another port, or {option} 0 for any free one"
                        ) from None
                    raise InputError(f"--bind {bind}: cannot listen there ({exc.strerror or exc})") from None
                held.append(sock)
                ports.append(sock.getsockname()[1])
                break
    finally:
        for sock in held:
            sock.close()
    return ports


def _die_with_parent() -> None:  # pragma: no cover - runs in the child between fork and exec
    """The viewer gets SIGTERM when `moseg view` dies, even by SIGKILL (Linux)."""
    import ctypes

    pr_set_pdeathsig = 1
    ctypes.CDLL(None, use_errno=True).prctl(pr_set_pdeathsig, signal.SIGTERM)


def _last_error(lines: Any) -> str:
    """The viewer's own reason for stopping, from its last log lines (colour codes removed)."""
    import re

    plain = [re.sub(r"\x1b\[[0-9;]*m", "", line).strip() for line in list(lines)]
    for line in reversed(plain):
        if "Error" in line or " WARN " in line or " ERROR " in line:
            return one_line(re.sub(r"^\S+Z\s+(WARN|ERROR)\s+\S+:\s*", "", line))
    return one_line(plain[-1]) if plain else "no message"


@contextlib.contextmanager
def _one_start_at_a_time() -> Iterator[None]:
    """Viewers start one at a time (per user of this machine): each finds its ports free and listens on
    them before the next looks, so two `moseg view --web` started together do not pick the same port."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - Windows
        yield
        return
    import tempfile

    try:
        lock = open(Path(tempfile.gettempdir()) / f"moseg-view-{os.getuid()}.lock", "a")  # noqa: SIM115
    except OSError:  # a read-only temporary folder: start unlocked
        yield
        return
    with lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        yield


def _serve_web(exe: str, recording: Path, bind: str, ports: list[tuple[str, int | None, int]]) -> None:
    """Runs the web viewer as a child of this process until it ends, or this process is stopped.

    `ports` are the web page's and the data's, as `reserve_ports` takes them. Ctrl-C and SIGTERM
    reach this process as KeyboardInterrupt (cli/app.py); the viewer is ended before they
    propagate, and on Linux it also ends when this process is killed.

    Raises:
        InputError: a port is taken, the viewer stopped on its own with an error, or it did not start
            listening.
    """
    import collections
    import socket
    import subprocess
    import threading
    from urllib.parse import quote

    host = {"0.0.0.0": "127.0.0.1", "::": "::1"}.get(bind, bind)
    shown = f"[{host}]" if ":" in host else host
    log: collections.deque[str] = collections.deque(maxlen=20)  # the viewer's log, kept for its error
    proc: subprocess.Popen[str] | None = None
    try:
        with _one_start_at_a_time():
            web_port, grpc_port = reserve_ports(bind, ports)
            args = [exe, "--web-viewer", "--bind", bind, "--port", str(grpc_port), "--web-viewer-port", str(web_port)]
            proc = subprocess.Popen(
                [*args, str(recording)],
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.PIPE,
                text=True,
                errors="replace",
                preexec_fn=_die_with_parent if sys.platform.startswith("linux") else None,
            )
            reader = threading.Thread(target=lambda: log.extend(proc.stderr or ()), daemon=True)
            reader.start()
            deadline = time.monotonic() + VIEWER_START_S
            while proc.poll() is None:
                try:
                    socket.create_connection((host, web_port), timeout=0.5).close()
                    break
                except OSError:
                    if time.monotonic() > deadline:
                        raise InputError(
                            f"the Rerun viewer did not start listening on {shown}:{web_port} in {VIEWER_START_S:.0f} s"
                        ) from None
                    time.sleep(0.05)
        if proc.poll() is None:
            data = quote(f"rerun+http://{shown}:{grpc_port}/proxy", safe="")
            typer.echo(f"serving {recording} at http://{shown}:{web_port}/?url={data}")
            typer.echo(f"(the viewer at http://{shown}:{web_port}, its data on port {grpc_port}; Ctrl-C stops it)")
        code = proc.wait()
        reader.join(timeout=1.0)
        if code != 0:
            raise InputError(f"the Rerun viewer stopped (exit code {code}): {_last_error(log)}")
    finally:
        if proc is not None:
            stop_child(proc)


@friendly
def view(
    recording: Annotated[Path, typer.Argument(help="A .rrd recording written by moseg.")],
    web: Annotated[
        bool,
        typer.Option("--web", help="Serve the viewer to a web browser instead of opening a window (works headless)."),
    ] = False,
    bind: Annotated[
        str,
        typer.Option(
            "--bind",
            callback=_check_bind,
            help="With --web: the IP address to listen on. 127.0.0.1 (default) serves this machine only; "
            "0.0.0.0 serves every network it is on (anyone who can reach the ports sees the recording).",
        ),
    ] = "127.0.0.1",
    web_port: Annotated[
        int | None,
        typer.Option(
            "--web-port",
            min=0,
            max=65535,
            show_default=False,
            help=f"With --web: the HTTP port of the viewer page (default: {WEB_PORT}, or any free port when it is "
            "taken; 0 = any free port).",
        ),
    ] = None,
    grpc_port: Annotated[
        int,
        typer.Option(
            "--grpc-port",
            min=0,
            max=65535,
            help="With --web: the port the page reads the data from (0 = any free port).",
        ),
    ] = 0,
) -> None:
    """Open a recording in the Rerun viewer (the 'rerun' program that ships with rerun-sdk).

    Headless (no display, over SSH): `moseg view --web REC` serves the viewer on
    http://127.0.0.1:9090 of this machine (another free port when a viewer already uses it) and
    prints the address to open; the viewer stops with `moseg view` (Ctrl-C, or SIGTERM). Forward the
    two printed ports (`ssh -L 9090:localhost:9090 -L PORT:localhost:PORT HOST`, with a fixed
    --grpc-port) or pass `--bind 0.0.0.0` to serve it to the network.
    """
    if not recording.is_file():
        raise InputError(f"{recording}: no such recording")
    with recording.open("rb") as f:
        head = f.read(4)
        if head[:3] != b"RRF":  # every .rrd version starts so
            raise InputError(f"{recording}: not a Rerun recording (.rrd)")
        f.seek(max(0, recording.stat().st_size - _RRF2_TAIL_BYTES))
        complete = head != b"RRF2" or _RRF2_FOOTER in f.read()
    exe = find_viewer()
    if exe is None:
        raise InputError(
            "the Rerun viewer ('rerun') was not found on PATH or beside this Python; install rerun-sdk, "
            f"or open {recording} at https://rerun.io/viewer"
        )
    if not web and not has_display():
        raise InputError(f"no display to open a window on (DISPLAY is unset); try 'moseg view --web {recording}'")
    if not web and (bind != "127.0.0.1" or web_port is not None or grpc_port != 0):
        raise InputError("--bind, --web-port and --grpc-port only apply with --web")
    if not complete:
        # Shown now: the viewer runs until Ctrl-C, after which deferred warnings are dropped.
        typer.echo(
            f"moseg: warning: {recording}: cut short (no end of recording: a copy or a run that did not finish); "
            "the viewer shows the part it holds",
            err=True,
        )
    if not web:
        sys.stdout.flush()
        os.execv(exe, [exe, str(recording)])
    _serve_web(exe, recording, bind, [("--web-port", web_port, WEB_PORT), ("--grpc-port", grpc_port, 0)])
