"""moseg run (a clip, or a whole video with --whole), moseg pair (two images) and moseg tracks (point
tracks made elsewhere): parse the options, one library call, print."""

from __future__ import annotations

import time
from enum import StrEnum
from pathlib import Path
from typing import Annotated, Any

import typer

from mosegpipe.cli.app import friendly, setup_run
from mosegpipe.cli.common import (
    check_model_path,
    default_out_here,
    frames_progress,
    lock_out,
    print_summary,
    print_total,
    print_tracks_summary,
    print_video_summary,
)
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
    Overwrite,
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
    enum_value,
    option_blocks,
    pipeline_cfg,
)
from mosegpipe.errors import InputError
from mosegpipe.settings import MAX_FRAME_INDEX, MAX_FRAMES
from mosegpipe.types import PRESET_NAMES, SEGMENT_METHODS, TRACKERS


class RunOutputs(StrEnum):
    """What `moseg run --outputs` writes."""

    all = "all"
    masks = "masks"


@friendly
@option_blocks
def run(
    clip: Annotated[Path, typer.Argument(help="A video file OpenCV can read, or a folder of frames.")],
    frames: Annotated[
        int,
        typer.Option(
            "--frames",
            "-f",
            min=2,
            max=MAX_FRAMES,
            help=f"Frames to segment, 2..{MAX_FRAMES} (the paper uses 5); with --whole, the window length.",
        ),
    ] = 5,
    start: Start = 0,
    out: Annotated[
        Path | None,
        typer.Option("--out", "-o", help="Output folder (default: in the current folder, the clip's name + '_moseg')."),
    ] = None,
    whole: Annotated[
        bool,
        typer.Option(
            "--whole", help="Segment the whole video (from --start) in consecutive windows of --frames frames."
        ),
    ] = False,
    max_frames: Annotated[
        int | None,
        typer.Option("--max-frames", min=1, max=MAX_FRAME_INDEX, help="With --whole: stop after this many frames."),
    ] = None,
    shot_cuts: Annotated[
        bool,
        typer.Option(
            "--shot-cuts/--no-shot-cuts",
            help="With --whole: a frame into which fewer than a quarter of the tracks survive is a shot cut; "
            "tracking and windows start afresh there.",
        ),
    ] = True,
    clustering: ClusterOptions = ClusterOptions(),
    method: Method = MethodChoice(SEGMENT_METHODS[0]),
    points: Points = PointsChoice(TRACKERS[0]),
    rigid_check: RigidCheck = RIGID_CHECK,
    tracker: TrackerOptions = TrackerOptions(),
    masks: MaskOptions = MaskOptions(),
    mask_extra_tracks: MaskExtraTracks = MASK_EXTRA_TRACKS,
    preset: Preset = PresetChoice(PRESET_NAMES[0]),
    max_side: MaxSide = None,
    outputs: Annotated[
        RunOutputs,
        typer.Option(
            "--outputs",
            help="all: masks, labels.npz, overlays, overlay.mp4, recording.rrd; masks: masks/, labels.npz and "
            "summary.json only (no overlays, no recording).",
        ),
    ] = RunOutputs.all,
    model: ModelOpt = None,
    overwrite: Overwrite = False,
    no_rrd: NoRrd = False,
    config: ConfigOpt = None,
    quiet: Quiet = False,
    threads: Threads = 1,
    verbose: Verbose = False,
) -> None:
    """Segment the motions in --frames frames of CLIP from --start (or the whole video with --whole).

    Writes summary.json, labels.npz, masks/ (palette PNGs), overlay/ (--whole: overlay.mp4) and
    recording.rrd into the output folder (--outputs masks: the masks only); see docs/OUTPUTS.md; `moseg
    export` turns the masks into per-object PNGs, alpha mattes or a cut-out video. With --whole a progress
    bar with the time left is drawn on stderr when it is a terminal. Exit code 1 with one 'moseg: error:' line on failure.
    """
    started = time.perf_counter()
    # Paths and option combinations first: the libraries take a second to import.
    if not clip.exists():
        raise InputError(f"{clip}: no such file or folder")
    if max_frames is not None and not whole:
        raise InputError("--max-frames only applies with --whole (without it, --frames frames are read)")
    if not shot_cuts and not whole:
        raise InputError("--no-shot-cuts only applies with --whole (a clip of --frames frames is one shot)")
    if whole and enum_value(points) != "klt":
        raise InputError(
            f"--points {enum_value(points)}: clips only (--whole tracks KLT corners from window to window)"
        )
    check_model_path(model)
    setup_run(threads, verbose, "mosegpipe.apps.outputs")
    from mosegpipe.apps.outputs import check_output_dir, write_clip_outputs
    from mosegpipe.apps.video_outputs import write_video_outputs
    from mosegpipe.embed.numpy_net import load_embedder
    from mosegpipe.pipeline import segment_clip

    cfg = pipeline_cfg(
        frames,
        clustering,
        segment_method=method,
        points=points,
        start=start,
        rigid_check=rigid_check,
        shot_cuts=shot_cuts,
        tracker=tracker,
        masks=masks,
        mask_extra_tracks=mask_extra_tracks,
        preset=preset,
        max_side=max_side,
    )
    views = outputs == RunOutputs.all
    rrd = views and not no_rrd
    out = out or default_out_here(clip, "_moseg")
    lock_out(out)
    check_output_dir(out, overwrite)
    _import_ahead(cfg, whole=whole, rrd=rrd)
    net = load_embedder(frames, model)
    if whole:
        with frames_progress(clip, cfg, max_frames, quiet) as on_window:
            summary = write_video_outputs(
                clip, out, cfg, net, overwrite, rrd, max_frames, on_window=on_window, overlays=views
            )
        print_video_summary(summary, out, rrd)
        print_total(started)
        return
    result = segment_clip(clip, cfg, net)
    summary = write_clip_outputs(result, out, cfg, overwrite=overwrite, rrd=rrd, overlays=views)
    print_summary(summary, out)
    print_total(started)


