"""The `moseg` command: help and version, a full run, and one line on stderr for every bad input."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from mosegpipe import __version__
from mosegpipe.cli import view as cli_view
from mosegpipe.cli.main import app
from mosegpipe.embed.model import available_default_frames
from mosegpipe.io.read import read_palette_png
from mosegpipe.synth.render import RenderedClip

from helpers import motion_checkpoint, read_rrd, render_scene, write_avi, write_frames

runner = CliRunner(env={"COLUMNS": "200"})
SAMPLES = Path(__file__).resolve().parents[1] / "samples"
COMMANDS = ("run", "pair", "batch", "view", "train", "eval")


@pytest.fixture(scope="module")
def scene() -> RenderedClip:
    return render_scene(6)


@pytest.fixture(scope="module")
def models(tmp_path_factory: pytest.TempPathFactory) -> dict[int, Path]:
    folder = tmp_path_factory.mktemp("models")
    return {f: motion_checkpoint(folder / f"motion{f}.pt", f) for f in (5, 2)}


@pytest.fixture(scope="module")
def clip_avi(tmp_path_factory: pytest.TempPathFactory, scene: RenderedClip) -> Path:
    return write_avi(tmp_path_factory.mktemp("clip") / "scene.avi", scene.frames)


def moseg(*args: object) -> tuple[int, str, str]:
    result = runner.invoke(app, [str(a) for a in args])
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        raise result.exception
    return result.exit_code, result.stdout, result.stderr


# ---------------------------------------------------------------------------------------------
# Help and version
# ---------------------------------------------------------------------------------------------


def test_version_and_help() -> None:
    code, out, _ = moseg("--version")
    assert code == 0 and out.strip() == f"moseg {__version__}"
    code, out, _ = moseg("--help")
    assert code == 0 and "Usage: moseg" in out
    for command in COMMANDS:
        assert command in out


@pytest.mark.parametrize(
    ("command", "expected"),
    [
        ("run", "--whole"),
        ("pair", "may differ in size"),
        ("batch", "Exit code: 0 when every clip"),
        ("view", "--web"),
        ("train", "--preset"),
        ("eval", "--variant"),
    ],
)
def test_each_command_has_help(command: str, expected: str) -> None:
    code, out, _ = moseg(command, "--help")
    assert code == 0 and f"Usage: moseg {command}" in out and expected in out


# ---------------------------------------------------------------------------------------------
# A full run
# ---------------------------------------------------------------------------------------------


def test_run_writes_every_output(tmp_path: Path, clip_avi: Path, models: dict[int, Path]) -> None:
    out = tmp_path / "out"
    code, stdout, stderr = moseg("run", clip_avi, "--model", models[5], "-o", out)
    assert code == 0, stderr
    lines = [line for line in stdout.splitlines() if not line.startswith("note: joint: ")]  # the models' note
    assert " tracks over 5 frames -> K = 3 (silhouette)" in lines[0]
    assert lines[1].startswith("scores per K: ") and "K=3: " in lines[1] and lines[2].startswith("timings: read ")
    assert lines[3] == f"wrote {out}/ (summary.json, labels.npz, masks/, overlay/, overlay.mp4, recording.rrd)"
    assert lines[4] == f"open it with `moseg view {out}/recording.rrd`"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["kind"] == "clip" and summary["k"] == 3 and summary["source"] == str(clip_avi)
    assert summary["model"]["recipe"] == "test-displacement-f5"
    masks = np.stack([read_palette_png(out / "masks" / f"{t:06d}.png") for t in range(5)])
    assert masks.shape == (5, 240, 320) and masks.max() == 2
    assert len(list((out / "overlay").glob("*.jpg"))) == 5
    assert read_rrd(out / "recording.rrd")["/video/mask"] == 5


def test_default_output_folder_and_overwrite(
    tmp_path: Path, scene: RenderedClip, models: dict[int, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    clip = write_frames(tmp_path / "shots" / "walk", scene.frames[:5])
    monkeypatch.chdir(tmp_path)  # the default folder is the current one's, not the input's
    code, stdout, _ = moseg("run", clip, "--model", models[5], "--k", "3", "--no-rrd")
    out = Path("walk_moseg")
    assert code == 0 and (out / "summary.json").exists() and not (out / "recording.rrd").exists()
    assert "wrote walk_moseg/ (" in stdout and not (tmp_path / "shots" / "walk_moseg").exists()
    assert "moseg view" not in stdout  # no recording, no hint
    (out / "stale.txt").write_text("old")
    code, _, stderr = moseg("run", clip, "--model", models[5], "--k", "3", "--no-rrd")
    assert code == 1 and stderr == f"moseg: error: {out}: already holds results; pass --overwrite to replace them\n"
    assert (out / "stale.txt").exists()
    code, _, _ = moseg("run", clip, "--model", models[5], "--k", "2", "--no-rrd", "--overwrite")
    assert code == 0 and not (out / "stale.txt").exists()
    assert json.loads((out / "summary.json").read_text())["k"] == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["shots", "walk_moseg"]


def test_pair_of_images_of_different_sizes(tmp_path: Path, models: dict[int, Path]) -> None:
    big = cv2.imread(str(SAMPLES / "basketball2.png"))
    small = tmp_path / "basketball2_small.png"
    cv2.imwrite(str(small), cv2.resize(big, (480, 360), interpolation=cv2.INTER_AREA))
    out = tmp_path / "pair"
    code, stdout, stderr = moseg("pair", SAMPLES / "basketball1.png", small, "--model", models[2], "-o", out)
    assert code == 0, stderr
    assert " matches -> " in stdout and f"wrote {out}/" in stdout
    summary = json.loads((out / "summary.json").read_text())
    assert summary["kind"] == "pair" and summary["size_hw"] == [[480, 640], [360, 480]]
    assert summary["num_matches"] >= 50
    assert read_palette_png(out / "masks" / "000001.png").shape == (360, 480)
    assert read_rrd(out / "recording.rrd")["/"] >= 1


def test_shipped_default_weights(tmp_path: Path, scene: RenderedClip, clip_avi: Path) -> None:
    available = available_default_frames()
    if 5 not in available or 2 not in available:
        pytest.skip(
            f"shipped weights subspacenet_f5.pt and subspacenet_f2.pt not in mosegpipe/weights yet (found F={available})"
        )
    code, _, stderr = moseg("run", clip_avi, "-o", tmp_path / "clip", "--no-rrd")  # no --model
    assert code == 0, stderr
    summary = json.loads((tmp_path / "clip" / "summary.json").read_text())
    assert summary["model"]["model_frames"] == 5 and summary["k"] >= 1
    assert len(list((tmp_path / "clip" / "masks").iterdir())) == 5
    images = [tmp_path / f"{i}.png" for i in (0, 1)]
    for path, frame in zip(images, (scene.frames[0], scene.frames[4])):
        cv2.imwrite(str(path), cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    code, _, stderr = moseg("pair", *images, "-o", tmp_path / "pair", "--no-rrd")
    assert code == 0, stderr
    assert json.loads((tmp_path / "pair" / "summary.json").read_text())["model"]["model_frames"] == 2


# ---------------------------------------------------------------------------------------------
# Bad input: exit code 1, one line on stderr, nothing left behind
# ---------------------------------------------------------------------------------------------


def _grey_frames(folder: Path, n: int) -> Path:
    folder.mkdir()
    for t in range(n):
        cv2.imwrite(str(folder / f"{t:06d}.png"), np.full((240, 320, 3), 128, np.uint8))
    return folder


def _grey_pair(tmp: Path) -> tuple[Path, Path]:
    folder = _grey_frames(tmp / "grey_pair", 2)
    return folder / "000000.png", folder / "000001.png"


def _garbage(path: Path) -> Path:
    path.write_bytes(np.random.default_rng(0).integers(0, 256, 4000, dtype=np.uint8).tobytes())
    return path


BadCase = Callable[[Path, dict[int, Path], Path], tuple[list[object], str]]

BAD_INPUTS: dict[str, BadCase] = {
    "missing file": lambda tmp, m, clip: (
        ["run", tmp / "nope.mp4", "--model", m[5]],
        "nope.mp4: no such file or folder",
    ),
    "folder without images": lambda tmp, m, clip: (
        ["run", (tmp / "empty").mkdir() or tmp / "empty", "--model", m[5]],
        "empty: folder holds no images",
    ),
    "corrupt video": lambda tmp, m, clip: (
        ["run", _garbage(tmp / "x.mp4"), "--model", m[5]],
        "x.mp4: not a readable video",
    ),
    "fewer frames than --frames": lambda tmp, m, clip: (
        ["run", clip, "--frames", "7", "--model", m[5]],
        "scene.avi: only 6 frames could be read; --frames needs 7",
    ),
    "blank frames": lambda tmp, m, clip: (
        ["run", _grey_frames(tmp / "grey", 5), "--model", m[5]],
        "grey: only 0 tracks survived 5 frames",
    ),
    "blank image pair": lambda tmp, m, clip: (
        ["pair", *_grey_pair(tmp), "--model", m[2]],
        "000001.png: only 0 SIFT matches; need at least 10",
    ),
    "--k larger than the tracks": lambda tmp, m, clip: (
        ["run", clip, "--k", "100000", "--model", m[5]],
        "--k 100000 is larger than the number of tracks",
    ),
    "corrupt --model": lambda tmp, m, clip: (
        ["run", clip, "--model", _garbage(tmp / "model.pt")],
        "model.pt: cannot read checkpoint",
    ),
    "--model that is not there": lambda tmp, m, clip: (
        ["run", clip, "--model", tmp / "gone.pt"],
        "gone.pt: checkpoint file not found",
    ),
    "--out is a file": lambda tmp, m, clip: (
        ["run", clip, "--model", m[5], "-o", _garbage(tmp / "out")],
        "out: exists and is not a folder",
    ),
    "--max-frames without --whole": lambda tmp, m, clip: (
        ["run", clip, "--model", m[5], "--max-frames", "3"],
        "--max-frames only applies with --whole",
    ),
    "--no-shot-cuts without --whole": lambda tmp, m, clip: (
        ["run", clip, "--model", m[5], "--no-shot-cuts"],
        "--no-shot-cuts only applies with --whole",
    ),
}


@pytest.mark.parametrize("case", list(BAD_INPUTS))
def test_bad_input_gives_one_error_line(case: str, tmp_path: Path, clip_avi: Path, models: dict[int, Path]) -> None:
    work = tmp_path / "work"
    work.mkdir()
    args, expected = BAD_INPUTS[case](work, models, clip_avi)
    before = sorted(p.name for p in work.iterdir())
    code, stdout, stderr = moseg(*args, "-o", work / "result") if "-o" not in args else moseg(*args)
    assert code == 1
    assert stderr.startswith("moseg: error: ") and stderr.count("\n") == 1, stderr
    assert expected in stderr and "Traceback" not in stderr + stdout
    assert sorted(p.name for p in work.iterdir()) == before  # no output folder, no .partial left


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["eval", "kitti", "-o", "out"], "PROTOCOL: 'kitti' is not one of 'kt3d-test', 'kt3d-loo',"),
        (["train", "--preset", "huge"], "--preset huge: 'huge' is not one of 'clip-f5', 'clip-f5-rendered',"),
        (["train", "--loss", "hinge"], "--loss hinge: 'hinge' is not one of 'mimi', 'l2', 'l2-balanced', 'ce'"),
        (
            ["study", "speed", "-o", "out"],
            "NAME: 'speed' is not one of 'model-selection', 'tsne', 'sampling-imbalance', 'lce-curve', 'losses', 'weak-supervision', 'embedding-dim', 'networks', 'depth'",
        ),
        (["study", "tsne", "-o", "out", "--budget", "huge"], "--budget huge: 'huge' is not one of 'cpu', 'full'"),
        (["eval", "kt3d-loo", "-o", "out", "--variant", "x"], "--variant x: 'x' is not one of 'vanilla', 'augment'"),
        (
            ["run", "x.avi", "--mask-method", "flood"],
            "--mask-method flood: 'flood' is not one of 'motion', 'watershed'",
        ),
    ],
)
def test_unknown_choices_are_usage_errors(args: list[str], expected: str) -> None:
    """Registry names (protocols, recipes, losses, studies) are Enums now: Click refuses them (exit code 2)
    before anything runs or is written."""
    code, stdout, stderr = moseg(*args)
    assert code == 2 and stdout == "" and stderr.count("\n") == 1, stderr
    assert stderr.startswith("moseg: error: ") and expected in stderr and "Value error" not in stderr


def test_truncated_real_video(tmp_path: Path, data_root: Path, models: dict[int, Path]) -> None:
    source = data_root / "videos" / "tree.avi"
    cut = tmp_path / "tree_cut.avi"
    with source.open("rb") as fh:
        cut.write_bytes(fh.read(source.stat().st_size // 20))  # the header and the first few frames
    code, _, stderr = moseg("run", cut, "--model", models[5], "-o", tmp_path / "out")
    assert code == 1 and stderr.count("\n") == 1
    assert (
        stderr.startswith("moseg: error: ")
        and "tree_cut.avi: only " in stderr
        and "truncated or corrupt video?" in stderr
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tree_cut.avi"]


def test_refusing_to_overwrite_a_folder_that_is_not_a_moseg_output(
    tmp_path: Path, clip_avi: Path, models: dict[int, Path]
) -> None:
    photos = write_frames(tmp_path / "photos", np.zeros((1, 8, 8, 3), np.uint8))
    code, _, stderr = moseg("run", clip_avi, "--model", models[5], "-o", photos, "--overwrite")
    assert code == 1 and "photos: holds files but no summary.json" in stderr
    assert [p.name for p in photos.iterdir()] == ["000000.png"]


def test_decoder_noise_is_kept_off_stderr(tmp_path: Path) -> None:
    """FFmpeg writes its complaints to fd 2, which CliRunner cannot see: open a corrupt video in a child process."""
    bad = _garbage(tmp_path / "x.mp4")
    script = (
        "import sys, cv2\n"
        "from mosegpipe.cli.app import _quiet_native_logs\n"
        "if sys.argv[2] == 'quiet': _quiet_native_logs()\n"
        "assert not cv2.VideoCapture(sys.argv[1]).isOpened()\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("OPENCV_FFMPEG_LOGLEVEL", "OPENCV_LOG_LEVEL")}

    def stderr_of(mode: str) -> str:
        # cwd away from the checkout: `python -c` puts the working folder first on sys.path, where the
        # source tree's mosegpipe/ (without cli/, which is mapped in at install) would shadow the install.
        proc = subprocess.run(
            [sys.executable, "-c", script, str(bad), mode],
            capture_output=True,
            text=True,
            env=env,
            timeout=60,
            cwd=tmp_path,
        )
        assert proc.returncode == 0, proc.stderr
        return proc.stderr

    assert stderr_of("quiet") == ""
    assert "moov atom not found" in stderr_of("loud")  # what a user would otherwise see


# ---------------------------------------------------------------------------------------------
# moseg view
# ---------------------------------------------------------------------------------------------


def test_view_reports_missing_recording_viewer_and_display(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    rec = tmp_path / "recording.rrd"
    code, _, stderr = moseg("view", rec)
    assert code == 1 and stderr == f"moseg: error: {rec}: no such recording\n"
    rec.write_bytes(b"PNG")
    code, _, stderr = moseg("view", "--web", rec)
    assert code == 1 and stderr == f"moseg: error: {rec}: not a Rerun recording (.rrd)\n"
    rec.write_bytes(b"RRF2")
    monkeypatch.setattr(cli_view, "find_viewer", lambda: None)
    code, _, stderr = moseg("view", rec)
    assert code == 1 and "the Rerun viewer ('rerun') was not found" in stderr and stderr.count("\n") == 1
    monkeypatch.setattr(cli_view, "find_viewer", lambda: "/opt/rerun")
    monkeypatch.setattr(cli_view, "has_display", lambda: False)
    code, _, stderr = moseg("view", rec)
    assert code == 1 and f"try 'moseg view --web {rec}'" in stderr


def test_view_opens_a_window_as_the_viewer_itself(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """With a display, `moseg view` becomes the viewer (nothing of it to outlive); the web options
    need --web. The web viewer: tests/test_view.py."""
    rec = tmp_path / "recording.rrd"
    rec.write_bytes(b"RRF2")
    calls: list[list[str]] = []

    def fake_execv(exe: str, args: list[str]) -> None:
        calls.append([exe, *args])
        raise SystemExit(0)

    monkeypatch.setattr(cli_view, "find_viewer", lambda: "/opt/rerun")
    monkeypatch.setattr(cli_view, "has_display", lambda: True)
    monkeypatch.setattr(cli_view.os, "execv", fake_execv)
    assert moseg("view", rec)[0] == 0
    assert calls == [["/opt/rerun", "/opt/rerun", str(rec)]]
    for extra in (["--bind", "0.0.0.0"], ["--web-port", "8000"], ["--grpc-port", "9000"]):
        code, _, stderr = moseg("view", *extra, rec)
        assert code == 1 and stderr == "moseg: error: --bind, --web-port and --grpc-port only apply with --web\n"


def test_view_runs_the_native_viewer() -> None:
    """rerun-sdk's `rerun` script is a Python wrapper that leaves the viewer running when it gets SIGTERM:
    the binary itself is run."""
    exe = cli_view.find_viewer()
    assert exe is not None
    with open(exe, "rb") as f:
        assert f.read(2) != b"#!"


def test_choices_are_enums_listed_in_help() -> None:
    """Typer Enums (usage errors are one line now, test_bad_inputs.py): the same values as the library's."""
    code, out, _ = moseg("run", "--help")
    assert code == 0 and "silhouette|residual" in out
    code, out, _ = moseg("batch", "--help")
    assert code == 0 and "process|ray|inline" in out
    code, out, _ = moseg("--help")
    assert code == 0 and "--install-completion" in out


