"""The options the commands share, each defined once: Annotated aliases for single options and option
blocks (dataclasses of them) for the groups several commands take alike.

An option block (`ClusterOptions`, `TrackerOptions`, `MaskOptions`) is a frozen dataclass whose fields
are Annotated Typer options with their defaults. A command decorated with `option_blocks` declares one
parameter typed with the block; Typer sees the block's options in that parameter's place (so --help
lists them where they stand), and the command receives the one dataclass. `pipeline_cfg` turns the
blocks into a PipelineConfig.

Every default is the library's, read from its config classes' fields (`mosegpipe.configs`, which import no
OpenCV, so --help stays light); every check of a value is the library's: an error names the setting, and
SETTING_OPTIONS names the option that set it.
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
import math
import os
import re
import typing
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import Enum, StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, TypeAlias, cast

import typer

from mosegpipe.cli.app import F, click_api
from mosegpipe.configs import ClusterConfig, MaskConfig, RigidCheckConfig, TrackConfig
from mosegpipe.errors import InputError
from mosegpipe.settings import (
    MAX_CORNERS,
    MAX_EXTRA_TRACKS,
    MAX_FORCED_K,
    MAX_FRAME_INDEX,
    MAX_K,
    MAX_MASK_DISTANCE_PX,
    MAX_MASK_MEDIAN_PX,
    MAX_MIN_DISTANCE_PX,
    MAX_THREADS,
    MAX_WIN_SIZE_PX,
    MIN_MAX_SIDE_PX,
    SettingError,
)
from mosegpipe.types import (
    DEVICE_CHOICES,
    K_METHODS,
    MASK_METHODS,
    PRESET_NAMES,
    SEGMENT_METHODS,
    TRACKERS,
    is_device_name,
)

# The upper bounds of the numeric options are the library's (mosegpipe.settings), checked before any work
# (a usage error naming the option): past them OpenCV crashes, overflows or runs for minutes.


def choice_type(name: str, values: Sequence[str]) -> Any:
    """The choices of an option: a StrEnum of the library's vocabulary (Typer lists and checks it), the
    members named after the values (`klt+flow` -> `klt_flow`)."""
    return StrEnum(name, [(re.sub(r"\W", "_", v), v) for v in values])


if TYPE_CHECKING:
    KMethodChoice: TypeAlias = StrEnum
    MaskMethodChoice: TypeAlias = StrEnum
    MethodChoice: TypeAlias = StrEnum
    PointsChoice: TypeAlias = StrEnum
    PresetChoice: TypeAlias = StrEnum
else:
    KMethodChoice = choice_type("KMethodChoice", K_METHODS)  # --k-method
    MaskMethodChoice = choice_type("MaskMethodChoice", MASK_METHODS)  # --mask-method
    MethodChoice = choice_type("MethodChoice", SEGMENT_METHODS)  # --method
    PointsChoice = choice_type("PointsChoice", TRACKERS)  # --points
    PresetChoice = choice_type("PresetChoice", PRESET_NAMES)  # --preset

Threads = Annotated[
    int,
    typer.Option(
        "--threads",
        min=1,
        max=MAX_THREADS,
        help=f"CPU threads, 1..{MAX_THREADS} (1 is fastest for one clip on small machines).",
    ),
]


Verbose = Annotated[bool, typer.Option("--verbose", "-v", help="Log progress.")]


Quiet = Annotated[
    bool,
    typer.Option(
        "--quiet",
        "-q",
        help="No progress bar or status line (drawn only on a terminal: stderr for run, replay, live; stdout for batch).",
    ),
]


KOpt = Annotated[
    int | None,
    typer.Option(
        "--k",
        min=1,
        max=MAX_FORCED_K,
        help=f"Force this many motions, 1..{MAX_FORCED_K} and at most the tracks (default: automatic K).",
    ),
]


def _default(config: type, name: str) -> Any:
    """The default of a config class's field (the library's default of the option that sets it)."""
    return next(f.default for f in dataclasses.fields(config) if f.name == name)


def enum_value(choice: Any) -> Any:
    """The plain value of an Enum choice (what the library and summary.json take)."""
    return choice.value if isinstance(choice, Enum) else choice


KMethod = Annotated[
    KMethodChoice,
    typer.Option("--k-method", help="Automatic K: silhouette (default, more often right) or residual (faster)."),
]


Method = Annotated[
    MethodChoice,
    typer.Option(
        "--method",
        help="How tracks become motions: joint (default: the learned embedding's groups, automatic K, the "
        "rigid-motion check, then a model per group chosen by GRIC that merges, splits and moves tracks), "
        "subspacenet (the embedding, automatic K and the rigid-motion check alone) or geometric (homographies / "
        "fundamental matrices fitted one after another, automatic K; no model needed). moseg pair always uses "
        "the embedding.",
    ),
]


Points = Annotated[
    PointsChoice,
    typer.Option(
        "--points",
        help="Where a clip's points come from: klt (default: KLT corners), flow (a regular grid carried along the "
        "dense optical flow, forward-backward checked: points on untextured parts too) or klt+flow (both). "
        "Clips only: --whole tracks KLT corners.",
    ),
]


KMax = Annotated[
    int, typer.Option("--k-max", min=1, max=MAX_K, help=f"Largest K considered by automatic K, 1..{MAX_K}.")
]


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


MaxSide = Annotated[
    int | None,
    typer.Option(
        "--max-side",
        min=MIN_MAX_SIDE_PX,
        help="Segment frames whose longer side exceeds N px shrunk to N (faster on HD video); the masks are "
        "written at the input's size (labels upsampled, edges snapped to the frame's).",
    ),
]


Start = Annotated[
    int,
    typer.Option(
        "--start",
        min=0,
        max=MAX_FRAME_INDEX,
        help="First frame to segment: its 0-based index in the video or frame folder (masks keep the source's frame numbers).",
    ),
]


_TRACKER = "Tracker (KLT)"


_MASKS = "Dense masks"


MaxCorners = Annotated[
    int,
    typer.Option(
        "--max-corners",
        min=1,
        max=MAX_CORNERS,
        help=f"Corners detected and tracked (Shi-Tomasi), 1..{MAX_CORNERS}; more tracks cost more time.",
        rich_help_panel=_TRACKER,
    ),
]


MinDistance = Annotated[
    float,
    typer.Option(
        "--min-distance",
        min=0.0,
        max=MAX_MIN_DISTANCE_PX,
        help=f"Minimum spacing between corners, pixels, 0..{MAX_MIN_DISTANCE_PX:g}: a coarser grid of tracks over the whole image.",
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
        max=MAX_WIN_SIZE_PX,
        help=f"Lucas-Kanade window, pixels, 3..{MAX_WIN_SIZE_PX}: larger follows faster motion and blur, smaller is more precise.",
        rich_help_panel=_TRACKER,
    ),
]


MaskMethod = Annotated[
    MaskMethodChoice,
    typer.Option(
        "--mask-method",
        help="Dense masks: motion (default: pixels whose optical flow the camera's motion does not explain, labelled by the tracks), watershed (track labels flooded along image edges), nearest (nearest track), vote, or learned (the moving pixels "
        "from a small network instead of the hand-made steps, mosegpipe/weights/masknet.pt).",
        rich_help_panel=_MASKS,
    ),
]


Preset = Annotated[
    PresetChoice,
    typer.Option(
        "--preset",
        help="Speed against accuracy of the motion masks: best (the most accurate flow), balanced (a coarser flow, "
        "the mask steps at half size) or fast (the flow on half-size frames: about half of best's CPU, DAVIS J 0.04 "
        "lower); the other options apply after it. CPU and J of each: docs/RESULTS.md, 'Speed'.",
        rich_help_panel=_MASKS,
    ),
]


MaskMaxDistance = Annotated[
    float,
    typer.Option(
        "--mask-max-distance",
        min=0.0,
        max=MAX_MASK_DISTANCE_PX,
        help=f"Pixels farther than this from every labelled track stay unknown (255); in (0, {MAX_MASK_DISTANCE_PX:g}].",
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
        max=MAX_MASK_MEDIAN_PX,
        help=f"Median filter over the label image, pixels (odd, 3..{MAX_MASK_MEDIAN_PX}; 0 = off): smoother borders, no specks.",
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
        max=MAX_EXTRA_TRACKS,
        help=f"Clips: up to this many more corners (0..{MAX_EXTRA_TRACKS}), spread over the image, tracked and labelled by motion "
        "for the masks only (0 = off; not used by --whole).",
        rich_help_panel=_MASKS,
    ),
]


K_MAX: int = _default(ClusterConfig, "k_max")
"""--k-max's default (ClusterConfig.k_max)."""
K_METHOD: Any = KMethodChoice(_default(ClusterConfig, "method"))
"""--k-method's default (ClusterConfig.method)."""


