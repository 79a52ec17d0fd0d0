"""`moseg batch --engine ray` on a real local Ray instance (2 CPUs, started once for this module).

The same semantics as the process pool: a failing clip, one that kills its worker and one that
hangs past the timeout are failed rows, the rest finish, a re-run skips what is done. Ray is the
optional extra `mosegpipe[ray]`; CI installs it, so there (CI set) a missing Ray is an error.
"""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

if os.environ.get("CI"):
    import ray
else:
    ray = pytest.importorskip("ray", reason="Ray is the optional extra: pip install '.[ray]'")


from mosegpipe.apps.batch.run import run_batch
from mosegpipe.cli.main import app
from mosegpipe.pipeline import PipelineConfig

import batch_faults
from batch_faults import WARNING_TEXT, faulty_segment
from helpers import FAULTY_CLIPS as FAULTY
from helpers import batch_rows as _rows
from helpers import file_tree as _tree
from helpers import motion_checkpoint, render_scene, write_avi

runner = CliRunner(env={"COLUMNS": "200"})


@pytest.fixture(scope="module")
def local_ray() -> Iterator[Any]:
    from ray import cloudpickle

    cloudpickle.register_pickle_by_value(batch_faults)  # Ray workers do not have tests/ on their path
    ray.init(num_cpus=2, include_dashboard=False, logging_level="WARNING", log_to_driver=False)
    try:
        yield ray
    finally:
        ray.shutdown()
        cloudpickle.unregister_pickle_by_value(batch_faults)


@pytest.fixture(scope="module")
def model_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return motion_checkpoint(tmp_path_factory.mktemp("models") / "motion5.pt", 5)


