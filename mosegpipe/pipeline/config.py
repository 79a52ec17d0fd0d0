"""PipelineConfig, the settings of one segmentation run, and its checked loading from dicts.

`PipelineConfig.from_dict` reads the `dataclasses.asdict` form back (summary.json `config`, replay):
every field is checked against its type hint by hand (`_typed_value`), with JSON / TOML types only (no
coercion from strings), and an error names the field (`summary.json: config.track.max_corners: ...`).
`PipelineConfig.with_settings` changes nested fields named by dotted paths (`mask.motion.fb_weight=0.5`),
checked the same way (benchmarks/davis_settings.py compares such variants on the DAVIS clips).
"""

from __future__ import annotations

import contextlib
import json
import types
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, fields, is_dataclass, replace
from typing import Any, Literal, Union, get_args, get_origin, get_type_hints

from mosegpipe.configs import (
    ClusterConfig,
    FlowConfig,
    FlowTrackConfig,
    GeometricConfig,
    JointConfig,
    LabelConfig,
    MaskConfig,
    MatchConfig,
    RigidCheckConfig,
    TrackConfig,
    WorldConfig,
)
from mosegpipe.errors import ConfigError, check_choice
from mosegpipe.settings import MIN_MAX_SIDE_PX, Check, SettingError, check_fields, check_setting, check_settings
from mosegpipe.types import PRESET_NAMES, SEGMENT_METHODS, TRACKERS

PRESETS: dict[str, tuple[str, ...]] = {
    "best": (),
    "balanced": (
        "mask.motion.flow.patch_stride=6",
        "mask.motion.flow.refinement_iterations=1",
        "mask.motion.work_scale=0.5",
        "track.win_size_px=11",
    ),
    "fast": ("mask.motion.flow.scale=0.5", "mask.motion.work_scale=0.5", "track.win_size_px=11"),
}
"""The settings each named preset (types.PRESET_NAMES, `--preset`) changes, as `with_settings` takes them; the
options given to a command and its --set apply after them (PipelineConfig.from_options). The dense flow is half
of a frame's CPU and the mask steps a fifth (`benchmarks/profile_video.py`), so the presets trade those:

- best: the defaults: DIS medium (patch stride 4, 1 refinement iteration) at full resolution, the mask steps
  at 0.75 of the frame size.
- balanced: DIS with a patch stride of 6 (half of DIS's time), the mask steps at half size, KLT's window 11 px.
- fast: the flow (DIS, its forward-backward check, the camera fit) on half-size frames and the mask steps at
  half size, KLT's window 11 px: about twice as fast as best, J about 0.04 lower.

Speed and J of each, measured on the DAVIS dev clips: docs/RESULTS.md, "Speed".
"""


OLDER_SUMMARIES: tuple[tuple[str, dict[str, Any]], ...] = (
    ("method", {"method": "subspacenet"}),  # before "geometric" and "joint": the embedding alone
    ("rigid", {"rigid.enabled": False}),  # before the rigid-motion check
    ("world", {"world.enabled": False, "world.parallax": False}),  # before the world was told by where its tracks are
    ("video_cut_survival", {"video_cut_survival": None}),  # before the shot-cut test
    ("mask.extra_tracks", {"mask.extra_tracks": 0}),  # before the extra mask tracks
    ("mask.unexplained_px", {"mask.unexplained_px": 0.0}),  # before the unexplained moving regions' own label
    (  # before the motion masks' spread, guided filter and colour memory
        "mask.motion.spread_weight",
        {"mask.motion.spread_weight": 0.0, "mask.motion.guided_radius": 0, "mask.motion.colour_memory": 0.0},
    ),
    ("mask.motion.anchor_tracks", {"mask.motion.anchor_tracks": 0}),  # before their regions kept by tracks
    ("mask.motion.local_colour_weight", {"mask.motion.local_colour_weight": 0.0}),  # before their local colour contrast
    ("mask.motion.smooth_lambda", {"mask.motion.smooth_lambda": 0.0}),  # before their global smoother
    ("mask.motion.flow.camera_fit", {"mask.motion.flow.camera_fit": "magsac"}),  # before the camera's fit by RANSAC
    ("joint.merge_most_pairs", {"joint.merge_most_pairs": False}),  # before merges counted tracks in most pairs
    ("mask.motion.max_side_px", {"mask.motion.max_side_px": None}),  # before the dense stage's size limit
)
"""The compatibility of `PipelineConfig.from_dict` with summaries written before a step existed, in one table:
(a field whose absence marks such a summary, the settings it then replays with: the step off, or the choice of
the time). A marker applies when the table holding it is in the summary but the field is not."""