@dataclass(frozen=True)
class ClusterOptions:
    """--k, --k-method, --k-max: how many motions (run, pair, tracks, batch)."""

    k: KOpt = None
    k_method: KMethod = K_METHOD
    k_max: KMax = K_MAX


@dataclass(frozen=True)
class TrackerOptions:
    """--max-corners, --min-distance, --quality, --win-size: the KLT tracker (run, batch). Each field's
    metadata names the TrackConfig field it sets, whose default is the option's."""

    max_corners: MaxCorners = field(default=_default(TrackConfig, "max_corners"), metadata={"config": "max_corners"})
    min_distance: MinDistance = field(
        default=_default(TrackConfig, "min_distance_px"), metadata={"config": "min_distance_px"}
    )
    quality: Quality = field(default=_default(TrackConfig, "quality_level"), metadata={"config": "quality_level"})
    win_size: WinSize = field(default=_default(TrackConfig, "win_size_px"), metadata={"config": "win_size_px"})

    def config_fields(self) -> dict[str, Any]:
        """The TrackConfig fields these options set."""
        return _config_fields(self)


@dataclass(frozen=True)
class MaskOptions:
    """--mask-method, --mask-max-distance, --mask-min-agree, --mask-median, --mask-scale: the dense masks
    (run, pair, batch; --mask-extra-tracks is an option of run and batch only). Each field's metadata
    names the MaskConfig field it sets, whose default is the option's."""

    mask_method: MaskMethod = field(
        default=MaskMethodChoice(_default(MaskConfig, "method")), metadata={"config": "method"}
    )
    mask_max_distance: MaskMaxDistance = field(
        default=_default(MaskConfig, "max_distance_px"), metadata={"config": "max_distance_px"}
    )
    mask_min_agree: MaskMinAgree = field(default=_default(MaskConfig, "min_agree"), metadata={"config": "min_agree"})
    mask_median: MaskMedian = field(default=_default(MaskConfig, "median_px"), metadata={"config": "median_px"})
    mask_scale: MaskScale = field(default=_default(MaskConfig, "scale"), metadata={"config": "scale"})

    def config_fields(self) -> dict[str, Any]:
        """The MaskConfig fields these options set."""
        return _config_fields(self)


