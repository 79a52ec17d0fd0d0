"""The bounds of the settings and the one check every setting passes, whatever door it came in by.

A `PipelineConfig` is built from CLI options (`PipelineConfig.from_options`), from `moseg eval --set`
(`with_settings`), from a replayed summary.json (`from_dict`) or by hand through the API; each way ends in
its constructor, which calls `check_settings`: every number finite (NaN and infinity are refused, not
compared: `nan < 0` is False), and the settings named in `BOUNDS` within their range. An error is a
`SettingError` naming the field by its dotted path (`cluster.num_threads: 100000 must lie in 1..256`).

This module imports the standard library only: the CLI reads the bounds for its options' ranges and
--help without importing OpenCV.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Iterator, Sequence
from typing import Any

from mosegpipe.errors import ConfigError

MAX_THREADS = 256
"""Threads a setting or option may ask for (a thread pool of 100000 crashes OpenMP: SIGSEGV)."""
MAX_K = 64
"""The largest K automatic K tries (each K is a K-means fit; the benchmarks have at most 5 motions)."""
MAX_FORCED_K = 100_000
"""The largest K that may be forced (at most the tracks, which MAX_CORNERS bounds in clips)."""
MAX_FRAMES = 10_000
"""The longest window of trajectories, frames ((N, 2F) per window)."""
MAX_FRAME_INDEX = 2**31 - 1
"""The largest frame index (OpenCV seeks with an int)."""
MIN_MAX_SIDE_PX = 32
"""Smallest `max_side` (PipelineConfig, `--max-side`) taken: below it no frame holds enough corners to track."""
MAX_CORNERS = 100_000
"""The most KLT corners or flow seeds (past 3e9 OpenCV overflows its int argument)."""
MAX_WIN_SIZE_PX = 255
"""The largest Lucas-Kanade window, pixels (100001 overflows in OpenCV)."""
MAX_MIN_DISTANCE_PX = 10_000.0
"""The largest spacing between corners, pixels (1e308 crashes goodFeaturesToTrack: SIGSEGV)."""
MAX_MASK_DISTANCE_PX = 100_000.0
"""The largest distance from a labelled track at which a pixel still takes its label, pixels."""
MAX_MASK_MEDIAN_PX = 255
"""The largest median filter over the label image, pixels (101 and up run for minutes)."""
MAX_EXTRA_TRACKS = 100_000
"""The most extra corners tracked for the masks only."""
MAX_CLIP_TIMEOUT_S = 1e6
"""The longest a batch clip may run, seconds (11.6 days): beyond it a float of seconds overflows the workers'
timers."""

BOUNDS: dict[str, tuple[float, float | None]] = {
    "frames": (2, MAX_FRAMES),
    "start": (0, MAX_FRAME_INDEX),
    "k": (1, MAX_FORCED_K),
    "min_tracks": (1, None),
    "outlier_inlier_ratio": (0, 1),
}
"""Inclusive bounds (low, high; None = no upper bound) of the settings of a PipelineConfig that their
own config classes do not bound, by dotted path; a None value (an optional setting left out) passes."""


class SettingError(ConfigError):
    """A setting out of its bounds, named by its dotted path.

    Attributes:
        path: the setting's dotted path in the config checked (`mask.motion.fb_weight`).
        reason: what is wrong with its value (`nan is not a finite number`).
    """

    def __init__(self, path: str, reason: str) -> None:
        super().__init__(f"{path}: {reason}")
        self.path = path
        self.reason = reason


def check_settings(config: Any, bounds: dict[str, tuple[float, float | None]] | None = None) -> None:
    """Checks every setting of a config dataclass, nested ones included: numbers finite, `bounds` held.

    Args:
        config: a config dataclass (a PipelineConfig: its track, cluster, mask, ... settings too).
        bounds: dotted path -> inclusive (low, high) (None: BOUNDS, the PipelineConfig's).

    Raises:
        SettingError: the first setting that is NaN or infinite, or out of its bounds, named by its path.
    """
    for path, value in _settings(config, ""):
        check_setting(path, value, bounds)


def check_setting(path: str, value: Any, bounds: dict[str, tuple[float, float | None]] | None = None) -> None:
    """Checks one setting, named by its dotted path: a number finite, within `bounds` (None: BOUNDS).

    `check_settings` calls it for every setting of a config; `PipelineConfig.from_dict` for every value it
    reads, before the value's config class checks it in its own terms (so that a NaN is named as such).

    Raises:
        SettingError: the value is NaN or infinite, or out of its bounds.
    """
    if isinstance(value, float) and not math.isfinite(value):
        raise SettingError(path, f"{value!r} is not a finite number")
    limits = BOUNDS if bounds is None else bounds
    if path in limits and value is not None:
        low, high = limits[path]
        if not low <= value or (high is not None and not value <= high):
            span = f"lie in {low!r}..{high!r}" if high is not None else f"be at least {low!r}"
            raise SettingError(path, f"{value!r} must {span}")


Check = tuple[str, Callable[[Any], bool], str]
"""One check of a config class's field: (field, test of its value, what the value must do: "lie in (0, 1]", "be > 0")."""


def check_fields(config: Any, checks: Sequence[Check]) -> None:
    """A config class's own checks of its fields (its `__post_init__`), each failure a SettingError naming
    the field: a NaN or infinite number is named as such, a value that fails its test by what it must be.
    None (an optional setting left out) is not tested.

    Raises:
        SettingError: the first field whose value fails, e.g. `scale: 0.0 must lie in (0, 1]`.
    """
    for name, ok, want in checks:
        value = getattr(config, name)
        if value is None:
            continue
        if isinstance(value, float) and not math.isfinite(value):
            raise SettingError(name, f"{value!r} is not a finite number")
        if not ok(value):
            raise SettingError(name, f"{value!r} must {want}")


def _settings(config: Any, prefix: str) -> Iterator[tuple[str, Any]]:
    """(dotted path, value) of every leaf setting of a config dataclass, depth first."""
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            yield from _settings(value, f"{prefix}{f.name}.")
        elif isinstance(value, (tuple, list)):
            yield from ((f"{prefix}{f.name}[{i}]", v) for i, v in enumerate(value))
        else:
            yield f"{prefix}{f.name}", value
