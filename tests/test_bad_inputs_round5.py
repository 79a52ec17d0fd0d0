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

from mosegpipe.locks import output_lock, output_lock_path

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

    from mosegpipe.learned.features import NUM_CHANNELS
    from mosegpipe.learned.net import shipped_path

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
    from mosegpipe.learned.net import shipped_path

    for model in (shipped_path("moving"), tmp_path / "nonexistent.pt"):
        for protocol in ("davis", "davis-clip5"):
            code, _, err = moseg("eval", protocol, "--out", tmp_path / "out", "--data-root", tmp_path, "--model", model)
            assert code == 1 and one_error_line(err).startswith(f"moseg: error: {model}: "), err
            assert not (tmp_path / "out").exists()


def test_mask_checkpoint_without_widths_is_a_checkpoint_error(bad_masknets: dict[str, Path]) -> None:
    from mosegpipe.errors import CheckpointError
    from mosegpipe.learned.net import MaskNet

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
    from mosegpipe.io import video_info

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
