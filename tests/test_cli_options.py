"""The `moseg` options of issue 12 (items 13 and 16) and issue 9: --config files, `moseg replay`, --start,
tracker and mask settings, help and Enums everywhere, the whole-video progress bar and one warning for
the windows whose K was ambiguous."""

from __future__ import annotations

import json
import logging
import os
import pty
import select
import subprocess
import sys
import typing
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pytest
import typer.main

from mosegpipe.apps.video_outputs import write_video_outputs
from mosegpipe.cli import batch as cli_batch
from mosegpipe.cli import config as cli_config
from mosegpipe.cli import evaluate as cli_evaluate
from mosegpipe.cli import options as cli_options
from mosegpipe.cli.main import app
from mosegpipe.embed.model import SubspaceNet
from mosegpipe.group.cluster import ClusterConfig
from mosegpipe.group.rigid import RigidCheckConfig
from mosegpipe.io.provenance import source_identity
from mosegpipe.io.read import read_palette_png
from mosegpipe.masks import MaskConfig
from mosegpipe.pipeline import PipelineConfig, segment_video
from mosegpipe.types import MASK_METHODS

from helpers import moseg, motion_checkpoint, one_error_line, render_scene, write_avi, write_frames


@pytest.fixture(scope="module")
def models(tmp_path_factory: pytest.TempPathFactory) -> dict[int, Path]:
    folder = tmp_path_factory.mktemp("models")
    return {f: motion_checkpoint(folder / f"motion{f}.pt", f) for f in (3, 5)}


