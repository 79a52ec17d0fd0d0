"""The faults of issue 56, each as its audit case: two commands writing one --out, a FIFO given as the clip,
--preset over explicit options, moseg train's checks before the data, --device of the mask recipes, a
mask checkpoint without widths, a shared --config file, --folds given twice.

The promise under test (README): one line `moseg: error: ...`, exit 1 (2 for usage errors), nothing
created, nothing of another command's removed.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from mosegpipe.io.locks import output_lock, output_lock_path

from helpers import moseg, one_error_line

SAMPLE = Path(__file__).resolve().parents[1] / "samples" / "vtest_8f.avi"


# ---------------------------------------------------------------------------------------------
# 1. Two commands writing one --out: the second is refused and the first's .partial stays
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "args",
    [
        ("run", SAMPLE, "--whole", "--no-rrd"),
        ("run", SAMPLE, "--whole", "--no-rrd", "--overwrite"),
        ("run", SAMPLE, "-f", "3", "--no-rrd"),
        ("live", SAMPLE, "--no-rrd"),
    ],
)
def test_second_command_into_a_folder_being_written_is_refused(tmp_path: Path, args: tuple[object, ...]) -> None:
    # The second run took the same .o.partial, deleted the first's and wrote its own; exit 0.
    out = tmp_path / "o"
    partial = tmp_path / ".o.partial"
    partial.mkdir()
    (partial / "000000.png").write_bytes(b"the first command's work")
    with output_lock(out):
        code, stdout, err = moseg(*args, "-o" if args[0] == "run" else "--out", out)
    assert code == 1 and one_error_line(err) == f"moseg: error: {out}: another moseg command is writing there"
    assert (partial / "000000.png").read_bytes() == b"the first command's work" and not out.exists()
    assert not output_lock_path(out).exists()


def test_output_lock_is_released_and_leaves_no_folders(tmp_path: Path) -> None:
    out = tmp_path / "a" / "b" / "o"
    with output_lock(out):
        assert output_lock_path(out).is_file()
    assert not (tmp_path / "a").exists()  # the folders made for the lock file went with it
    with output_lock(out):  # free again
        out.mkdir()
    assert out.is_dir() and not output_lock_path(out).exists()


# ---------------------------------------------------------------------------------------------
# 2, 7, 10. A mask checkpoint that cannot be used: refused once, before any clip (eval, the pipeline)
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def bad_masknets(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    import torch

    from mosegpipe.masks.learned.features import NUM_CHANNELS
    from mosegpipe.masks.learned.net import shipped_path

    root = tmp_path_factory.mktemp("masknets")
    shipped = shipped_path("moving").read_bytes()
    (root / "truncated.pt").write_bytes(shipped[: len(shipped) // 2])
    (root / "random.pt").write_bytes(os.urandom(4096))
    (root / "empty.pt").write_bytes(b"")
    no_widths = {"kind": "masknet", "output": "moving", "in_channels": NUM_CHANNELS, "widths": [], "state_dict": {}}
    torch.save(no_widths, root / "no_widths.pt")
    torch.save({**no_widths, "widths": [8, 8, 8, 8, 8]}, root / "five_levels.pt")
    return {
        "missing": root / "missing.pt",
        **{p.stem: p for p in root.iterdir()},
        "which": shipped_path("which"),  # the per-motion network where the mask network is asked for
    }


@pytest.mark.parametrize("case", ["missing", "truncated", "random", "empty", "no_widths", "five_levels", "which"])
@pytest.mark.parametrize("protocol", ["davis", "davis-clip5", "composite", "composite-clip5", "rendered"])
def test_eval_refuses_an_unusable_mask_network_before_any_clip(
    tmp_path: Path, bad_masknets: dict[str, Path], protocol: str, case: str
) -> None:
    # davis and composite warned once per clip and wrote a table of zeros (exit 0); no_widths was an IndexError.
    out = tmp_path / "out"
    args = ["eval", protocol, "--out", out, "--data-root", tmp_path, "--mask-method", "learned"]
    code, stdout, err = moseg(*args, "--set", f"mask.learned.weights={bad_masknets[case]}")
    line = one_error_line(err)
    assert code == 1 and line.startswith(f"moseg: error: mask.learned.weights: {bad_masknets[case]}: "), line
    assert stdout == "" and not out.exists()


def test_eval_davis_refuses_a_model_that_is_not_a_subspacenet(tmp_path: Path) -> None:
    from mosegpipe.masks.learned.net import shipped_path

    for model in (shipped_path("moving"), tmp_path / "nonexistent.pt"):
        for protocol in ("davis", "davis-clip5"):
            code, _, err = moseg("eval", protocol, "--out", tmp_path / "out", "--data-root", tmp_path, "--model", model)
            assert code == 1 and one_error_line(err).startswith(f"moseg: error: {model}: "), err
            assert not (tmp_path / "out").exists()


def test_mask_checkpoint_without_widths_is_a_checkpoint_error(bad_masknets: dict[str, Path]) -> None:
    from mosegpipe.errors import CheckpointError
    from mosegpipe.masks.learned.net import MaskNet

    for case in ("no_widths", "five_levels"):
        with pytest.raises(CheckpointError, match="widths .*expected 1 to 4 channel counts"):
            MaskNet.from_checkpoint(bad_masknets[case])


def test_which_learned_checks_its_weights_before_any_frame(tmp_path: Path) -> None:
    # Only a frame with two moving motions loaded the per-motion network: other clips ran on without a word.
    import numpy as np

    from mosegpipe.errors import CheckpointError
    from mosegpipe.pipeline import PipelineConfig, check_video_settings, segment_frames
    from mosegpipe.types import Frames

    cfg = PipelineConfig(frames=3).with_settings(["mask.which=learned", f"mask.learned.which_weights={tmp_path}/w.pt"])
    frames = Frames(images=np.zeros((3, 64, 64, 3), np.uint8))  # blank: no motion, no tracks
    with pytest.raises(CheckpointError, match=f"mask.learned.which_weights: {tmp_path}/w.pt: no mask network"):
        segment_frames(frames, cfg)
    with pytest.raises(CheckpointError, match="mask.learned.which_weights: "):
        check_video_settings(cfg, None)
    # Masks that never ask which motion a pixel is (watershed) do not need the network.
    check_video_settings(cfg.with_settings(["mask.method=watershed"]), None)


# ---------------------------------------------------------------------------------------------
# 3. A FIFO (or any file that is not a regular one) as the clip: refused before it is opened
# ---------------------------------------------------------------------------------------------


def test_a_fifo_as_the_clip_is_refused_without_opening_it(tmp_path: Path) -> None:
    # open() on a FIFO blocked until a writer came: the run hung and ignored SIGINT and SIGTERM.
    import threading

    from mosegpipe.errors import InputError
    from mosegpipe.io.read import video_info

    fifo = tmp_path / "clip.avi"
    os.mkfifo(fifo)
    caught: list[BaseException] = []

    def probe() -> None:
        try:
            video_info(fifo)
        except BaseException as exc:  # noqa: BLE001 - handed to the test's thread
            caught.append(exc)

    thread = threading.Thread(target=probe, daemon=True)  # daemon: a hang fails the test, not the suite
    thread.start()
    thread.join(10)
    assert not thread.is_alive(), "video_info blocked on the FIFO"
    assert len(caught) == 1 and isinstance(caught[0], InputError)
    assert str(caught[0]) == f"{fifo}: not a regular file or folder (a FIFO, socket or device is not read as a video)"
    for extra in ((), ("--whole",)):
        code, _, err = moseg("run", fifo, "-o", tmp_path / "o", *extra)
        assert code == 1 and one_error_line(err) == f"moseg: error: {caught[0]}" and not (tmp_path / "o").exists()


# ---------------------------------------------------------------------------------------------
# 4. --preset first, the options given after it (command line and --config file)
# ---------------------------------------------------------------------------------------------


def test_an_option_given_wins_over_the_preset(tmp_path: Path) -> None:
    # --preset fast --win-size 31 recorded win_size_px 11: the preset applied after the options.
    from mosegpipe.pipeline import PipelineConfig

    cfg = PipelineConfig.from_options(5, preset="fast", track={"win_size_px": 31})
    assert cfg.track.win_size_px == 31 and cfg.mask.motion.flow.scale == 0.5
    (tmp_path / "fast.toml").write_text('preset = "fast"\nwin-size = 31\n')
    runs = {"typed": ("--preset", "fast", "--win-size", "31"), "file": ("--config", tmp_path / "fast.toml")}
    runs["preset only"] = ("--preset", "fast")
    for name, options in runs.items():
        out = tmp_path / name
        code, _, err = moseg("run", SAMPLE, "-f", "3", "--k", "2", "--no-rrd", "-o", out, *options)
        assert code == 0, err
        config = json.loads((out / "summary.json").read_text())["config"]
        assert config["track"]["win_size_px"] == (11 if name == "preset only" else 31), name
        assert config["mask"]["motion"]["flow"]["scale"] == 0.5 and config["mask"]["motion"]["work_scale"] == 0.5


# ---------------------------------------------------------------------------------------------
# 5, 6, 14. moseg train: --out, --lr, --seed and --device checked before any data is read
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("preset", ["masknet", "whichnet", "clip-f5"])
@pytest.mark.parametrize(
    ("option", "value", "reason"),
    [
        ("--lr", "nan", "a learning rate is a finite number above 0"),
        ("--lr", "-1", "a learning rate is a finite number above 0"),
        ("--lr", "inf", "a learning rate is a finite number above 0"),
        ("--seed", "-1", "Input should be greater than or equal to 0"),
        ("--seed", "9" * 70, "Input should be less than or equal to 4294967295"),
        ("--device", "banana", "choose cpu, cuda, cuda:N, auto"),
        ("--device", "cuda:x", "choose cpu, cuda, cuda:N, auto"),
    ],
)
def test_train_option_values_are_usage_errors(
    tmp_path: Path, preset: str, option: str, value: str, reason: str
) -> None:
    # --lr nan, --seed -1 and a 70-digit seed were tracebacks; --device banana trained on the CPU (masknet) or exited 1.
    out = tmp_path / "m.pt"
    code, _, err = moseg("train", "--preset", preset, "--out", out, "--data-root", tmp_path / "none", option, value)
    assert code == 2 and one_error_line(err) == f"moseg: error: {option} {value}: {reason} (see 'moseg train --help')"
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("preset", ["masknet", "whichnet"])
def test_train_out_is_checked_before_the_data(tmp_path: Path, preset: str) -> None:
    # A folder as --out left a 225 KB d.tmp after the training; '' was a traceback; all after building the data.
    folder = tmp_path / "d"
    folder.mkdir()
    (tmp_path / "file").write_text("")
    cases = {
        folder: f"--out {folder}: a folder; give the checkpoint's file name (e.g. {folder / 'model.pt'})",
        Path(""): "--out .: a folder; give the checkpoint's file name (e.g. model.pt)",
        tmp_path / "file" / "m.pt": f"--out {tmp_path / 'file' / 'm.pt'}: {tmp_path / 'file'} is not a folder",
    }
    for out, message in cases.items():
        code, _, err = moseg("train", "--preset", preset, "--out", out, "--data-root", tmp_path / "none")
        assert code == 1 and one_error_line(err) == f"moseg: error: {message}", err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d", "file"] and list(folder.iterdir()) == []


def test_train_out_read_only_is_refused_before_the_data(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # The suite may run as root, for whom every folder is writable: the answer of access(2) is what is tested.
    real = os.access
    monkeypatch.setattr(os, "access", lambda p, mode: False if Path(p) == tmp_path else real(p, mode))
    code, _, err = moseg("train", "--preset", "masknet", "--out", tmp_path / "m.pt", "--data-root", tmp_path / "none")
    assert code == 1 and one_error_line(err) == (
        f"moseg: error: --out {tmp_path / 'm.pt'}: cannot write there ({tmp_path} is read-only)"
    )


def test_train_mask_recipe_refuses_a_device_torch_does_not_see(tmp_path: Path) -> None:
    import torch

    if torch.cuda.is_available():
        pytest.skip("a CUDA device is here")
    for device in ("cuda", "cuda:99"):
        code, _, err = moseg("train", "--preset", "masknet", "--out", tmp_path / "m.pt", "--device", device)
        assert code == 1 and "torch sees no CUDA device here" in one_error_line(err), err
    assert list(tmp_path.iterdir()) == []


def test_eval_device_name_is_a_usage_error(tmp_path: Path) -> None:
    # eval davis-clip5 --device banana was accepted.
    code, _, err = moseg("eval", "davis-clip5", "--out", tmp_path / "o", "--device", "banana")
    assert code == 2 and "--device banana: choose cpu, cuda, cuda:N, auto" in one_error_line(err)


def test_mask_network_save_leaves_no_temporary_file_on_a_full_disk(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A full disk left m.pt.tmp beside the checkpoint.
    import errno

    import torch

    from mosegpipe.masks.learned.net import MaskNet

    def full(obj: object, f: object) -> None:
        Path(f).write_bytes(b"half a checkpoint")  # type: ignore[arg-type]
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(torch, "save", full)
    with pytest.raises(OSError, match="No space left"):
        MaskNet().save(tmp_path / "m.pt")
    assert list(tmp_path.iterdir()) == []


def test_fit_runs_on_the_device_and_returns_a_cpu_network() -> None:
    import numpy as np
    import torch

    from mosegpipe.masks.learned.net import MaskNet
    from mosegpipe.training.masks.masknet import fit, mask_loss

    seen: list[str] = []
    net = MaskNet(widths=(4,))
    original = net.forward

    def forward(x: torch.Tensor) -> torch.Tensor:
        seen.append(str(x.device))
        return original(x)

    net.forward = forward  # type: ignore[method-assign]
    batch = lambda: (torch.zeros(2, net.in_channels, 8, 8), torch.zeros(2, 8, 8))  # noqa: E731
    device = "cuda" if torch.cuda.is_available() else "cpu"
    fit(net, 2, 1e-3, 0.0, 1, batch, mask_loss, lambda n: np.array([float(next(n.parameters()).is_cpu)]), None, device)
    assert seen == [device.split(":")[0]] * 2 and next(net.parameters()).is_cpu


# ---------------------------------------------------------------------------------------------
# 8, 9. Signals: batch workers start with Ctrl-C blocked; live --serve's server is out of its reach
# ---------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_batch_workers_are_born_ignoring_ctrl_c(tmp_path: Path) -> None:
    # A Ctrl-C while the workers started reached them before their initializer set it aside: a traceback each.
    import signal

    from mosegpipe.apps.batch.plan import Job
    from mosegpipe.apps.batch.pool import WorkerPool, mp_context
    from mosegpipe.pipeline import PipelineConfig, segment_clip

    from helpers import tiny_model

    before = signal.getsignal(signal.SIGINT)  # SIG_IGN where the suite runs as a background job
    pool = WorkerPool(1, tiny_model(5), Job(PipelineConfig(), False, "h", segment_clip))
    manager = pool.executor._executor_manager_thread
    pool.kill()
    # The executor's thread has closed its wake-up pipe before kill returns: left running, it raced the
    # interpreter's exit, which writes to that pipe ("Exception ignored ... Bad file descriptor" on stderr).
    assert manager is not None and not manager.is_alive()
    # A process the forkserver forks, before any code of ours runs in it: Ctrl-C does nothing there.
    child = mp_context().Process(target=signal.raise_signal, args=(signal.SIGINT,))
    child.start()
    child.join(60)
    assert child.exitcode == 0  # 1: a KeyboardInterrupt (and its traceback on stderr)
    assert signal.getsignal(signal.SIGINT) is before  # this process's handler is back


def test_ctrl_c_while_the_workers_start_waits_until_they_are_all_recorded() -> None:
    # Interrupted inside a worker's start, the batch left without killing that worker, which then printed
    # a FileNotFoundError traceback (the queue it was to read was gone).
    import signal
    import threading

    from mosegpipe.apps.batch.pool import stops_deferred

    if threading.current_thread() is not threading.main_thread():
        pytest.skip("signal handlers are the main thread's")
    # Python's own Ctrl-C handler, as in a terminal (a suite run as a background job inherits SIGINT ignored)
    outer = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        reached = []
        with pytest.raises(KeyboardInterrupt), stops_deferred():
            signal.raise_signal(signal.SIGINT)
            reached.append("the start went on")
        assert reached == ["the start went on"] and signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        signal.signal(signal.SIGINT, outer)


def test_live_serve_server_has_a_session_of_its_own(monkeypatch: pytest.MonkeyPatch) -> None:
    # Ctrl-C reached the server with the rest of the terminal's process group: Rerun's client then printed two
    # raw ANSI ERROR lines while the last frames were flushed to a server that was gone.
    import subprocess

    from mosegpipe.cli import live
    from mosegpipe.cli.view import find_viewer

    if find_viewer() is None:
        pytest.skip("no rerun program here")
    started: list[subprocess.Popen[bytes]] = []
    real = subprocess.Popen

    def popen(*args: object, **kwargs: object) -> subprocess.Popen[bytes]:
        started.append(real(*args, **kwargs))  # type: ignore[call-overload]
        return started[-1]

    monkeypatch.setattr(subprocess, "Popen", popen)
    with live._sinks(False, None, True) as sinks:
        assert len(sinks) == 1 and len(started) == 1
        assert os.getsid(started[0].pid) == started[0].pid != os.getsid(0)
    assert started[0].poll() is not None  # ended with the command


# ---------------------------------------------------------------------------------------------
# 11, 12, 14. eval: composite records --preset, --folds once each, --folds where there are none
# ---------------------------------------------------------------------------------------------


def test_composite_records_the_preset(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from mosegpipe.evaluation import composite
    from mosegpipe.evaluation.protocols import EvalRequest
    from mosegpipe.pipeline import PipelineConfig
    from mosegpipe.synth import composite as synth

    row = {"name": "dev-00", "plate": "bear", "objects": 2, "kinds": "", "j_per_object": "", "error": ""}
    row |= {key: 0.5 for key in (*composite.SUMMARY_FIELDS, "seconds")}
    monkeypatch.setattr(synth, "composite_set", lambda root, part, names=None: [])
    monkeypatch.setattr(composite, "composite_rows", lambda clips, mode, cfg, model: [dict(row)])
    req = EvalRequest(out_dir=tmp_path / "out", data_root=tmp_path, preset="fast", folds=("dev-00",))
    composite.run_composite("composite-clip5", req, PipelineConfig.from_options(5, preset="fast"))
    assert json.loads((tmp_path / "out" / "results.json").read_text())["config"]["preset"] == "fast"


def test_folds_are_taken_once_each_without_spaces(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # --folds bear,bear ran bear twice and counted it twice; ' dev-03' was refused as 'dev-03'.
    from mosegpipe.evaluation import protocols

    asked: list[object] = []

    class Fake:
        data = None

        @staticmethod
        def run(proto: object, req: protocols.EvalRequest) -> protocols.EvalResult:
            asked.append(req.folds)
            return protocols.EvalResult([], {}, "table")

    monkeypatch.setattr(protocols, "get_protocol", lambda name: Fake)
    code, _, err = moseg("eval", "davis", "--out", tmp_path / "o", "--folds", "bear,bear, dev-03 ,,")
    assert code == 0 and asked == [("bear", "dev-03")], err


def test_folds_of_a_protocol_without_folds_are_refused(tmp_path: Path) -> None:
    # eval rendered --folds nope ran every clip.
    code, _, err = moseg("eval", "rendered", "--out", tmp_path / "o", "--folds", "nope")
    assert code == 1 and one_error_line(err) == "moseg: error: --folds nope: rendered has no folds (it runs every clip)"
    assert not (tmp_path / "o").exists()


# ---------------------------------------------------------------------------------------------
# 13. One --config file for every command: a key of another command is not an error
# ---------------------------------------------------------------------------------------------


def test_a_config_file_is_shared_across_commands(tmp_path: Path) -> None:
    # CLI.md's own example broke `moseg pair` (unknown key 'frames'), a top-level preset pair and tracks.
    shared = tmp_path / "moseg.toml"
    shared.write_text('frames = 5\nk-method = "residual"\npreset = "fast"\nwin-size = 31\n[run]\nwhole = true\n')
    for command in (("pair", tmp_path / "a.png", tmp_path / "b.png"), ("tracks", tmp_path / "t.npz")):
        code, _, err = moseg(*command, "--config", shared, "-o", tmp_path / "o")
        assert code == 1 and one_error_line(err).endswith(
            ": no such image file" if command[0] == "pair" else ": no such file"
        )
    # A key no command reads, and a command's own table, are still checked.
    (tmp_path / "typo.toml").write_text("framez = 5\n")
    code, _, err = moseg("pair", tmp_path / "a.png", tmp_path / "b.png", "--config", tmp_path / "typo.toml")
    assert code == 1 and "unknown key 'framez' for 'moseg pair'" in one_error_line(err)
    (tmp_path / "table.toml").write_text("[pair]\nframes = 5\n")
    code, _, err = moseg("pair", tmp_path / "a.png", tmp_path / "b.png", "--config", tmp_path / "table.toml")
    assert code == 1 and "unknown key 'pair.frames' for 'moseg pair'" in one_error_line(err)


# ---------------------------------------------------------------------------------------------
# 15. Words that point at the cause
# ---------------------------------------------------------------------------------------------


def test_a_one_frame_track_file_says_so(tmp_path: Path) -> None:
    import numpy as np

    path = tmp_path / "t.npz"
    np.savez(path, xy=np.random.default_rng(0).random((30, 1, 2)).astype(np.float32) * 100)
    code, _, err = moseg("tracks", path, "-o", tmp_path / "o")
    assert code == 1 and one_error_line(err) == (
        f"moseg: error: {path}: the tracks span 1 frame; segmenting needs tracks over 2 or more frames"
    )


def test_stdin_frames_without_tracks_name_the_stdin_size(tmp_path: Path) -> None:
    # 384-px frames given as 383 px wide got "textureless video?" only: a 1-px shear is too little to tell.
    from typer.testing import CliRunner

    from mosegpipe.cli.main import app

    data = bytes(20 * 160 * 120 * 3)  # blank frames: no tracks, nothing to tell a shear by
    args = ["live", "-", "--stdin-size", "159x120", "--no-rrd", "--out", str(tmp_path / "o")]
    result = CliRunner().invoke(app, args, input=data)
    assert result.exit_code == 1, result.stderr
    assert one_error_line(result.stderr).endswith("(raw frames read as 159x120: is --stdin-size right?)")


def test_a_full_disk_names_the_file_being_written(tmp_path: Path) -> None:
    # A full disk shows when a file is closed, and Python's OSError then names no file: `--overwrite` on a full
    # disk said "moseg: error: No space left on device" alone.
    import errno

    from mosegpipe.io.read import atomic_write

    final = tmp_path / ".o.partial" / "overlay" / "000003.jpg"
    with pytest.raises(OSError) as caught, atomic_write(final) as tmp:
        tmp.write_bytes(b"half a frame")
        raise OSError(errno.ENOSPC, "No space left on device")
    assert caught.value.errno == errno.ENOSPC and caught.value.filename == str(final)
    assert list(final.parent.iterdir()) == []
    from mosegpipe.cli.app import shown_path

    assert shown_path(caught.value.filename) == str(tmp_path / "o" / "overlay" / "000003.jpg")
