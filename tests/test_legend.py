"""The legend: which colour is which motion and how many tracks it has, drawn into the overlays and written
into the recordings, each value always in the colour of its tracks' dots and its mask pixels."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mosegpipe import colours
from mosegpipe.masks import draw_legend, overlay_image, overlay_with_legend
from mosegpipe.types import Frames, Tracks
from mosegpipe.viz import VideoRecorder, write_recording


def _legend_texts(path: Path) -> list[str]:
    """Every text logged at /legend in a recording, in file order."""
    from rerun.chunk import RrdReader

    texts = []
    for chunk in RrdReader(path).stream().to_chunks():
        if chunk.entity_path == "/legend":
            batch = chunk.to_record_batch()
            texts += [row[0] for row in batch.column("TextDocument:text").to_pylist()]
    return texts


def test_rows_count_tracks_and_keep_each_values_colour() -> None:
    rows = colours.legend_rows(np.array([0, 0, 0, 2, 2, 5, -1]), np.array([254]))
    assert [(v, name, n) for v, name, _, n in rows] == [
        (0, "the world (motion 0)", 3),
        (2, "motion 2", 2),
        (5, "motion 5", 1),
        (254, "moving, no clustered motion", 0),
    ]
    dots = colours.point_palette()
    assert all(rgb == tuple(dots[v]) for v, _, rgb, _ in rows)  # the colour of the value's dots, any frame
    assert colours.legend_rows(np.array([5]))[0][2] == rows[2][2]


def test_overlay_legend_sits_in_the_corner_with_the_motions_colours() -> None:
    image = np.full((240, 320, 3), 128, np.uint8)
    mask = np.zeros((240, 320), np.uint8)
    mask[150:200, 200:260] = 1
    xy = np.array([[230.0, 170.0], [50.0, 200.0], [60.0, 210.0]], np.float32)
    labels = np.array([1, 0, 0])
    plain = overlay_image(image, mask, xy, labels)
    shown = overlay_with_legend(image, mask, xy, labels)
    changed = np.argwhere((shown != plain).any(axis=2))
    assert changed.size and changed[:, 0].max() < 60 and changed[:, 1].max() < 200  # the top-left corner only
    red = tuple(colours.point_palette()[1])
    assert (shown[:60, :40] == red).all(axis=2).sum() >= 9  # the swatch of motion 1
    tiny = overlay_image(image[:16, :40], mask[:16, :40], xy[:0], labels[:0])
    np.testing.assert_array_equal(draw_legend(tiny.copy(), colours.legend_rows(labels)), tiny)  # no room: none


def test_clip_recording_holds_the_legend(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    frames = Frames(rng.integers(0, 256, (2, 24, 32, 3), dtype=np.uint8))
    xy = np.tile(np.array([[4.0, 4.0], [8.0, 8.0], [20.0, 10.0]], np.float32)[:, None], (1, 2, 1))
    tracks = Tracks(xy=xy, visible=np.ones((3, 2), bool), size_hw=(24, 32))
    masks = np.zeros((2, 24, 32), np.uint8)
    masks[:, :, 16:] = 1
    masks[1, :2, :2] = 255
    labels = np.array([0, 0, 1])
    path = write_recording(tmp_path / "clip.rrd", frames, tracks, np.arange(3), labels, np.eye(3), masks, {}, 2)
    (text,) = _legend_texts(path)
    assert "| 0 | #ffffff | the world (motion 0) | 2 |" in text
    assert "| 1 | #800000 | motion 1 | 1 |" in text
    assert "| 255 | #a0a0a0 | unknown | 0 |" in text


def test_video_recording_has_a_legend_per_window(tmp_path: Path) -> None:
    path = tmp_path / "video.rrd"
    with VideoRecorder(path, fps=10.0) as rec:
        rec.log_window(0, 2, {2: 0.5}, labels=np.array([0, 0, 3]))
        rec.log_frame(0, np.zeros((16, 16, 3), np.uint8), np.zeros((1, 2)), np.array([0]), np.array([0]))
        rec.log_window(4, 2, {2: 0.5}, labels=np.array([0, 4]))
        rec.log_frame(4, np.zeros((16, 16, 3), np.uint8), np.zeros((1, 2)), np.array([0]), np.array([0]))
    first, second = _legend_texts(path)
    assert "motion 3 | 1 |" in first and "motion 4" not in first
    assert "motion 4 | 1 |" in second and "motion 3" not in second
