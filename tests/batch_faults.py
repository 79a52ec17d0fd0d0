"""Faults on demand for the batch tests: a segment_fn that fails, kills its worker or hangs by clip name.

A module of its own (not a test module) so that worker processes and Ray workers can import or
unpickle it without collecting tests. The clip's file or folder name decides:
"boom*" raises RuntimeError, "crash*" SIGKILLs its own process, "hang*" sleeps for an hour,
"slow*" sleeps SLOW_S first, "warn*" logs a warning (WARNING_TEXT) and is segmented, "stuck*" is
segmented and then hangs while its output folder is half written (after touching the file
`<clip>.writing` beside it); anything else is segmented normally.
"""

from __future__ import annotations

import logging
import os
import signal
import time
from pathlib import Path
from typing import Any

from mosegpipe.pipeline import PipelineConfig, segment_clip

SLOW_S = 0.4
WARNING_TEXT = "only a few tracks on the moving object"


def _hang_after_labels(source: Path) -> None:
    """From now on in this process, writing labels.npz (the first output file) hangs for an hour."""
    import mosegpipe.apps.outputs as outputs

    real = outputs.write_npz

    def write_npz(*args: Any, **kwargs: Any) -> None:
        real(*args, **kwargs)
        Path(f"{source}.writing").touch()
        time.sleep(3600)

    outputs.write_npz = write_npz  # type: ignore[assignment]


def faulty_segment(source: Path, cfg: PipelineConfig, model: Any) -> Any:
    name = Path(source).name
    if name.startswith("boom"):
        raise RuntimeError("boom\nin two lines")
    if name.startswith("crash"):
        os.kill(os.getpid(), signal.SIGKILL)
    if name.startswith("hang"):
        time.sleep(3600)
    if name.startswith("slow"):
        time.sleep(SLOW_S)
    if name.startswith("warn"):
        logging.getLogger("mosegpipe.pipeline").warning(WARNING_TEXT)
    if name.startswith("stuck"):
        _hang_after_labels(Path(source))
    return segment_clip(source, cfg, model)
