"""The `moseg` command: a thin Typer layer over mosegpipe.pipeline, batch, train and evaluate.

Only this layer prints, and only here does a MosegError become one line on stderr and exit code 1.
"""

from __future__ import annotations

import atexit
import contextlib
import functools
import gc
import importlib
import logging
import os
import re
import signal
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import replace
from enum import Enum, StrEnum
from pathlib import Path
from typing import Annotated, Any, TypeVar, cast, get_args

import typer
from typer.core import TyperGroup

from mosegpipe import __version__
from mosegpipe.errors import InputError, MosegError, check_choice
from mosegpipe.types import KMethodName

try:  # Typer >= 0.26 bundles its own copy of Click; its exceptions are the ones raised
    from typer import _click
except ImportError:  # pragma: no cover - older Typer uses the click package
    import click as _click  # type: ignore[no-redef]

EXIT_CODES = {0: "success", 1: "bad input, a failed or interrupted run (one 'moseg: error:' line)", 2: "usage error"}
"""Exit codes of every moseg command (README, docs/OUTPUTS.md)."""


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _usage_message(exc: Any, args: list[str]) -> str:
    """One line for a usage error; a bad option value is named with the value given (`--frames 0: ...`)."""
    param = getattr(exc, "param", None)
    if isinstance(exc, _click.exceptions.BadParameter) and param is not None and getattr(param, "opts", None):
        for i, arg in enumerate(args):
            for opt in param.opts:
                if arg == opt and i + 1 < len(args):
                    return f"{opt} {args[i + 1]}: {_one_line(exc.message).rstrip('.')}"
                if arg.startswith(f"{opt}="):
                    return f"{opt} {arg[len(opt) + 1 :]}: {_one_line(exc.message).rstrip('.')}"
    return _one_line(exc.format_message()).rstrip(".")


class _MosegGroup(TyperGroup):
    """The moseg command group: usage errors are one line on stderr, not Click's framed box.

    Click's own exit code 2 is kept for usage errors (a bad option value, a missing argument, an
    unknown option); everything a command reports itself exits with 1 (see EXIT_CODES).
    """

    def main(
        self,
        args: Any = None,
        prog_name: str | None = None,
        complete_var: str | None = None,
        standalone_mode: bool = True,
        windows_expand_args: bool = True,
        **extra: Any,
    ) -> Any:
        try:
            rv = super().main(
                args=args,
                prog_name=prog_name,
                complete_var=complete_var,
                standalone_mode=False,
                windows_expand_args=windows_expand_args,
                **extra,
            )
            code = rv if isinstance(rv, int) else 0
        except _click.exceptions.NoArgsIsHelpError as exc:
            typer.echo(exc.ctx.get_help() if exc.ctx is not None else "")
            code = exc.exit_code
        except _click.exceptions.UsageError as exc:
            where = exc.ctx.command_path if exc.ctx is not None else "moseg"
            message = _usage_message(exc, sys.argv[1:] if args is None else list(args))
            typer.echo(f"moseg: error: {message} (see '{where} --help')", err=True)
            code = exc.exit_code
        except _click.exceptions.ClickException as exc:
            typer.echo(f"moseg: error: {_one_line(exc.format_message())}", err=True)
            code = exc.exit_code
        except typer.Abort:
            typer.echo("moseg: error: interrupted", err=True)
            code = 1
        if standalone_mode:
            sys.exit(code)
        return code


app = typer.Typer(
    name="moseg",
    cls=_MosegGroup,
    help="Motion segmentation of tracked points with SubspaceNet: clips, image pairs, folders of clips.",
    no_args_is_help=True,
    add_completion=True,
    pretty_exceptions_enable=False,
    rich_markup_mode="markdown",  # docstring paragraphs wrap to the terminal instead of keeping source line breaks
)

F = TypeVar("F", bound=Callable[..., Any])


def _fail(message: str) -> None:
    _WARNINGS.drop()
    typer.echo(f"moseg: error: {message}", err=True)
    raise typer.Exit(code=1)


def _shown_path(name: object) -> str:
    """A path as the user knows it: `OUT/file`, not the temporary `.OUT.partial/.file.1a2b3c4d.tmp`."""
    text = re.sub(r"(^|/)\.([^/]+)\.partial(?=/|$)", r"\1\2", os.fsdecode(name))  # type: ignore[arg-type]
    return re.sub(r"(^|/)\.([^/]+)\.[0-9a-f]{8}\.tmp(\.[^/.]*)?$", r"\1\2\3", text)