@pytest.fixture(scope="module")
def long_avi(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """13 frames of the rendered three-motion scene."""
    return write_avi(tmp_path_factory.mktemp("clip") / "long.avi", render_scene(13).frames)


def summary_of(out: Path) -> dict[str, typing.Any]:
    return json.loads((out / "summary.json").read_text())


# ---------------------------------------------------------------------------------------------
# --config FILE.toml
# ---------------------------------------------------------------------------------------------


def test_config_file_sets_options_and_the_command_line_wins(
    tmp_path: Path, long_avi: Path, models: dict[int, Path]
) -> None:
    conf = tmp_path / "conf"
    conf.mkdir()
    (conf / "moseg.toml").write_text(
        "frames = 3\n"
        'k-method = "residual"\n'
        "[run]\n"
        "max_corners = 300\n"
        "mask-median = 3\n"
        "no-rrd = true\n"
        f'model = "{os.path.relpath(models[3], conf)}"\n'  # relative to the file, not to the shell
        "[batch]\n"
        "jobs = 1\n"  # another command's table: not read by run
    )
    code, _, stderr = moseg("run", long_avi, "--config", conf / "moseg.toml", "-o", tmp_path / "a")
    assert code == 0 and stderr == "", stderr
    summary = summary_of(tmp_path / "a")
    assert summary["frames"] == 3 and summary["k_method"] == "residual"
    assert summary["config"]["track"]["max_corners"] == 300 and summary["config"]["mask"]["median_px"] == 3
    assert summary["model"]["checkpoint"] == str(models[3]) and not (tmp_path / "a" / "recording.rrd").exists()
    code, _, stderr = moseg(
        "run", long_avi, "--config", conf / "moseg.toml", "-o", tmp_path / "b", "--frames", "5", "--model", models[5]
    )
    assert code == 0, stderr
    summary = summary_of(tmp_path / "b")
    assert summary["frames"] == 5 and summary["model"]["checkpoint"] == str(models[5])
    assert summary["k_method"] == "residual"  # from the file: not given on the command line


def test_config_file_gives_a_required_option_to_batch(tmp_path: Path, long_avi: Path, models: dict[int, Path]) -> None:
    clips = tmp_path / "clips"
    clips.mkdir()
    (clips / "a.avi").write_bytes(long_avi.read_bytes())
    (tmp_path / "batch.toml").write_text(
        "frames = 5\n"  # the top level: every command
        f'[batch]\nout = "results"\nengine = "inline"\nframes = 3\nstart = 2\nmodel = "{models[3]}"\nno-rrd = true\n'
    )  # the command's table wins over the top level
    code, stdout, stderr = moseg("batch", clips, "--config", tmp_path / "batch.toml")
    assert code == 0 and "1 segmented" in stdout, stderr
    summary = summary_of(tmp_path / "results" / "a.avi")
    assert summary["start"] == 2 and summary["frames"] == 3 and summary["config"]["start"] == 2


BAD_CONFIGS = {
    "unknown key": ("framez = 3\n", "moseg.toml: unknown key 'framez' for 'moseg run'; did you mean 'frames'?"),
    "string for an integer": ('frames = "3"\n', "moseg.toml: frames: expected an integer, got '3'"),
    "number for a flag": ("whole = 1\n", "moseg.toml: whole: expected true or false, got 1"),
    "out of range": ("frames = 1\n", "moseg.toml: frames = 1: Input should be greater than or equal to 2"),
    "unknown choice": ('k-method = "elbow"\n', "moseg.toml: k-method = 'elbow': 'elbow' is not one of 'silhouette'"),
    "not TOML": ("frames = \n", "moseg.toml: not valid TOML (Invalid value (at line 1, column 10))"),
    "unknown table": ("[view]\nweb = true\n", "moseg.toml: unknown table [view] (tables: run, pair, batch, tracks)"),
    "bad key in the command's table": (
        "[run]\nengine = 'ray'\n",
        "moseg.toml: unknown key 'run.engine' for 'moseg run'",
    ),
}


@pytest.mark.parametrize("case", list(BAD_CONFIGS))
def test_bad_config_file_is_one_error_line(case: str, tmp_path: Path, long_avi: Path) -> None:
    text, expected = BAD_CONFIGS[case]
    (tmp_path / "moseg.toml").write_text(text)
    code, stdout, stderr = moseg("run", long_avi, "--config", tmp_path / "moseg.toml", "-o", tmp_path / "out")
    assert code == 1 and stdout == ""
    assert expected in one_error_line(stderr)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["moseg.toml"]


def test_config_file_that_is_missing_or_for_another_command(tmp_path: Path) -> None:
    code, _, stderr = moseg("run", tmp_path, "--config", tmp_path / "nope.toml")
    assert code == 1 and one_error_line(stderr).endswith("nope.toml: no such config file (--config)")
    (tmp_path / "run.toml").write_text("[pair]\nwhole = true\n")  # at the top level, pair leaves run's key alone
    code, _, stderr = moseg("pair", tmp_path / "a.png", tmp_path / "b.png", "--config", tmp_path / "run.toml")
    assert code == 1 and "run.toml: unknown key 'pair.whole' for 'moseg pair'" in one_error_line(stderr)


# ---------------------------------------------------------------------------------------------
# moseg replay
# ---------------------------------------------------------------------------------------------


def test_replay_a_clip_run_with_its_settings(tmp_path: Path, long_avi: Path, models: dict[int, Path]) -> None:
    out = tmp_path / "run"
    args = ["--frames", "3", "--start", "4", "--k-method", "residual", "--max-corners", "400", "--mask-median", "5"]
    code, _, stderr = moseg("run", long_avi, *args, "--model", models[3], "-o", out, "--no-rrd")
    assert code == 0, stderr
    code, stdout, stderr = moseg("replay", out / "summary.json", "--no-rrd")
    assert code == 0, stderr
    again = tmp_path / "run_replay"  # the default: beside the run's folder
    assert f"replayed {out / 'summary.json'}: K = 3 as recorded" in stdout
    before, after = summary_of(out), summary_of(again)
    assert after["config"] == before["config"] and after["config"]["start"] == 4
    assert after["model"] == before["model"] and after["start"] == 4
    assert np.array_equal(np.load(out / "labels.npz")["labels"], np.load(again / "labels.npz")["labels"])
    assert sorted(p.name for p in (again / "masks").iterdir()) == ["000004.png", "000005.png", "000006.png"]


def test_replay_a_whole_video_and_external_tracks(tmp_path: Path, long_avi: Path, models: dict[int, Path]) -> None:
    out = tmp_path / "video"
    code, _, stderr = moseg(
        "run", long_avi, "--whole", "--frames", "3", "--start", "2", "--max-frames", "9", "--k", "3",
        "--model", models[3], "-o", out, "--no-rrd", "--no-shot-cuts",
    )  # fmt: skip
    assert code == 0, stderr
    code, stdout, stderr = moseg("replay", out / "summary.json", "-o", tmp_path / "again", "--no-rrd")
    assert code == 0 and "K as recorded in all 4 windows" in stdout, stderr
    before, after = summary_of(out), summary_of(tmp_path / "again")
    assert before["config"]["video_cut_survival"] is None and after["config"] == before["config"]
    assert before["shot_cuts"] == []
    assert after["windows"] == before["windows"] and after["frames"] == 9 and before["windows"][0]["start"] == 2
    for name in sorted(p.name for p in (out / "masks").iterdir()):
        assert np.array_equal(
            read_palette_png(out / "masks" / name), read_palette_png(tmp_path / "again" / "masks" / name)
        )

    rng = np.random.default_rng(0)
    velocity = np.where(np.arange(200)[:, None] < 100, [[2.0, 0.0]], [[0.0, -3.0]])
    xy = rng.uniform(0, 300, (200, 1, 2)) + np.arange(8)[None, :, None] * velocity[:, None, :]
    np.savez(tmp_path / "tracks.npz", xy=xy.astype(np.float32))
    code, _, stderr = moseg("tracks", tmp_path / "tracks.npz", "--start", "2", "--frames", "5", "-o", tmp_path / "t")
    assert code == 0, stderr
    code, stdout, stderr = moseg("replay", tmp_path / "t" / "summary.json")
    assert code == 0 and "K = 2 as recorded" in stdout, stderr
    assert summary_of(tmp_path / "t_replay")["start"] == 2 and summary_of(tmp_path / "t_replay")["frames"] == 5


def _edited(summary: Path, edit: typing.Callable[[dict[str, typing.Any]], object]) -> Path:
    data = json.loads(summary.read_text())
    edit(data)
    path = summary.parent.parent / f"edited_{len(list(summary.parent.parent.iterdir()))}.json"
    path.write_text(json.dumps(data))
    return path


def test_replay_refuses_what_it_cannot_replay(tmp_path: Path, long_avi: Path, models: dict[int, Path]) -> None:
    out = tmp_path / "run"
    code, _, _ = moseg("run", long_avi, "--frames", "3", "--model", models[3], "-o", out, "--no-rrd")
    assert code == 0
    summary = out / "summary.json"
    (tmp_path / "batch_summary.json").write_text(json.dumps({"counts": {}, "rows": []}))
    cases = [
        (tmp_path / "nope.json", "nope.json: no such file"),
        (out / "labels.npz", "labels.npz: not a JSON file"),
        (tmp_path / "batch_summary.json", "a batch summary; replay one clip's OUT/NAME/summary.json"),
        (_edited(summary, lambda d: d.pop("schema")), "not a moseg summary.json"),
        (_edited(summary, lambda d: d.update(kind="movie")), "kind 'movie' cannot be replayed"),
        (_edited(summary, lambda d: d["source_identity"].update(path=str(tmp_path / "gone.avi"))), "gone.avi: no such file or folder"),
        (_edited(summary, lambda d: d.update(source="gone.avi", source_identity=None)), "gone.avi: no such file or folder"),
        (_edited(summary, lambda d: d.update(source_identity=["x"])), "'source_identity' has no absolute 'path'"),
        (_edited(summary, lambda d: d["model"].update(checkpoint=str(tmp_path / "m.pt"))), "m.pt: the checkpoint"),
        (_edited(summary, lambda d: d["model"].update(recipe="other")), "the run used a model with recipe 'other'"),
        (_edited(summary, lambda d: d["config"]["track"].update(max_corners="many")), "config.track.max_corners: expected an integer"),
        (_edited(summary, lambda d: d["config"].update(colour=1)), "config.colour: unknown setting"),
        (_edited(summary, lambda d: d["config"]["mask"].update(median_px=2)), "config.mask.median_px: 2 must be 0, 1 (off) or an odd"),
    ]  # fmt: skip
    before = sorted(p.name for p in tmp_path.iterdir())
    for path, expected in cases:
        code, stdout, stderr = moseg("replay", path, "-o", tmp_path / "again")
        assert code == 1 and stdout == "" and expected in one_error_line(stderr), (path, stderr)
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # no output folder, nothing half-written


def test_replay_from_another_folder_replays_the_recorded_source(
    tmp_path: Path, long_avi: Path, models: dict[int, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    """A relative source is recorded with its absolute path: a replay started elsewhere reads the run's
    input, not a file of the same name in its own folder (issue 24)."""
    started, elsewhere = tmp_path / "started", tmp_path / "elsewhere"
    started.mkdir()
    elsewhere.mkdir()
    (started / "clip.avi").write_bytes(long_avi.read_bytes())
    write_avi(elsewhere / "clip.avi", render_scene(13, seed=5).frames)  # a different video, same relative path
    monkeypatch.chdir(started)
    code, _, stderr = moseg(
        "run", "clip.avi", "--frames", "3", "--model", models[3], "-o", tmp_path / "run", "--no-rrd"
    )
    assert code == 0, stderr
    recorded = summary_of(tmp_path / "run")
    assert recorded["source"] == "clip.avi"  # as given
    identity = recorded["source_identity"]
    assert identity["path"] == str(started / "clip.avi") and identity["size"] == long_avi.stat().st_size
    assert len(identity["sha256_first_mib"]) == 64
    monkeypatch.chdir(elsewhere)
    code, stdout, stderr = moseg("replay", tmp_path / "run" / "summary.json", "--no-rrd")
    assert code == 0 and "as recorded" in stdout, stderr
    again = summary_of(tmp_path / "run_replay")
    assert again["source_identity"] == identity
    assert np.array_equal(
        np.load(tmp_path / "run" / "labels.npz")["xy"], np.load(tmp_path / "run_replay" / "labels.npz")["xy"]
    )


def test_replay_refuses_a_source_that_changed_or_went(
    tmp_path: Path, long_avi: Path, models: dict[int, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    (tmp_path / "clip.avi").write_bytes(long_avi.read_bytes())
    monkeypatch.chdir(tmp_path)
    code, _, stderr = moseg("run", "clip.avi", "--frames", "3", "--model", models[3], "-o", "run", "--no-rrd")
    assert code == 0, stderr
    summary = tmp_path / "run" / "summary.json"
    write_avi(tmp_path / "clip.avi", render_scene(13, seed=5).frames)  # replaced by another video, same name
    before = sorted(p.name for p in tmp_path.iterdir())
    code, stdout, stderr = moseg("replay", summary, "--no-rrd")
    line = one_error_line(stderr)
    assert code == 1 and stdout == ""
    assert line.startswith(f"moseg: error: {summary}: the source {tmp_path / 'clip.avi'} changed since the run ("), line
    assert "first MiB" in line
    (tmp_path / "clip.avi").unlink()
    code, stdout, stderr = moseg("replay", summary, "--no-rrd")
    assert code == 1 and stdout == ""
    assert f"{tmp_path / 'clip.avi'}: no such file or folder" in one_error_line(stderr)
    assert sorted(p.name for p in tmp_path.iterdir()) == [n for n in before if n != "clip.avi"]


def test_replay_of_a_summary_without_source_identity(
    tmp_path: Path, long_avi: Path, models: dict[int, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Summaries written before the identity existed: the source as recorded, a relative one from the working folder."""
    (tmp_path / "clip.avi").write_bytes(long_avi.read_bytes())
    monkeypatch.chdir(tmp_path)
    code, _, stderr = moseg("run", "clip.avi", "--frames", "3", "--model", models[3], "-o", "run", "--no-rrd")
    assert code == 0, stderr
    old = _edited(tmp_path / "run" / "summary.json", lambda d: d.pop("source_identity"))
    code, stdout, stderr = moseg("replay", old, "-o", "again", "--no-rrd")
    assert code == 0 and "as recorded" in stdout, stderr
    assert summary_of(tmp_path / "again")["source"] == "clip.avi"


def test_source_identity_of_folders_pairs_and_tracks(tmp_path: Path) -> None:
    folder = write_frames(tmp_path / "frames", render_scene(10).frames)
    (folder / "notes.txt").write_text("not an image")
    identity = source_identity(folder)
    assert identity is not None and identity["path"] == str(folder)
    assert [f["name"] for f in identity["files"]] == [f"{t:06d}.png" for t in range(8)]
    assert identity["files"][0]["size"] == (folder / "000000.png").stat().st_size
    assert source_identity("") is None and source_identity(tmp_path / "nope.avi") is None
    samples = Path(__file__).resolve().parents[1] / "samples"
    code, _, stderr = moseg(
        "pair", samples / "basketball1.png", samples / "basketball2.png", "-o", tmp_path / "p", "--no-rrd"
    )
    assert code == 0, stderr
    pair = summary_of(tmp_path / "p")["source_identity"]
    assert [i["path"] for i in pair] == [str(samples / "basketball1.png"), str(samples / "basketball2.png")]
    code, _, stderr = moseg("replay", tmp_path / "p" / "summary.json", "--no-rrd")
    assert code == 0, stderr
    rng = np.random.default_rng(0)
    velocity = np.where(np.arange(60)[:, None] < 30, [[2.0, 0.0]], [[0.0, -3.0]])
    xy = rng.uniform(0, 300, (60, 1, 2)) + np.arange(5)[None, :, None] * velocity[:, None, :]
    np.savez(tmp_path / "tracks.npz", xy=xy.astype(np.float32))
    code, _, stderr = moseg("tracks", tmp_path / "tracks.npz", "-o", tmp_path / "t")
    assert code == 0, stderr
    tracks = summary_of(tmp_path / "t")["source_identity"]
    assert tracks["path"] == str(tmp_path / "tracks.npz") and tracks["size"] == (tmp_path / "tracks.npz").stat().st_size


# ---------------------------------------------------------------------------------------------
# --start, tracker and mask settings
# ---------------------------------------------------------------------------------------------


def test_start_is_the_first_frame_in_every_command(tmp_path: Path, long_avi: Path, models: dict[int, Path]) -> None:
    code, _, stderr = moseg("run", long_avi, "-f", "3", "--start", "10", "--model", models[3], "-o", tmp_path / "a")
    assert code == 0, stderr
    summary = summary_of(tmp_path / "a")
    assert summary["start"] == 10 and summary["config"]["start"] == 10
    assert sorted(p.name for p in (tmp_path / "a" / "masks").iterdir()) == ["000010.png", "000011.png", "000012.png"]
    code, _, stderr = moseg(
        "run", long_avi, "-f", "3", "--start", "10", "--whole", "--model", models[3], "-o", tmp_path / "b"
    )
    assert code == 0, stderr
    assert [w["start"] for w in summary_of(tmp_path / "b")["windows"]] == [10]
    code, _, stderr = moseg("run", long_avi, "-f", "3", "--start", "11", "--model", models[3], "-o", tmp_path / "c")
    assert code == 1 and "long.avi: only 2 frames could be read from frame 11; --frames needs 3" in one_error_line(
        stderr
    )
    code, _, stderr = moseg("run", long_avi, "--start", "40", "--whole", "--model", models[3], "-o", tmp_path / "d")
    assert code == 1 and "start=40" in one_error_line(stderr)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a", "b"]


def test_tracker_and_mask_options_reach_the_pipeline(tmp_path: Path, long_avi: Path, models: dict[int, Path]) -> None:
    base = ["run", long_avi, "-f", "3", "--k", "3", "--model", models[3], "--no-rrd"]
    code, _, stderr = moseg(*base, "-o", tmp_path / "default")
    assert code == 0, stderr
    tracker = ["--max-corners", "80", "--min-distance", "12", "--quality", "0.05", "--win-size", "15"]
    masks = ["--mask-method", "nearest", "--mask-max-distance", "8", "--mask-median", "3", "--mask-scale", "0.5"]
    masks += ["--mask-extra-tracks", "0"]
    code, _, stderr = moseg(*base, *tracker, *masks, "--mask-min-agree", "2", "-o", tmp_path / "set")
    assert code == 0, stderr
    summary = summary_of(tmp_path / "set")
    track, mask = summary["config"]["track"], summary["config"]["mask"]
    assert (track["max_corners"], track["min_distance_px"], track["quality_level"], track["win_size_px"]) == (
        80,
        12,
        0.05,
        15,
    )
    assert (mask["method"], mask["max_distance_px"], mask["median_px"], mask["scale"], mask["min_agree"]) == (
        "nearest", 8, 3, 0.5, 2
    )  # fmt: skip
    assert mask["extra_tracks"] == 0 and summary_of(tmp_path / "default")["config"]["mask"]["extra_tracks"] == 1000
    assert summary["num_tracks_detected"] <= 80 < summary_of(tmp_path / "default")["num_tracks_detected"]

    def unknown(name: str) -> int:
        return int((read_palette_png(tmp_path / name / "masks" / "000000.png") == 255).sum())

    assert unknown("set") > unknown("default")  # 8 px from the nearest track, not 40


def test_rigid_check_switch_reaches_the_pipeline(tmp_path: Path, long_avi: Path, models: dict[int, Path]) -> None:
    base = ["run", long_avi, "-f", "3", "--model", models[3], "--no-rrd"]
    code, _, stderr = moseg(*base, "-o", tmp_path / "on")
    assert code == 0, stderr
    code, _, stderr = moseg(*base, "--no-rigid-check", "-o", tmp_path / "off")
    assert code == 0, stderr
    assert summary_of(tmp_path / "on")["config"]["rigid"] == asdict(RigidCheckConfig())
    assert summary_of(tmp_path / "off")["config"]["rigid"] == asdict(RigidCheckConfig(enabled=False))
    group = typer.main.get_command(app)
    for command in ("run", "batch", "tracks", "eval"):
        defaults = {p.name: p.default for p in group.commands[command].params}
        assert defaults["rigid_check"] is RigidCheckConfig().enabled, command


@pytest.mark.parametrize(
    ("option", "value", "code", "expected"),
    [
        ("--quality", "0", 1, "--quality: 0.0 must lie in (0, 1]"),
        ("--quality", "1.5", 2, "--quality 1.5: "),
        ("--max-corners", "0", 2, "--max-corners 0: "),
        ("--win-size", "2", 2, "--win-size 2: "),
        ("--mask-max-distance", "0", 1, "--mask-max-distance: 0.0 must be > 0"),
        ("--mask-median", "4", 1, "--mask-median: 4 must be 0, 1 (off) or an odd number >= 3"),
        ("--mask-min-agree", "6", 1, "--mask-min-agree: 6 must lie in 1..vote_k (5)"),
        ("--mask-scale", "0", 1, "--mask-scale: 0.0 must lie in (0, 1]"),
        ("--start", "-1", 2, "--start -1: "),
    ],
)
def test_bad_tracker_and_mask_values(
    option: str, value: str, code: int, expected: str, tmp_path: Path, long_avi: Path, models: dict[int, Path]
) -> None:
    got, stdout, stderr = moseg("run", long_avi, option, value, "--model", models[3], "-f", "3", "-o", tmp_path / "o")
    assert got == code and stdout == "" and expected in one_error_line(stderr)
    assert not (tmp_path / "o").exists()


def test_every_option_default_is_its_config_fields_default() -> None:
    """Every option that sets a setting (SETTING_OPTIONS) defaults to that setting's default, in every command
    that has it; the defaults are read from the config classes, not written out."""
    from mosegpipe.pipeline import PipelineConfig

    defaults = PipelineConfig(frames=5)
    group = typer.main.get_command(app)
    checked = 0
    for command in ("run", "pair", "tracks", "batch", "live", "eval"):
        options = {p.opts[0]: p for p in group.commands[command].params if p.param_type_name == "option"}
        for path, option in cli_options.SETTING_OPTIONS.items():
            # --frames, --k: no library default (F is the command's; K automatic); None: the protocol's own
            if option not in options or option in ("--frames", "--k") or options[option].default is None:
                continue
            value: object = defaults
            for key in path.split("."):
                value = getattr(value, key)
            assert cli_options.enum_value(options[option].default) == value, (command, option, path)
            checked += 1
    assert checked > 40
    rigid = {p.name: p.default for p in group.commands["run"].params}["rigid_check"]
    assert rigid == PipelineConfig().rigid.enabled


# ---------------------------------------------------------------------------------------------
# Help text and Enums
# ---------------------------------------------------------------------------------------------

FREE_TEXT = {("batch", "address"), ("view", "bind"), ("train", "exclude"), ("eval", "baselines")}
FREE_TEXT |= {
    ("export", "objects"),  # comma-separated mask values, checked by export.parse_objects
    ("export", "background"),  # a colour, #RRGGBB or R,G,B, checked by export.parse_colour
    ("eval", "folds"),
    ("eval", "settings"),
    ("study", "clips"),
    ("live", "source"),
    ("live", "connect"),
    ("live", "stdin_size"),
    # --device: cpu, cuda, cuda:N or auto (a GPU index cannot be an Enum); checked by training.loop.resolve_device.
    ("train", "device"),
    ("eval", "device"),
    ("study", "device"),
}
"""The only options that take free text (addresses, comma-separated lists); every other choice is an Enum."""


def test_every_option_has_help_and_every_choice_is_an_enum() -> None:
    group = typer.main.get_command(app)
    assert sorted(group.commands) == sorted(
        ["run", "pair", "tracks", "export", "batch", "replay", "view", "live", "train", "eval", "study"]
    )
    for name, command in group.commands.items():
        hints = cli_config._option_hints(name)
        for param in command.params:
            assert getattr(param, "help", None), f"moseg {name}: {param.name} has no help text"
            if hints[param.name] is str:
                assert (name, param.name) in FREE_TEXT, f"moseg {name} {param.name}: a choice should be an Enum"


def test_choices_come_from_the_library() -> None:
    """Each choice is the library's vocabulary or registry itself, its default the library's default (the
    first of the vocabulary); the registries of recipes, losses and baselines hold their vocabularies."""
    from mosegpipe.evaluation.baselines import BASELINES
    from mosegpipe.evaluation.protocols import PROTOCOLS, Variant
    from mosegpipe.group.cluster import ClusterConfig
    from mosegpipe.pipeline import PipelineConfig
    from mosegpipe.studies import STUDIES, Budget
    from mosegpipe.training.losses import LOSSES
    from mosegpipe.training.recipes import RECIPES
    from mosegpipe.types import (
        BASELINE_NAMES,
        ENGINES,
        K_METHODS,
        LOSS_NAMES,
        MASKNET_PRESET,
        RECIPE_NAMES,
        SEGMENT_METHODS,
        TRACKERS,
        TRAIN_PRESETS,
        WHICHNET_PRESET,
    )

    vocabularies = {
        cli_options.KMethodChoice: K_METHODS,
        cli_options.MaskMethodChoice: MASK_METHODS,
        cli_options.MethodChoice: SEGMENT_METHODS,
        cli_options.PointsChoice: TRACKERS,
        cli_batch.EngineChoice: ENGINES,
        cli_evaluate.ProtocolChoice: tuple(PROTOCOLS),
        cli_evaluate.StudyChoice: tuple(STUDIES),
        cli_evaluate.VariantChoice: typing.get_args(Variant),
        cli_evaluate.BudgetChoice: typing.get_args(Budget),
        cli_evaluate.PresetChoice: RECIPE_NAMES,
        cli_evaluate.TrainPresetChoice: TRAIN_PRESETS,
        cli_evaluate.LossChoice: LOSS_NAMES,
    }
    for choice, names in vocabularies.items():
        assert tuple(c.value for c in choice) == tuple(names), choice
    assert (tuple(RECIPES), tuple(LOSSES), tuple(BASELINES)) == (RECIPE_NAMES, LOSS_NAMES, BASELINE_NAMES)
    assert TRAIN_PRESETS == (*RECIPE_NAMES, MASKNET_PRESET, WHICHNET_PRESET)
    defaults = (ClusterConfig().method, MaskConfig().method, PipelineConfig().method, PipelineConfig().tracker)
    assert defaults == (K_METHODS[0], MASK_METHODS[0], SEGMENT_METHODS[0], TRACKERS[0])
    group = typer.main.get_command(app)
    for command in ("run", "batch"):
        given = {p.name: cli_options.enum_value(p.default) for p in group.commands[command].params}
        assert (given["k_method"], given["mask_method"], given["method"], given["points"]) == defaults, command


def test_train_help_lists_every_loss_and_recipe() -> None:
    from mosegpipe.training.losses import LOSSES
    from mosegpipe.training.recipes import RECIPES

    code, out, _ = moseg("train", "--help")
    assert code == 0
    for name in [*LOSSES, *RECIPES, "masknet"]:
        assert name in out, name
    # A short choice list stays in the type column; a long one that the help text names shows as <name>.
    for command, listed in [("study", "cpu|full"), ("eval", "vanilla|augment")]:
        code, out, _ = moseg(command, "--help")
        assert code == 0 and listed in out, command
    code, out, _ = moseg("batch", "--help")
    line = next(line for line in out.splitlines() if "--mask-method" in line)
    assert code == 0 and "<name>" in line and "motion|watershed" not in out
    assert all(f"{name} (" in " ".join(out.split()) for name in ("motion", "watershed", "nearest")), out


def test_kmeans_raw_docstrings_name_the_rule_the_code_uses() -> None:
    from mosegpipe.evaluation import baselines

    method = ClusterConfig().method  # what kmeans_raw's ClusterConfig(k_max=..., seed=...) chooses K by
    assert method == "silhouette"
    for doc in (baselines.__doc__ or "", baselines.kmeans_raw.__doc__ or ""):
        part = doc[doc.index("kmeans-raw") :] if "kmeans-raw" in doc else doc
        assert "silhouette" in part.split("spectral-raw")[0] and "residual" not in part.split("spectral-raw")[0]


# ---------------------------------------------------------------------------------------------
# The whole-video progress bar (issue 12, item 13)
# ---------------------------------------------------------------------------------------------


def _on_a_terminal(args: list[str], cwd: Path) -> tuple[int, str, str]:
    """Runs moseg in a child process whose stderr is a pseudo-terminal; returns its exit code, stdout and
    what it drew on the terminal."""
    master, slave = pty.openpty()
    env = {**os.environ, "TERM": "xterm-256color", "COLUMNS": "120", "OMP_NUM_THREADS": "1"}
    # cwd outside the checkout: the installed package is imported, not the source folder.
    proc = subprocess.Popen(
        [sys.executable, "-m", "mosegpipe.cli.main", *args],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=slave,
        cwd=cwd,
        env=env,
    )
    os.close(slave)
    drawn = b""
    try:
        while select.select([master], [], [], 300)[0]:
            try:
                chunk = os.read(master, 65536)
            except OSError:  # EIO: the child closed the terminal
                break
            if not chunk:
                break
            drawn += chunk
        stdout = proc.communicate(timeout=300)[0]
    finally:
        os.close(master)
        if proc.poll() is None:
            proc.kill()
    return proc.returncode, stdout.decode(), drawn.decode(errors="replace")


def test_whole_video_progress_bar_on_a_terminal_only(tmp_path: Path, long_avi: Path, models: dict[int, Path]) -> None:
    args = ["run", str(long_avi), "--whole", "-f", "3", "--k", "3", "--model", str(models[3]), "--no-rrd"]
    code, stdout, drawn = _on_a_terminal([*args, "-o", str(tmp_path / "tty")], tmp_path)
    assert code == 0 and "13 frames in 6 windows of 3" in stdout, drawn
    assert "long.avi frames" in drawn and "/13" in drawn and "ETA" in drawn  # name, frames n/N, time left
    assert "moseg: error" not in drawn and "ETA" not in stdout
    code, _, drawn = _on_a_terminal([*args, "-o", str(tmp_path / "quiet"), "--quiet"], tmp_path)
    assert code == 0 and drawn == ""
    code, stdout, stderr = moseg(*args, "-o", tmp_path / "pipe")  # stderr is not a terminal: nothing drawn
    assert code == 0 and stderr == "" and "13 frames in 6 windows" in stdout


# ---------------------------------------------------------------------------------------------
# Ambiguous K in whole-video mode: one warning line, a flag per window (issue 9)
# ---------------------------------------------------------------------------------------------


def test_ambiguous_k_is_one_warning_for_the_whole_video(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, models: dict[int, Path]
) -> None:
    frames = write_frames(tmp_path / "frames", render_scene(9).frames)
    always = PipelineConfig(frames=3, cluster=ClusterConfig(ambiguity_margin=10.0))  # every sweep is ambiguous
    model = SubspaceNet.from_checkpoint(models[3])
    with caplog.at_level(logging.INFO):
        windows = list(segment_video(frames, always, model))
    assert len(windows) == 4 and all(w.is_k_ambiguous and "ambiguous" in w.k_note for w in windows)
    warnings = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert warnings == [
        "K was ambiguous in 4 of 4 windows: frames 0-2, 2-4, 4-6 and 1 more (runner-up within 10; "
        "summary.json windows[].k_ambiguous); pass --k to decide"
    ]
    assert sum("ambiguous" in r.getMessage() for r in caplog.records if r.levelno == logging.INFO) == 4  # -v shows each
    summary = write_video_outputs(frames, tmp_path / "out", always, model, rrd=False)
    assert [w["k_ambiguous"] for w in summary["windows"]] == [True] * 4
    clear = write_video_outputs(frames, tmp_path / "clear", PipelineConfig(frames=3, k=3), model, rrd=False)
    assert [w["k_ambiguous"] for w in clear["windows"]] == [False] * 4


def test_ambiguous_k_warning_on_the_command_line(tmp_path: Path, long_avi: Path, models: dict[int, Path]) -> None:
    out = tmp_path / "video"
    code, _, _ = moseg("run", long_avi, "--whole", "-f", "3", "--model", models[3], "-o", out, "--no-rrd")
    assert code == 0
    edited = _edited(out / "summary.json", lambda d: d["config"]["cluster"].update(ambiguity_margin=10.0))
    code, _, stderr = moseg("replay", edited, "-o", tmp_path / "again", "--no-rrd")
    assert code == 0
    assert stderr.splitlines() == [
        "moseg: warning: K was ambiguous in 6 of 6 windows: frames 0-2, 2-4, 4-6 and 3 more (runner-up within 10; "
        "summary.json windows[].k_ambiguous); pass --k to decide"
    ]
    assert all(w["k_ambiguous"] for w in summary_of(tmp_path / "again")["windows"])


def test_presets_are_settings_applied_through_from_options() -> None:
    from mosegpipe.errors import ConfigError
    from mosegpipe.pipeline import PRESETS
    from mosegpipe.types import PRESET_NAMES

    assert tuple(PRESETS) == PRESET_NAMES and PRESET_NAMES[0] == "best"
    assert PipelineConfig.from_options(5, preset="best") == PipelineConfig.from_options(5) == PipelineConfig()
    for name in PRESET_NAMES:
        cfg = PipelineConfig.from_options(5, preset=name)
        assert cfg == PipelineConfig().with_settings(PRESETS[name]), name
        assert (cfg != PipelineConfig()) == bool(PRESETS[name]), name
    # The preset applies first, the options after it (an option given wins), --set last.
    fast = PipelineConfig.from_options(
        5, preset="fast", mask={"method": "motion"}, settings=["mask.motion.work_scale=1"]
    )
    assert fast.mask.motion.flow.scale == 0.5 and fast.mask.motion.work_scale == 1.0
    with pytest.raises(ConfigError, match="preset 'quick': choose 'best' or 'balanced' or 'fast'"):
        PipelineConfig.from_options(5, preset="quick")


def test_preset_option_reaches_the_pipeline(tmp_path: Path, long_avi: Path, models: dict[int, Path]) -> None:
    base = ["run", long_avi, "-f", "3", "--k", "2", "--model", models[3], "--no-rrd"]
    code, _, stderr = moseg(*base, "--preset", "fast", "-o", tmp_path / "fast")
    assert code == 0, stderr
    assert summary_of(tmp_path / "fast")["config"] == asdict(PipelineConfig.from_options(3, k=2, preset="fast"))
    code, _, stderr = moseg(*base, "--preset", "quick", "-o", tmp_path / "bad")
    assert code == 2 and "quick" in stderr and not (tmp_path / "bad").exists()
    for command, default in [("run", "best"), ("batch", "best"), ("live", "fast")]:
        code, out, _ = moseg(command, "--help")
        line = " ".join(out.split())
        assert code == 0 and "--preset" in out and f"[default: {default}]" in line.split("--preset", 1)[1], command
