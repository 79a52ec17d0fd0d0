"""A whole video's output folder is a sink the run feeds (mosegpipe.apps.video_outputs): what a caller's own loop
writes is what `write_video_outputs` writes, and a run that fails half way leaves no folder behind."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mosegpipe.apps.video_outputs import VideoOutputs, feed_windows, video_summary, write_video_outputs
from mosegpipe.embed.numpy_net import load_embedder
from mosegpipe.pipeline import PipelineConfig, segment_video

VIDEO = Path(__file__).resolve().parents[1] / "samples" / "vtest_8f.avi"
CFG = PipelineConfig(frames=3)


def _folder_files(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted((folder / "masks").iterdir())}


def test_a_callers_own_loop_writes_what_write_video_outputs_writes(tmp_path: Path) -> None:
    model = load_embedder(CFG.frames)
    written = write_video_outputs(VIDEO, tmp_path / "a", CFG, model, rrd=False)
    shown: list[int] = []
    with VideoOutputs(tmp_path / "b", CFG, fps=0.0, rrd=False) as sink:
        windows = segment_video(VIDEO, CFG, model, masks=False)
        feed_windows(windows, CFG, sink, on_frame=lambda fr, mask: shown.append(fr.index))
        sink.finish()
        fed = video_summary(VIDEO, {"size_hw": (288, 384)}, sink.windows, CFG, model, 1.0)
        sink.write_summary(fed)
    assert shown == list(range(8)) and fed["frames"] == written["frames"] == 8
    assert _folder_files(tmp_path / "b") == _folder_files(tmp_path / "a") and len(_folder_files(tmp_path / "a")) == 8
    a, b = np.load(tmp_path / "a" / "labels.npz"), np.load(tmp_path / "b" / "labels.npz")
    assert sorted(a.files) == sorted(b.files) and all(np.array_equal(a[k], b[k]) for k in a.files)
    assert (tmp_path / "b" / "overlay.mp4").stat().st_size > 0 and (tmp_path / "b" / "summary.json").is_file()


def test_a_run_that_fails_after_its_first_window_leaves_no_folder(tmp_path: Path) -> None:
    model = load_embedder(CFG.frames)

    def two_then_fail():  # type: ignore[no-untyped-def]
        for i, window in enumerate(segment_video(VIDEO, CFG, model, masks=False)):
            if i == 1:
                raise KeyboardInterrupt
            yield window

    with pytest.raises(KeyboardInterrupt), VideoOutputs(tmp_path / "o", CFG, fps=25.0) as sink:
        feed_windows(two_then_fail(), CFG, sink)
    assert list(tmp_path.iterdir()) == []


def test_without_a_sink_the_loop_still_gives_every_frame_its_mask() -> None:
    masks: dict[int, np.ndarray] = {}
    windows = segment_video(VIDEO, CFG, load_embedder(CFG.frames), masks=False)
    feed_windows(windows, CFG, None, on_frame=lambda fr, mask: masks.setdefault(fr.index, mask))
    assert sorted(masks) == list(range(8))
    assert all(
        m.shape == (288, 384) and m.dtype == np.uint8 and (m == 0).any() and (m == 1).any() for m in masks.values()
    )