@dataclass(frozen=True)
class PipelineConfig:
    """Settings of one segmentation run, one line each; what the defaults give is in docs/RESULTS.md (the
    benchmark of each setting's stage; "Speed" for video_k_step), how they were chosen in docs/HISTORY.md.

    Attributes:
        frames: F, the number of frames segmented (the paper's clips are 5 frames).
        start: index of the first frame read from a video or frame folder (0-based; not used for given images).
        k: force this many motions (None = automatic K).
        method: how tracks become motions (types.SegmentMethod); pairs are always segmented with the embedding.
        min_tracks: fewer surviving tracks / matches than this is an error (too little texture).
        tracker: where a clip's points come from (types.PointSource); whole videos track KLT corners.
        track: KLT settings.
        flow_tracks: the settings of the flow tracker (its dense flow: `flow`).
        match: SIFT matching settings (pairs).
        cluster: automatic-K settings.
        rigid: the rigid-motion check after automatic K (clips, whole videos, tracks; not pairs, not with k given).
        geometric: the settings of method "geometric".
        joint: the settings of method "joint".
        mask: dense-mask settings (and, as mask.motion.flow, the dense flow: the property `flow`).
        world: how the world's motion (label 0) is told from the moving ones (mosegpipe.group.world).
        labels: whole videos: how a motion keeps its label through the windows it is missing from (pipeline.labels).
        outlier_inlier_ratio: pairs: a cluster whose best fundamental-matrix fit explains less of it is outliers.
        video_k_step: whole videos: a window tries K up to the previous window's K plus this (None = the full sweep).
        video_cut_survival: whole videos: fewer surviving tracks than this share is a shot cut (None = no cut detection).
        max_side: frames with a longer side shrunk to it to segment, masks written at the input's size (None = off).
    """

    frames: int = 5
    start: int = 0
    k: int | None = None
    method: str = "joint"  # a summary without it replays as "subspacenet" (OLDER_SUMMARIES)
    min_tracks: int = 10
    tracker: str = "klt"
    track: TrackConfig = field(default_factory=TrackConfig)
    flow_tracks: FlowTrackConfig = field(default_factory=FlowTrackConfig)
    match: MatchConfig = field(default_factory=MatchConfig)
    cluster: ClusterConfig = field(default_factory=ClusterConfig)
    rigid: RigidCheckConfig = field(default_factory=RigidCheckConfig)
    geometric: GeometricConfig = field(default_factory=GeometricConfig)
    joint: JointConfig = field(default_factory=JointConfig)
    mask: MaskConfig = field(default_factory=MaskConfig)
    world: WorldConfig = field(default_factory=WorldConfig)
    labels: LabelConfig = field(default_factory=LabelConfig)
    outlier_inlier_ratio: float = 0.5
    video_k_step: int | None = 2
    video_cut_survival: float | None = 0.25
    max_side: int | None = None

    def __post_init__(self) -> None:
        check_fields(self, _PIPELINE_CHECKS)
        check_settings(self)

    @property
    def flow(self) -> FlowConfig:
        """The dense flow of a clip or window, computed once and used by the flow tracker (`tracker` "flow",
        "klt+flow") and the motion masks alike. Its settings are stored (and named in summary.json and
        `--set`) as `mask.motion.flow`, where the motion masks, which came first, hold them."""
        return self.mask.motion.flow

    @classmethod
    def from_options(
        cls,
        frames: int,
        *,
        start: int = 0,
        k: int | None = None,
        k_method: str | None = None,
        k_max: int | None = None,
        method: str | None = None,
        points: str | None = None,
        rigid_check: bool = True,
        shot_cuts: bool = True,
        track: Mapping[str, Any] | None = None,
        mask: Mapping[str, Any] | None = None,
        preset: str | None = None,
        settings: Sequence[str] = (),
    ) -> PipelineConfig:
        """The settings of a command's options (`moseg run`, `pair`, `tracks`, `batch`, `live`, `eval`): the
        one way from options to a PipelineConfig. None (or left out) = the library's default.

        Args:
            frames: F.
            start: the first frame read.
            k: force this many motions (None = automatic K).
            k_method: the automatic-K rule (ClusterConfig.method).
            k_max: the largest K, of automatic K and of method "geometric" alike.
            method: how tracks become motions (SEGMENT_METHODS).
            points: where a clip's points come from (TRACKERS).
            rigid_check: the rigid-motion check after automatic K.
            shot_cuts: whole videos: detect shot cuts (video_cut_survival; False = None).
            track: TrackConfig fields to change.
            mask: MaskConfig fields to change.
            preset: a named preset (PRESETS): its settings apply first, the options above after them (an option
                given wins over the preset), then `settings` (None = "best", the defaults).
            settings: then settings changed by dotted path (`with_settings`).

        Raises:
            ConfigError: a value that is not allowed, named.
        """
        defaults = cls()
        if preset is not None:
            defaults = defaults.with_settings(PRESETS[check_choice("preset", preset, PRESET_NAMES)])
        given = {"method": k_method, "k_max": k_max}
        cluster = _changed("cluster", defaults.cluster, **{key: v for key, v in given.items() if v is not None})
        geometric = _changed("geometric", defaults.geometric, **({"k_max": k_max} if k_max is not None else {}))
        track_cfg = _changed("track", defaults.track, **(track or {}))
        mask_cfg = _changed("mask", defaults.mask, **(mask or {}))
        config = replace(
            defaults,
            frames=frames,
            start=start,
            k=k,
            method=method if method is not None else defaults.method,
            tracker=points if points is not None else defaults.tracker,
            track=track_cfg,
            cluster=cluster,
            geometric=geometric,
            rigid=replace(defaults.rigid, enabled=rigid_check),
            mask=mask_cfg,
            video_cut_survival=defaults.video_cut_survival if shot_cuts else None,
        )
        return config.with_settings(settings) if settings else config

    def with_settings(self, settings: Sequence[str]) -> PipelineConfig:
        """These settings with nested fields changed, each given as `dotted.path=value`.

        The value is read as JSON (`0.5`, `3`, `true`, `null`, `"ransac"`); a value that is not JSON is
        taken as a string (`mask.motion.flow.camera_fit=magsac`). The result is checked as `from_dict`
        checks a summary's settings.

        Args:
            settings: e.g. ["mask.motion.fb_weight=0.5", "mask.motion.flow.preset=fast"].

        Raises:
            ConfigError: a setting without `=`, an unknown field or a value of the wrong type, named
                (`--set mask.motion.fb_weight: expected a number, got 'high'`).
        """
        data = asdict(self)
        for setting in settings:
            path, sep, text = setting.partition("=")
            keys = path.strip().split(".")
            if not sep or not all(keys):
                raise ConfigError(f"--set {setting!r}: expected dotted.field=value, e.g. mask.motion.fb_weight=0.5")
            node = data
            for depth, key in enumerate(keys[:-1]):
                if not isinstance(node.get(key), dict):
                    raise ConfigError(f"--set {'.'.join(keys[: depth + 1])}: not a group of settings")
                node = node[key]
            if keys[-1] not in node:
                raise ConfigError(f"--set {path.strip()}: unknown setting (known here: {', '.join(node)})")
            try:
                node[keys[-1]] = json.loads(text)
            except json.JSONDecodeError:
                node[keys[-1]] = text.strip()
        try:
            return type(self).from_dict(data, where="settings")
        except ConfigError as exc:  # named as the user wrote it
            raise ConfigError(str(exc).replace("settings.", "--set ", 1)) from exc

    @classmethod
    def from_dict(cls, data: Any, where: str = "config") -> PipelineConfig:
        """The settings from their `dataclasses.asdict` form (summary.json `config`), checked field by field.

        A field left out takes its default (a summary written before the field existed), except the markers
        of OLDER_SUMMARIES: a summary without one was made before a step existed, and replays with that step
        off (or the choice of the time), so that a replay segments as that run did (but for whole videos'
        motion masks, whose windows' first frames take the flow back to the frame before since
        `local_colour_weight` came in). An unknown field, a value of the wrong type or one the config classes
        refuse is an error.

        Args:
            data: a dict as `asdict(cfg)` gives it (nested dicts for track, match, cluster, mask).
            where: how errors name the dict (`summary.json: config`).

        Raises:
            ConfigError: naming the field, e.g. `summary.json: config.track.max_corners: expected an
                integer, got 'many'`.
        """
        config = _dataclass_from_dict(cls, data, where, "")
        assert isinstance(config, cls)
        for marker, older in OLDER_SUMMARIES:
            *parents, key = marker.split(".")
            node = data
            for name in parents:
                node = node.get(name) if isinstance(node, Mapping) else None
            if isinstance(node, Mapping) and key not in node:
                for path, value in older.items():
                    config = _replaced(config, path.split("."), value)
        return config


