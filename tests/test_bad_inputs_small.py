"""The small fault classes of issue 24: batch edges (--clip-timeout past a float's range, a ray://
address without Ray Client), --whole on 1x1 frames, a summary.json nested too deep to read, and a
raw-pickle checkpoint whose refusal printed torch's warning before the error line.

Each case failed before its fix (a traceback, an empty --out left behind, or stray stderr). The
promise under test (README): one line `moseg: error: ...`, exit 1 (2 for usage errors), nothing created.
"""

from __future__ import annotations

import pickle
import sys
import types
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest

from mosegpipe.apps.batch.run import run_batch
from mosegpipe.errors import InputError

from helpers import moseg, motion_checkpoint, one_error_line, render_scene, write_avi


@pytest.fixture(scope="module")
def model5(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return motion_checkpoint(tmp_path_factory.mktemp("models") / "motion5.pt", 5)


@pytest.fixture(scope="module")
def clips(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("clips")
    write_avi(root / "scene.avi", render_scene(6).frames)
    return root


# ---------------------------------------------------------------------------------------------
# --clip-timeout: inf, nan and values past a float of seconds' range, before any work
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("value", "reason"),
    [
        ("nan", "not a number; give seconds, more than 0 and at most 1000000"),
        ("inf", "Input should be less than or equal to 1000000"),
        ("1e300", "Input should be less than or equal to 1000000"),
        ("-inf", "Input should be greater than 0"),
        ("0", "Input should be greater than 0"),
        ("-1", "Input should be greater than 0"),
    ],
)
def test_cli_clip_timeout_out_of_range_is_a_usage_error(tmp_path: Path, clips: Path, value: str, reason: str) -> None:
    # nan said "Input should be less than or equal to 1000000", 0 was let through to run_batch.
    out = tmp_path / "out"
    code, stdout, err = moseg("batch", clips, "--out", out, "--clip-timeout", value)
    assert code == 2 and one_error_line(err) == (
        f"moseg: error: --clip-timeout {value}: {reason} (see 'moseg batch --help')"
    )
    assert stdout == "" and not out.exists()


@pytest.mark.parametrize("value", [float("inf"), float("nan"), 1e300, -1.0, 0.0])
def test_api_clip_timeout_out_of_range_creates_nothing(tmp_path: Path, clips: Path, value: float) -> None:
    # inf was an OverflowError in the workers' timers after --out was created; nan passed the check.
    out = tmp_path / "out"
    with pytest.raises(InputError, match="--clip-timeout .* must be > 0 and at most 1e\\+06 seconds"):
        run_batch(clips, out, clip_timeout=value)
    assert not out.exists()


# ---------------------------------------------------------------------------------------------
# --engine ray --address ray://... without Ray Client (no real Ray is started)
# ---------------------------------------------------------------------------------------------


def test_ray_client_address_without_ray_client(
    tmp_path: Path, clips: Path, model5: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    fake = types.ModuleType("ray")

    def init(*args: object, **kwargs: object) -> None:  # what ray.init says without grpc installed
        raise ValueError("Ray Client requires pip package `ray[client]`.")

    fake.init = init  # type: ignore[attr-defined]
    fake.is_initialized = lambda: False  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "ray", fake)
    monkeypatch.setitem(sys.modules, "grpc", None)  # `import grpc` raises ImportError
    out = tmp_path / "out"
    code, stdout, err = moseg(
        "batch", clips, "--out", out, "--model", model5, "--engine", "ray", "--address", "ray://head:10001"
    )
    line = one_error_line(err)
    assert code == 1 and "--address ray://head:10001" in line and "ray[client]" in line and stdout == ""
    assert not out.exists()


# ---------------------------------------------------------------------------------------------
# --whole on frames too small to track
# ---------------------------------------------------------------------------------------------


def _one_pixel_avi(path: Path, frames: int = 8) -> Path:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (1, 1))
    assert writer.isOpened()
    for t in range(frames):
        writer.write(np.full((1, 1, 3), 30 * t, np.uint8))
    writer.release()
    return path


def _one_pixel_folder(folder: Path, frames: int = 8) -> Path:
    folder.mkdir()
    for t in range(frames):
        assert cv2.imwrite(str(folder / f"{t:06d}.png"), np.full((1, 1, 3), 30 * t, np.uint8))
    return folder


@pytest.mark.parametrize("make", [_one_pixel_avi, _one_pixel_folder], ids=["avi", "folder"])
def test_whole_on_one_pixel_frames(tmp_path: Path, model5: Path, make: object) -> None:
    source = make(tmp_path / "tiny.avi" if make is _one_pixel_avi else tmp_path / "tiny")  # type: ignore[operator]
    out = tmp_path / "out"
    code, _, err = moseg("run", source, "--whole", "--model", model5, "--out", out, "--no-rrd")
    line = one_error_line(err)
    assert code == 1 and str(source) in line and "1x1 px are too small to track" in line
    assert not out.exists()


# ---------------------------------------------------------------------------------------------
# moseg replay: a summary.json nested deeper than json can read
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("text", ["[" * 100_000 + "]" * 100_000, '{"a": ' * 100_000 + "1" + "}" * 100_000])
def test_replay_summary_nested_too_deep(tmp_path: Path, text: str) -> None:
    summary = tmp_path / "summary.json"
    summary.write_text(text)
    code, stdout, err = moseg("replay", summary)
    line = one_error_line(err)
    assert code == 1 and str(summary) in line and "nested too deeply" in line and stdout == ""


# ---------------------------------------------------------------------------------------------
# A raw-pickle checkpoint: refused with its error line only, its payload not run
# ---------------------------------------------------------------------------------------------


class _Payload:
    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self) -> tuple[object, tuple[object, ...]]:
        return (Path.touch, (self.marker,))


def test_raw_pickle_checkpoint_only_its_error_line(tmp_path: Path, clips: Path) -> None:
    marker = tmp_path / "payload-ran"
    ckpt = tmp_path / "raw.pt"
    ckpt.write_bytes(pickle.dumps({"state_dict": _Payload(marker)}, protocol=4))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        code, stdout, err = moseg("run", clips / "scene.avi", "--model", ckpt, "--out", tmp_path / "out")
    assert code == 1 and "raw.pt: cannot read checkpoint" in one_error_line(err) and stdout == ""
    assert [str(w.message) for w in caught] == []
    assert not marker.exists() and not (tmp_path / "out").exists()


def test_raw_pickle_checkpoint_from_the_library(tmp_path: Path) -> None:
    from mosegpipe.embed.model import SubspaceNet
    from mosegpipe.errors import CheckpointError

    marker = tmp_path / "payload-ran"
    ckpt = tmp_path / "raw.pt"
    ckpt.write_bytes(pickle.dumps({"state_dict": _Payload(marker)}, protocol=4))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with pytest.raises(CheckpointError, match="raw.pt: cannot read checkpoint"):
            SubspaceNet.from_checkpoint(ckpt)
    assert [str(w.message) for w in caught] == [] and not marker.exists()