class _Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread like Ctrl-C so that the same clean-up runs (no .partial
    folder left behind)."""


def _raise_terminated(signum: int, frame: Any) -> None:
    signal.signal(signal.SIGTERM, signal.SIG_IGN)  # a second SIGTERM must not cut the clean-up short
    raise _Terminated()


class _DeferredWarnings(logging.Handler):
    """Holds the library's warnings until the command ends.

    After a success they are printed (`moseg: warning: ...`, at most `limit`, then a count); after a
    failure they are dropped, so that stderr holds only the one error line (a blank video in
    whole-video mode would otherwise print a warning per window before its error).
    """

    def __init__(self, limit: int = 10) -> None:
        super().__init__(logging.WARNING)
        self.limit = limit
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)

    def drop(self) -> None:
        self.records.clear()

    def show(self) -> None:
        records, self.records = self.records, []
        for record in records[: self.limit]:
            typer.echo(f"moseg: warning: {_one_line(record.getMessage())}", err=True)
        if len(records) > self.limit:
            typer.echo(f"moseg: warning: ... and {len(records) - self.limit} more warnings (-v shows them)", err=True)


_WARNINGS = _DeferredWarnings()


def _friendly(fn: F) -> F:
    """Turns MosegError, OS errors (a full disk, a read-only folder), Ctrl-C and SIGTERM into one
    line on stderr and exit code 1; the library's warnings are shown after a success only. Anything
    else is a bug and keeps its traceback."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        _WARNINGS.drop()
        previous = None
        with contextlib.suppress(ValueError):  # signals can only be handled in the main thread
            previous = signal.signal(signal.SIGTERM, _raise_terminated)
        try:
            result = fn(*args, **kwargs)
            _WARNINGS.show()
            return result
        except MosegError as exc:
            _fail(_one_line(str(exc)))
        except OSError as exc:
            where = f"{_shown_path(exc.filename)}: " if exc.filename else ""
            _fail(f"{where}{exc.strerror or exc}")
        except KeyboardInterrupt as exc:
            _fail("terminated (SIGTERM)" if isinstance(exc, _Terminated) else "interrupted")
        finally:
            if previous is not None:
                signal.signal(signal.SIGTERM, previous)

    return wrapper  # type: ignore[return-value]


def _quiet_native_logs() -> None:
    """Keeps FFmpeg's and OpenCV's own messages off stderr (they are read when the first video opens).

    FFmpeg inside OpenCV prints decoder complaints ("moov atom not found", "cinepak_decode failed")
    straight to file descriptor 2; the failure they lead to is reported once, as a moseg error line.
    A value the user set in the environment wins.
    """
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")  # AV_LOG_QUIET
    os.environ.setdefault("OPENCV_LOG_LEVEL", "ERROR")


@contextlib.contextmanager
def _collector_paused() -> Iterator[None]:
    """Runs the start-up imports with Python's cyclic garbage collector paused, then freezes what they built.

    torch, scikit-learn and SciPy build about 250 k objects (functions, classes, module dicts) as
    they are imported, and they live until the process exits. With the collector running, the
    imports trigger several full collections that walk everything imported so far again, and the
    interpreter's last collection at exit walks it all once more: about 1 s of a `moseg run` on 5
    frames on the 2-core machine (benchmarks/speed.py, table (d)). `gc.freeze()` moves them to the
    permanent generation, which collections skip: later ones walk only what the command builds (a
    whole video is still collected as it goes), and the one at exit walks nothing. The price: the
    few thousand objects of cyclic garbage the imports leave behind are kept until exit. Only the
    first start-up in a process pauses; one that imported torch already (the CLI invoked in-process,
    as the tests do) keeps its collector as it is.
    """
    if not gc.isenabled() or "torch" in sys.modules:
        yield
        return
    gc.disable()
    try:
        yield
    finally:
        gc.freeze()
        gc.enable()
        atexit.register(gc.freeze)  # at exit: before the interpreter's last collection


def _setup(threads: int, verbose: bool, *preload: str) -> None:
    """Logging, native log levels and thread counts; then `preload`, the modules the command imports
    next (names for importlib), imported with the collector paused (see _collector_paused)."""
    from mosegpipe.runtime import set_threads

    root = logging.getLogger()
    if root.handlers and all(h is _WARNINGS for h in root.handlers) and verbose:
        root.removeHandler(_WARNINGS)  # an earlier command in this process deferred its warnings
    if verbose:
        logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    else:
        if _WARNINGS not in root.handlers:
            root.addHandler(_WARNINGS)
        root.setLevel(logging.WARNING)
        _quiet_native_logs()
    with _collector_paused():
        set_threads(threads)  # imports torch and OpenCV
        for name in preload:
            importlib.import_module(name)


def _default_out(path: Path, suffix: str) -> Path:
    """<name><suffix> beside the input (resolved, so that "." or "clip/" still have a name)."""
    path = path.resolve()
    return path.with_name(f"{path.stem}{suffix}")


def _version(value: bool) -> None:
    if value:
        typer.echo(f"moseg {__version__}")
        raise typer.Exit()


@app.callback()
def main(
    version: Annotated[
        bool, typer.Option("--version", callback=_version, is_eager=True, help="Print the version and exit.")
    ] = False,
) -> None:
    """moseg: which tracked points move together, dense masks and a Rerun recording."""


