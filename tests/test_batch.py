"""`moseg batch` and mosegpipe.apps.batch.run: finding clips, fault isolation, resume, the batch summary."""

from __future__ import annotations

import errno
import fcntl
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from mosegpipe.apps import outputs
from mosegpipe.apps.batch import run as batch_module
from mosegpipe.apps.batch.run import LOCK_FILE, find_clips, output_name, plan, plan_paths, run_batch
from mosegpipe.cli.main import app
from mosegpipe.embed.model import SubspaceNet
from mosegpipe.errors import InputError
from mosegpipe.pipeline import PipelineConfig

from batch_faults import faulty_segment
from helpers import FAULTY_CLIPS, batch_rows, file_tree, motion_checkpoint, render_scene, write_avi, write_frames

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
        ("a_frames", "a_frames"),
        ("sub/b.avi", "sub__b.avi"),
        ("sub/broken.mp4", "sub__broken.mp4"),
    ]
    # An output folder inside the input folder is never taken for input (its masks/ are images).
    (clips / "results" / "a_frames" / "masks").mkdir(parents=True)
    (clips / "results" / "a_frames" / "masks" / "000000.png").write_bytes(b"")
    assert [i.name for i in plan(clips, clips / "results")] == ["a_frames", "sub/b.avi", "sub/broken.mp4"]
    with pytest.raises(InputError, match="nowhere: not a folder"):
        find_clips(tmp_path / "nowhere")


_rows = batch_rows


def test_batch_isolates_failures_and_resumes(clips: Path, tmp_path: Path, model_path: Path) -> None:
    out = tmp_path / "out"
    args = ["batch", str(clips), "-o", str(out), "--model", str(model_path), "--k", "3", "--no-rrd"]
    result = runner.invoke(app, args)
    assert result.exit_code == 1, result.output
    assert result.stderr == f"moseg: error: 1 of 3 clips failed (reasons in {out}/batch_summary.csv)\n"
    assert "failed sub/broken.mp4: " in result.stdout and "not a readable video" in result.stdout
    assert "2 segmented, 0 skipped (done earlier), 1 failed" in result.stdout

    rows = _rows(out)
    assert [(r["name"], r["status"]) for r in rows] == [
        ("a_frames", "ok"),
        ("sub/b.avi", "ok"),
        ("sub/broken.mp4", "failed"),
    ]
    assert rows[0]["k"] == rows[1]["k"] == "3" and int(rows[0]["tracks"]) >= 100
    assert "broken.mp4: not a readable video" in rows[2]["error"] and rows[2]["k"] == ""
    data = json.loads((out / "batch_summary.json").read_text())
    assert data["counts"] == {"ok": 2, "skipped": 0, "failed": 1} and data["root"] == str(clips)
    assert [r["status"] for r in data["rows"]] == ["ok", "ok", "failed"]
    assert sorted(p.name for p in out.iterdir()) == [
        "a_frames",
        "batch_summary.csv",
        "batch_summary.json",
        "sub__b.avi",
    ]
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
    rows = run_batch(clips, out, PipelineConfig(k=3), model, rrd=False, engine="inline")
    assert [r["status"] for r in rows] == ["ok", "failed", "failed"]
    assert rows[1]["error"] == "RuntimeError: codec exploded"  # one line

    # A summary.json that cannot be parsed means the clip is not done: it is segmented again.
    (out / "a_frames" / "summary.json").write_text("{truncated")
    monkeypatch.setattr(batch_module, "segment_clip", real)
    rows = run_batch(clips, out, PipelineConfig(k=3), model, rrd=False, engine="inline")
    assert [r["status"] for r in rows] == ["ok", "ok", "failed"]
    assert json.loads((out / "a_frames" / "summary.json").read_text())["k"] == 3


def test_batch_without_clips(tmp_path: Path, model_path: Path) -> None:
    (tmp_path / "empty").mkdir()
    result = runner.invoke(
        app, ["batch", str(tmp_path / "empty"), "-o", str(tmp_path / "out"), "--model", str(model_path)]
    )
    assert result.exit_code == 1
    assert result.stderr == f"moseg: error: {tmp_path / 'empty'}: no video files or frame folders found\n"
    assert not (tmp_path / "out").exists()
    with pytest.raises(InputError, match="no video files or frame folders"):
        run_batch(tmp_path / "empty", tmp_path / "out", model=SubspaceNet.from_checkpoint(model_path))
    assert np.array_equal(sorted(p.name for p in tmp_path.iterdir()), ["empty"])


