"""Batch edges of issue 24: what a batch leaves in --out and prints on stderr besides its own lines.

Each case failed before its fix: a clip folder was built inside a second temporary folder
(`..NAME.partial.partial`), a clip killed by --clip-timeout left its `.NAME.partial` until the next
run swept it, and a worker's warnings reached stderr as bare lines, without `moseg: warning:`.
(Ctrl-C, SIGTERM and SIGHUP sent to a batch: test_bad_inputs_signals.py; the same cases under
Ray: test_batch_ray.py.)
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from mosegpipe.apps import outputs
from mosegpipe.apps.batch import run as batch
from mosegpipe.apps.batch.run import run_batch
from mosegpipe.pipeline import PipelineConfig

from batch_faults import WARNING_TEXT, faulty_segment
from helpers import moseg, motion_checkpoint, render_scene, write_avi


@pytest.fixture(scope="module")
def model5(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return motion_checkpoint(tmp_path_factory.mktemp("models") / "motion5.pt", 5)


@pytest.fixture(scope="module")
def clip_bytes(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    return write_avi(tmp_path_factory.mktemp("avi") / "clip.avi", render_scene(5).frames).read_bytes()


def _clips(root: Path, names: list[str], data: bytes) -> Path:
    root.mkdir()
    for name in names:
        (root / name).write_bytes(data)
    return root


def test_a_clip_folder_is_built_under_one_temporary_name(
    tmp_path: Path, model5: Path, clip_bytes: bytes, monkeypatch: pytest.MonkeyPatch
) -> None:
    folders: list[str] = []
    real = outputs.write_npz

    def write_npz(path: Any, **arrays: Any) -> None:
        folders.append(Path(path).parent.name)
        real(path, **arrays)

    monkeypatch.setattr(outputs, "write_npz", write_npz)
    root = _clips(tmp_path / "clips", ["a.avi"], clip_bytes)
    rows = run_batch(root, tmp_path / "out", PipelineConfig(k=2), checkpoint=model5, rrd=False, engine="inline")
    assert [r["status"] for r in rows] == ["ok"]
    assert folders == [".a.avi.partial"]  # was "..a.avi.partial.partial", renamed into ".a.avi.partial"


def test_a_clip_killed_by_the_timeout_leaves_no_partial_folder(tmp_path: Path, model5: Path, clip_bytes: bytes) -> None:
    root = _clips(tmp_path / "clips", ["a.avi", "stuck.avi"], clip_bytes)
    out = tmp_path / "out"
    rows = run_batch(
        root,
        out,
        PipelineConfig(k=2),
        checkpoint=model5,
        rrd=False,
        jobs=2,
        clip_timeout=6,  # a 5-frame clip is segmented in about a second: "stuck" is killed half written
        segment_fn=faulty_segment,
    )
    assert [(r["name"], r["status"], r["error"]) for r in rows] == [
        ("a.avi", "ok", ""),
        ("stuck.avi", "failed", "timed out after 6 s (--clip-timeout)"),
    ]
    assert (root / "stuck.avi.writing").exists()  # it was killed while its folder was being written
    assert sorted(p.name for p in out.iterdir()) == ["a.avi", "batch_summary.csv", "batch_summary.json"]


def test_worker_warnings_are_the_batch_processes(
    tmp_path: Path,
    model5: Path,
    clip_bytes: bytes,
    monkeypatch: pytest.MonkeyPatch,
    capfd: pytest.CaptureFixture[str],
) -> None:
    root = _clips(tmp_path / "clips", ["a.avi", "warn.avi"], clip_bytes)
    monkeypatch.setattr(batch, "segment_clip", faulty_segment)  # what the workers run: "warn*" logs a warning
    code, _, err = moseg("batch", root, "--out", tmp_path / "out", "--model", model5, "--no-rrd", "-q", "-j", "2")
    assert code == 0 and err == f"moseg: warning: warn.avi: {WARNING_TEXT}\n"
    assert WARNING_TEXT not in capfd.readouterr().err  # the worker's own bare line, on the shared stderr
    assert "_warnings" not in (tmp_path / "out" / "batch_summary.csv").read_text()