def _import_ahead(cfg: Any, whole: bool = False, rrd: bool = True) -> None:
    """What only `run`'s later steps need loads on a thread of its own while the frames are read and tracked
    (runtime.import_ahead), in the order the steps ask for it: SciPy for the rigid-motion check and the
    world, scikit-image's thresholds for the motion masks, SciPy's assignment for a video's label memory,
    PyAV and Pillow for the files, Rerun for the recording."""
    from mosegpipe.runtime import LATER_IMPORTS, import_ahead

    unneeded = {
        *([] if cfg.mask.method == "motion" else ["skimage.filters.thresholding"]),
        *([] if whole else ["scipy.optimize"]),
    }
    import_ahead(
        *(name for name in LATER_IMPORTS if name not in unneeded),
        "av",
        "PIL.Image",
        *(["rerun", "rerun.blueprint"] if rrd else []),
    )


@friendly
@option_blocks
def pair(
    img1: Annotated[Path, typer.Argument(help="First image.")],
    img2: Annotated[Path, typer.Argument(help="Second image (may differ in size).")],
    out: Annotated[
        Path | None,
        typer.Option(
            "--out", "-o", help="Output folder (default: in the current folder, IMG1's name + '_pair_moseg')."
        ),
    ] = None,
    clustering: ClusterOptions = ClusterOptions(),
    masks: MaskOptions = MaskOptions(),
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
    check_model_path(model)
    setup_run(threads, verbose, "mosegpipe.apps.outputs")
    from mosegpipe.apps.outputs import check_output_dir, write_pair_outputs
    from mosegpipe.embed.numpy_net import load_embedder
    from mosegpipe.pipeline import segment_pair

    cfg = pipeline_cfg(2, clustering, masks=masks)
    out = out or default_out_here(img1, "_pair_moseg")
    lock_out(out)
    check_output_dir(out, overwrite)
    result = segment_pair(img1, img2, cfg, load_embedder(2, model))
    summary = write_pair_outputs(result, out, cfg, overwrite=overwrite, sources=(str(img1), str(img2)), rrd=not no_rrd)
    print_summary(summary, out)
    print_total(started)


def read_tracks_file(path: Path) -> tuple[Any, Any]:
    """(N, T, 2) positions and (N, T) visibility from a .npz of point tracks.

    Accepted layouts (arrays by name): `xy` (N, T, 2) with optional `visible` (N, T) (ours);
    `tracks` (T, N, 2) or (1, T, N, 2) with optional `visibility` (T, N) or (1, T, N) (CoTracker's
    time-first output); `tracks` (N, T, 2) with `occluded` (N, T) (TAPIR: visible = not occluded).

    Raises:
        InputError: not a readable .npz, or none of the layouts.
    """
    import zipfile

    import numpy as np

    unreadable = f"{path}: not a readable .npz file (numpy.savez, no pickled objects)"
    try:
        loaded = np.load(path, allow_pickle=False)
        if not isinstance(loaded, np.lib.npyio.NpzFile):  # a .npy (one array) under a .npz name
            raise InputError(f"{path}: a single .npy array, not a .npz archive of named arrays (numpy.savez)")
        with loaded as data:
            arrays = {name: data[name] for name in data.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:  # BadZipFile: a truncated archive
        raise InputError(f"{unreadable}: {exc}") from exc
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


@friendly
@option_blocks
def tracks(
    file: Annotated[Path, typer.Argument(help="A .npz of point tracks from another tracker (layouts: docs/CLI.md).")],
    out: Annotated[
        Path | None,
        typer.Option("--out", "-o", help="Output folder (default: in the current folder, FILE's name + '_moseg')."),
    ] = None,
    start: Start = 0,
    frames: Annotated[
        int | None,
        typer.Option(
            "--frames",
            "-f",
            min=2,
            max=MAX_FRAMES,
            help=f"Window length, 2..{MAX_FRAMES} (default: from --start to the last frame).",
        ),
    ] = None,
    clustering: ClusterOptions = ClusterOptions(),
    method: Method = MethodChoice(SEGMENT_METHODS[0]),
    rigid_check: RigidCheck = RIGID_CHECK,
    model: ModelOpt = None,
    video: Annotated[
        Path | None,
        typer.Option(
            "--video",
            help="The video (or frame folder) the tracks were made on, frame t of the tracks = its frame t: also "
            "write masks/, overlay/, overlay.mp4 and recording.rrd, as moseg run does.",
        ),
    ] = None,
    overwrite: Overwrite = False,
    no_rrd: NoRrd = False,
    config: ConfigOpt = None,
    threads: Threads = 1,
    verbose: Verbose = False,
) -> None:
    """Segment point tracks made elsewhere (CoTracker, TAPIR, ...) with our embedding and clustering.

    Tracks visible in every frame of the window (--frames frames from --start) are segmented;
    summary.json and labels.npz (label of every track, -1 = not visible throughout) go into the
    output folder; with --video, also the masks, overlays and recording of the window's frames.
    """
    started = time.perf_counter()
    if not file.is_file():
        raise InputError(f"{file}: no such file")
    if video is not None and not video.exists():
        raise InputError(f"{video}: no such file or folder")
    check_model_path(model)
    setup_run(threads, verbose, "mosegpipe.apps.outputs")
    from mosegpipe.apps.outputs import check_output_dir, write_tracks_outputs
    from mosegpipe.embed.numpy_net import load_embedder
    from mosegpipe.pipeline import segment_tracks, tracks_clip

    xy, visible = read_tracks_file(file)
    window = frames if frames is not None else (xy.shape[1] - start if getattr(xy, "ndim", 0) == 3 else 2)
    cfg = pipeline_cfg(max(2, window), clustering, segment_method=method, start=start, rigid_check=rigid_check)
    out = out or default_out_here(file, "_moseg")
    lock_out(out)
    check_output_dir(out, overwrite)
    net = load_embedder(max(2, window), model)
    try:
        result = segment_tracks(xy, visible, cfg, net, start=start, frames=frames)
    except InputError as exc:  # everything segment_tracks refuses is in the file: name it
        raise type(exc)(f"{file}: {exc}") from exc
    clip = None if video is None else tracks_clip(result, video, cfg)
    summary = write_tracks_outputs(result, out, cfg, source=str(file), overwrite=overwrite, clip=clip, rrd=not no_rrd)
    print_tracks_summary(summary, out)
    print_total(started)
