"""`moseg batch` and mosegpipe.batch: finding clips, fault isolation, resume, the batch summary."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from mosegpipe import batch as batch_module
from mosegpipe.batch import find_clips, plan, run_batch
from mosegpipe.cli.main import app
from mosegpipe.errors import InputError
from mosegpipe.model import SubspaceNet
from mosegpipe.pipeline import PipelineConfig

from helpers import motion_checkpoint, render_scene, write_avi, write_frames

runner = CliRunner(env={"COLUMNS": "200"})


@pytest.fixture(scope="module")
def model_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return motion_checkpoint(tmp_path_factory.mktemp("models") / "motion5.pt", 5)


@pytest.fixture()
def clips(tmp_path: Path) -> Path:
    """root/a_frames/ (PNG frames), root/sub/b.avi (MJPG), root/sub/broken.mp4 (garbage bytes)."""
    frames = render_scene(5).frames
    root = tmp_path / "clips"
    write_frames(root / "a_frames", frames)
    (root / "sub").mkdir()
    write_avi(root / "sub" / "b.avi", frames[:, ::-1].copy())  # upside down: a different clip
    (root / "sub" / "broken.mp4").write_bytes(b"\x00\x01garbage" * 500)
    (root / ".hidden").mkdir()
    (root / ".hidden" / "x.avi").write_bytes(b"never looked at")
    return root


def test_find_clips_and_plan(clips: Path, tmp_path: Path) -> None:
    assert find_clips(clips) == [clips / "a_frames", clips / "sub" / "b.avi", clips / "sub" / "broken.mp4"]
    items = plan(clips, tmp_path / "out")
    assert [(i.name, i.out_dir.name) for i in items] == [
        ("a_frames", "a_frames"), ("sub/b.avi", "sub__b.avi"), ("sub/broken.mp4", "sub__broken.mp4"),
    ]
    # An output folder inside the input folder is never taken for input (its masks/ are images).
    (clips / "results" / "a_frames" / "masks").mkdir(parents=True)
    (clips / "results" / "a_frames" / "masks" / "000000.png").write_bytes(b"")
    assert [i.name for i in plan(clips, clips / "results")] == ["a_frames", "sub/b.avi", "sub/broken.mp4"]
    with pytest.raises(InputError, match="nowhere: not a folder"):
        find_clips(tmp_path / "nowhere")


def _rows(out: Path) -> list[dict[str, str]]:
    with (out / "batch_summary.csv").open() as fh:
        return list(csv.DictReader(fh))


def test_batch_isolates_failures_and_resumes(clips: Path, tmp_path: Path, model_path: Path) -> None:
    out = tmp_path / "out"
    args = ["batch", str(clips), "-o", str(out), "--model", str(model_path), "--k", "3", "--no-rrd"]
    result = runner.invoke(app, args)
    assert result.exit_code == 1, result.output
    assert result.stderr == f"moseg: error: 1 of 3 clips failed (reasons in {out}/batch_summary.csv)\n"
    assert "failed sub/broken.mp4: " in result.stdout and "not a readable video" in result.stdout
    assert "2 segmented, 0 skipped (done earlier), 1 failed" in result.stdout

    rows = _rows(out)
    assert [(r["name"], r["status"]) for r in rows] == [("a_frames", "ok"), ("sub/b.avi", "ok"), ("sub/broken.mp4", "failed")]
    assert rows[0]["k"] == rows[1]["k"] == "3" and int(rows[0]["tracks"]) >= 100
    assert "broken.mp4: not a readable video" in rows[2]["error"] and rows[2]["k"] == ""
    data = json.loads((out / "batch_summary.json").read_text())
    assert data["counts"] == {"ok": 2, "skipped": 0, "failed": 1} and data["root"] == str(clips)
    assert [r["status"] for r in data["rows"]] == ["ok", "ok", "failed"]
    assert sorted(p.name for p in out.iterdir()) == ["a_frames", "batch_summary.csv", "batch_summary.json", "sub__b.avi"]
    for name in ("a_frames", "sub__b.avi"):
        summary = json.loads((out / name / "summary.json").read_text())
        assert summary["k"] == 3 and len(list((out / name / "masks").iterdir())) == 5

    # Resume: the finished clips are skipped (not rewritten), the broken one is tried again.
    stamp = (out / "a_frames" / "summary.json").stat().st_mtime_ns
    result = runner.invoke(app, args)
    assert result.exit_code == 1
    assert [r["status"] for r in _rows(out)] == ["skipped", "skipped", "failed"]
    assert (out / "a_frames" / "summary.json").stat().st_mtime_ns == stamp
    assert "0 segmented, 2 skipped (done earlier), 1 failed" in result.stdout

    # Without the broken clip everything is ok or skipped: exit code 0.
    (clips / "sub" / "broken.mp4").unlink()
    result = runner.invoke(app, args)
    assert result.exit_code == 0 and result.stderr == ""
    assert [r["status"] for r in _rows(out)] == ["skipped", "skipped"]


def test_unexpected_errors_and_unreadable_summaries(
    clips: Path, tmp_path: Path, model_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    model = SubspaceNet.from_checkpoint(model_path)
    out = tmp_path / "out"
    real = batch_module.segment_clip

    def flaky(source: Path, cfg: PipelineConfig, net: SubspaceNet) -> object:
        if source.name == "b.avi":
            raise RuntimeError("codec\nexploded")
        return real(source, cfg, net)

    monkeypatch.setattr(batch_module, "segment_clip", flaky)
    rows = run_batch(clips, out, PipelineConfig(k=3), model, rrd=False)
    assert [r["status"] for r in rows] == ["ok", "failed", "failed"]
    assert rows[1]["error"] == "RuntimeError: codec exploded"  # one line

    # A summary.json that cannot be parsed means the clip is not done: it is segmented again.
    (out / "a_frames" / "summary.json").write_text("{truncated")
    monkeypatch.setattr(batch_module, "segment_clip", real)
    rows = run_batch(clips, out, PipelineConfig(k=3), model, rrd=False)
    assert [r["status"] for r in rows] == ["ok", "ok", "failed"]
    assert json.loads((out / "a_frames" / "summary.json").read_text())["k"] == 3


def test_batch_without_clips(tmp_path: Path, model_path: Path) -> None:
    (tmp_path / "empty").mkdir()
    result = runner.invoke(app, ["batch", str(tmp_path / "empty"), "-o", str(tmp_path / "out"), "--model", str(model_path)])
    assert result.exit_code == 1
    assert result.stderr == f"moseg: error: {tmp_path / 'empty'}: no video files or frame folders found\n"
    assert not (tmp_path / "out").exists()
    with pytest.raises(InputError, match="no video files or frame folders"):
        run_batch(tmp_path / "empty", tmp_path / "out", model=SubspaceNet.from_checkpoint(model_path))
    assert np.array_equal(sorted(p.name for p in tmp_path.iterdir()), ["empty"])
