"""The `moseg` command: a thin Typer layer over mosegpipe.pipeline, batch, train and evaluate.

Only this layer prints, and only here does a MosegError become one line on stderr and exit code 1.
"""

from __future__ import annotations

import contextlib
import functools
import importlib
import logging
import os
import re
import signal
import sys
import time
from collections.abc import Callable
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


def _bad_value(exc: Any) -> str:
    """The reason in a BadParameter, one line, without the validator's "Value error, " prefix."""
    return _one_line(exc.message).removeprefix("Value error, ").rstrip(".")


def _usage_message(exc: Any, args: list[str]) -> str:
    """One line for a usage error; a bad option value is named with the value given (`--frames 0: ...`)."""
    param = getattr(exc, "param", None)
    if isinstance(exc, _click.exceptions.BadParameter) and param is not None and getattr(param, "opts", None):
        for i, arg in enumerate(args):
            for opt in param.opts:
                if arg == opt and i + 1 < len(args):
                    return f"{opt} {args[i + 1]}: {_bad_value(exc)}"
                if arg.startswith(f"{opt}="):
                    return f"{opt} {arg[len(opt) + 1 :]}: {_bad_value(exc)}"
        missing = isinstance(exc, _click.exceptions.MissingParameter)
        if not missing and not any(opt.startswith("-") for opt in param.opts):  # PROTOCOL: 'x' is not one of ...
            return f"{param.name.upper()}: {_bad_value(exc)}"
    return _one_line(exc.format_message()).replace(": Value error, ", ": ").rstrip(".")


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


def _setup(threads: int, verbose: bool, *preload: str) -> None:
    """Logging, native log levels and thread counts; then `preload`, the modules the command imports
    next (names for importlib), imported with the collector paused (see runtime.collector_paused)."""
    from mosegpipe.runtime import collector_paused, set_threads

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
    with collector_paused("sklearn"):
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
Quiet = Annotated[
    bool,
    typer.Option(
        "--quiet", "-q", help="No progress bar (it is drawn on stderr only when stderr is a terminal anyway)."
    ),
]
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


class MaskMethodChoice(StrEnum):
    """--mask-method: the values of mosegpipe.masks.MASK_METHODS (a test keeps them equal)."""

    watershed = "watershed"
    nearest = "nearest"
    vote = "vote"


class PresetChoice(StrEnum):
    """train --preset: the names of mosegpipe.training.recipes.RECIPES (a test keeps them equal)."""

    clip_f5 = "clip-f5"
    clip_f5_rendered = "clip-f5-rendered"
    base_f5 = "base-f5"
    synthetic_f5 = "synthetic-f5"
    pair_f2 = "pair-f2"
    synthetic_f2 = "synthetic-f2"
    lce = "lce"


class LossChoice(StrEnum):
    """--loss: the names of mosegpipe.training.losses.LOSSES (a test keeps them equal)."""

    mimi = "mimi"
    l2 = "l2"
    l2_balanced = "l2-balanced"
    ce = "ce"
    triplet = "triplet"
    lifted = "lifted"
    facility = "facility"


class ProtocolChoice(StrEnum):
    """eval PROTOCOL: the names of mosegpipe.evaluation.protocols.PROTOCOLS (a test keeps them equal)."""

    kt3d_test = "kt3d-test"
    kt3d_loo = "kt3d-loo"
    adelaide_test = "adelaide-test"
    adelaide_loo = "adelaide-loo"
    hopkins_test = "hopkins-test"
    lce = "lce"
    kt3d_video = "kt3d-video"
    adelaide_pairs = "adelaide-pairs"
    kt3d_video_loo = "kt3d-video-loo"
    adelaide_pairs_loo = "adelaide-pairs-loo"
    rendered = "rendered"
    rendered_long = "rendered-long"


class VariantChoice(StrEnum):
    """eval --variant: the values of mosegpipe.evaluation.protocols.Variant (a test keeps them equal)."""

    vanilla = "vanilla"
    augment = "augment"


class StudyChoice(StrEnum):
    """study NAME: the names of mosegpipe.evaluation.studies.STUDIES (a test keeps them equal)."""

    model_selection = "model-selection"
    tsne = "tsne"
    sampling_imbalance = "sampling-imbalance"
    lce_curve = "lce-curve"
    losses = "losses"
    weak_supervision = "weak-supervision"
    embedding_dim = "embedding-dim"
    networks = "networks"
    depth = "depth"


class BudgetChoice(StrEnum):
    """study --budget: the values of mosegpipe.evaluation.studies.Budget (a test keeps them equal)."""

    cpu = "cpu"
    full = "full"


BASELINE_NAMES = ("kmeans-raw", "spectral-raw", "ssc")
"""eval --baselines: the names of mosegpipe.evaluation.baselines.BASELINES (a test keeps them equal)."""


def _value(choice: Any) -> Any:
    """The plain value of an Enum choice (what the library and summary.json take)."""
    return choice.value if isinstance(choice, Enum) else choice


