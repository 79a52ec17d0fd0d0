"""One colour per mask value in every output (mosegpipe.colours): the mask PNGs, the overlays and the
recordings of a clip, a pair and a whole video; and the summary's account of the K written."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image

from mosegpipe import colours, masks
from mosegpipe.apps.outputs import write_clip_outputs, write_mask_png, write_pair_outputs
from mosegpipe.pipeline import ClipResult, PairResult, PipelineConfig
from mosegpipe.types import Clustering, Frames, Matches, Tracks, Trajectories

from helpers import annotation_contexts

BLOCK = 16  # px per value in the mosaic masks
GREY = 100  # the flat frame under the masks


def _mosaic(values: list[int]) -> np.ndarray:
    """(16 * rows, 16 * 16) uint8 mask: value values[i] in the i-th 16 x 16 block, 0 where none is left."""
    rows = -(-len(values) // 16)
    cells = np.zeros(rows * 16, np.uint8)
    cells[: len(values)] = values
    return np.kron(cells.reshape(rows, 16), np.ones((BLOCK, BLOCK), np.uint8)).astype(np.uint8)


def _at(image: np.ndarray, i: int) -> np.ndarray:
    """Mean colour of the middle 8 x 8 pixels of block i."""
    y, x = (i // 16) * BLOCK + 4, (i % 16) * BLOCK + 4
    return image[y : y + 8, x : x + 8].reshape(-1, image.shape[-1]).mean(axis=0)


def _png_colours(path: Path, values: list[int]) -> dict[int, tuple[int, ...]]:
    """Value -> RGB of a mask PNG as an image viewer shows it (the file's own palette)."""
    with Image.open(path) as png:
        assert png.mode == "P"
        index = np.asarray(png)
        palette = np.array(png.getpalette()[: 3 * 256], np.uint8).reshape(-1, 3)
    assert [int(index[int(c[0]), int(c[1])]) for c in (_centre(i) for i in range(len(values)))] == values
    return {v: tuple(int(c) for c in palette[v]) for v in values}


def _centre(i: int) -> tuple[int, int]:
    return (i // 16) * BLOCK + BLOCK // 2, (i % 16) * BLOCK + BLOCK // 2


def _assert_one_colour(
    folder_png: Path, overlay_jpg: Path | None, rrd: Path, mask_entity: str, values: list[int], unknown: str
) -> None:
    """Every value in `values` has one colour: the PNG's palette, the overlay (exactly at alpha 1; the
    written JPEG at alpha 0.45, blended over the flat frame) and the recording's two contexts."""
    mask = _mosaic(values)
    image = np.full((*mask.shape, 3), GREY, np.uint8)
    png = _png_colours(folder_png, values)
    full = masks.overlay_image(image, mask, np.zeros((0, 2), np.float32), np.zeros(0, np.int64), alpha=1.0)
    written = None if overlay_jpg is None else cv2.imread(str(overlay_jpg))[:, :, ::-1]
    contexts = annotation_contexts(rrd)
    assert {"/", mask_entity} <= set(contexts)
    mask_ctx, point_ctx = contexts[mask_entity], contexts["/"]
    for i, v in enumerate(values):
        name, rgba = mask_ctx[v]  # every value the masks can hold has a class
        assert point_ctx[v][0] == name
        tint = _at(full, i)
        if v == colours.WORLD:  # the world is never coloured: black in the PNG, untinted, transparent
            assert png[v] == (0, 0, 0) and (tint == GREY).all() and rgba[3] == 0, v
            assert point_ctx[v][1] == (*colours.WORLD_POINT_RGB, 255)
            continue
        assert png[v] == tuple(tint) == rgba[:3] == point_ctx[v][1][:3], (v, png[v], tint, rgba, point_ctx[v])
        assert rgba[3] == 255 and point_ctx[v][1][3] == 255
        if written is not None:  # 0.55 frame + 0.45 colour, through JPEG
            np.testing.assert_allclose(_at(written, i), 0.55 * GREY + 0.45 * np.array(png[v]), atol=12, err_msg=str(v))
    assert mask_ctx[colours.MOVING_UNCLUSTERED][0] == "moving, no clustered motion"
    assert mask_ctx[colours.UNKNOWN] == (unknown, (*colours.UNKNOWN_RGB, 255))
    assert mask_ctx[colours.WORLD][0] == "the world (motion 0)"


def _clip_result(mask: np.ndarray, k: int, scores: dict[int, float], note: str = "") -> ClipResult:
    num = 2
    images = np.full((num, *mask.shape, 3), GREY, np.uint8)
    xy = np.stack([np.array([[2.0, 15.0], [18.0, 15.0]], np.float32)] * num, axis=1)  # (2 tracks, T, 2)
    tracks = Tracks(xy=xy, visible=np.ones((2, num), bool), size_hw=mask.shape)
    traj = Trajectories(data=xy.reshape(2, -1), track_ids=np.arange(2, dtype=np.int64))
    clustering = Clustering(np.array([0, k - 1], np.int64), k, scores, "silhouette", note)
    return ClipResult(
        frames=Frames(images, fps=10.0, source="", start=0),
        tracks=tracks,
        trajectories=traj,
        embeddings=np.eye(2, 3, dtype=np.float32),
        clustering=clustering,
        masks=np.stack([mask] * num),
        timings={},
        model_info={},
    )


def test_clip_every_value_has_one_colour(tmp_path: Path) -> None:
    k = 3
    values = [*range(k), colours.MOVING_UNCLUSTERED, colours.UNKNOWN]
    out = tmp_path / "clip"
    write_clip_outputs(_clip_result(_mosaic(values), k, {2: 0.4, 3: 0.45}), out)
    _assert_one_colour(
        out / "masks" / "000000.png",
        out / "overlay" / "000000.jpg",
        out / "recording.rrd",
        "/video/mask",
        values,
        "unknown",
    )


def test_pair_every_value_has_one_colour(tmp_path: Path) -> None:
    values = [0, 1, 2, colours.UNKNOWN]
    mask = _mosaic(values)
    image = np.full((*mask.shape, 3), GREY, np.uint8)
    xy = np.array([[2.0, 15.0], [18.0, 15.0], [34.0, 15.0]], np.float32)  # dots clear of the sampled middles
    matches = Matches(xy1=xy, xy2=xy, score=np.zeros(3, np.float32), size1_hw=mask.shape, size2_hw=mask.shape)
    result = PairResult(
        images=(image, image),
        matches=matches,
        embeddings=np.eye(3, dtype=np.float32),
        clustering=Clustering(np.array([0, 1, 2]), 3, {2: 0.3, 3: 0.5}, "silhouette"),
        labels=np.array([0, 1, -1]),
        outlier_cluster=2,
        masks=(mask, mask),
        timings={},
        model_info={},
    )
    out = tmp_path / "pair"
    write_pair_outputs(result, out, PipelineConfig(frames=2))
    for i in (0, 1):
        png, jpg = out / "masks" / f"00000{i}.png", out / "overlay" / f"00000{i}.jpg"
        _assert_one_colour(png, jpg, out / "recording.rrd", f"/image{i + 1}/mask", values, "unknown / outlier")


def test_whole_video_every_value_has_one_colour(tmp_path: Path) -> None:
    from mosegpipe.viz import VideoRecorder, VizConfig

    values = list(range(256))  # a video names every value up front
    mask = _mosaic(values)
    write_mask_png(tmp_path / "000000.png", mask)  # as write_video_outputs writes each frame's mask
    with VideoRecorder(tmp_path / "video.rrd", cfg=VizConfig(video_frames="jpeg"), fps=10.0) as rec:
        rec.log_frame(0, np.full((*mask.shape, 3), GREY, np.uint8), np.zeros((0, 2), np.float32), [], [], mask)
    _assert_one_colour(tmp_path / "000000.png", None, tmp_path / "video.rrd", "/video/mask", values, "unknown")


def test_the_colour_table() -> None:
    # The values mean what mosegpipe.masks says they mean.
    assert (colours.MOVING_UNCLUSTERED, colours.UNKNOWN) == (masks.MOVING_UNCLUSTERED, masks.UNKNOWN)
    palette = colours.mask_palette()
    assert len({tuple(c) for c in palette}) == 256  # no two values alike; unknown's grey is no motion's
    np.testing.assert_array_equal(palette[:255], colours.voc_palette()[:255])  # DAVIS colours for the rest
    assert tuple(palette[colours.MOVING_UNCLUSTERED]) == (96, 224, 192)  # teal
    assert tuple(palette[colours.UNKNOWN]) == colours.UNKNOWN_RGB
    assert colours.value_names(2) == {
        0: "the world (motion 0)",
        1: "motion 1",
        254: "moving, no clustered motion",
        255: "unknown",
    }
    assert len(colours.value_names(255)) == 256  # motions 0..253, then 254 and 255


# --- the K written and why -------------------------------------------------------------------


def test_summary_says_the_k_written_and_that_the_rigid_check_split_a_motion(tmp_path: Path) -> None:
    from test_viz import _column, _read

    note = "the rigid-motion check split off 1 group (K = 2 -> 3)"
    values = [0, 1, 2, colours.UNKNOWN]
    out = tmp_path / "clip"
    summary = write_clip_outputs(_clip_result(_mosaic(values), 3, {2: 0.459, 3: 0.436}, note), out)
    expected = (
        "K = 3 written: automatic K chose 2 (score 0.459, runner-up K = 3: 0.436), "
        "the rigid-motion check split off 1 group"
    )
    assert summary["k_reason"] == expected
    assert json.loads((out / "summary.json").read_text())["k_reason"] == expected
    got = _read(out / "recording.rrd")["batches"]
    text = _column(got["/summary"], "TextDocument:text")[0][0]
    assert text.startswith(f"**{expected}**\n\n") and "margin" not in text
    # The chart marks the K automatic K chose; the summary says how the 3 came about.
    colors = _column(got["/k_scores/scores"], "Points2D:colors")[0]
    assert colors[0] != colors[1]


@pytest.mark.parametrize(
    ("k", "scores", "note", "method", "expected"),
    [
        (
            2,
            {2: 0.6, 3: 0.1},
            "",
            "silhouette",
            "K = 2 written: automatic K chose it (score 0.6, runner-up K = 3: 0.1)",
        ),
        (4, {}, "", "fixed", "K = 4 written: given (--k)"),
        (
            1,
            {},
            "K = 1: one motion explains every track",
            "residual",
            "K = 1 written, without a score per K (K = 1: one motion explains every track)",
        ),
        (
            5,
            {2: 0.5, 3: 0.49},
            "the K choice is ambiguous: ...; the rigid-motion check split off 2 groups (K = 3 -> 5)",
            "silhouette",
            "K = 5 written: automatic K chose 3 (score 0.49, runner-up K = 2: 0.5), the rigid-motion check split off 2 groups",
        ),
    ],
)
def test_k_statement(k: int, scores: dict[int, float], note: str, method: str, expected: str) -> None:
    from mosegpipe.viz import k_statement

    assert k_statement(k, scores, note, method) == expected


def test_the_statement_reads_the_note_check_rigid_writes(monkeypatch: pytest.MonkeyPatch) -> None:
    from mosegpipe.group import refine as common
    from mosegpipe.viz import k_statement

    def split_one(points, labels, size_hw, cfg, max_k):  # the check finds one group that its motion does not explain
        return np.where(np.arange(len(labels)) == 0, labels.max() + 1, labels), 1

    monkeypatch.setattr(common, "split_by_rigid_motion", split_one)
    before = Clustering(np.array([0, 0, 1, 1]), 2, {2: 0.459, 3: 0.436}, "silhouette")
    after = common.check_rigid(before, np.zeros((4, 10), np.float32), (48, 64), PipelineConfig(frames=5))
    assert after.k == 3
    assert k_statement(after.k, after.scores, after.note, after.method) == (
        "K = 3 written: automatic K chose 2 (score 0.459, runner-up K = 3: 0.436), the rigid-motion check split off 1 group"
    )