Threads = Annotated[
    int, typer.Option("--threads", min=1, help="CPU threads (1 is fastest for one clip on small machines).")
]
Verbose = Annotated[bool, typer.Option("--verbose", "-v", help="Log progress.")]
KOpt = Annotated[int | None, typer.Option("--k", min=1, help="Force this many motions (default: automatic K).")]


class KMethodChoice(StrEnum):
    """--k-method: the values of mosegpipe.types.KMethodName (a test keeps them equal)."""

    silhouette = "silhouette"
    residual = "residual"


class EngineChoice(StrEnum):
    """--engine: the values of mosegpipe.batch.ENGINES (a test keeps them equal)."""

    process = "process"
    ray = "ray"
    inline = "inline"


def _value(choice: Any) -> Any:
    """The plain value of an Enum choice (what the library and summary.json take)."""
    return choice.value if isinstance(choice, Enum) else choice


KMethod = Annotated[
    KMethodChoice,
    typer.Option("--k-method", help="Automatic K: silhouette (default, more often right) or residual (faster)."),
]
KMax = Annotated[int, typer.Option("--k-max", min=1, help="Largest K considered by automatic K.")]
ModelOpt = Annotated[Path | None, typer.Option("--model", help="A checkpoint instead of the shipped weights.")]
Overwrite = Annotated[bool, typer.Option("--overwrite", help="Replace results already in the output folder.")]
NoRrd = Annotated[bool, typer.Option("--no-rrd", help="Skip the Rerun recording.")]
MaskMethod = Annotated[
    str,
    typer.Option(
        "--mask-method",
        help="Dense masks from track labels: 'watershed' (default: follows image edges), 'nearest' (nearest track) or 'vote'.",
    ),
]


def _protocol_help() -> str:
    """The protocol names from the registry: benchmark ones, then end-to-end ones."""
    from mosegpipe.evaluation.protocols import PROTOCOLS

    bench = [p.name for p in PROTOCOLS.values() if p.kind == "benchmark"]
    e2e = [p.name for p in PROTOCOLS.values() if p.kind == "end-to-end"]
    return f"{', '.join(bench)}; end to end: {', '.join(e2e)}."


def _pipeline_cfg(frames: int, k: int | None, k_method: str, k_max: int, mask_method: str = "watershed") -> Any:
    from mosegpipe.cluster import ClusterConfig
    from mosegpipe.masks import MASK_METHODS, MaskConfig
    from mosegpipe.pipeline import PipelineConfig

    method = cast(KMethodName, check_choice("--k-method", _value(k_method), get_args(KMethodName)))
    if mask_method not in MASK_METHODS:
        raise InputError(f"--mask-method {mask_method!r}: choose {', '.join(map(repr, MASK_METHODS))}")
    return PipelineConfig(
        frames=frames,
        k=k,
        cluster=replace(ClusterConfig(), method=method, k_max=k_max),
        mask=MaskConfig(method=mask_method),
    )


def _progress_columns() -> tuple[Any, ...]:
    """Description, bar, n/N done, elapsed and remaining time (rich.progress)."""
    from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    return (
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TextColumn("ETA"),
        TimeRemainingColumn(),
    )


def _check_model_path(model: Path | None) -> None:
    if model is not None and not model.is_file():
        raise InputError(f"{model}: checkpoint file not found (--model)")


def _print_total(started: float) -> None:
    typer.echo(f"total {time.perf_counter() - started:.1f} s")


def _plural(n: int, word: str, plural: str = "") -> str:
    return f"{n} {word}" if n == 1 else f"{n} {plural or word + 's'}"


def _print_summary(summary: dict[str, Any], out: Path) -> None:
    """Three or four lines: what was found, the evidence for K, where the time went, what was written."""
    if summary["kind"] == "clip":
        typer.echo(
            f"{_plural(summary['num_tracks_segmented'], 'track')} over {summary['frames']} frames -> K = {summary['k']} "
            f"({summary['k_method']}) · tracks per motion {summary['tracks_per_motion']}"
        )
    else:
        typer.echo(
            f"{_plural(summary['num_matches'], 'match', 'matches')} -> {_plural(summary['num_motions'], 'motion')} + "
            f"{_plural(summary['num_outliers'], 'outlier')} (K = {summary['k']}, {summary['k_method']}) · "
            f"matches per motion {summary['matches_per_motion']}"
        )
    scores = ", ".join(f"K={k}: {v:.3g}" for k, v in summary["k_scores"].items())
    if scores:
        typer.echo(f"scores per K: {scores}")
    if summary.get("k_note"):
        typer.echo(f"note: {summary['k_note']}")
    typer.echo("timings: " + ", ".join(f"{k} {1000 * v:.0f} ms" for k, v in summary["timings_s"].items()))
    files = "summary.json, labels.npz, masks/, overlay/" + (
        ", recording.rrd" if (out / "recording.rrd").exists() else ""
    )
    typer.echo(f"wrote {out}/ ({files})")