KMethod = Annotated[
    KMethodChoice,
    typer.Option("--k-method", help="Automatic K: silhouette (default, more often right) or residual (faster)."),
]
KMax = Annotated[int, typer.Option("--k-max", min=1, help="Largest K considered by automatic K.")]
RigidCheck = Annotated[
    bool,
    typer.Option(
        "--rigid-check/--no-rigid-check",
        help="After automatic K, split off groups of tracks that their cluster's rigid motion does not explain.",
    ),
]
ModelOpt = Annotated[Path | None, typer.Option("--model", help="A checkpoint instead of the shipped weights.")]
Overwrite = Annotated[bool, typer.Option("--overwrite", help="Replace results already in the output folder.")]
NoRrd = Annotated[bool, typer.Option("--no-rrd", help="Skip the Rerun recording.")]
Start = Annotated[
    int,
    typer.Option(
        "--start",
        min=0,
        help="First frame to segment: its 0-based index in the video or frame folder (masks keep the source's frame numbers).",
    ),
]

# Tracker and mask settings. The defaults are the library's (TrackConfig, MaskConfig; a test keeps them
# equal), written out here so that --help shows them without importing OpenCV.
_TRACKER = "Tracker (KLT)"
_MASKS = "Dense masks"
MaxCorners = Annotated[
    int,
    typer.Option(
        "--max-corners",
        min=1,
        help="Corners detected and tracked (Shi-Tomasi); more tracks cost more time.",
        rich_help_panel=_TRACKER,
    ),
]
MinDistance = Annotated[
    float,
    typer.Option(
        "--min-distance",
        min=0.0,
        help="Minimum spacing between corners, pixels: a coarser grid of tracks over the whole image.",
        rich_help_panel=_TRACKER,
    ),
]
Quality = Annotated[
    float,
    typer.Option(
        "--quality",
        min=0.0,
        max=1.0,
        help="Corner quality threshold relative to the strongest corner, in (0, 1]; lower keeps weakly textured areas.",
        rich_help_panel=_TRACKER,
    ),
]
WinSize = Annotated[
    int,
    typer.Option(
        "--win-size",
        min=3,
        help="Lucas-Kanade window, pixels: larger follows faster motion and blur, smaller is more precise.",
        rich_help_panel=_TRACKER,
    ),
]
MaskMethod = Annotated[
    MaskMethodChoice,
    typer.Option(
        "--mask-method",
        help="Dense masks from track labels: watershed (default: follows image edges), nearest (nearest track) or vote.",
        rich_help_panel=_MASKS,
    ),
]
MaskMaxDistance = Annotated[
    float,
    typer.Option(
        "--mask-max-distance",
        min=0.0,
        help="Pixels farther than this from every labelled track stay unknown (255); must be > 0.",
        rich_help_panel=_MASKS,
    ),
]
MaskMinAgree = Annotated[
    int,
    typer.Option(
        "--mask-min-agree",
        min=1,
        help="Watershed: a track seeds its label only when this many of its 5 nearest tracks (itself included) carry it (1 = every track).",
        rich_help_panel=_MASKS,
    ),
]
MaskMedian = Annotated[
    int,
    typer.Option(
        "--mask-median",
        min=0,
        help="Median filter over the label image, pixels (odd, >= 3; 0 = off): smoother borders, no specks.",
        rich_help_panel=_MASKS,
    ),
]
MaskScale = Annotated[
    float,
    typer.Option(
        "--mask-scale",
        min=0.0,
        max=1.0,
        help="Watershed floods the image scaled by this, in (0, 1] (0.5 costs a quarter of the time).",
        rich_help_panel=_MASKS,
    ),
]
MaskExtraTracks = Annotated[
    int,
    typer.Option(
        "--mask-extra-tracks",
        min=0,
        help="Clips: up to this many more corners, spread over the image, tracked and labelled by motion "
        "for the masks only (0 = off; not used by --whole).",
        rich_help_panel=_MASKS,
    ),
]

TRACKER_DEFAULTS = {"max_corners": 1000, "min_distance_px": 7.0, "quality_level": 0.01, "win_size_px": 21}
"""TrackConfig fields set by --max-corners, --min-distance, --quality, --win-size, with their defaults."""
MASK_DEFAULTS = {"method": "watershed", "max_distance_px": 40.0, "min_agree": 1, "median_px": 0, "scale": 1.0}
"""MaskConfig fields set by --mask-method, --mask-max-distance, --mask-min-agree, --mask-median, --mask-scale."""


def _tracker(max_corners: int, min_distance: float, quality: float, win_size: int) -> dict[str, Any]:
    """The TrackConfig fields of the tracker options."""
    return dict(zip(TRACKER_DEFAULTS, (max_corners, min_distance, quality, win_size)))


def _masks(
    method: Any, max_distance: float, min_agree: int, median: int, scale: float, extra_tracks: int | None = None
) -> dict[str, Any]:
    """The MaskConfig fields of the mask options (extra_tracks: `run` and `batch` only; None = not an option)."""
    fields = dict(zip(MASK_DEFAULTS, (_value(method), max_distance, min_agree, median, scale)))
    return fields if extra_tracks is None else {**fields, "extra_tracks": extra_tracks}


