"""The long-rendered-video protocol: its clip with a cut, labels per object, video-level rows."""

from __future__ import annotations

import numpy as np

from mosegpipe.evaluation.e2e import labels_per_object, long_rendered_clip, long_rendered_rows
from mosegpipe.evaluation.protocols import get_protocol


def test_labels_per_object_counts_identity_switches() -> None:
    gt = np.zeros((3, 20, 20), np.uint8)
    gt[:, 5:15, 5:15] = 1  # one object, 100 px in every frame
    pred = np.zeros_like(gt)
    pred[0:2, 5:15, 5:15] = 3
    pred[2, 5:15, 5:15] = 4  # its label switches in the last frame
    assert labels_per_object(pred, gt, min_px=50) == {1: 2}
    pred[2, 5:15, 5:15] = 255  # unknown there: the frame says nothing
    assert labels_per_object(pred, gt, min_px=50) == {1: 1}
    assert labels_per_object(pred, gt, min_px=101) == {}  # too small in every frame
    pred[2, 5:15, 5:15] = 0  # taken for the background in the last frame
    assert labels_per_object(pred, gt, min_px=50) == {1: 2}
    assert labels_per_object(pred, gt, min_px=50, ignore=0) == {1: 1}


def test_long_clip_has_a_cut_and_new_object_ids_after_it() -> None:
    clip = long_rendered_clip(0, size_hw=(60, 80), frames=10)
    assert clip.frames.shape == (10, 60, 80, 3) and clip.masks.shape == (10, 60, 80)
    assert "|" in clip.camera_motion
    first, second = set(np.unique(clip.masks[:5])) - {0}, set(np.unique(clip.masks[5:])) - {0}
    assert first.isdisjoint(second)  # objects after the cut are other objects
    assert np.abs(clip.frames[5].astype(int) - clip.frames[4].astype(int)).mean() > 20  # a real cut


def test_long_rendered_rows_score_a_short_video() -> None:
    rows = long_rendered_rows(None, seeds=[1], size_hw=(120, 160), frames=16)
    (row,) = rows
    assert 0.0 <= row["J"] <= 1.0 and 0.0 <= row["F"] <= 1.0
    assert row["num_motions"] >= 1 and row["labels_per_object"] >= 1.0
    assert get_protocol("rendered-long").kind == "end-to-end"