_PIPELINE_CHECKS: tuple[Check, ...] = (
    ("method", lambda v: v in SEGMENT_METHODS, f"be one of {', '.join(SEGMENT_METHODS)}"),
    ("tracker", lambda v: v in TRACKERS, f"be one of {', '.join(TRACKERS)}"),
    ("video_k_step", lambda v: v >= 1, "be at least 1 (or None: no limit)"),
    ("video_cut_survival", lambda v: 0 < v < 1, "lie in (0, 1) (or None: no cut detection)"),
    ("max_side", lambda v: v >= MIN_MAX_SIDE_PX, f"be at least {MIN_MAX_SIDE_PX} pixels (or None: the input's size)"),
)
"""PipelineConfig's checks of its own choices and switches (its numbers' bounds: settings.BOUNDS)."""


def _changed(name: str, config: Any, **changes: Any) -> Any:
    """`config` (the field `name` of a PipelineConfig) with the fields in `changes` changed; an error names the
    setting by its path in the PipelineConfig (`mask.scale`)."""
    try:
        return replace(config, **changes)
    except SettingError as exc:
        raise SettingError(f"{name}.{exc.path}", exc.reason) from exc


def _replaced(config: Any, keys: list[str], value: Any) -> Any:
    """`config` with the nested field named by `keys` set to `value`."""
    head, *rest = keys
    return replace(config, **{head: _replaced(getattr(config, head), rest, value) if rest else value})