MASK_EXTRA_TRACKS: int = _default(MaskConfig, "extra_tracks")
"""--mask-extra-tracks' default (MaskConfig.extra_tracks)."""
RIGID_CHECK: bool = _default(RigidCheckConfig, "enabled")
"""--rigid-check's default (RigidCheckConfig.enabled)."""


def _config_fields(block: TrackerOptions | MaskOptions) -> dict[str, Any]:
    given = _given()
    return {
        f.metadata["config"]: enum_value(getattr(block, f.name))
        for f in dataclasses.fields(block)
        if given is None or f.name in given
    }


def _given() -> set[str] | None:
    """The parameters of the running command that were given (on its command line or in its --config file), not
    left at their defaults: only those are passed on, so that a --preset's settings stay where no option was
    given (None: outside a command, where every value counts as given)."""
    ctx = click_api.globals.get_current_context(silent=True)
    if ctx is None:
        return None
    default = click_api.core.ParameterSource.DEFAULT
    return {name for name in ctx.params if ctx.get_parameter_source(name) not in (None, default)}


OPTION_BLOCKS: tuple[type, ...] = (ClusterOptions, TrackerOptions, MaskOptions)
"""The dataclasses `option_blocks` expands into options."""


def _option_name(block: type, name: str) -> str:
    """The option a block's field declares (`--max-corners`)."""
    option = typing.get_type_hints(block, include_extras=True)[name].__metadata__[0]
    return next(d for d in (option.default, *option.param_decls) if isinstance(d, str) and d.startswith("--"))


SETTING_OPTIONS: dict[str, str] = {
    **{
        f"track.{f.metadata['config']}": _option_name(TrackerOptions, f.name)
        for f in dataclasses.fields(TrackerOptions)
    },
    **{f"mask.{f.metadata['config']}": _option_name(MaskOptions, f.name) for f in dataclasses.fields(MaskOptions)},
    "mask.extra_tracks": "--mask-extra-tracks",
    "cluster.method": "--k-method",
    "cluster.k_max": "--k-max",
    "geometric.k_max": "--k-max",
    "k": "--k",
    "frames": "--frames",
    "start": "--start",
    "method": "--method",
    "tracker": "--points",
}
"""The option that sets each setting of a PipelineConfig (dotted path -> option), by which an error in a
setting is reported: `--mask-scale: 0.0 must lie in (0, 1]`."""