# ---------------------------------------------------------------------------------------------
# A closed stdout, Ctrl-C, help at 80 columns
# ---------------------------------------------------------------------------------------------


def _moseg_process(*args: object, code: str = "") -> subprocess.Popen[str]:
    """moseg in a fresh process (after `code`, e.g. a patch) whose stdout is a pipe nobody reads:
    closed before moseg writes, as `moseg ... | head -1` does after its line."""
    script = (
        f"import sys\n{code}\nfrom mosegpipe.cli.main import app\nsys.argv = {['moseg', *map(str, args)]!r}\napp()\n"
    )
    env = {**os.environ, "COLUMNS": "80", "OMP_NUM_THREADS": "1"}
    # Run outside the repository: `python -c` puts the working folder first on sys.path, and there the
    # source tree's mosegpipe/ (without cli/, which installs as mosegpipe.cli) would shadow the installed one.
    proc = subprocess.Popen(
        [sys.executable, "-c", script],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        cwd=tempfile.gettempdir(),
    )
    assert proc.stdout is not None
    proc.stdout.close()
    return proc


def test_a_closed_stdout_ends_quietly(tmp_path: Path, clip_avi: Path, models: dict[int, Path]) -> None:
    out = tmp_path / "out"
    for args in (["run", clip_avi, "--model", models[5], "-o", out], ["run", "--help"], ["--version"]):
        proc = _moseg_process(*args)
        _, stderr = proc.communicate(timeout=120)
        assert (proc.returncode, stderr) == (0, ""), args
    assert (out / "recording.rrd").exists()  # the run itself was complete


