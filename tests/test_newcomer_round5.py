"""What a new user tripped on in issue 56: `moseg batch` over a folder that holds moseg's own outputs took
them for clips, inline batch warnings did not name their clip, and a folder of other files was answered
"pass --overwrite", which then refused it."""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from mosegpipe.apps.batch.run import find_clips, run_batch
from mosegpipe.apps.outputs import SUMMARY_SCHEMA, check_output_dir
from mosegpipe.errors import InputError, OutputExistsError, TooFewTracksError
from mosegpipe.pipeline import PipelineConfig

from helpers import tiny_model, write_avi


def _run_folder(folder: Path, summary: dict[str, Any]) -> Path:
    """A folder laid out as `moseg run` writes one (its files' contents do not matter here)."""
    (folder / "masks").mkdir(parents=True)
    (folder / "masks" / "000000.png").write_bytes(b"png")
    (folder / "overlay").mkdir()
    (folder / "overlay" / "000000.jpg").write_bytes(b"jpg")
    (folder / "overlay.mp4").write_bytes(b"mp4")
    (folder / "summary.json").write_text(json.dumps(summary, indent=2))
    return folder


def test_batch_skips_the_output_folders_of_moseg(tmp_path: Path) -> None:
    # `moseg run videos/dog.mp4` then `moseg batch videos`: dog_moseg/masks, overlay/ and overlay.mp4 were clips.
    videos = tmp_path / "videos"
    write_avi(videos / "dog.avi", np.zeros((3, 32, 32, 3), np.uint8))
    _run_folder(videos / "dog_moseg", {"schema": SUMMARY_SCHEMA, "kind": "video"})
    _run_folder(videos / "old_moseg", {"schema": "mosegpipe.summary/1", "kind": "clip"})  # an older version's
    (videos / "results").mkdir()
    (videos / "results" / "batch_summary.json").write_text("{}")  # a batch's output folder
    _run_folder(videos / "results" / "dog.avi", {"schema": SUMMARY_SCHEMA, "kind": "clip"})
    (videos / "theirs").mkdir()  # a summary.json of another tool's beside frames: searched
    (videos / "theirs" / "summary.json").write_text(json.dumps({"schema": "another tool"}))
    (videos / "theirs" / "000000.png").write_bytes(b"png")
    assert find_clips(videos) == [videos / "dog.avi", videos / "theirs"]
    for ours in (videos / "dog_moseg", videos / "results"):
        with pytest.raises(InputError, match="an output folder of moseg, not a folder of clips"):
            find_clips(ours)


def test_inline_batch_warnings_name_their_clip(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    # The process engine named them; the inline engine printed the bare warning.
    clips = tmp_path / "clips"
    write_avi(clips / "a.avi", np.zeros((3, 32, 32, 3), np.uint8))

    def segment(source: Path, cfg: PipelineConfig, model: Any) -> Any:
        logging.getLogger("mosegpipe.pipeline").warning("the K choice is ambiguous")
        raise TooFewTracksError("no tracks")

    with caplog.at_level(logging.WARNING):
        rows = run_batch(clips, tmp_path / "out", model=tiny_model(5), engine="inline", segment_fn=segment)
    assert [r["status"] for r in rows] == ["failed"]
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert warnings == ["a.avi: the K choice is ambiguous"]


def test_a_folder_of_other_files_is_not_told_to_pass_overwrite(tmp_path: Path) -> None:
    # "already holds results; pass --overwrite", and --overwrite then refused it as not a moseg output.
    (tmp_path / "notes.txt").write_text("mine")
    for overwrite in (False, True):
        with pytest.raises(InputError, match="holds files but no summary.json, so it is not a moseg output") as exc:
            check_output_dir(tmp_path, overwrite)
        assert not isinstance(exc.value, OutputExistsError)
    (tmp_path / "summary.json").write_text("{}")
    with pytest.raises(OutputExistsError, match="pass --overwrite"):
        check_output_dir(tmp_path, False)