@pytest.fixture(scope="module")
def clip_bytes(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    return write_avi(tmp_path_factory.mktemp("avi") / "clip.avi", render_scene(5).frames).read_bytes()


def test_ray_isolates_failures_crashes_and_hangs(
    local_ray: Any, tmp_path: Path, model_path: Path, clip_bytes: bytes
) -> None:
    root = _tree(tmp_path / "clips", FAULTY, clip_bytes)
    out = tmp_path / "out"
    seen: list[str] = []
    rows = run_batch(
        root,
        out,
        PipelineConfig(k=2),
        checkpoint=model_path,
        rrd=False,
        engine="ray",
        jobs=2,
        clip_timeout=8,  # a clip's Ray worker starts and loads the model within it on a loaded 2-core machine
        segment_fn=faulty_segment,
        on_item=lambda item, row: seen.append(item.name),
    )
    assert [(r["name"], r["status"], r["error"]) for r in rows] == [
        ("a.avi", "ok", ""),
        ("boom.avi", "failed", "RuntimeError: boom in two lines"),
        ("crash.avi", "failed", "its Ray worker process died"),
        ("hang.avi", "failed", "timed out after 8 s (--clip-timeout)"),
        ("z.avi", "ok", ""),
    ]
    assert sorted(seen) == sorted(FAULTY)
    assert sorted(p.name for p in out.iterdir()) == ["a.avi", "batch_summary.csv", "batch_summary.json", "z.avi"]
    assert json.loads((out / "batch_summary.json").read_text())["engine"] == "ray"
    assert local_ray.is_initialized()  # a Ray instance the caller started is left running

    # Resume: the broken clips removed, the finished ones are skipped.
    for name in ("boom.avi", "crash.avi", "hang.avi"):
        (root / name).unlink()
    rows = run_batch(root, out, PipelineConfig(k=2), checkpoint=model_path, rrd=False, engine="ray", jobs=2)
    assert [(r["name"], r["status"]) for r in rows] == [("a.avi", "skipped"), ("z.avi", "skipped")]


def test_cli_engine_ray(local_ray: Any, tmp_path: Path, model_path: Path, clip_bytes: bytes) -> None:
    root = _tree(tmp_path / "clips", ["a.avi", "sub/b.avi", "sub/broken.mp4"], clip_bytes)
    (root / "sub" / "broken.mp4").write_bytes(b"\x00\x01garbage" * 500)
    out = tmp_path / "out"
    args = ["batch", str(root), "-o", str(out), "--model", str(model_path), "--k", "2", "--no-rrd", "--engine", "ray"]
    result = runner.invoke(app, args)
    assert (
        result.exit_code == 1
        and result.stderr == f"moseg: error: 1 of 3 clips failed (reasons in {out}/batch_summary.csv)\n"
    )
    assert [(r["name"], r["status"]) for r in _rows(out)] == [
        ("a.avi", "ok"),
        ("sub/b.avi", "ok"),
        ("sub/broken.mp4", "failed"),
    ]
    assert "2 segmented, 0 skipped (done earlier), 1 failed" in result.stdout

    result = runner.invoke(app, ["batch", str(root), "-o", str(out), "--address", "auto"])
    assert result.exit_code == 1 and result.stderr == "moseg: error: --address only applies with --engine ray\n"


def test_ray_timeout_and_worker_warnings(
    local_ray: Any, tmp_path: Path, model_path: Path, clip_bytes: bytes, caplog: pytest.LogCaptureFixture
) -> None:
    # A clip killed half written left its .NAME.partial (named ..NAME.partial.partial) until the next
    # run; a worker's warning was a line of Ray's on stderr, not one of the batch's.
    root = _tree(tmp_path / "clips", ["stuck.avi", "warn.avi"], clip_bytes)
    out = tmp_path / "out"
    with caplog.at_level(logging.WARNING):
        rows = run_batch(
            root,
            out,
            PipelineConfig(k=2),
            checkpoint=model_path,
            rrd=False,
            engine="ray",
            jobs=2,
            clip_timeout=6,  # a 5-frame clip is segmented in about a second
            segment_fn=faulty_segment,
        )
    assert [(r["name"], r["status"], r["error"]) for r in rows] == [
        ("stuck.avi", "failed", "timed out after 6 s (--clip-timeout)"),
        ("warn.avi", "ok", ""),
    ]
    assert (root / "stuck.avi.writing").exists()  # it was killed while its folder was being written
    assert sorted(p.name for p in out.iterdir()) == ["batch_summary.csv", "batch_summary.json", "warn.avi"]
    assert f"warn.avi: {WARNING_TEXT}" in [
        r.getMessage() for r in caplog.records if r.name == "mosegpipe.apps.batch.run"
    ]


_RAY_CLI = """
import sys
import batch_faults
import mosegpipe.apps.batch.run
from mosegpipe.cli.main import app
mosegpipe.apps.batch.run.segment_clip = batch_faults.faulty_segment
sys.argv = ["moseg", "batch", {root!r}, "--out", {out!r}, "--model", {model!r}, "--no-rrd", "-q",
            "--engine", "ray", "-j", "1"]
app()
"""


def test_cli_ray_run_prints_only_its_own_lines(tmp_path: Path, model_path: Path, clip_bytes: bytes) -> None:
    # A Ray instance of its own (a fresh process): Ray's WARNING line about token authentication and
    # the worker's bare warning line were on stderr.
    root = _tree(tmp_path / "clips", ["warn.avi"], clip_bytes)
    out = tmp_path / "out"
    env = {
        **{k: v for k, v in os.environ.items() if not k.startswith("RAY_")},  # as set by local_ray's ray.init
        "OMP_NUM_THREADS": "1",
        "PYTHONPATH": str(Path(__file__).parent),
    }
    proc = subprocess.run(
        [sys.executable, "-c", _RAY_CLI.format(root=str(root), out=str(out), model=str(model_path))],
        capture_output=True,
        text=True,
        timeout=400,
        env=env,
        cwd=tempfile.gettempdir(),
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr == f"moseg: warning: warn.avi: {WARNING_TEXT}\n"
    assert sorted(p.name for p in out.iterdir()) == ["batch_summary.csv", "batch_summary.json", "warn.avi"]