def _dataclass_from_dict(cls: type, data: Any, where: str, path: str) -> Any:
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a table of settings, got {type(data).__name__} {data!r}")
    hints = get_type_hints(cls)
    names = [f.name for f in fields(cls)]
    unknown = [key for key in data if key not in names]
    if unknown:
        raise ConfigError(f"{where}.{unknown[0]}: unknown setting (known: {', '.join(names)})")
    values = {}
    for name, value in data.items():
        values[name] = _typed_value(hints[name], value, f"{where}.{name}", f"{path}{name}")
        try:  # before the value's config class checks it in its own terms: a NaN is named as such
            check_setting(f"{path}{name}", values[name])
        except SettingError as exc:
            raise ConfigError(f"{where}.{name}: {exc.reason}") from exc
    try:
        return cls(**values)
    except SettingError as exc:  # the field is known: named by its path
        raise ConfigError(f"{where}.{exc.path.removeprefix(path)}: {exc.reason}") from exc


_TYPE_NAMES = {bool: "true or false", int: "an integer", float: "a number", str: "a string"}


def _typed_value(hint: Any, value: Any, where: str, path: str) -> Any:
    """`value` checked against the type hint of a config field (JSON / TOML types: no coercion from strings)."""
    if is_dataclass(hint):
        return _dataclass_from_dict(hint, value, where, f"{path}.")  # type: ignore[arg-type]
    origin = get_origin(hint)
    if origin is Union or origin is types.UnionType:
        options = get_args(hint)
        if value is None and type(None) in options:
            return None
        for option in options:
            if option is not type(None):
                with contextlib.suppress(ConfigError):
                    return _typed_value(option, value, where, path)
        wanted = " or ".join("null" if o is type(None) else _TYPE_NAMES.get(o, str(o)) for o in options)
        raise ConfigError(f"{where}: expected {wanted}, got {value!r}")
    if origin is Literal:
        if value not in get_args(hint):
            raise ConfigError(f"{where}: {value!r} is not one of {', '.join(map(repr, get_args(hint)))}")
        return value
    ok = {
        bool: isinstance(value, bool),
        int: isinstance(value, int) and not isinstance(value, bool),
        float: isinstance(value, (int, float)) and not isinstance(value, bool),
        str: isinstance(value, str),
    }
    if hint not in ok:
        raise TypeError(f"{where}: config fields of type {hint} are not supported")
    if not ok[hint]:
        raise ConfigError(f"{where}: expected {_TYPE_NAMES[hint]}, got {value!r}")
    return float(value) if hint is float else value