def option_blocks(fn: F) -> F:
    """A command whose option-block parameters (OPTION_BLOCKS) stand for the block's options, in place.

    Typer reads the signature (`__signature__`) and the type hints (`__annotations__`) of what it is
    given: both list each block's fields as options where the block parameter stood; the command is
    called with the block built from them.
    """
    hints = typing.get_type_hints(fn, include_extras=True)
    params: list[inspect.Parameter] = []
    blocks: dict[str, type] = {}
    for param in inspect.signature(fn).parameters.values():
        hint = hints[param.name]
        if hint not in OPTION_BLOCKS:
            params.append(param.replace(annotation=hint))
            continue
        blocks[param.name] = hint
        block_hints = typing.get_type_hints(hint, include_extras=True)
        params += [
            inspect.Parameter(f.name, param.kind, default=f.default, annotation=block_hints[f.name])
            for f in dataclasses.fields(hint)
        ]

    @functools.wraps(fn)
    def wrapper(**kwargs: Any) -> Any:
        for name, block in blocks.items():
            kwargs[name] = block(**{f.name: kwargs.pop(f.name) for f in dataclasses.fields(block)})
        return fn(**kwargs)

    wrapper.__signature__ = inspect.Signature(params, return_annotation=None)  # type: ignore[attr-defined]
    wrapper.__annotations__ = {p.name: p.annotation for p in params} | {"return": None}
    return cast(F, wrapper)


def pipeline_cfg(
    frames: int,
    clustering: ClusterOptions,
    *,
    segment_method: StrEnum | str | None = None,
    points: StrEnum | str | None = None,
    start: int = 0,
    rigid_check: bool = True,
    shot_cuts: bool = True,
    tracker: TrackerOptions | None = None,
    masks: MaskOptions | None = None,
    mask_extra_tracks: int | None = None,
    preset: StrEnum | str | None = None,
    max_side: int | None = None,
) -> Any:
    """The PipelineConfig of a command's options (`PipelineConfig.from_options`; tracker / masks None: the
    library's defaults; mask_extra_tracks None: not an option of the command; preset None: "best"; max_side
    None: frames segmented at their size). The preset applies first, then the tracker and mask options that were
    given (`_given`): an option typed or set in a --config file wins over the preset, one left at its default does
    not undo it."""
    from dataclasses import replace

    from mosegpipe.pipeline import PipelineConfig

    track = tracker.config_fields() if tracker is not None else {}
    mask = masks.config_fields() if masks is not None else {}
    given = _given()
    if mask_extra_tracks is not None and (given is None or "mask_extra_tracks" in given):
        mask["extra_tracks"] = mask_extra_tracks
    try:
        config = PipelineConfig.from_options(
            frames,
            start=start,
            k=clustering.k,
            k_method=enum_value(clustering.k_method),
            k_max=clustering.k_max,
            method=enum_value(segment_method),
            points=enum_value(points),
            rigid_check=rigid_check,
            shot_cuts=shot_cuts,
            track=track,
            mask=mask,
            preset=enum_value(preset),
        )
        return config if max_side is None else replace(config, max_side=max_side)
    except SettingError as exc:  # named by the option that set it
        if exc.path not in SETTING_OPTIONS:
            raise
        raise InputError(f"{SETTING_OPTIONS[exc.path]}: {exc.reason}") from exc


def resolve_data_root(data_root: Path | None) -> Path:
    root = data_root or Path(os.environ.get("MOSEG_DATA", "../shared/data"))
    if not root.is_dir():
        raise InputError(f"{root}: benchmark data folder not found (use --data-root or MOSEG_DATA)")
    return root


DataRoot = Annotated[
    Path | None, typer.Option("--data-root", help="Benchmark folder (default: $MOSEG_DATA or ../shared/data).")
]


def _device_name(value: str | None) -> str | None:
    """--device's callback: a name that is none of DEVICE_CHOICES is a usage error (whether this machine has
    the device is asked where it is used: training.loop.resolve_device)."""
    if value is not None and not is_device_name(value):
        raise typer.BadParameter(f"choose {', '.join(DEVICE_CHOICES)}")
    return value


def learning_rate(value: float | None) -> float | None:
    """--lr's callback: a finite number above 0."""
    if value is not None and not (math.isfinite(value) and value > 0):
        raise typer.BadParameter("a learning rate is a finite number above 0")
    return value


LearningRate = Annotated[
    float | None, typer.Option("--lr", callback=learning_rate, help="Override the recipe's learning rate (> 0).")
]


MAX_SEED = 2**32 - 1
"""The largest --seed (NumPy's and torch's seeds are 32-bit where they meet)."""


Seed = Annotated[
    int | None, typer.Option("--seed", min=0, max=MAX_SEED, help=f"Override the recipe's random seed, 0..{MAX_SEED}.")
]


Device = Annotated[
    str | None,
    typer.Option(
        "--device",
        callback=_device_name,
        help="Where models train: cpu (the default; lce-curve --budget full: cuda when there is one), cuda, "
        "cuda:N or auto (cuda when torch sees one).",
    ),
]