@app.command()
@_friendly
def run(
    clip: Annotated[Path, typer.Argument(help="A video file OpenCV can read, or a folder of frames.")],
    frames: Annotated[
        int,
        typer.Option(
            "--frames", "-f", min=2, help="Frames to segment (the paper uses 5); with --whole, the window length."
        ),
    ] = 5,
    out: Annotated[
        Path | None,
        typer.Option("--out", "-o", help="Output folder (default: beside the clip, named after it + '_moseg')."),
    ] = None,
    whole: Annotated[
        bool, typer.Option("--whole", help="Segment the whole video in consecutive windows of --frames frames.")
    ] = False,
    max_frames: Annotated[
        int | None, typer.Option("--max-frames", min=1, help="With --whole: stop after this many frames.")
    ] = None,
    k: KOpt = None,
    k_method: KMethod = KMethodChoice.silhouette,
    k_max: KMax = 8,
    mask_method: MaskMethod = "watershed",
    model: ModelOpt = None,
    overwrite: Overwrite = False,
    no_rrd: NoRrd = False,
    threads: Threads = 1,
    verbose: Verbose = False,
) -> None:
    """Segment the motions in the first --frames frames of CLIP (or the whole video with --whole).

    Writes summary.json, labels.npz, masks/ (palette PNGs), overlay/ and recording.rrd into the
    output folder; see docs/OUTPUTS.md. Exit code 1 with one 'moseg: error:' line on failure.
    """
    started = time.perf_counter()
    # Paths and option combinations first: torch and scikit-learn take seconds to import.
    if not clip.exists():
        raise InputError(f"{clip}: no such file or folder")
    if max_frames is not None and not whole:
        raise InputError("--max-frames only applies with --whole (without it, --frames frames are read)")
    _check_model_path(model)
    _setup(threads, verbose, "mosegpipe.outputs")
    from mosegpipe.outputs import check_output_dir, write_clip_outputs, write_video_outputs
    from mosegpipe.pipeline import load_model, segment_clip

    cfg = _pipeline_cfg(frames, k, k_method, k_max, mask_method)
    out = out or _default_out(clip, "_moseg")
    check_output_dir(out, overwrite)
    net = load_model(frames, model)
    if whole:
        summary = write_video_outputs(clip, out, cfg, net, overwrite=overwrite, rrd=not no_rrd, max_frames=max_frames)
        typer.echo(
            f"{summary['frames']} frames in {summary['num_windows']} windows of {summary['window_frames']} "
            f"({summary['num_windows_labelled']} labelled) -> {summary['num_motions']} motion labels"
        )
        typer.echo(f"{summary['seconds']:.1f} s, {summary['processing_fps']:.1f} frames/s")
        typer.echo(
            f"wrote {out}/ (summary.json, labels.npz, masks/, overlay.mp4" + (", recording.rrd)" if not no_rrd else ")")
        )
        _print_total(started)
        return
    result = segment_clip(clip, cfg, net)
    summary = write_clip_outputs(result, out, cfg, overwrite=overwrite, rrd=not no_rrd)
    _print_summary(summary, out)
    _print_total(started)


@app.command()
@_friendly
def pair(
    img1: Annotated[Path, typer.Argument(help="First image.")],
    img2: Annotated[Path, typer.Argument(help="Second image (may differ in size).")],
    out: Annotated[
        Path | None,
        typer.Option("--out", "-o", help="Output folder (default: beside IMG1, named after it + '_pair_moseg')."),
    ] = None,
    k: KOpt = None,
    k_method: KMethod = KMethodChoice.silhouette,
    k_max: KMax = 8,
    mask_method: MaskMethod = "watershed",
    model: ModelOpt = None,
    overwrite: Overwrite = False,
    no_rrd: NoRrd = False,
    threads: Threads = 1,
    verbose: Verbose = False,
) -> None:
    """Segment the motions between two images from SIFT matches; outliers get their own label."""
    started = time.perf_counter()
    for p in (img1, img2):
        if not p.is_file():
            raise InputError(f"{p}: no such image file")
    _check_model_path(model)
    _setup(threads, verbose, "mosegpipe.outputs")
    from mosegpipe.outputs import check_output_dir, write_pair_outputs
    from mosegpipe.pipeline import load_model, segment_pair

    cfg = _pipeline_cfg(2, k, k_method, k_max, mask_method)
    out = out or _default_out(img1, "_pair_moseg")
    check_output_dir(out, overwrite)
    result = segment_pair(img1, img2, cfg, load_model(2, model))
    summary = write_pair_outputs(result, out, cfg, overwrite=overwrite, sources=(str(img1), str(img2)), rrd=not no_rrd)
    _print_summary(summary, out)
    _print_total(started)