def test_ctrl_c_exits_130_with_one_line(tmp_path: Path, clip_avi: Path, models: dict[int, Path]) -> None:
    patch = (
        "import os, signal\nimport mosegpipe.apps.outputs as outputs\n"
        "def interrupted(*args, **kwargs):\n    os.kill(os.getpid(), signal.SIGINT)\n"
        "outputs.write_npz = interrupted"
    )
    proc = _moseg_process("run", clip_avi, "--model", models[5], "-o", tmp_path / "out", code=patch)
    _, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130 and stderr == "moseg: error: interrupted\n"
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("command", ["run", "batch", "pair", "tracks", "replay", "view", "train", "eval", "study"])
def test_help_at_80_columns_reads_well(command: str) -> None:
    result = CliRunner(env={"COLUMNS": "80"}).invoke(app, [command, "--help"])
    assert result.exit_code == 0
    usage = next(line for line in result.stdout.splitlines() if "Usage:" in line)
    assert "{" not in usage and "<bool>" not in result.stdout, usage  # CLIP, not {clip}; flags have no type
    if command == "run":
        assert usage.split() == ["Usage:", "moseg", "run", "[OPTIONS]", "CLIP"]


def test_eval_help_lists_protocols_by_name_at_80_columns() -> None:
    from mosegpipe.evaluation.protocols import PROTOCOLS

    result = CliRunner(env={"COLUMNS": "80"}).invoke(app, ["eval", "--help"])
    assert result.exit_code == 0
    text = result.stdout
    arguments = text[text.index("Arguments") : text.index("Options")]
    assert "<name>" in arguments and "|" not in arguments.replace("│", "")  # no choice list in a sliver
    words = arguments.replace("│", " ").replace(",", " ").replace(".", " ").replace(";", " ").split()
    assert set(PROTOCOLS) <= set(words)  # every name, whole
    # The help texts get the width: no line over 80, and an option's help starts on its own line at
    # column <= 34 and runs on for more than 40 characters (rich's boxed table left them 16).
    lines = text.splitlines()
    assert max(map(len, lines)) <= 80
    loss = next(line for line in lines if line.lstrip().startswith("--loss"))
    assert loss.index("Per-fold") <= 34 and len(loss) - loss.index("Per-fold") > 40, loss