def _protocol_help() -> str:
    """The protocol names from the registry: benchmark ones, then end-to-end ones."""
    from mosegpipe.evaluation.protocols import PROTOCOLS

    bench = [p.name for p in PROTOCOLS.values() if p.kind == "benchmark"]
    e2e = [p.name for p in PROTOCOLS.values() if p.kind == "end-to-end"]
    return f"{', '.join(bench)}; end to end: {', '.join(e2e)}."


def _check_settings(track: dict[str, Any], mask: dict[str, Any], vote_k: int) -> None:
    """What the option ranges cannot say, as one error line naming the option."""
    quality, scale = track.get("quality_level"), mask.get("scale")
    if quality is not None and not 0 < quality <= 1:
        raise InputError(f"--quality {quality:g}: must be in (0, 1]")
    if mask.get("max_distance_px") is not None and mask["max_distance_px"] <= 0:
        raise InputError(f"--mask-max-distance {mask['max_distance_px']:g}: must be > 0")
    if scale is not None and not 0 < scale <= 1:
        raise InputError(f"--mask-scale {scale:g}: must be in (0, 1]")
    median = mask.get("median_px")
    if median is not None and median not in (0, 1) and (median < 3 or median % 2 == 0):
        raise InputError(f"--mask-median {median}: must be 0 (off) or an odd number >= 3")
    agree = mask.get("min_agree")
    if agree is not None and not 1 <= agree <= vote_k:
        raise InputError(f"--mask-min-agree {agree}: must be in 1..{vote_k} (the nearest tracks consulted)")


def _pipeline_cfg(
    frames: int,
    k: int | None,
    k_method: str,
    k_max: int,
    *,
    start: int = 0,
    rigid_check: bool = True,
    shot_cuts: bool = True,
    track: dict[str, Any] | None = None,
    mask: dict[str, Any] | None = None,
) -> Any:
    """The PipelineConfig of a command's options; `track` and `mask` hold TrackConfig / MaskConfig fields."""
    from mosegpipe.cluster import ClusterConfig
    from mosegpipe.masks import MASK_METHODS, MaskConfig
    from mosegpipe.pipeline import PipelineConfig
    from mosegpipe.rigid import RigidCheckConfig
    from mosegpipe.track import TrackConfig

    method = cast(KMethodName, check_choice("--k-method", _value(k_method), get_args(KMethodName)))
    track = dict(track or {})
    mask = {name: _value(value) for name, value in (mask or {}).items()}
    if mask.get("method", "watershed") not in MASK_METHODS:
        raise InputError(f"--mask-method {mask['method']!r}: choose {', '.join(map(repr, MASK_METHODS))}")
    _check_settings(track, mask, MaskConfig().vote_k)
    try:
        track_cfg = replace(TrackConfig(), **track)
        mask_cfg = replace(MaskConfig(), **mask)
    except ValueError as exc:  # the checks above should have caught it; still one line, not a traceback
        raise InputError(_one_line(str(exc))) from exc
    return PipelineConfig(
        frames=frames,
        start=start,
        k=k,
        track=track_cfg,
        cluster=replace(ClusterConfig(), method=method, k_max=k_max),
        rigid=RigidCheckConfig(enabled=rigid_check),
        mask=mask_cfg,
        video_cut_survival=PipelineConfig().video_cut_survival if shot_cuts else None,
    )


# ---------------------------------------------------------------------------------------------
# --config FILE.toml: option values from a file (the command line wins)
# ---------------------------------------------------------------------------------------------

CONFIG_COMMANDS = ("run", "pair", "batch", "tracks")
"""The commands that take --config (a [table] named after one of them applies to that command only)."""


class _ConfigError(_click.exceptions.ClickException):
    """A bad config file: one 'moseg: error:' line and exit code 1 (not a usage error)."""

    exit_code = 1


def _option_hints(command: str) -> dict[str, Any]:
    """The Python type of each parameter of a command (Annotated and Optional stripped)."""
    import types
    import typing

    fn = next(c.callback for c in app.registered_commands if (c.name or getattr(c.callback, "__name__", "")) == command)
    hints = {}
    for name, hint in typing.get_type_hints(fn).items():
        union = typing.get_origin(hint) in (typing.Union, types.UnionType)
        hints[name] = next(a for a in get_args(hint) if a is not type(None)) if union else hint
    return hints


def _toml_value(value: Any, kind: Any, where: str, folder: Path) -> Any:
    """A value from the file checked against the option's type (TOML types, no coercion from strings)."""
    expected = {bool: "true or false", int: "an integer", float: "a number"}.get(kind, "a string")
    if kind is bool:
        ok = isinstance(value, bool)
    elif kind is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif kind is float:
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
    else:
        ok = isinstance(value, str)
    if not ok:
        raise _ConfigError(f"{where}: expected {expected}, got {value!r}")
    if kind is Path:
        path = Path(value).expanduser()
        return str(path if path.is_absolute() else (folder / path).resolve())  # relative to the file, not the shell
    return value