def read_tracks_file(path: Path) -> tuple[Any, Any]:
    """(N, T, 2) positions and (N, T) visibility from a .npz of point tracks.

    Accepted layouts (arrays by name): `xy` (N, T, 2) with optional `visible` (N, T) (ours);
    `tracks` (T, N, 2) or (1, T, N, 2) with optional `visibility` (T, N) or (1, T, N) (CoTracker's
    time-first output); `tracks` (N, T, 2) with `occluded` (N, T) (TAPIR: visible = not occluded).

    Raises:
        InputError: not a readable .npz, or none of the layouts.
    """
    import numpy as np

    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {name: data[name] for name in data.files}
    except (OSError, ValueError, EOFError) as exc:
        raise InputError(f"{path}: not a readable .npz file (numpy.savez, no pickled objects)") from exc
    if "xy" in arrays:
        return arrays["xy"], arrays.get("visible")
    if "tracks" in arrays and "occluded" in arrays:
        return arrays["tracks"], ~np.asarray(arrays["occluded"]).astype(bool)
    if "tracks" in arrays:
        tracks, vis = arrays["tracks"], arrays.get("visibility")
        if tracks.ndim == 4 and tracks.shape[0] == 1:
            tracks, vis = tracks[0], None if vis is None else vis[0]
        if tracks.ndim != 3:
            raise InputError(f"{path}: 'tracks' has shape {tracks.shape}; expected (T, N, 2) or (1, T, N, 2)")
        return np.swapaxes(tracks, 0, 1), None if vis is None else np.swapaxes(np.asarray(vis), 0, 1)
    raise InputError(
        f"{path}: holds {sorted(arrays)}; expected 'xy' (N, T, 2) [+ 'visible'], 'tracks' (T, N, 2) "
        "[+ 'visibility'] (CoTracker) or 'tracks' (N, T, 2) + 'occluded' (TAPIR)"
    )


@app.command()
@_friendly
def tracks(
    file: Annotated[Path, typer.Argument(help="A .npz of point tracks from another tracker (layouts: README).")],
    out: Annotated[
        Path | None,
        typer.Option("--out", "-o", help="Output folder (default: beside FILE, named after it + '_moseg')."),
    ] = None,
    start: Annotated[int, typer.Option("--start", min=0, help="First frame of the window segmented.")] = 0,
    frames: Annotated[
        int | None,
        typer.Option("--frames", "-f", min=2, help="Window length (default: from --start to the last frame)."),
    ] = None,
    k: KOpt = None,
    k_method: KMethod = KMethodChoice.silhouette,
    k_max: KMax = 8,
    model: ModelOpt = None,
    overwrite: Overwrite = False,
    threads: Threads = 1,
    verbose: Verbose = False,
) -> None:
    """Segment point tracks made elsewhere (CoTracker, TAPIR, ...) with our embedding and clustering.

    Tracks visible in every frame of the window are segmented; summary.json and labels.npz (label
    of every track, -1 = not visible throughout) go into the output folder.
    """
    started = time.perf_counter()
    if not file.is_file():
        raise InputError(f"{file}: no such file")
    _check_model_path(model)
    _setup(threads, verbose, "mosegpipe.outputs")
    from mosegpipe.outputs import check_output_dir, write_tracks_outputs
    from mosegpipe.pipeline import load_model, segment_tracks

    xy, visible = read_tracks_file(file)
    window = frames if frames is not None else (xy.shape[1] - start if getattr(xy, "ndim", 0) == 3 else 2)
    cfg = _pipeline_cfg(max(2, window), k, k_method, k_max)
    out = out or _default_out(file, "_moseg")
    check_output_dir(out, overwrite)
    net = load_model(max(2, window), model)
    result = segment_tracks(xy, visible, cfg, net, start=start, frames=frames)
    summary = write_tracks_outputs(result, out, cfg, source=str(file), overwrite=overwrite)
    typer.echo(
        f"{_plural(summary['num_tracks_segmented'], 'track')} of {summary['num_tracks']} over {summary['frames']} "
        f"frames -> K = {summary['k']} ({summary['k_method']}) · tracks per motion {summary['tracks_per_motion']}"
    )
    if summary["k_note"]:
        typer.echo(f"note: {summary['k_note']}")
    typer.echo(f"wrote {out}/ (summary.json, labels.npz)")
    _print_total(started)


