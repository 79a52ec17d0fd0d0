"""Faults on demand for the batch tests: a segment_fn that fails, kills its worker or hangs by clip name.

A module of its own (not a test module) so that worker processes and Ray workers can import or
unpickle it without collecting tests. The clip's file or folder name decides:
"boom*" raises RuntimeError, "crash*" SIGKILLs its own process, "hang*" sleeps for an hour,
"slow*" sleeps SLOW_S first; anything else is segmented normally.
"""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path
from typing import Any

from mosegpipe.pipeline import PipelineConfig, segment_clip

SLOW_S = 0.4


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
    return segment_clip(source, cfg, model)
