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