@app.command()
@_friendly
def batch(
    folder: Annotated[Path, typer.Argument(help="Folder searched for video files and frame folders.")],
    out: Annotated[
        Path, typer.Option("--out", "-o", help="Output folder: one sub-folder per clip plus batch_summary.csv/json.")
    ],
    frames: Annotated[int, typer.Option("--frames", "-f", min=2)] = 5,
    k: KOpt = None,
    k_method: KMethod = KMethodChoice.silhouette,
    k_max: KMax = 8,
    model: ModelOpt = None,
    overwrite: Annotated[
        bool, typer.Option("--overwrite", help="Redo clips that already have outputs (default: resume).")
    ] = False,
    no_rrd: NoRrd = False,
    jobs: Annotated[
        int | None,
        typer.Option(
            "--jobs",
            "-j",
            min=1,
            help="Clips at once: worker processes (default: the number of cores), or Ray tasks in flight with --engine ray (default: the cluster's CPUs).",
        ),
    ] = None,
    engine: Annotated[
        EngineChoice,
        typer.Option(
            "--engine",
            help="process (worker processes on this machine), ray (Ray tasks: pip install 'mosegpipe[ray]') or inline (this process, one clip after another).",
        ),
    ] = EngineChoice.process,
    address: Annotated[
        str | None,
        typer.Option(
            "--address",
            help="With --engine ray: the cluster to use ('auto', 'ray://HEAD:10001', ...); default: a local Ray instance. On a cluster --out must be a shared path.",
        ),
    ] = None,
    clip_timeout: Annotated[
        float | None,
        typer.Option(
            "--clip-timeout",
            help="Seconds a clip may run before its worker is killed and it is reported failed (default: no limit).",
        ),
    ] = None,
    threads: Threads = 1,
    verbose: Verbose = False,
) -> None:
    """Segment every clip under FOLDER (video files and frame folders, searched recursively).

    Each clip gets its own sub-folder of --out (as from 'moseg run'), and batch_summary.csv/json
    list every clip with its status. --jobs clips run at once, each worker with one thread. A clip
    that fails, runs past --clip-timeout or kills its worker is reported and the others go on; a
    re-run skips the clips already done with the same options and weights (resume) and redoes the
    others.

    Exit code: 0 when every clip was segmented or skipped, 1 when any clip failed (after all the
    others were processed and the summary written).
    """
    started = time.perf_counter()
    if not folder.exists():
        raise InputError(f"{folder}: no such file or folder")
    _check_model_path(model)
    _setup(threads, verbose)
    from rich.markup import escape
    from rich.progress import Progress

    from mosegpipe.batch import ENGINES, plan, run_batch
    from mosegpipe.pipeline import load_model

    cfg = _pipeline_cfg(frames, k, k_method, k_max)
    engine = _value(engine)
    if engine not in ENGINES:
        raise InputError(f"--engine {engine!r}: choose {', '.join(map(repr, ENGINES))}")
    if address is not None and engine != "ray":
        raise InputError("--address only applies with --engine ray")
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is not a folder; choose another --out")
    items = plan(folder, out)
    if not items:
        raise InputError(f"{folder}: no video files or frame folders found")
    net = load_model(frames, model)
    with Progress(*_progress_columns(), transient=True) as bar:
        task = bar.add_task("segmenting", total=len(items))

        def step(item: Any, row: dict[str, Any]) -> None:
            bar.update(task, advance=1, description=f"{escape(item.name)} {row['status']}")
            if row["status"] == "failed":
                bar.console.print(f"[red]failed[/red] {escape(item.name)}: {escape(row['error'])}")

        rows = run_batch(
            folder,
            out,
            cfg,
            net,
            rrd=not no_rrd,
            overwrite=overwrite,
            on_item=step,
            jobs=jobs,
            engine=engine,
            address=address,
            clip_timeout=clip_timeout,
        )
    width = max(4, *(len(r["name"]) for r in rows))
    typer.echo(f"{'clip':<{width}}  status    K  tracks  seconds")
    for r in rows:
        typer.echo(f"{r['name']:<{width}}  {r['status']:<7} {r['k']!s:>3}  {r['tracks']!s:>6}  {r['seconds']!s:>7}")
    counts = {s: sum(r["status"] == s for r in rows) for s in ("ok", "skipped", "failed")}
    typer.echo(
        f"{counts['ok']} segmented, {counts['skipped']} skipped (done earlier), {counts['failed']} failed; "
        f"wrote {out}/batch_summary.csv and batch_summary.json"
    )
    _print_total(started)
    if counts["failed"]:
        _fail(f"{counts['failed']} of {len(rows)} clips failed (reasons in {out}/batch_summary.csv)")


def _find_viewer() -> str | None:
    """The `rerun` executable: on PATH, else beside this Python (a virtualenv not on PATH)."""
    import shutil

    beside = Path(sys.executable).with_name("rerun")
    return shutil.which("rerun") or (str(beside) if beside.is_file() else None)


def _has_display() -> bool:
    if sys.platform.startswith("linux"):
        return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    return True


