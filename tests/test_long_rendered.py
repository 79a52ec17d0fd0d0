"""The long-rendered-video protocol: its clip with a cut, labels per object, video-level rows."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from mosegpipe import pipeline
from mosegpipe.evaluation.e2e import labels_per_object, long_rendered_clip, long_rendered_rows
from mosegpipe.evaluation.protocols import get_protocol
from mosegpipe.synth.render import RenderedClip


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


def _oracle(clip: RenderedClip, switch_at: int | None = None) -> Callable[..., Iterator[SimpleNamespace]]:
    """A stand-in for segment_video that hands out the ground truth (object i -> label i, world 0) in
    windows of 5 frames; from frame `switch_at` on, object 1 gets a new label (an identity switch)."""

    def segment_video(source: str, cfg: object, model: object) -> Iterator[SimpleNamespace]:
        assert len(list(Path(source).glob("*.png"))) == len(clip.frames)  # the clip went to disk whole
        masks = clip.masks.copy()
        if switch_at is not None:
            masks[switch_at:][masks[switch_at:] == 1] = 200
        for start in range(0, len(masks), 5):
            frames = [SimpleNamespace(index=t, mask=masks[t]) for t in range(start, min(start + 5, len(masks)))]
            yield SimpleNamespace(num_motions=int(masks[: start + 5].max()), frames=frames)

    return segment_video


def test_long_rendered_rows_score_the_masks_segment_video_gives(monkeypatch: pytest.MonkeyPatch) -> None:
    clip = long_rendered_clip(1, size_hw=(120, 160), frames=16)
    visible = labels_per_object(clip.masks, clip.masks)  # every object with 200 px somewhere: 1 label
    monkeypatch.setattr(pipeline, "segment_video", _oracle(clip))
    (row,) = long_rendered_rows(None, seeds=[1], size_hw=(120, 160), frames=16)
    assert (row["seed"], row["camera"], row["objects"]) == (1, clip.camera_motion, len(visible))
    assert (row["J"], row["F"]) == (1.0, 1.0)
    assert row["labels_per_object"] == row["max_labels_per_object"] == row["moving_labels_per_object"] == 1
    assert row["num_motions"] == clip.masks.max() and row["fps"] > 0

    # Object 1 relabelled half-way: two labels for it, and video-level J scores only the frames with
    # the label it kept most (its other frames count as misses).
    monkeypatch.setattr(pipeline, "segment_video", _oracle(clip, switch_at=4))
    (row,) = long_rendered_rows(None, seeds=[1], size_hw=(120, 160), frames=16)
    assert row["max_labels_per_object"] == 2 and row["labels_per_object"] == (len(visible) + 1) / len(visible)
    assert row["J"] < 1.0 and row["F"] < 1.0


def test_long_rendered_rows_segment_a_short_video() -> None:
    """The real pipeline on 16 frames (a cut after 8): it finds the moving objects of both shots (0.79 /
    0.80 when measured; the floor leaves room for changes in the mask steps)."""
    (row,) = long_rendered_rows(None, seeds=[1], size_hw=(120, 160), frames=16)
    assert (row["camera"], row["objects"]) == ("pan|forward", 3)
    assert row["num_motions"] >= 2  # new objects after the cut get labels of their own
    assert row["J"] > 0.5 and row["F"] > 0.5
    assert get_protocol("rendered-long").kind == "end-to-end"
