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
from typing import Any, Literal, Union, cast, get_args, get_origin, get_type_hints

from mosegpipe.cluster import ClusterConfig
from mosegpipe.errors import ConfigError, check_choice
from mosegpipe.flow_tracks import FlowTrackConfig
from mosegpipe.geometry_select import JointConfig
from mosegpipe.grouping import GeometricConfig
from mosegpipe.masks import MaskConfig
from mosegpipe.match import MatchConfig
from mosegpipe.rigid import RigidCheckConfig
from mosegpipe.settings import SettingError, check_setting, check_settings
from mosegpipe.track import TrackConfig
from mosegpipe.types import PRESET_NAMES, SEGMENT_METHODS, TRACKERS, KMethodName
from mosegpipe.world import WorldConfig

PRESETS: dict[str, tuple[str, ...]] = {
    "best": (),
    "balanced": (
        "mask.motion.flow.patch_stride=6",
        "mask.motion.flow.refinement_iterations=1",
        "mask.motion.work_scale=0.5",
    ),
    "fast": ("mask.motion.flow.scale=0.5", "mask.motion.work_scale=0.5"),
}
"""The settings each named preset (types.PRESET_NAMES, `--preset`) changes, as `with_settings` takes them; the
options and --set of a command apply after them. Chosen from `benchmarks/profile_video.py` (the dense flow is
half of a frame's CPU, the mask steps a fifth) and measured on the 20 DAVIS dev clips only (docs/RESULTS.md,
"Speed": CPU per frame and J side by side):

- best: the defaults, DIS medium (patch stride 4, 3 refinement iterations) at full resolution, the mask
  steps at 0.75 of the frame size.
- balanced: DIS with a patch stride of 6 and 1 refinement iteration (half of DIS's time), the mask steps at
  half size.
- fast: the flow (DIS, its forward-backward check, the camera fit) on half-size frames (a quarter of the
  pixels) and the mask steps at half size: half of best's CPU, J 0.04 lower. DIS's "fast" preset at full
  size cost as much J (its finest scale is half the image's) for less speed.
"""


