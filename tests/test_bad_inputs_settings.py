"""Issue 40, items 1 and 6: settings that were taken though they should be refused, through every door.

`moseg eval --set cluster.num_threads=100000` crashed (SIGSEGV); NaN changed the score, `frames=0` ran
5 frames and recorded 0, `k=0` gave a row of zeros, `start=-1` and `min_tracks=-1` ran, all with exit 0;
a replayed summary.json with NaN or 1e999 in a setting ran. Each door (the API, `--set`, a replayed
summary, the CLI's eval) now ends in the one check (`mosegpipe.settings.check_settings`, called by the
PipelineConfig constructor) and gives the same line naming the field: exit 1, nothing written.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from mosegpipe.errors import ConfigError
from mosegpipe.group.cluster import ClusterConfig
from mosegpipe.pipeline import PipelineConfig
from mosegpipe.settings import MAX_THREADS

from helpers import moseg, motion_checkpoint, one_error_line, render_scene, write_avi

BAD_SETTINGS = [
    ("cluster.num_threads=100000", "cluster.num_threads: 100000 must lie in 1..256"),
    ("cluster.num_threads=0", "cluster.num_threads: 0 must lie in 1..256"),
    ("mask.motion.flow.workers=100000", "mask.motion.flow.workers: 100000 must lie in 1..256"),
    ("mask.motion.fb_weight=NaN", "mask.motion.fb_weight: nan is not a finite number"),
    ("outlier_inlier_ratio=NaN", "outlier_inlier_ratio: nan is not a finite number"),
    ("outlier_inlier_ratio=2", "outlier_inlier_ratio: 2.0 must lie in 0..1"),
    ("mask.motion.colour_weight=1e999", "mask.motion.colour_weight: inf is not a finite number"),
    ("track.quality_level=-Infinity", "track.quality_level: -inf is not a finite number"),
    ("frames=0", "frames: 0 must lie in 2..10000"),
    ("start=-1", "start: -1 must lie in 0..2147483647"),
    ("min_tracks=-1", "min_tracks: -1 must be at least 1"),
    ("k=0", "k: 0 must lie in 1..100000"),
]
"""(`--set` argument, the error after its door's prefix) — each was taken before the fix."""

IDS = [s.partition("=")[0] + "=" + s.partition("=")[2] for s, _ in BAD_SETTINGS]


def enum_value(setting: str) -> Any:
    return json.loads(setting.partition("=")[2])


def _nested(setting: str) -> dict[str, Any]:
    """`a.b=v` as the dict {"a": {"b": v}}."""
    path, _, _ = setting.partition("=")
    keys = path.split(".")
    data: dict[str, Any] = {keys[-1]: enum_value(setting)}
    for key in reversed(keys[:-1]):
        data = {key: data}
    return data


def _merged(base: dict[str, Any], changes: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for key, value in changes.items():
        out[key] = _merged(out[key], value) if isinstance(value, dict) else value
    return out


@pytest.mark.parametrize(("setting", "expected"), BAD_SETTINGS, ids=IDS)
def test_set_refuses_the_setting_by_name(setting: str, expected: str) -> None:
    with pytest.raises(ConfigError) as caught:
        PipelineConfig().with_settings([setting])
    assert str(caught.value) == f"--set {expected}"


@pytest.mark.parametrize(("setting", "expected"), BAD_SETTINGS, ids=IDS)
def test_a_summary_config_with_the_setting_is_refused(setting: str, expected: str) -> None:
    from dataclasses import asdict

    data = _merged(asdict(PipelineConfig()), _nested(setting))
    with pytest.raises(ConfigError) as caught:
        PipelineConfig.from_dict(data, where="summary.json: config")
    assert str(caught.value) == f"summary.json: config.{expected}"


def test_the_api_door_is_the_same_check() -> None:
    """A config built by hand is checked by the same function (nested settings too)."""
    from dataclasses import replace

    base = PipelineConfig()
    with pytest.raises(ConfigError, match=r"^fb_weight: nan is not a finite number$"):
        replace(base, mask=replace(base.mask, motion=replace(base.mask.motion, fb_weight=float("nan"))))
    with pytest.raises(ConfigError, match=r"^frames: 0 must lie in 2\.\.10000$"):
        PipelineConfig(frames=0)
    with pytest.raises(ConfigError, match=r"^k: 0 must lie in 1\.\.100000$"):
        PipelineConfig(k=0)
    with pytest.raises(ConfigError, match=rf"^num_threads: 100000 must lie in 1\.\.{MAX_THREADS}$"):
        ClusterConfig(num_threads=100_000)  # cluster_auto_k's own config, used without a PipelineConfig
    assert PipelineConfig(k=None, video_k_step=None, video_cut_survival=None).k is None  # None = left out


def test_a_motion_mask_setting_names_itself_alone() -> None:
    # the check of colour_bins named colour_weight=0.75 as well (issue 40, item 10)
    with pytest.raises(ConfigError) as caught:
        PipelineConfig().with_settings(["mask.motion.colour_bins=0"])
    assert str(caught.value) == "--set mask.motion.colour_bins: 0 must lie in 2..64"


def test_unknown_setting_is_refused_by_name() -> None:
    with pytest.raises(ConfigError, match=r"^--set nope: unknown setting \(known here: frames, start"):
        PipelineConfig().with_settings(["nope=1"])
    with pytest.raises(ConfigError, match=r"^--set cluster\.nope: unknown setting"):
        PipelineConfig().with_settings(["cluster.nope=1"])


@pytest.mark.parametrize(
    ("setting", "expected"), [*BAD_SETTINGS, ("nope=1", "nope: unknown setting")], ids=[*IDS, "nope"]
)
def test_eval_set_is_one_line_and_writes_nothing(tmp_path: Path, setting: str, expected: str) -> None:
    """`moseg eval ... --set`: the line before any clip is read (no data needed for rendered)."""
    out = tmp_path / "ev"
    code, stdout, stderr = moseg("eval", "rendered", "--baselines", "", "--out", out, "--set", setting)
    assert (code, stdout) == (1, "")
    assert one_error_line(stderr).startswith(f"moseg: error: --set {expected}")
    assert not out.exists()


def test_eval_set_on_a_benchmark_protocol_is_refused(tmp_path: Path) -> None:
    """A benchmark protocol feeds the dataset's own trajectories, not the pipeline: --set cannot apply (it
    was ignored and not recorded)."""
    out = tmp_path / "ev"
    code, stdout, stderr = moseg("eval", "lce", "--out", out, "--set", "cluster.n_init=3")
    assert (code, stdout) == (1, "") and not out.exists()
    assert "--set applies to end-to-end protocols only" in one_error_line(stderr)


@pytest.fixture(scope="module")
def summary(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("run")
    model = motion_checkpoint(root / "motion3.pt", 3)
    write_avi(root / "scene.avi", render_scene(4).frames)
    code, _, stderr = moseg("run", root / "scene.avi", "-f", "3", "--model", model, "--no-rrd", "-o", root / "o")
    assert code == 0, stderr
    return root / "o" / "summary.json"


@pytest.mark.parametrize(
    ("setting", "text"),
    [
        ("mask.motion.fb_weight=NaN", "mask.motion.fb_weight: nan is not a finite number"),
        ("mask.motion.colour_weight=1e999", "mask.motion.colour_weight: inf is not a finite number"),
        ("cluster.num_threads=100000", "cluster.num_threads: 100000 must lie in 1..256"),
        ("frames=0", "frames: 0 must lie in 2..10000"),
    ],
)
def test_replay_of_an_edited_summary_is_refused(tmp_path: Path, summary: Path, setting: str, text: str) -> None:
    data = json.loads(summary.read_text())
    data["config"] = _merged(data["config"], _nested(setting))
    edited = summary.parent / f"edited_{tmp_path.name}.json"
    # Written as a hand edit writes it: 1e999 as such (json.dumps would write Infinity).
    edited.write_text(json.dumps(data).replace("Infinity", "1e999"))
    out = tmp_path / "again"
    code, stdout, stderr = moseg("replay", edited, "-o", out)
    assert (code, stdout) == (1, "") and not out.exists()
    assert one_error_line(stderr) == f"moseg: error: {edited}: config.{text}"