def _config_defaults(path: Path, ctx: Any) -> dict[str, Any]:
    """Option values from a TOML file, checked as the command line would check them, keyed by parameter name."""
    import tomllib

    command = ctx.info_name or ""
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise _ConfigError(f"{path}: no such config file (--config)") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise _ConfigError(f"{path}: cannot read the config file ({getattr(exc, 'strerror', None) or exc})") from None
    except tomllib.TOMLDecodeError as exc:
        raise _ConfigError(f"{path}: not valid TOML ({_one_line(str(exc))})") from None
    options = {
        opt[2:]: param
        for param in ctx.command.params
        if param.name not in ("config", "help")
        for opt in param.opts
        if opt.startswith("--")
    }
    for key, value in data.items():
        if isinstance(value, dict) and key not in CONFIG_COMMANDS:
            raise _ConfigError(f"{path}: unknown table [{key}] (tables: {', '.join(CONFIG_COMMANDS)})")
    # The top level first, then this command's table: its values win.
    values = {key: value for key, value in data.items() if not isinstance(value, dict)}
    table = data.get(command)
    values |= {f"{command}.{key}": value for key, value in table.items()} if isinstance(table, dict) else {}
    hints = _option_hints(command)
    defaults: dict[str, Any] = {}
    for key, value in values.items():
        name = key.rsplit(".", 1)[-1]
        param = options.get(name.replace("_", "-"))
        if param is None:
            import difflib

            close = difflib.get_close_matches(name.replace("_", "-"), list(options), n=1)
            hint = f"; did you mean {close[0]!r}?" if close else f" (options: {', '.join(sorted(options))})"
            raise _ConfigError(f"{path}: unknown key {key!r} for 'moseg {command}'{hint}")
        where = f"{path}: {key}"
        raw = _toml_value(value, hints.get(param.name, str), where, path.parent)
        try:
            param.process_value(ctx, raw)
        except _click.exceptions.BadParameter as exc:
            raise _ConfigError(f"{where} = {value!r}: {_bad_value(exc)}") from None
        defaults[param.name] = raw
    return defaults


def _load_config(ctx: typer.Context, param: typer.CallbackParam, value: Path | None) -> Path | None:
    """--config callback (eager: it runs before the other options pick their defaults)."""
    if value is not None and not ctx.resilient_parsing:
        ctx.default_map = {**(ctx.default_map or {}), **_config_defaults(value, ctx)}
    return value


ConfigOpt = Annotated[
    Path | None,
    typer.Option(
        "--config",
        is_eager=True,
        callback=_load_config,
        help="A TOML file of option values (keys: option names without '--', e.g. frames = 5, k-method = 'residual'; "
        "a [run] / [pair] / [batch] / [tracks] table applies to that command only). Options on the command line win. "
        "See docs/CLI.md.",
    ),
]


# ---------------------------------------------------------------------------------------------
# Printing
# ---------------------------------------------------------------------------------------------


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


@contextlib.contextmanager
def _frames_progress(clip: Path, cfg: Any, max_frames: int | None, quiet: bool) -> Any:
    """A progress bar over the frames of a whole-video run, on stderr; yields write_video_outputs' on_window.

    Only on a terminal: with --quiet, or when stderr is a file or a pipe (scripts, CI), nothing is
    drawn and stderr keeps only the error line or the warnings. Transient: the bar is erased when
    the run ends, so the results that follow on stdout stand alone.
    """
    if quiet or not sys.stderr.isatty():
        yield None
        return
    from rich.console import Console
    from rich.markup import escape
    from rich.progress import Progress

    from mosegpipe.pipeline import video_frames_to_read

    total = video_frames_to_read(clip, cfg, max_frames)
    with Progress(*_progress_columns(), console=Console(stderr=True), transient=True) as bar:
        task = bar.add_task(f"{escape(clip.name)} frames", total=total)
        yield lambda window: bar.update(task, completed=window.num_frames_read)


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


def _print_video_summary(summary: dict[str, Any], out: Path, rrd: bool) -> None:
    typer.echo(
        f"{summary['frames']} frames in {summary['num_windows']} windows of {summary['window_frames']} "
        f"({summary['num_windows_labelled']} labelled) -> {summary['num_motions']} motion labels"
    )
    typer.echo(f"{summary['seconds']:.1f} s, {summary['processing_fps']:.1f} frames/s")
    typer.echo(f"wrote {out}/ (summary.json, labels.npz, masks/, overlay.mp4" + (", recording.rrd)" if rrd else ")"))


def _print_tracks_summary(summary: dict[str, Any], out: Path) -> None:
    typer.echo(
        f"{_plural(summary['num_tracks_segmented'], 'track')} of {summary['num_tracks']} over {summary['frames']} "
        f"frames -> K = {summary['k']} ({summary['k_method']}) · tracks per motion {summary['tracks_per_motion']}"
    )
    if summary["k_note"]:
        typer.echo(f"note: {summary['k_note']}")
    typer.echo(f"wrote {out}/ (summary.json, labels.npz)")