@app.command()
@_friendly
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
            help="With --web: the address to listen on. 127.0.0.1 (default) serves this machine only; "
            "0.0.0.0 serves every network it is on (anyone who can reach the port sees the recording).",
        ),
    ] = "127.0.0.1",
    web_port: Annotated[
        int, typer.Option("--web-port", min=0, max=65535, help="With --web: the HTTP port (0 = any free port).")
    ] = 9090,
) -> None:
    """Open a recording in the Rerun viewer (the 'rerun' program that ships with rerun-sdk).

    Headless (no display, over SSH): `moseg view --web REC` serves the viewer on
    http://127.0.0.1:9090 of this machine; forward the port (`ssh -L 9090:localhost:9090 HOST`)
    or pass `--bind 0.0.0.0` to serve it to the network.
    """
    if not recording.is_file():
        raise InputError(f"{recording}: no such recording")
    exe = _find_viewer()
    if exe is None:
        raise InputError(
            "the Rerun viewer ('rerun') was not found on PATH or beside this Python; install rerun-sdk, "
            f"or open {recording} at https://rerun.io/viewer"
        )
    if not web and not _has_display():
        raise InputError(f"no display to open a window on (DISPLAY is unset); try 'moseg view --web {recording}'")
    if not web and (bind != "127.0.0.1" or web_port != 9090):
        raise InputError("--bind and --web-port only apply with --web")
    web_args = ["--web-viewer", "--bind", bind, "--web-viewer-port", str(web_port)]
    args = [exe, *web_args, str(recording)] if web else [exe, str(recording)]
    sys.stdout.flush()
    os.execv(exe, args)


def _data_root(data_root: Path | None) -> Path:
    root = data_root or Path(os.environ.get("MOSEG_DATA", "../shared/data"))
    if not root.is_dir():
        raise InputError(f"{root}: benchmark data folder not found (use --data-root or MOSEG_DATA)")
    return root


DataRoot = Annotated[
    Path | None, typer.Option("--data-root", help="Benchmark folder (default: $MOSEG_DATA or ../shared/data).")
]


@app.command()
@_friendly
def train(
    preset: Annotated[
        str, typer.Option("--preset", help="Named recipe: clip-f5, synthetic-f5, pair-f2, synthetic-f2, lce.")
    ] = "clip-f5",
    out: Annotated[Path, typer.Option("--out", "-o", help="Checkpoint file to write.")] = Path("runs/model.pt"),
    steps: Annotated[int | None, typer.Option("--steps", min=1, help="Override the recipe's step count.")] = None,
    batch_size: Annotated[int | None, typer.Option("--batch-size", min=1)] = None,
    lr: Annotated[float | None, typer.Option("--lr")] = None,
    loss: Annotated[str | None, typer.Option("--loss", help="mimi, l2 or ce.")] = None,
    seed: Annotated[int | None, typer.Option("--seed")] = None,
    init: Annotated[Path | None, typer.Option("--init", help="Fine-tune from this checkpoint.")] = None,
    exclude: Annotated[
        str | None, typer.Option("--exclude", help="Comma-separated source names to leave out (leave-one-dataset-out).")
    ] = None,
    time_budget: Annotated[float | None, typer.Option("--time-budget", help="Stop after this many seconds.")] = None,
    data_root: DataRoot = None,
    threads: Annotated[int, typer.Option("--threads", min=1)] = 2,
    verbose: Verbose = False,
) -> None:
    """Train a SubspaceNet checkpoint from a named recipe (synthetic data generated on the fly).

    Without --init a recipe starts from its own starting recipe (clip-f5 from base-f5, pair-f2 from
    synthetic-f2), trained first into the --out folder when its checkpoint is not there yet.
    """
    _setup(threads, verbose)
    from mosegpipe.training.run import TrainOverrides, needs_data, train_recipe

    dropped = {s.strip() for s in exclude.split(",")} if exclude else set()
    root = _data_root(data_root) if needs_data(preset, dropped) else data_root
    result = train_recipe(
        preset,
        out,
        root,
        init=init,
        overrides=TrainOverrides(
            steps=steps, batch_size=batch_size, lr=lr, loss=loss, seed=seed, time_budget_s=time_budget
        ),
        exclude_sources=dropped,
        command=" ".join(["moseg", *sys.argv[1:]]),
        on_start=lambda recipe, cfg, described: typer.echo(
            f"training {recipe.name}: {cfg.steps} steps × {cfg.batch_size} clips, sources {described}"
        ),
        on_log=lambda e: typer.echo(
            f"step {int(e['step']):>6}  loss {e['loss']:.4f}  lr {e['lr']:.2e}  {e['seconds']:.0f} s"
        ),
    )
    typer.echo(f"wrote {out} ({result.steps_done} steps, {result.seconds:.0f} s)")


