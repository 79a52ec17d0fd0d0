"""moseg batch: every clip under a folder, with resume, fault isolation and a choice of engine."""

from __future__ import annotations

import math
import time
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, TypeAlias

import typer

from mosegpipe.cli.app import exit_with_error, friendly, setup_run
from mosegpipe.cli.common import check_model_path, print_total, progress_columns
from mosegpipe.cli.config import ConfigOpt
from mosegpipe.cli.options import (
    MASK_EXTRA_TRACKS,
    RIGID_CHECK,
    ClusterOptions,
    MaskExtraTracks,
    MaskOptions,
    MaxSide,
    Method,
    MethodChoice,
    ModelOpt,
    NoRrd,
    Points,
    PointsChoice,
    Preset,
    PresetChoice,
    Quiet,
    RigidCheck,
    Start,
    Threads,
    TrackerOptions,
    Verbose,
    choice_type,
    enum_value,
    option_blocks,
    pipeline_cfg,
)
from mosegpipe.errors import InputError
from mosegpipe.settings import MAX_CLIP_TIMEOUT_S, MAX_FRAMES
from mosegpipe.types import ENGINES, PRESET_NAMES, SEGMENT_METHODS, TRACKERS

if TYPE_CHECKING:
    EngineChoice: TypeAlias = StrEnum
else:
    EngineChoice = choice_type("EngineChoice", ENGINES)  # --engine


MAX_JOBS = 1024


def _check_clip_timeout(value: float | None) -> float | None:
    """--clip-timeout: seconds in (0, MAX_CLIP_TIMEOUT_S], refused in the words of the other options'
    bounds; NaN named as such (Click's range check called it too large)."""
    if value is None or 0 < value <= MAX_CLIP_TIMEOUT_S:
        return value
    if math.isnan(value):
        raise typer.BadParameter(f"not a number; give seconds, more than 0 and at most {MAX_CLIP_TIMEOUT_S:.0f}")
    if value > 0:
        raise typer.BadParameter(f"Input should be less than or equal to {MAX_CLIP_TIMEOUT_S:.0f}")
    raise typer.BadParameter("Input should be greater than 0")


@friendly
@option_blocks
def batch(
    folder: Annotated[Path, typer.Argument(help="Folder searched for video files and frame folders.")],
    out: Annotated[
        Path, typer.Option("--out", "-o", help="Output folder: one sub-folder per clip plus batch_summary.csv/json.")
    ],
    frames: Annotated[
        int,
        typer.Option("--frames", "-f", min=2, max=MAX_FRAMES, help=f"Frames to segment in each clip, 2..{MAX_FRAMES}."),
    ] = 5,
    start: Start = 0,
    clustering: ClusterOptions = ClusterOptions(),
    method: Method = MethodChoice(SEGMENT_METHODS[0]),
    points: Points = PointsChoice(TRACKERS[0]),
    rigid_check: RigidCheck = RIGID_CHECK,
    tracker: TrackerOptions = TrackerOptions(),
    masks: MaskOptions = MaskOptions(),
    mask_extra_tracks: MaskExtraTracks = MASK_EXTRA_TRACKS,
    preset: Preset = PresetChoice(PRESET_NAMES[0]),
    max_side: MaxSide = None,
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
            max=MAX_JOBS,
            help=f"Clips at once (1..{MAX_JOBS}): worker processes (default: the number of cores), or Ray tasks in flight with --engine ray (default: the cluster's CPUs).",
        ),
    ] = None,
    engine: Annotated[
        EngineChoice,
        typer.Option(
            "--engine",
            help="process (worker processes on this machine), ray (Ray tasks: pip install 'mosegpipe[ray]') or inline (this process, one clip after another).",
        ),
    ] = EngineChoice(ENGINES[0]),
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
            callback=_check_clip_timeout,
            help=f"Seconds a clip may run, up to {MAX_CLIP_TIMEOUT_S:g}, before its worker is killed and it is reported failed (default: no limit).",
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
    check_model_path(model)
    setup_run(threads, verbose)
    from rich.markup import escape
    from rich.progress import Progress

    from mosegpipe.apps.batch.run import check_ray, plan, run_batch
    from mosegpipe.embed.numpy_net import load_model

    cfg = pipeline_cfg(
        frames,
        clustering,
        segment_method=method,
        points=points,
        start=start,
        rigid_check=rigid_check,
        tracker=tracker,
        masks=masks,
        mask_extra_tracks=mask_extra_tracks,
        preset=preset,
        max_side=max_side,
    )
    engine = enum_value(engine)
    if address is not None and engine != "ray":
        raise InputError("--address only applies with --engine ray")
    if engine == "ray":
        check_ray(address)  # before the model is loaded and --out created
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is not a folder; choose another --out")
    items = plan(folder, out)
    if not items:
        raise InputError(f"{folder}: no video files or frame folders found")
    net = load_model(frames, model)
    with Progress(*progress_columns(), transient=True, disable=quiet) as bar:
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
    print_total(started)
    if counts["failed"]:
        exit_with_error(f"{counts['failed']} of {len(rows)} clips failed (reasons in {out}/batch_summary.csv)")