# ---------------------------------------------------------------------------------------------
# Commands
# ---------------------------------------------------------------------------------------------


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
    start: Start = 0,
    out: Annotated[
        Path | None,
        typer.Option("--out", "-o", help="Output folder (default: beside the clip, named after it + '_moseg')."),
    ] = None,
    whole: Annotated[
        bool,
        typer.Option(
            "--whole", help="Segment the whole video (from --start) in consecutive windows of --frames frames."
        ),
    ] = False,
    max_frames: Annotated[
        int | None, typer.Option("--max-frames", min=1, help="With --whole: stop after this many frames.")
    ] = None,
    shot_cuts: Annotated[
        bool,
        typer.Option(
            "--shot-cuts/--no-shot-cuts",
            help="With --whole: a frame into which fewer than a quarter of the tracks survive is a shot cut; "
            "tracking and windows start afresh there.",
        ),
    ] = True,
    k: KOpt = None,
    k_method: KMethod = KMethodChoice.silhouette,
    k_max: KMax = 8,
    rigid_check: RigidCheck = True,
    max_corners: MaxCorners = 1000,
    min_distance: MinDistance = 7.0,
    quality: Quality = 0.01,
    win_size: WinSize = 21,
    mask_method: MaskMethod = MaskMethodChoice.watershed,
    mask_max_distance: MaskMaxDistance = 40.0,
    mask_min_agree: MaskMinAgree = 1,
    mask_median: MaskMedian = 0,
    mask_scale: MaskScale = 1.0,
    mask_extra_tracks: MaskExtraTracks = 1000,
    model: ModelOpt = None,
    overwrite: Overwrite = False,
    no_rrd: NoRrd = False,
    config: ConfigOpt = None,
    quiet: Quiet = False,
    threads: Threads = 1,
    verbose: Verbose = False,
) -> None:
    """Segment the motions in --frames frames of CLIP from --start (or the whole video with --whole).

    Writes summary.json, labels.npz, masks/ (palette PNGs), overlay/ and recording.rrd into the
    output folder; see docs/OUTPUTS.md. With --whole a progress bar with the time left is drawn on
    stderr when it is a terminal. Exit code 1 with one 'moseg: error:' line on failure.
    """
    started = time.perf_counter()
    # Paths and option combinations first: torch and scikit-learn take seconds to import.
    if not clip.exists():
        raise InputError(f"{clip}: no such file or folder")
    if max_frames is not None and not whole:
        raise InputError("--max-frames only applies with --whole (without it, --frames frames are read)")
    if not shot_cuts and not whole:
        raise InputError("--no-shot-cuts only applies with --whole (a clip of --frames frames is one shot)")
    _check_model_path(model)
    _setup(threads, verbose, "mosegpipe.outputs")
    from mosegpipe.inference import load_embedder
    from mosegpipe.outputs import check_output_dir, write_clip_outputs, write_video_outputs
    from mosegpipe.pipeline import segment_clip

    cfg = _pipeline_cfg(
        frames,
        k,
        k_method,
        k_max,
        start=start,
        rigid_check=rigid_check,
        shot_cuts=shot_cuts,
        track=_tracker(max_corners, min_distance, quality, win_size),
        mask=_masks(mask_method, mask_max_distance, mask_min_agree, mask_median, mask_scale, mask_extra_tracks),
    )
    out = out or _default_out(clip, "_moseg")
    check_output_dir(out, overwrite)
    net = load_embedder(frames, model)
    if whole:
        with _frames_progress(clip, cfg, max_frames, quiet) as on_window:
            summary = write_video_outputs(
                clip, out, cfg, net, overwrite=overwrite, rrd=not no_rrd, max_frames=max_frames, on_window=on_window
            )
        _print_video_summary(summary, out, not no_rrd)
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
    mask_method: MaskMethod = MaskMethodChoice.watershed,
    mask_max_distance: MaskMaxDistance = 40.0,
    mask_min_agree: MaskMinAgree = 1,
    mask_median: MaskMedian = 0,
    mask_scale: MaskScale = 1.0,
    model: ModelOpt = None,
    overwrite: Overwrite = False,
    no_rrd: NoRrd = False,
    config: ConfigOpt = None,
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
    from mosegpipe.inference import load_embedder
    from mosegpipe.outputs import check_output_dir, write_pair_outputs
    from mosegpipe.pipeline import segment_pair

    cfg = _pipeline_cfg(
        2,
        k,
        k_method,
        k_max,
        mask=_masks(mask_method, mask_max_distance, mask_min_agree, mask_median, mask_scale),
    )
    out = out or _default_out(img1, "_pair_moseg")
    check_output_dir(out, overwrite)
    result = segment_pair(img1, img2, cfg, load_embedder(2, model))
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
    start: Start = 0,
    frames: Annotated[
        int | None,
        typer.Option("--frames", "-f", min=2, help="Window length (default: from --start to the last frame)."),
    ] = None,
    k: KOpt = None,
    k_method: KMethod = KMethodChoice.silhouette,
    k_max: KMax = 8,
    rigid_check: RigidCheck = True,
    model: ModelOpt = None,
    overwrite: Overwrite = False,
    config: ConfigOpt = None,
    threads: Threads = 1,
    verbose: Verbose = False,
) -> None:
    """Segment point tracks made elsewhere (CoTracker, TAPIR, ...) with our embedding and clustering.

    Tracks visible in every frame of the window (--frames frames from --start) are segmented;
    summary.json and labels.npz (label of every track, -1 = not visible throughout) go into the
    output folder.
    """
    started = time.perf_counter()
    if not file.is_file():
        raise InputError(f"{file}: no such file")
    _check_model_path(model)
    _setup(threads, verbose, "mosegpipe.outputs")
    from mosegpipe.inference import load_embedder
    from mosegpipe.outputs import check_output_dir, write_tracks_outputs
    from mosegpipe.pipeline import segment_tracks

    xy, visible = read_tracks_file(file)
    window = frames if frames is not None else (xy.shape[1] - start if getattr(xy, "ndim", 0) == 3 else 2)
    cfg = _pipeline_cfg(max(2, window), k, k_method, k_max, start=start, rigid_check=rigid_check)
    out = out or _default_out(file, "_moseg")
    check_output_dir(out, overwrite)
    net = load_embedder(max(2, window), model)
    result = segment_tracks(xy, visible, cfg, net, start=start, frames=frames)
    summary = write_tracks_outputs(result, out, cfg, source=str(file), overwrite=overwrite)
    _print_tracks_summary(summary, out)
    _print_total(started)