@app.command("eval")
@_friendly
def eval_(
    protocol: Annotated[
        str,
        typer.Argument(
            help=_protocol_help(),
        ),
    ],
    out: Annotated[
        Path, typer.Option("--out", "-o", help="Results folder (results.md/csv/json; per-fold files to resume).")
    ],
    model: ModelOpt = None,
    variant: Annotated[str, typer.Option("--variant", help="kt3d-loo: 'vanilla' or 'augment'.")] = "vanilla",
    frames: Annotated[
        int | None,
        typer.Option(
            "--frames",
            "-f",
            help="Trajectory length (default: 5; 2 for adelaide; hopkins-test 0 = all frames, resampled to the model's).",
        ),
    ] = None,
    init: Annotated[Path | None, typer.Option("--init", help="LOO folds start from this checkpoint.")] = None,
    steps: Annotated[int | None, typer.Option("--steps", min=1, help="Training steps per fold.")] = None,
    batch_size: Annotated[int | None, typer.Option("--batch-size", min=1)] = None,
    lr: Annotated[float | None, typer.Option("--lr")] = None,
    loss: Annotated[
        str | None, typer.Option("--loss", help="Per-fold training loss: l2 (default), ce or mimi.")
    ] = None,
    synthetic_weight: Annotated[
        float, typer.Option("--synthetic-weight", help="LOO: weight of synthetic clips mixed into each fold.")
    ] = 0.0,
    baselines: Annotated[
        str, typer.Option("--baselines", help="Comma-separated baselines ('' for none).")
    ] = "kmeans-raw,spectral-raw,ssc",
    folds: Annotated[str | None, typer.Option("--folds", help="Comma-separated held-out names (default: all).")] = None,
    k_method: KMethod = KMethodChoice.silhouette,
    k_max: KMax = 8,
    data_root: DataRoot = None,
    threads: Annotated[int, typer.Option("--threads", min=1)] = 1,
    verbose: Verbose = False,
) -> None:
    """Run a benchmark protocol: per-clip table, mean/median error, NMI, correct K, time, baselines."""
    _setup(threads, verbose)
    from mosegpipe.evaluation.protocols import EvalRequest, get_protocol

    proto = get_protocol(protocol)
    k_method = _value(k_method)
    check_choice("--k-method", k_method, get_args(KMethodName))
    request = EvalRequest(
        out_dir=out,
        data_root=_data_root(data_root) if proto.data else data_root,
        model=model,
        init=init,
        frames=frames,
        variant=variant,
        steps=steps,
        batch_size=batch_size,
        lr=lr,
        loss=loss,
        synthetic_weight=synthetic_weight,
        baselines=tuple(b for b in baselines.split(",") if b),
        folds=tuple(folds.split(",")) if folds else None,
        k_method=k_method,
        k_max=k_max,
        progress=typer.echo,
    )
    result = proto.run(proto, request)
    typer.echo(result.table)
    typer.echo(f"wrote {out}/results.md, results.csv, results.json")


def _study_help() -> str:
    """The study names from the registry, each with the part of the paper it reproduces."""
    from mosegpipe.evaluation.studies import STUDIES

    return "; ".join(f"{s.name} ({s.paper})" for s in STUDIES.values()) + "."


@app.command()
@_friendly
def study(
    name: Annotated[str, typer.Argument(help=_study_help())],
    out: Annotated[
        Path, typer.Option("--out", "-o", help="Results folder (table.md, results.json, plot.png; parts/ to resume).")
    ],
    budget: Annotated[
        str, typer.Option("--budget", help="'cpu' (fits a small CPU machine) or 'full' (the paper's scale).")
    ] = "cpu",
    model: Annotated[
        Path | None, typer.Option("--model", help="A 5-frame checkpoint for the KT3DMoSeg clips (default: shipped).")
    ] = None,
    pair_model: Annotated[
        Path | None,
        typer.Option("--pair-model", help="A two-view checkpoint for the AdelaideRMF pairs (default: shipped)."),
    ] = None,
    clips: Annotated[
        str | None,
        typer.Option("--clips", help="tsne: comma-separated KT3DMoSeg sequences / AdelaideRMF pairs."),
    ] = None,
    k_max: KMax = 8,
    data_root: DataRoot = None,
    threads: Annotated[int, typer.Option("--threads", min=1)] = 1,
    verbose: Verbose = False,
) -> None:
    """Run a study of the paper: prints and writes a table, results.json and a plot; a re-run skips finished parts."""
    _setup(threads, verbose)
    from mosegpipe.evaluation.studies import StudyRequest, get_study

    chosen = get_study(name)
    _check_model_path(model)
    if pair_model is not None and not pair_model.is_file():
        raise InputError(f"{pair_model}: checkpoint file not found (--pair-model)")
    request = StudyRequest(
        out_dir=out,
        data_root=_data_root(data_root) if chosen.needs_data else data_root,
        budget=budget,
        model=model,
        pair_model=pair_model,
        clips=tuple(c.strip() for c in clips.split(",") if c.strip()) if clips else None,
        k_max=k_max,
        progress=typer.echo if verbose else None,
    )
    result = chosen.run(chosen, request)
    typer.echo(result.table)
    typer.echo(f"wrote {', '.join(str(p) for p in result.files)}")


if __name__ == "__main__":
    app()
