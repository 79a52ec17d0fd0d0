"""What the segmenting commands share: the default output folder, the --model check, the progress
bar of whole-video runs and the summaries they print."""

from __future__ import annotations

import contextlib
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import typer

from mosegpipe.errors import InputError


def default_out(path: Path, suffix: str) -> Path:
    """<name><suffix> beside `path` (resolved, so that "." or "clip/" still have a name): replay's folder beside
    the run's."""
    path = path.resolve()
    return path.with_name(f"{path.stem}{suffix}")


def default_out_here(path: Path, suffix: str) -> Path:
    """<name><suffix> in the current folder, named after the input (resolved, so that "." or "clip/" still have
    a name): run's, pair's and tracks' folder without --out. Not beside the input, whose folder may be shared,
    read-only or a folder of clips that a later `moseg batch` reads."""
    return Path(f"{path.resolve().stem}{suffix}")


def lock_out(out: Path) -> None:
    """Holds the lock of output folder `out` until the command ends (mosegpipe.io.locks.output_lock): a second
    command writing there is refused in one line, and never removes the first one's work."""
    from mosegpipe.cli.app import click_api
    from mosegpipe.io.locks import output_lock

    click_api.globals.get_current_context().with_resource(output_lock(out))


def check_model_path(model: Path | None) -> None:
    if model is not None and not model.is_file():
        raise InputError(f"{model}: checkpoint file not found (--model)")


def progress_columns() -> tuple[Any, ...]:
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
def frames_progress(clip: Path, cfg: Any, max_frames: int | None, quiet: bool) -> Any:
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
    with Progress(*progress_columns(), console=Console(stderr=True), transient=True) as bar:
        task = bar.add_task(f"{escape(clip.name)} frames", total=total)
        yield lambda window: bar.update(task, completed=window.num_frames_read)


def print_total(started: float) -> None:
    typer.echo(f"total {time.perf_counter() - started:.1f} s")


def _plural(n: int, word: str, plural: str = "") -> str:
    return f"{n} {word}" if n == 1 else f"{n} {plural or word + 's'}"


def print_summary(summary: dict[str, Any], out: Path) -> None:
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
    typer.echo(f"wrote {out}/ ({_written(out)})")
    _print_view_hint(out)


def _written(out: Path) -> str:
    """What an output folder holds, in the order docs/OUTPUTS.md lists it: `summary.json, labels.npz, masks/, ...`."""
    names = ("summary.json", "labels.npz", "masks/", "overlay/", "overlay.mp4", "recording.rrd")
    return ", ".join(name for name in names if (out / name.rstrip("/")).exists())


def _print_view_hint(out: Path) -> None:
    """How to look at the recording just written (stdout, after the `wrote` line; also with --quiet,
    which only turns off the progress bar)."""
    if (out / "recording.rrd").exists():
        typer.echo(f"open it with `moseg view {out / 'recording.rrd'}`")


def print_video_summary(summary: dict[str, Any], out: Path, rrd: bool) -> None:
    typer.echo(
        f"{summary['frames']} frames in {summary['num_windows']} windows of {summary['window_frames']} "
        f"({summary['num_windows_labelled']} labelled) -> {summary['num_motions']} motion labels"
    )
    typer.echo(f"{summary['seconds']:.1f} s, {summary['processing_fps']:.1f} frames/s")
    typer.echo(f"wrote {out}/ ({_written(out)})")
    _print_view_hint(out)


def print_tracks_summary(summary: dict[str, Any], out: Path) -> None:
    typer.echo(
        f"{_plural(summary['num_tracks_segmented'], 'track')} of {summary['num_tracks']} over {summary['frames']} "
        f"frames -> K = {summary['k']} ({summary['k_method']}) · tracks per motion {summary['tracks_per_motion']}"
    )
    if summary["k_note"]:
        typer.echo(f"note: {summary['k_note']}")
    views = [name for name in ("masks/", "overlay/", "overlay.mp4", "recording.rrd") if (out / name).exists()]
    typer.echo(f"wrote {out}/ ({', '.join(['summary.json', 'labels.npz', *views])})")
    _print_view_hint(out)


def stop_child(proc: subprocess.Popen[Any], timeout_s: float = 5.0) -> None:
    """Ends a child process (a viewer or server we started): SIGTERM, then SIGKILL after timeout_s."""
    if proc.poll() is not None:
        return
    proc.terminate()
    try:
        proc.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