@dataclass(frozen=True)
class PipelineConfig:
    """Settings of one segmentation run.

    Attributes:
        frames: F, the number of frames segmented (the paper's clips are 5 frames).
        start: index of the first frame read from a video or frame folder (0-based, in the source);
            segment_clip reads frames start .. start + F - 1, segment_video starts its first window
            there. Not used by segment_frames / segment_pair (they are given their images).
        k: force this many motions (None = automatic K).
        method: how tracks become motions (SEGMENT_METHODS): "subspacenet" embeds them and clusters
            the embeddings (cluster, rigid); "geometric" fits rigid motions to them one after another
            (mosegpipe.grouping.group_geometric with `geometric`; no embedding, no rigid-motion check);
            "joint" clusters the embeddings (cluster), then splits, merges and moves tracks by the
            model each group selects (mosegpipe.geometry_select with `joint`, after the rigid-motion check).
            Pairs are always segmented with the embedding.
        min_tracks: fewer surviving tracks / matches than this is an error (too little texture).
        tracker: where a clip's points come from (`mosegpipe.flow_tracks.TRACKERS`): "klt" corners,
            "flow" (a grid carried along the dense flow) or "klt+flow" (both). Whole videos track
            with KLT whatever this says.
        track: KLT settings.
        flow_tracks: the settings of the flow tracker.
        match: SIFT matching settings (pairs).
        cluster: automatic-K settings.
        rigid: the rigid-motion check after automatic K (clips, whole videos, tracks; not pairs, not
            with k given): groups of tracks that their cluster's rigid motion does not explain
            become clusters of their own (mosegpipe.rigid).
        geometric: the settings of method "geometric".
        joint: the settings of method "joint".
        mask: dense-mask settings.
        world: how the world's motion (label 0) is told from the moving ones (mosegpipe.world).
        outlier_inlier_ratio: pairs: a cluster whose best fundamental-matrix RANSAC fit explains less
            than this fraction of its points is labelled as outliers.
        video_k_step: whole videos: a window tries K up to the previous window's K plus this (and at
            most cluster.k_max), so K rises by at most this much every F - 1 frames; None = the full
            sweep in every window. The sweep's larger K cost the most K-means time; on the long
            rendered clips the limit changed no segmentation (docs/RESULTS.md, "Speed").
        video_cut_survival: whole videos: a frame into which fewer than this fraction of the previous
            frame's tracks survive (of at least 2 * min_tracks) is a shot cut: the window ends on the
            frame before it, and tracking and clustering start afresh on it. None = no cut detection.
    """

    frames: int = 5
    start: int = 0
    k: int | None = None
    method: str = "subspacenet"  # a summary without it was made before "geometric" existed
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
    outlier_inlier_ratio: float = 0.5
    video_k_step: int | None = 2
    video_cut_survival: float | None = 0.25

    def __post_init__(self) -> None:
        check_choice("method", self.method, SEGMENT_METHODS)
        check_choice("tracker", self.tracker, TRACKERS)
        check_settings(self)
        if self.video_k_step is not None and self.video_k_step < 1:
            raise SettingError("video_k_step", f"{self.video_k_step} must be at least 1 (or None: no limit)")
        if self.video_cut_survival is not None and not 0 < self.video_cut_survival < 1:
            raise SettingError(
                "video_cut_survival", f"{self.video_cut_survival} must lie in (0, 1) (or None: no cut detection)"
            )

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
            preset: a named preset (PRESETS): its settings apply after the options above, before `settings`
                (None = "best", the defaults).
            settings: then settings changed by dotted path (`with_settings`).

        Raises:
            ConfigError: a value that is not allowed, named.
        """
        defaults = cls()
        cluster, geometric = defaults.cluster, defaults.geometric
        if k_method is not None:
            cluster = replace(cluster, method=cast(KMethodName, k_method))  # ClusterConfig checks it
        if k_max is not None:
            cluster, geometric = replace(cluster, k_max=k_max), replace(geometric, k_max=k_max)
        try:
            track_cfg = replace(defaults.track, **(track or {}))
            mask_cfg = replace(defaults.mask, **(mask or {}))
        except ConfigError:
            raise
        except ValueError as exc:  # MaskConfig's own checks raise ValueError: one line, not a traceback
            raise ConfigError(" ".join(str(exc).split())) from exc
        config = cls(
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
        if preset is not None:
            settings = (*PRESETS[check_choice("preset", preset, PRESET_NAMES)], *settings)
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

        A field left out takes its default (a summary written before the field existed), except
        `rigid`, `world`, `video_cut_survival`, `mask.extra_tracks`, `mask.unexplained_px`, `mask.motion.spread_weight`,
        `mask.motion.anchor_tracks`, `mask.motion.local_colour_weight`, `mask.motion.smooth_lambda` and
        `mask.motion.flow.camera_fit`: a summary without them was made before the rigid-motion check (the
        shot-cut test, the extra mask tracks, the unexplained moving regions' own label, the motion masks'
        spread, guided filter and colour memory, their regions kept by tracks, their local colour contrast,
        their global smoother) existed, or before the world was told by where its tracks are, so it stays off, or before the camera's fit by RANSAC, so it fits by
        MAGSAC; a replay segments as that run did (but for whole videos' motion masks, whose windows' first
        frames take the flow back to the frame before since `local_colour_weight` came in). An unknown
        field, a value of the wrong type or one the config classes refuse is an error.

        Args:
            data: a dict as `asdict(cfg)` gives it (nested dicts for track, match, cluster, mask).
            where: how errors name the dict (`summary.json: config`).

        Raises:
            ConfigError: naming the field, e.g. `summary.json: config.track.max_corners: expected an
                integer, got 'many'`.
        """
        config = _dataclass_from_dict(cls, data, where, "")
        assert isinstance(config, cls)
        if isinstance(data, Mapping) and "rigid" not in data:
            config = replace(config, rigid=RigidCheckConfig(enabled=False))
        if isinstance(data, Mapping) and "world" not in data:
            config = replace(config, world=WorldConfig(enabled=False, parallax=False))
        if isinstance(data, Mapping) and "video_cut_survival" not in data:
            config = replace(config, video_cut_survival=None)
        if isinstance(data, Mapping) and isinstance(data.get("mask"), Mapping) and "extra_tracks" not in data["mask"]:
            config = replace(config, mask=replace(config.mask, extra_tracks=0))
        if isinstance(data, Mapping) and isinstance(data.get("mask"), Mapping) and "unexplained_px" not in data["mask"]:
            config = replace(config, mask=replace(config.mask, unexplained_px=0.0))
        motion = data.get("mask", {}).get("motion") if isinstance(data, Mapping) else None
        if isinstance(motion, Mapping):
            older: dict[str, Any] = {}  # the motion masks' settings of a summary written before a step existed
            if "spread_weight" not in motion:
                older.update(spread_weight=0.0, guided_radius=0, colour_memory=0.0)
            if "anchor_tracks" not in motion:
                older["anchor_tracks"] = 0
            if "local_colour_weight" not in motion:
                older["local_colour_weight"] = 0.0
            if "smooth_lambda" not in motion:
                older["smooth_lambda"] = 0.0
            if isinstance(motion.get("flow"), Mapping) and "camera_fit" not in motion["flow"]:
                older["flow"] = replace(config.mask.motion.flow, camera_fit="magsac")
            if older:
                config = replace(config, mask=replace(config.mask, motion=replace(config.mask.motion, **older)))
        return config


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
    except ValueError as exc:  # a config class's own check (ConfigError, or ValueError in masks, motion, flow)
        raise ConfigError(f"{where}: {' '.join(str(exc).split())}") from exc


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
