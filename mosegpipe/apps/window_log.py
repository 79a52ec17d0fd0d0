"""What a whole-video run's outputs keep of its windows (`WindowLog`): each window's row of summary.json, and
labels.npz's arrays spooled to the output folder as the windows arrive (memory flat over a long live run)."""

from __future__ import annotations

import array
from pathlib import Path

import numpy as np

from mosegpipe.io.read import write_npz
from mosegpipe.pipeline import WindowResult

_RECORD_FIELDS = ("start", "frames", "num_tracks", "k", "k_ambiguous", "shot_start")
"""WindowResult.record()'s keys, in the order WindowLog keeps them."""


class WindowLog:
    """What a whole-video run's outputs keep of its windows, in (nearly) constant memory.

    summary.json needs each window's record (six integers here, 48 bytes a window) and labels.npz every
    labelled track's id and label: those go to spool files in the output folder as the windows arrive and
    are read back in chunks when labels.npz is written (a long live run held them all in memory before:
    about 13 kB a window, 5 MiB a minute at 25 frames/s).

    Args:
        folder: where the spool files go (the output folder under construction); they are removed by
            `write_labels`.
    """

    def __init__(self, folder: Path) -> None:
        self._records = array.array("q")
        self._paths = {name: folder / f".labels-{name}.bin" for name in ("track_ids", "labels", "window")}
        self._files = {name: open(p, "wb") for name, p in self._paths.items()}  # noqa: SIM115 (closed in write_labels)
        self.num_windows = 0
        self.num_frames_read = 0
        self.num_motions = 0
        self.num_labels_reused = 0

    def add(self, window: WindowResult) -> None:
        """Keeps a window's record and spools its labelled tracks."""
        record = window.record()
        self._records.extend(int(record[key]) for key in _RECORD_FIELDS)
        if window.is_labelled:
            self._files["track_ids"].write(np.asarray(window.track_ids, np.int64).tobytes())
            self._files["labels"].write(np.asarray(window.labels, np.int64).tobytes())
            self._files["window"].write(np.full(window.track_ids.size, self.num_windows, np.int64).tobytes())
        self.num_windows += 1
        self.num_frames_read = window.num_frames_read
        self.num_motions = window.num_motions
        self.num_labels_reused = window.num_labels_reused

    def records(self) -> list[dict[str, int | bool]]:
        """Each window's row in summary.json (WindowResult.record())."""
        rows = np.frombuffer(self._records, np.int64).reshape(-1, len(_RECORD_FIELDS)).tolist()
        flags = ("k_ambiguous", "shot_start")
        return [{key: bool(v) if key in flags else v for key, v in zip(_RECORD_FIELDS, row)} for row in rows]

    def write_labels(self, path: Path) -> None:
        """labels.npz of the video: the labelled windows' track ids and labels, and each one's window (its
        index among all windows); the arrays are read from the spool files in chunks, which are then removed."""
        self.close()
        arrays = {
            name: np.memmap(p, np.int64, mode="r") if p.stat().st_size else np.zeros(0, np.int64)
            for name, p in self._paths.items()
        }
        write_npz(path, **arrays)
        del arrays
        for p in self._paths.values():
            p.unlink()

    def close(self) -> None:
        """Closes the spool files (write_labels does; for a run that failed, the folder goes anyway)."""
        for fh in self._files.values():
            fh.close()

    def __enter__(self) -> WindowLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