@app.command()
@_friendly
def batch(
    folder: Annotated[Path, typer.Argument(help="Folder searched for video files and frame folders.")],
    out: Annotated[
        Path, typer.Option("--out", "-o", help="Output folder: one sub-folder per clip plus batch_summary.csv/json.")
    ],
    frames: Annotated[int, typer.Option("--frames", "-f", min=2, help="Frames to segment in each clip.")] = 5,
    start: Start = 0,
    k: KOpt = None,
    k_method: KMethod = KMethodChoice.silhouette,
    k_max: KMax = 8,
    rigid_check: RigidCheck = True,
    max_corners: MaxCorners = 1000,
    min_distance: MinDistance = 7.0,
    quality: Quality = 0.01,
    win_size: WinSize = 21,
    mask_method: MaskMethod = MaskMethodChoice.watershed,
    mask_max_distance: MaskMaxDistance = 40.0,
    mask_min_agree: MaskMinAgree = 1,
    mask_median: MaskMedian = 0,
    mask_scale: MaskScale = 1.0,
    mask_extra_tracks: MaskExtraTracks = 1000,
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
    config: ConfigOpt = None,
    quiet: Quiet = False,
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

    cfg = _pipeline_cfg(
        frames,
        k,
        k_method,
        k_max,
        start=start,
        rigid_check=rigid_check,
        track=_tracker(max_corners, min_distance, quality, win_size),
        mask=_masks(mask_method, mask_max_distance, mask_min_agree, mask_median, mask_scale, mask_extra_tracks),
    )
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
    with Progress(*_progress_columns(), transient=True, disable=quiet) as bar:
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


# ---------------------------------------------------------------------------------------------
# moseg replay: an earlier run again, from its summary.json
# ---------------------------------------------------------------------------------------------

REPLAY_KINDS = ("clip", "video", "pair", "tracks")
"""The summary.json kinds `moseg replay` re-runs (docs/OUTPUTS.md)."""


def _read_run_summary(path: Path) -> dict[str, Any]:
    """A run's summary.json, checked enough to replay it (kind, source, model; config in the library)."""
    import json

    if not path.is_file():
        raise InputError(f"{path}: no such file")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        raise InputError(f"{path}: not a JSON file ({_one_line(str(exc))})") from exc
    if not isinstance(data, dict) or not str(data.get("schema", "")).startswith("mosegpipe.summary/"):
        if isinstance(data, dict) and "clips" in data or path.name == "batch_summary.json":
            raise InputError(f"{path}: a batch summary; replay one clip's OUT/NAME/summary.json, or re-run the batch")
        raise InputError(f"{path}: not a moseg summary.json (no 'schema': 'mosegpipe.summary/...')")
    kind = data.get("kind")
    if kind not in REPLAY_KINDS:
        raise InputError(f"{path}: kind {kind!r} cannot be replayed (kinds: {', '.join(REPLAY_KINDS)})")
    source = data.get("source")
    sources = source if kind == "pair" else [source]
    if not isinstance(sources, list) or not sources or not all(isinstance(s, str) and s for s in sources):
        raise InputError(f"{path}: 'source' is missing or not a path: {source!r}")
    for s in sources:
        if not Path(s).exists():
            raise InputError(
                f"{s}: no such file or folder (the source recorded in {path}; relative paths are taken from "
                "the folder the run was started in)"
            )
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


@app.command()
@_friendly
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

    Same input (the recorded source path), the same frames (--start, --frames; whole-video mode and
    the frames it read), every pipeline setting (summary.json `config`: tracker, automatic K,
    masks, ...) and the same weights (the recorded --model file, or the shipped weights). Only the
    outputs (--out, --no-rrd) are chosen here. Prints whether K came out as recorded.
    """
    started = time.perf_counter()
    recorded = _read_run_summary(summary)
    _setup(threads, verbose)
    from mosegpipe.inference import load_embedder
    from mosegpipe.outputs import (
        check_output_dir,
        write_clip_outputs,
        write_pair_outputs,
        write_tracks_outputs,
        write_video_outputs,
    )
    from mosegpipe.pipeline import PipelineConfig, segment_clip, segment_pair, segment_tracks

    kind, source = recorded["kind"], recorded["source"]
    cfg = PipelineConfig.from_dict(recorded.get("config", {}), f"{summary}: config")
    out = out or _default_out(summary.parent, "_replay")
    check_output_dir(out, overwrite)
    net = load_embedder(recorded["model"]["model_frames"], recorded["model"].get("checkpoint"))
    _check_same_model(net, recorded["model"], summary)
    if kind == "video":
        clip = Path(source)
        read = recorded.get("frames")  # the frames the run read: the same ones again
        with _frames_progress(clip, cfg, read, quiet) as on_window:
            result = write_video_outputs(
                clip, out, cfg, net, overwrite=overwrite, rrd=not no_rrd, max_frames=read, on_window=on_window
            )
        _print_video_summary(result, out, not no_rrd)
        then = [w.get("k") for w in recorded.get("windows", [])]
        now = [w["k"] for w in result["windows"]]
        differ = sum(a != b for a, b in zip(then, now)) + abs(len(then) - len(now))
        typer.echo(
            f"replayed {summary}: K as recorded in all {len(now)} windows"
            if not differ
            else f"replayed {summary}: K differs from the recorded run in {differ} of {len(now)} windows"
        )
        _print_total(started)
        return
    if kind == "clip":
        written = write_clip_outputs(segment_clip(source, cfg, net), out, cfg, overwrite=overwrite, rrd=not no_rrd)
        _print_summary(written, out)
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
        _print_summary(written, out)
    else:
        xy, visible = read_tracks_file(Path(source))
        segmented = segment_tracks(xy, visible, cfg, net, start=recorded.get("start", 0), frames=recorded.get("frames"))
        written = write_tracks_outputs(segmented, out, cfg, source=source, overwrite=overwrite)
        _print_tracks_summary(written, out)
    same = written["k"] == recorded.get("k")
    typer.echo(
        f"replayed {summary}: K = {written['k']} as recorded"
        if same
        else f"replayed {summary}: K = {written['k']}, the recorded run found K = {recorded.get('k')}"
    )
    _print_total(started)


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
        PresetChoice,
        typer.Option(
            "--preset",
            help="Named recipe: clip-f5 (the shipped 5-frame model), base-f5 (its starting point), synthetic-f5, "
            "pair-f2 (the shipped two-view model), synthetic-f2, lce (the paper's LCE study).",
        ),
    ] = PresetChoice.clip_f5,
    out: Annotated[Path, typer.Option("--out", "-o", help="Checkpoint file to write.")] = Path("runs/model.pt"),
    steps: Annotated[int | None, typer.Option("--steps", min=1, help="Override the recipe's step count.")] = None,
    batch_size: Annotated[
        int | None, typer.Option("--batch-size", min=1, help="Override the recipe's clips per training step.")
    ] = None,
    lr: Annotated[float | None, typer.Option("--lr", help="Override the recipe's learning rate.")] = None,
    loss: Annotated[
        LossChoice | None,
        typer.Option(
            "--loss",
            help="Override the recipe's loss: mimi (the paper's MaxInterMinIntra), l2, l2-balanced (every pair of groups "
            "weighted alike) or ce (affinity losses), "
            "triplet, lifted or facility (the metric-learning baselines of the paper's Table 2).",
        ),
    ] = None,
    seed: Annotated[int | None, typer.Option("--seed", help="Override the recipe's random seed.")] = None,
    init: Annotated[Path | None, typer.Option("--init", help="Fine-tune from this checkpoint.")] = None,
    exclude: Annotated[
        str | None, typer.Option("--exclude", help="Comma-separated source names to leave out (leave-one-dataset-out).")
    ] = None,
    time_budget: Annotated[float | None, typer.Option("--time-budget", help="Stop after this many seconds.")] = None,
    data_root: DataRoot = None,
    threads: Annotated[int, typer.Option("--threads", min=1, help="CPU threads for torch.")] = 2,
    verbose: Verbose = False,
) -> None:
    """Train a SubspaceNet checkpoint from a named recipe (synthetic data generated on the fly).

    Without --init a recipe starts from its own starting recipe (clip-f5 from base-f5, pair-f2 from
    synthetic-f2), trained first into the --out folder when its checkpoint is not there yet.
    """
    _setup(threads, verbose)
    from mosegpipe.training.run import TrainOverrides, needs_data, train_recipe

    preset = _value(preset)
    dropped = {s.strip() for s in exclude.split(",")} if exclude else set()
    root = _data_root(data_root) if needs_data(preset, dropped) else data_root
    result = train_recipe(
        preset,
        out,
        root,
        init=init,
        overrides=TrainOverrides(
            steps=steps, batch_size=batch_size, lr=lr, loss=_value(loss), seed=seed, time_budget_s=time_budget
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
    protocol: Annotated[ProtocolChoice, typer.Argument(help=_protocol_help())],
    out: Annotated[
        Path, typer.Option("--out", "-o", help="Results folder (results.md/csv/json; per-fold files to resume).")
    ],
    model: ModelOpt = None,
    variant: Annotated[
        VariantChoice,
        typer.Option(
            "--variant", help="kt3d-loo: vanilla (the paper's protocol) or augment (with track augmentation)."
        ),
    ] = VariantChoice.vanilla,
    frames: Annotated[
        int | None,
        typer.Option(
            "--frames",
            "-f",
            help="Trajectory length (default: 5; 2 for adelaide; hopkins-test 0 = all frames, resampled to the model's).",
        ),
    ] = None,
    init: Annotated[Path | None, typer.Option("--init", help="LOO folds start from this checkpoint.")] = None,
    recipe: Annotated[
        PresetChoice | None,
        typer.Option(
            "--recipe",
            help="kt3d-video-loo / adelaide-pairs-loo: the recipe each fold trains (default: the shipped one).",
        ),
    ] = None,
    steps: Annotated[int | None, typer.Option("--steps", min=1, help="Training steps per fold.")] = None,
    batch_size: Annotated[
        int | None, typer.Option("--batch-size", min=1, help="Clips per training step of each fold.")
    ] = None,
    lr: Annotated[float | None, typer.Option("--lr", help="Learning rate of each fold.")] = None,
    loss: Annotated[
        LossChoice | None,
        typer.Option("--loss", help="Per-fold training loss (default: l2); the losses of 'moseg train --loss'."),
    ] = None,
    synthetic_weight: Annotated[
        float, typer.Option("--synthetic-weight", help="LOO: weight of synthetic clips mixed into each fold.")
    ] = 0.0,
    baselines: Annotated[
        str,
        typer.Option("--baselines", help=f"Comma-separated baselines from {', '.join(BASELINE_NAMES)} ('' for none)."),
    ] = ",".join(BASELINE_NAMES),
    folds: Annotated[str | None, typer.Option("--folds", help="Comma-separated held-out names (default: all).")] = None,
    k_method: KMethod = KMethodChoice.silhouette,
    k_max: KMax = 8,
    rigid_check: RigidCheck = True,
    data_root: DataRoot = None,
    threads: Annotated[int, typer.Option("--threads", min=1, help="CPU threads.")] = 1,
    verbose: Verbose = False,
) -> None:
    """Run a benchmark protocol: per-clip table, mean/median error, NMI, correct K, time, baselines."""
    _setup(threads, verbose)
    from mosegpipe.evaluation.protocols import EvalRequest, get_protocol

    proto = get_protocol(_value(protocol))
    k_method = _value(k_method)
    check_choice("--k-method", k_method, get_args(KMethodName))
    request = EvalRequest(
        out_dir=out,
        data_root=_data_root(data_root) if proto.data else data_root,
        model=model,
        init=init,
        frames=frames,
        variant=_value(variant),
        recipe=_value(recipe),
        steps=steps,
        batch_size=batch_size,
        lr=lr,
        loss=_value(loss),
        synthetic_weight=synthetic_weight,
        baselines=tuple(b for b in baselines.split(",") if b),
        folds=tuple(folds.split(",")) if folds else None,
        k_method=k_method,
        k_max=k_max,
        rigid_check=rigid_check,
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
    name: Annotated[StudyChoice, typer.Argument(help=_study_help())],
    out: Annotated[
        Path, typer.Option("--out", "-o", help="Results folder (table.md, results.json, plot.png; parts/ to resume).")
    ],
    budget: Annotated[
        BudgetChoice, typer.Option("--budget", help="cpu (fits a small CPU machine) or full (the paper's scale).")
    ] = BudgetChoice.cpu,
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
    threads: Annotated[int, typer.Option("--threads", min=1, help="CPU threads.")] = 1,
    verbose: Verbose = False,
) -> None:
    """Run a study of the paper: prints and writes a table, results.json and a plot; a re-run skips finished parts."""
    _setup(threads, verbose)
    from mosegpipe.evaluation.studies import StudyRequest, get_study

    chosen = get_study(_value(name))
    _check_model_path(model)
    if pair_model is not None and not pair_model.is_file():
        raise InputError(f"{pair_model}: checkpoint file not found (--pair-model)")
    request = StudyRequest(
        out_dir=out,
        data_root=_data_root(data_root) if chosen.needs_data else data_root,
        budget=_value(budget),
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