# ---------------------------------------------------------------------------------------------
# Output names (issue 12.3), resume against changed options (issue 12.4), write failures, the lock
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def clip_bytes(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    """One tiny MJPG clip (5 frames, 240x320), to copy under many names."""
    return write_avi(tmp_path_factory.mktemp("avi") / "clip.avi", render_scene(5).frames).read_bytes()


_tree = file_tree


def test_output_names_are_unique_and_stable() -> None:
    assert (
        output_name("a/b.avi") == "a__b.avi" and output_name("a_frames") == "a_frames" and output_name(".") == "_root"
    )
    tricky = [
        "a/b.avi",
        "a__b.avi",
        "a_/b.avi",
        "a/_b.avi",
        "a___b.avi",
        "_root",
        "x/_root",
        "batch_summary.json",
        ".hidden/c.avi",
        "a/b.avi___" + "0" * 10,
        "d" * 300 + ".avi",
        "d" * 300 + ".mp4",
    ]
    names = [output_name(n) for n in tricky]
    assert len(set(names)) == len(names)  # injective
    assert names == [output_name(n) for n in tricky]  # stable: the path alone decides
    assert all("/" not in n and not n.startswith(".") and len(n.encode()) <= 255 for n in names)
    assert names[1].startswith("a__b.avi___") and len(names[1]) == len("a__b.avi___") + 10


def test_colliding_paths_get_their_own_folders(tmp_path: Path, model_path: Path, clip_bytes: bytes) -> None:
    """Issue 12.3: a/b.avi and a__b.avi used to share one folder; the second was 'skipped' with the first's results."""
    root = _tree(tmp_path / "clips", ["a/b.avi", "a__b.avi"], clip_bytes)
    out = tmp_path / "out"
    rows = run_batch(
        root, out, PipelineConfig(k=2), SubspaceNet.from_checkpoint(model_path), rrd=False, engine="inline"
    )
    assert [(r["name"], r["status"]) for r in rows] == [("a/b.avi", "ok"), ("a__b.avi", "ok")]
    assert rows[0]["output"] != rows[1]["output"]
    for r in rows:
        summary = json.loads((out / r["output"] / "summary.json").read_text())
        assert summary["source"] == str(root / r["name"]) and summary["batch"]["name"] == r["name"]

    # The Python API on a list of paths: names relative to their common folder, a repeated path listed once.
    rows = run_batch(
        [root / "a__b.avi", root / "a" / "b.avi", root / "a__b.avi"],
        out,
        PipelineConfig(k=2),
        SubspaceNet.from_checkpoint(model_path),
        rrd=False,
        engine="inline",
    )
    assert [(r["name"], r["status"]) for r in rows] == [("a__b.avi", "skipped"), ("a/b.avi", "skipped")]
    assert plan_paths([root / "a" / "b.avi"], out, root=root)[0].out_dir == out / "a__b.avi"


def test_resume_redoes_clips_whose_options_changed(tmp_path: Path, model_path: Path) -> None:
    """Issue 12.4: a re-run with --k 3 --frames 6 skipped every clip and reported the old results as new."""
    root = tmp_path / "clips"
    write_frames(root / "one", render_scene(6).frames)
    write_frames(root / "two", render_scene(6, seed=1).frames[:, ::-1].copy())
    out = tmp_path / "out"
    base = ["batch", str(root), "-o", str(out), "--model", str(model_path), "--no-rrd", "--engine", "inline"]
    assert runner.invoke(app, [*base, "--k", "2"]).exit_code == 0
    assert [r["k"] for r in _rows(out)] == ["2", "2"]
    model6 = motion_checkpoint(tmp_path / "motion6.pt", 6)
    changed = ["batch", str(root), "-o", str(out), "--model", str(model6), "--no-rrd", "--engine", "inline"]
    result = runner.invoke(app, [*changed, "--k", "3", "--frames", "6"])
    assert result.exit_code == 0, result.output
    assert [(r["status"], r["k"]) for r in _rows(out)] == [("ok", "3"), ("ok", "3")]
    for name in ("one", "two"):
        summary = json.loads((out / name / "summary.json").read_text())
        assert summary["k"] == 3 and summary["frames"] == 6 and len(list((out / name / "masks").iterdir())) == 6
    hashes = {json.loads((out / n / "summary.json").read_text())["batch"]["config_hash"] for n in ("one", "two")}
    assert hashes == {json.loads((out / "batch_summary.json").read_text())["config_hash"]}
    # Same options again: skipped; other weights with the same options: redone.
    assert runner.invoke(app, [*changed, "--k", "3", "--frames", "6"]).exit_code == 0
    assert [r["status"] for r in _rows(out)] == ["skipped", "skipped"]
    assert runner.invoke(app, [*base, "--k", "3", "--frames", "6"]).exit_code == 0
    assert [r["status"] for r in _rows(out)] == ["ok", "ok"]


def test_a_clip_whose_writing_fails_is_failed_and_the_rest_go_on(
    tmp_path: Path, model_path: Path, clip_bytes: bytes, monkeypatch: pytest.MonkeyPatch
) -> None:
    root = _tree(tmp_path / "clips", ["a.avi", "b.avi", "c.avi"], clip_bytes)
    real = outputs.write_npz

    def full_disk(path: Path, **arrays: object) -> None:
        if "b.avi" in str(path):
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        real(path, **arrays)

    monkeypatch.setattr(outputs, "write_npz", full_disk)
    out = tmp_path / "out"
    rows = run_batch(
        root, out, PipelineConfig(k=2), SubspaceNet.from_checkpoint(model_path), rrd=False, engine="inline"
    )
    assert [r["status"] for r in rows] == ["ok", "failed", "ok"]
    assert rows[1]["error"].startswith("cannot write its outputs: No space left on device (") and rows[1]["k"] == ""
    assert sorted(p.name for p in out.iterdir()) == ["a.avi", "batch_summary.csv", "batch_summary.json", "c.avi"]


def test_a_second_batch_into_the_same_folder_is_refused(tmp_path: Path, model_path: Path, clip_bytes: bytes) -> None:
    root = _tree(tmp_path / "clips", ["a.avi"], clip_bytes)
    out = tmp_path / "out"
    out.mkdir()
    with open(out / LOCK_FILE, "w") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        with pytest.raises(InputError, match="another moseg batch is writing into this folder"):
            run_batch(root, out, model=SubspaceNet.from_checkpoint(model_path), engine="inline")
    # Leftovers of a killed batch are swept; the lock file goes when the batch ends.
    (out / ".a.avi.partial").mkdir()
    (out / ".batch_summary.1234abcd.tmp.csv").write_text("")
    rows = run_batch(
        root, out, PipelineConfig(k=2), SubspaceNet.from_checkpoint(model_path), rrd=False, engine="inline"
    )
    assert [r["status"] for r in rows] == ["ok"]
    assert sorted(p.name for p in out.iterdir()) == ["a.avi", "batch_summary.csv", "batch_summary.json"]
    with pytest.raises(InputError, match="choose 'process', 'ray', 'inline'"):
        run_batch(root, out, engine="threads")
    with pytest.raises(InputError, match="--clip-timeout needs worker processes"):
        run_batch(root, out, engine="inline", clip_timeout=1)


# ---------------------------------------------------------------------------------------------
# Worker processes: a failing, a crashing and a hanging clip; SIGKILL of the parent
# ---------------------------------------------------------------------------------------------

FAULTY = FAULTY_CLIPS
FAULTY_EXPECTED = [
    ("a.avi", "ok", ""),
    ("boom.avi", "failed", "RuntimeError: boom in two lines"),
    ("crash.avi", "failed", "its worker process died (killed by SIGKILL; out of memory?)"),
    ("hang.avi", "failed", "timed out after 3 s (--clip-timeout)"),
    ("z.avi", "ok", ""),
]


def test_process_pool_isolates_failures_crashes_and_hangs(tmp_path: Path, model_path: Path, clip_bytes: bytes) -> None:
    root = _tree(tmp_path / "clips", FAULTY, clip_bytes)
    out = tmp_path / "out"
    seen: list[str] = []
    rows = run_batch(
        root,
        out,
        PipelineConfig(k=2),
        checkpoint=model_path,
        rrd=False,
        jobs=2,
        clip_timeout=3,
        segment_fn=faulty_segment,
        on_item=lambda item, row: seen.append(item.name),
    )
    assert [(r["name"], r["status"], r["error"]) for r in rows] == FAULTY_EXPECTED
    assert sorted(seen) == sorted(FAULTY)  # progress: each clip reported once
    assert sorted(p.name for p in out.iterdir()) == ["a.avi", "batch_summary.csv", "batch_summary.json", "z.avi"]
    data = json.loads((out / "batch_summary.json").read_text())
    assert data["counts"] == {"ok": 2, "skipped": 0, "failed": 3} and data["engine"] == "process" and data["jobs"] == 2


_KILLED_BATCH = """
import sys
sys.path.insert(0, {tests!r})
from batch_faults import faulty_segment
from mosegpipe.apps.batch.run import run_batch
from mosegpipe.pipeline import PipelineConfig
run_batch({root!r}, {out!r}, PipelineConfig(k=2), checkpoint={model!r}, rrd=False, jobs=2, segment_fn=faulty_segment)
"""


def _processes_with(marker: str) -> list[int]:
    """Live (not zombie) processes whose environment holds `marker` (Linux /proc)."""
    found = []
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit():
            continue
        try:
            if (
                marker.encode() in (proc / "environ").read_bytes().split(b"\0")
                and " Z " not in (proc / "stat").read_text()
            ):
                found.append(int(proc.name))
        except OSError:
            continue
    return found


@pytest.mark.skipif(not Path("/proc/self/environ").exists(), reason="needs Linux /proc")
def test_sigkill_of_the_parent_loses_and_duplicates_nothing(
    tmp_path: Path, model_path: Path, clip_bytes: bytes
) -> None:
    names = [f"slow{i:02d}.avi" for i in range(10)]
    root = _tree(tmp_path / "clips", names, clip_bytes)
    out = tmp_path / "out"
    script = _KILLED_BATCH.format(tests=str(Path(__file__).parent), root=str(root), out=str(out), model=str(model_path))
    marker = f"MOSEG_KILLED_BATCH={tmp_path}"
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MOSEG_KILLED_BATCH": str(tmp_path)}
    child = subprocess.Popen([sys.executable, "-c", script], env=env)
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not any(p.is_dir() and not p.name.startswith(".") for p in out.glob("*")):
            assert child.poll() is None, "the batch ended before it could be killed"
            time.sleep(0.01)
        child.send_signal(signal.SIGKILL)
    finally:
        child.wait(10)
    deadline = time.monotonic() + 10  # the workers (and the forkserver) end with the batch process
    while _processes_with(marker) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert _processes_with(marker) == []
    before = sorted(p.name for p in out.iterdir())
    time.sleep(1.0)
    assert sorted(p.name for p in out.iterdir()) == before
    done = [n for n in before if not n.startswith(".")]
    assert 1 <= len(done) < len(names) and "batch_summary.json" not in done
    for name in done:  # every visible clip folder is complete
        assert json.loads((out / name / "summary.json").read_text())["batch"]["name"] == name
        assert len(list((out / name / "masks").iterdir())) == 5

    rows = run_batch(
        root, out, PipelineConfig(k=2), checkpoint=model_path, rrd=False, jobs=2, segment_fn=faulty_segment
    )
    assert [r["name"] for r in rows] == names  # one row per clip, none lost, none twice
    assert {r["name"] for r in rows if r["status"] == "skipped"} == set(done)
    assert {r["name"] for r in rows if r["status"] == "ok"} == set(names) - set(done)
    assert sorted(p.name for p in out.iterdir()) == sorted([*names, "batch_summary.csv", "batch_summary.json"])


def test_engine_ray_without_ray_is_one_line(
    tmp_path: Path, model_path: Path, clip_bytes: bytes, monkeypatch: pytest.MonkeyPatch
) -> None:
    root = _tree(tmp_path / "clips", ["a.avi"], clip_bytes)
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray -> ImportError
    result = runner.invoke(
        app, ["batch", str(root), "-o", str(tmp_path / "out"), "--model", str(model_path), "--engine", "ray"]
    )
    assert result.exit_code == 1
    assert result.stderr == "moseg: error: --engine ray needs Ray: pip install 'mosegpipe[ray]'\n"
