from __future__ import annotations

import pickle
import subprocess
import sys
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from mosegpipe import viz
from mosegpipe.errors import InputError
from mosegpipe.masks import MaskConfig, labels_to_masks
from mosegpipe.types import Frames, Tracks
from mosegpipe.viz import (
    VizConfig,
    class_names,
    embedding_to_3d,
    fit_in_box,
    k_chart,
    k_margin,
    score_lead,
    write_recording,
)

from helpers import annotation_contexts, assert_layout_first

T, H, W = 3, 24, 32


def _inputs() -> dict:
    rng = np.random.default_rng(0)
    frames = Frames(rng.integers(0, 256, (T, H, W, 3), dtype=np.uint8), fps=10.0, source="synthetic", start=10)
    xy = np.zeros((6, T, 2), np.float32)
    xy[:, 0] = [[4, 4], [8, 20], [16, 12], [24, 4], [28, 20], [12, 8]]
    for t in range(1, T):
        xy[:, t] = xy[:, 0] + [t, -0.5 * t]
    visible = np.ones((6, T), bool)
    visible[2, 2] = False  # lost in the last frame
    xy[2, 2] = np.nan
    tracks = Tracks(xy=xy, visible=visible, size_hw=(H, W))
    track_ids = np.array([0, 1, 2, 3, 4], np.int64)  # track 5 was not segmented
    labels = np.array([0, 0, 1, 1, 1], np.int64)
    masks = labels_to_masks(tracks, track_ids, labels, MaskConfig(max_distance_px=10))
    return dict(
        frames=frames,
        tracks=tracks,
        track_ids=track_ids,
        labels=labels,
        embeddings=rng.normal(size=(5, 4)),
        masks=masks,
        k_scores={1: 0.5, 2: 0.1, 3: 0.3},
        k=2,
    )


def _read(path: Path) -> dict:
    import pyarrow as pa
    from rerun.chunk import RrdReader

    reader = RrdReader(path)
    reader.store()  # reads the footer manifest: fails on a file that was not closed properly
    rows: Counter[str] = Counter()
    batches: dict[str, list] = {}
    for chunk in reader.stream().to_chunks():
        rows[chunk.entity_path] += chunk.num_rows
        batch = chunk.to_record_batch()
        # Skip log_time and other timestamp columns: nanoseconds do not convert to datetime.
        columns = {
            name: batch.column(name).to_pylist()
            for name, kind in zip(batch.schema.names, batch.schema.types)
            if not pa.types.is_timestamp(kind)
        }
        batches.setdefault(chunk.entity_path, []).append(columns)
    return {"rows": rows, "batches": batches, "blueprints": reader.blueprints(), "recordings": reader.recordings()}


def _layout(path: Path) -> dict:
    """The default blueprint of a recording: views by name, containers, panel states.

    views: name -> {"class", "origin", "props": {property archetype: {field: [instances]}}};
    containers: id -> {"kind", "contents" (names of views / container ids), "col_shares", "row_shares"};
    panels: "blueprint_panel" / "selection_panel" / "time_panel" -> state (2 collapsed, 3 expanded).
    """
    from rerun.chunk import RrdReader

    reader = RrdReader(path)
    (store,) = reader.blueprints()
    rows: dict[str, dict] = {}
    for chunk in reader.stream(store=store).to_chunks():
        batch = chunk.to_record_batch()
        fields = rows.setdefault(chunk.entity_path.strip("/"), {})
        for name in batch.schema.names:
            if ":" in name:
                fields[name.split(":", 1)[1]] = batch.column(name).to_pylist()[-1]  # the instances of the last row
    names = {key: f["display_name"][0] for key, f in rows.items() if key.count("/") == 1 and "display_name" in f}
    views = {
        names[key]: {"class": f["class_identifier"][0], "origin": f["space_origin"][0], "props": {}}
        for key, f in rows.items()
        if key in names
    }
    for key, f in rows.items():
        parent, _, prop = key.rpartition("/")
        if parent in names:
            views[names[parent]]["props"][prop] = f
    containers = {
        key: {
            "kind": f["container_kind"][0],
            "contents": [names.get(c, c) for c in f["contents"]],
            "col_shares": f.get("col_shares"),
            "row_shares": f.get("row_shares"),
        }
        for key, f in rows.items()
        if key.startswith("container/")
    }
    panels = {key: f["state"][0] for key, f in rows.items() if key.endswith("_panel")}
    return {"views": views, "containers": containers, "panels": panels}


def _column(batches: list[dict], suffix: str) -> list:
    return [v for b in batches for name, col in b.items() if name.endswith(suffix) for v in col]


def test_recording_holds_every_entity(tmp_path: Path) -> None:
    inputs = _inputs()
    path = write_recording(tmp_path / "clip.rrd", **inputs)
    assert path == tmp_path / "clip.rrd"
    assert [p.name for p in tmp_path.iterdir()] == ["clip.rrd"]  # no temporary file left

    got = _read(path)
    assert len(got["recordings"]) == 1 and got["recordings"][0].application_id == "mosegpipe"
    assert len(got["blueprints"]) == 1
    rows = got["rows"]
    for entity in ("/video/frame", "/video/tracks", "/video/points"):
        assert rows[entity] == T, entity
    assert len(_column(got["batches"]["/video/mask"], "SegmentationImage:buffer")) == T  # + its colours
    for entity in ("/", "/embedding", "/embedding/box", "/k_scores/k", "/k_scores/scores", "/summary"):
        assert rows[entity] == 1, entity

    points = got["batches"]["/video/points"]
    assert sorted(_column(points, "frame")) == [10, 11, 12]  # source frame indices
    counts = [len(p) for p in _column(points, "Points2D:positions")]
    assert sorted(counts) == [4, 5, 5]  # track 2 lost in the last frame; track 5 never drawn
    class_ids = _column(points, "Points2D:class_ids")
    assert sorted(class_ids, key=len)[0] == [0, 0, 1, 1]  # the labels, without the lost track

    embedding = _column(got["batches"]["/embedding"], "Points3D:positions")[0]
    assert len(embedding) == 5 and len(embedding[0]) == 3
    context = str(got["batches"]["/"])
    assert "motion 0" in context and "motion 1" in context and "unknown" in context


def test_clip_trails_follow_each_visible_track(tmp_path: Path) -> None:
    inputs = _inputs()
    got = _read(write_recording(tmp_path / "clip.rrd", **inputs, cfg=VizConfig(trail_frames=2)))
    by_frame = {
        frame: (strips, ids)
        for b in got["batches"]["/video/tracks"]
        if "LineStrips2D:strips" in b
        for frame, strips, ids in zip(b["frame"], b["LineStrips2D:strips"], b["LineStrips2D:class_ids"])
    }
    xy = inputs["tracks"].xy
    assert sorted(by_frame) == [11, 12]  # frame 10 has no history: cleared
    strips, ids = by_frame[11]
    np.testing.assert_allclose(np.array(strips), xy[:5, 0:2])  # every track, frames 10-11
    assert ids == [0, 0, 1, 1, 1]
    strips, ids = by_frame[12]  # track 2 is lost in frame 12; trails of 2 frames: 11-12
    np.testing.assert_allclose(np.array(strips), xy[[0, 1, 3, 4], 1:3])
    assert ids == [0, 0, 1, 1]


def test_annotation_context_matches_rerun_class_descriptions() -> None:
    import rerun as rr

    colors = viz.mask_colors()
    expected = rr.AnnotationContext(
        [
            rr.ClassDescription(info=rr.AnnotationInfo(id=i, label=name, color=tuple(int(c) for c in colors[i])))
            for i, name in class_names(3, "unknown / outlier").items()
        ]
    )
    got = viz.blocks._annotation_context(class_names(3, "unknown / outlier"), colors)
    assert got.context is not None and expected.context is not None
    assert got.context.pa_array.to_pylist() == expected.context.pa_array.to_pylist()


def test_every_class_is_named_once_in_both_contexts(tmp_path: Path) -> None:
    # Colours per value across the PNGs, overlays and recordings: test_colours.py. Here: which classes.
    clip = annotation_contexts(write_recording(tmp_path / "clip.rrd", **_inputs()))
    assert set(clip) == {"/", "/video/mask"} and set(clip["/video/mask"]) == {0, 1, 254, 255}
    pair = annotation_contexts(_write_pair(tmp_path / "pair.rrd"))
    assert set(pair) == {"/", "/image1/mask", "/image2/mask"} and pair["/"][255][0] == "unknown / outlier"
    (tmp_path / "video").mkdir()
    path = tmp_path / "video" / "video.rrd"
    _record_video(path, VizConfig())  # motions 0, 1, then 2 from the fourth frame
    video = annotation_contexts(path)  # every class named up front, logged once
    assert set(video) == {"/", "/video/mask"} and set(video["/"]) == set(range(256))
    assert video["/"][254][0] == "moving, no clustered motion" and video["/"][253][0] == "motion 253"
    assert video["/"][1][1] == (128, 0, 0, 255)  # motion 1 red, as in the mask PNGs and overlays


def test_overlay_and_viewer_draw_motion_0_alike() -> None:
    from mosegpipe.masks import overlay_image

    image = np.full((9, 9, 3), 90, np.uint8)
    mask = np.zeros((9, 9), np.uint8)
    out = overlay_image(image, mask, np.array([[4.0, 4.0]], np.float32), np.array([0]))
    assert (out[0, 0] == image[0, 0]).all()  # the background untinted: transparent in the viewer
    assert viz.mask_colors()[0, 3] == 0
    assert tuple(out[4, 4]) == tuple(viz.point_colors()[0, :3]) == (255, 255, 255)  # a white dot


def test_first_recording_does_not_import_pyarrow_compute(tmp_path: Path) -> None:
    # pyarrow.compute costs ~0.1 s on first import (benchmarks/output_size.py --startup); nothing
    # a recording needs should pull it in.
    # The inputs travel pickled: the fresh interpreter imports only what a recording needs (no test module).
    (tmp_path / "inputs.pkl").write_bytes(pickle.dumps(_inputs()))
    code = f"""
import pickle, sys
from mosegpipe.viz import write_recording
with open({str(tmp_path / "inputs.pkl")!r}, "rb") as f:
    inputs = pickle.load(f)
write_recording({str(tmp_path / "c.rrd")!r}, **inputs)
print("pyarrow.compute" in sys.modules)
"""
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "False"


def test_clip_layout(tmp_path: Path) -> None:
    path = write_recording(tmp_path / "clip.rrd", **_inputs())
    assert_layout_first(path)
    layout = _layout(path)
    views = layout["views"]
    assert {name: (v["class"], v["origin"]) for name, v in views.items()} == {
        "frame, tracks and masks": ("2D", "video"),
        "summary": ("TextDocument", "summary"),
        "legend": ("TextDocument", "legend"),
        "score per K": ("2D", "k_scores"),
        "embedding": ("3D", "embedding"),
    }
    (root,) = [c for c in layout["containers"].values() if c["col_shares"]]
    assert root["contents"][0] == "frame, tracks and masks"
    assert root["col_shares"][1] / sum(root["col_shares"]) <= 0.25  # side column: a quarter of the width
    (side,) = [c for c in layout["containers"].values() if c["row_shares"]]
    assert side["contents"] == ["summary", "legend", "score per K", "embedding"]
    assert side["row_shares"][0] / sum(side["row_shares"]) >= 0.2  # the summary gets room for its lines
    # The viewer's own side panels start folded; the time panel stays open for scrubbing.
    assert layout["panels"] == {"blueprint_panel": 2, "selection_panel": 2, "time_panel": 3}
    eye = views["embedding"]["props"]["EyeControls3D"]
    assert eye["look_target"] == [[0.0, 0.0, 0.0]] and eye["eye_up"] == [[0.0, 0.0, 1.0]]
    # The cube [-1, 1]^3 (bounding sphere radius sqrt(3)) fits a 45-degree view from the eye.
    distance = float(np.linalg.norm(eye["position"][0]))
    assert np.sqrt(3) / distance < np.sin(np.radians(45 / 2))


def test_k_chart_labels_every_k_and_marks_the_chosen_one(tmp_path: Path) -> None:
    inputs = _inputs() | {"k_scores": {1: 0.05, 2: 0.6, 3: -0.2, 4: float("nan")}}
    path = write_recording(tmp_path / "clip.rrd", **inputs)
    got = _read(path)["batches"]
    assert _column(got["/k_scores/k"], "Points2D:labels")[0] == ["K=1", "K=2", "K=3", "K=4"]
    assert _column(got["/k_scores/values"], "Points2D:labels")[0] == [".05", ".60", "-.20", "0"]
    assert "Points2D:labels" not in got["/k_scores/scores"][0]  # a tip's own label would lie on its stem
    tips = np.array(_column(got["/k_scores/scores"], "Points2D:positions")[0])
    np.testing.assert_allclose(tips[:, 0], [1, 2, 3, 4])  # x is K
    assert tips[1, 1] < tips[0, 1] < tips[3, 1] == 0 < tips[2, 1]  # y down: higher scores sit higher
    colors = _column(got["/k_scores/scores"], "Points2D:colors")[0]
    assert colors[1] != colors[0] and colors[0] == colors[2] == colors[3]  # K = 2 was chosen
    values_xy = np.array(_column(got["/k_scores/values"], "Points2D:positions")[0])
    assert (values_xy[[0, 1, 3], 1] < tips[[0, 1, 3], 1]).all() and values_xy[2, 1] > tips[2, 1]  # beyond the tips
    labels_xy = np.array(_column(got["/k_scores/k"], "Points2D:positions")[0])
    assert (labels_xy[:, 1] > values_xy[:, 1].max()).all()  # K labels under every stem and score
    # The 2-D view's bounds frame every point of the chart.
    bounds = _layout(path)["views"]["score per K"]["props"]["VisualBounds2D"]["range"][0]
    for x, y in np.vstack([tips, values_xy, labels_xy]):
        assert bounds["x_range"][0] < x < bounds["x_range"][1] and bounds["y_range"][0] < y < bounds["y_range"][1]
    summary = _column(got["/summary"], "TextDocument:text")[0][0]
    assert summary.startswith("**K = 2 written: automatic K chose it (score 0.6, runner-up K = 1: 0.05)**")
    assert len(summary.strip().splitlines()) <= 5


def _overlaps(a: tuple[float, ...], b: tuple[float, ...]) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


@pytest.mark.parametrize(
    "k_scores",
    [
        {k: s for k, s in zip(range(2, 9), [0.436, 0.459, 0.451, 0.447, 0.449, 0.44, 0.452])},  # 7 close scores
        {k: s for k, s in zip(range(1, 9), [0.2, -0.31, 0.05, -0.02, 0.0, 0.61, -0.6, 0.33])},  # 8, both signs
        {2: 0.5, 3: 0.5},
        {2: -0.3, 3: -0.01, 4: -0.3},
        {k: -0.2 - 0.01 * (k % 2) for k in range(2, 9)},  # wide labels ("-.21") side by side: staggered
        {k: 1.0 - 0.001 * k for k in range(2, 9)},  # "1.00" x 7
    ],
)
def test_k_chart_labels_touch_nothing(k_scores: dict[int, float]) -> None:
    chart = k_chart(k_scores)
    (x_lo, x_hi), (y_lo, y_hi) = chart.x_range, chart.y_range
    for scale in (viz.CHART_PX_PER_UNIT, 2 * viz.CHART_PX_PER_UNIT):  # more pixels a unit: smaller text
        values, k_labels = chart.label_boxes(scale)
        boxes = values + k_labels
        for i, a in enumerate(boxes):
            assert x_lo <= a[0] and a[2] <= x_hi and y_lo <= a[1] and a[3] <= y_hi, "inside the view"
            assert not any(_overlaps(a, b) for b in boxes[i + 1 :]), "labels apart"
            # Neither a stem (x = K, from 0 to its tip), nor the zero line, nor a point (radius <= 6 px) under it.
            for x, y in chart.tips:
                stem = (x - 1e-3, min(0.0, y), x + 1e-3, max(0.0, y))
                dot = 6.0 / scale
                assert not _overlaps(a, stem) and not _overlaps(a, (x - dot, y - dot, x + dot, y + dot))
            assert not _overlaps(a, (x_lo, -1e-3, x_hi, 1e-3)), "off the zero line"
    assert all(len(t) <= 4 for t in chart.value_labels)  # two decimals, no leading zero


def test_k_chart_and_margin_helpers() -> None:
    chart = k_chart({3: 0.2, 1: 0.4, 2: 0.0})
    assert chart.ks.tolist() == [1, 2, 3]
    np.testing.assert_allclose(chart.tips[:, 1], [-1.8, 0.0, -0.9])  # tallest stem 0.45 * (3 + 1)
    assert k_chart({2: 0.0}).tips.tolist() == [[2.0, 0.0]]  # all zero: no division by zero
    assert k_margin({1: 0.1, 2: 0.5, 3: 0.3}, 2) == pytest.approx((0.2, 3))
    assert k_margin({1: 0.1, 2: 0.5, 3: 0.3}, 1) == pytest.approx((-0.4, 2))  # a forced K can trail
    assert k_margin({2: 0.5}, 2) is None and k_margin({}, 2) is None and k_margin({1: 0.1, 2: 0.5}, 3) is None
    assert k_margin({1: float("nan"), 2: 0.5, 3: 0.3}, 2) == pytest.approx((0.2, 3))  # NaN scores do not compete
    assert k_margin({1: 0.1, 2: float("nan")}, 2) is None
    # The video's chart: how clearly the scores chose, never below 0 (a K the rigid check raised
    # trails the best-scoring K: as a margin it read -0.6, like an error).
    assert score_lead({1: 0.1, 2: 0.7, 3: 0.2}) == pytest.approx(0.5)
    assert k_margin({1: 0.1, 2: 0.7, 3: 0.2}, 3) == pytest.approx((-0.5, 2))
    assert score_lead({2: 0.5, 3: 0.5}) == 0.0 and score_lead({2: 0.5, 3: float("nan")}) is None
    assert k_chart({1: 0.3, 2: 0.9, 3: -0.4}).x_range == (0.0, 4.0)
    assert [viz.short_score(v) for v in (0.459, -0.0226, 1.0, 0.0, -0.001, 12.345)] == [
        ".46",
        "-.02",
        "1.00",
        "0",
        "0",
        "12.3",
    ]


def test_embedding_is_framed_in_the_cube(tmp_path: Path) -> None:
    rng = np.random.default_rng(5)
    far = np.vstack([rng.normal(size=(4, 6)), rng.normal(size=(1, 6)) + 40.0])  # one cluster far out
    inputs = _inputs() | {"embeddings": far}
    got = _read(write_recording(tmp_path / "clip.rrd", **inputs))["batches"]
    xyz = np.array(_column(got["/embedding"], "Points3D:positions")[0])
    assert np.abs(xyz).max() == pytest.approx(1.0) and (np.abs(xyz) <= 1.0).all()
    assert _column(got["/embedding/box"], "Boxes3D:half_sizes")[0] == [[1.0, 1.0, 1.0]]


def test_fit_in_box() -> None:
    pts = np.array([[0.0, 0, 0], [4, 2, 0], [2, 1, 6]])
    out = fit_in_box(pts)
    np.testing.assert_allclose(out, [[-2 / 3, -1 / 3, -1], [2 / 3, 1 / 3, -1], [0, 0, 1]], atol=1e-6)
    assert fit_in_box(np.ones((3, 3))).tolist() == [[0.0] * 3] * 3  # coincident points: the centre
    assert fit_in_box(np.zeros((0, 3))).shape == (0, 3)


def test_recording_without_masks_and_with_raw_frames(tmp_path: Path) -> None:
    inputs = _inputs() | {"masks": None, "k_scores": {}}
    path = write_recording(tmp_path / "raw.rrd", **inputs, cfg=VizConfig(jpeg_quality=0, trail_frames=2))
    rows = _read(path)["rows"]
    assert "/video/mask" not in rows and not any(e.startswith("/k_scores") for e in rows)
    assert rows["/video/frame"] == T and rows["/summary"] == 1
    assert "score per K" not in _layout(path)["views"]  # no scores (K forced): no empty chart


def test_failed_write_leaves_no_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def broken(*_args, **_kwargs):
        raise RuntimeError("encoder exploded")

    monkeypatch.setattr(viz.blocks, "_image_archetype", broken)
    with pytest.raises(RuntimeError, match="encoder exploded"):
        write_recording(tmp_path / "clip.rrd", **_inputs())
    assert list(tmp_path.iterdir()) == []


def test_inconsistent_inputs_are_rejected(tmp_path: Path) -> None:
    inputs = _inputs()
    with pytest.raises(InputError, match="labels must be in 0..1"):
        write_recording(tmp_path / "a.rrd", **(inputs | {"labels": np.array([0, 0, 1, 2, 1])}))
    with pytest.raises(InputError, match="must match"):
        write_recording(tmp_path / "a.rrd", **(inputs | {"embeddings": np.zeros((4, 3))}))
    with pytest.raises(InputError, match="masks have shape"):
        write_recording(tmp_path / "a.rrd", **(inputs | {"masks": np.zeros((T, H, W + 1), np.uint8)}))
    assert list(tmp_path.iterdir()) == []


def test_embedding_to_3d() -> None:
    two = np.array([[1.0, 2.0], [3.0, 4.0]])
    np.testing.assert_array_equal(embedding_to_3d(two), [[1, 2, 0], [3, 4, 0]])
    three = np.random.default_rng(1).normal(size=(7, 3))
    np.testing.assert_allclose(embedding_to_3d(three), three, rtol=1e-6)
    # Points in a 3-D subspace of R^6: the PCA projection keeps all pairwise distances.
    basis, _ = np.linalg.qr(np.random.default_rng(2).normal(size=(6, 3)))
    high = three @ basis.T + 5.0
    low = embedding_to_3d(high)
    d_high = np.linalg.norm(high[:, None] - high[None], axis=2)
    d_low = np.linalg.norm(low[:, None] - low[None], axis=2)
    np.testing.assert_allclose(d_low, d_high, atol=1e-5)


def test_class_names_match_mask_values() -> None:
    assert class_names(2) == {
        0: "the world (motion 0)",
        1: "motion 1",
        254: "moving, no clustered motion",
        255: "unknown",
    }


def _pair_inputs() -> tuple:
    from mosegpipe.types import Matches

    rng = np.random.default_rng(3)
    img1 = rng.integers(0, 256, (20, 30, 3), dtype=np.uint8)
    img2 = rng.integers(0, 256, (24, 28, 3), dtype=np.uint8)
    xy1 = rng.uniform(0, 19, (6, 2)).astype(np.float32)
    matches = Matches(xy1=xy1, xy2=xy1 + 1, score=np.zeros(6, np.float32), size1_hw=(20, 30), size2_hw=(24, 28))
    labels = np.array([0, 0, 1, 1, -1, 2])
    masks = [np.zeros((20, 30), np.uint8), np.ones((24, 28), np.uint8)]
    return (img1, img2), matches, labels, rng.normal(size=(6, 2)), masks, {2: 0.1, 3: 0.2}, 3


def _write_pair(path: Path) -> Path:
    from mosegpipe.viz import write_pair_recording

    return write_pair_recording(path, *_pair_inputs())


def test_pair_layout(tmp_path: Path) -> None:
    path = _write_pair(tmp_path / "pair.rrd")
    assert_layout_first(path)
    views = _layout(path)["views"]
    assert {name: (v["class"], v["origin"]) for name, v in views.items()} == {
        "image 1": ("2D", "image1"),
        "image 2": ("2D", "image2"),
        "summary": ("TextDocument", "summary"),
        "legend": ("TextDocument", "legend"),
        "score per K": ("2D", "k_scores"),
        "embedding": ("3D", "embedding"),
    }


def test_pair_recording(tmp_path: Path) -> None:
    from mosegpipe.viz import write_pair_recording

    (img1, img2), matches, labels, _, _, _, _ = _pair_inputs()
    path = _write_pair(tmp_path / "pair.rrd")

    got = _read(path)
    for entity in ("/image1/frame", "/image1/points", "/image2/frame", "/image2/points", "/embedding"):
        assert got["rows"][entity] == 1, entity
    assert len(_column(got["batches"]["/image1/mask"], "SegmentationImage:buffer")) == 1  # + its colours
    class_ids = _column(got["batches"]["/image2/points"], "Points2D:class_ids")[0]
    assert class_ids == [0, 0, 1, 1, 255, 2]  # outlier -> class 255 (unknown)
    assert "unknown / outlier" in str(got["batches"]["/"])
    assert _column(got["batches"]["/k_scores/k"], "Points2D:labels")[0] == ["K=2", "K=3"]
    layout = _layout(path)
    assert {"image 1", "image 2", "summary", "legend", "score per K", "embedding"} == set(layout["views"])
    assert layout["panels"] == {"blueprint_panel": 2, "selection_panel": 2, "time_panel": 2}  # no timeline
    with pytest.raises(InputError, match="sizes do not match"):
        write_pair_recording(tmp_path / "bad.rrd", (img2, img1), matches, labels, np.zeros((6, 2)), None, {}, 3)


def _decode(mp4: bytes) -> tuple[list[np.ndarray], list[tuple[int, int]]]:
    """Frames (RGB) and (pts, dts) of each packet, in decoding order."""
    import io

    import av

    with av.open(io.BytesIO(mp4)) as container:
        stream = container.streams.video[0]
        stamps = [(p.pts, p.dts) for p in container.demux(stream) if p.size]
    with av.open(io.BytesIO(mp4)) as container:
        frames = [f.to_ndarray(format="rgb24") for f in container.decode(video=0)]
    return frames, stamps


def _record_video(path: Path, cfg: VizConfig, num: int = 4) -> list[np.ndarray]:
    from mosegpipe.viz import VideoRecorder

    rng = np.random.default_rng(4)
    blocks = np.repeat(np.repeat(rng.integers(0, 256, (6, 8, 3), dtype=np.uint8), 4, axis=0), 4, axis=1)
    images = []
    with VideoRecorder(path, cfg=cfg, fps=25.0) as rec:
        assert not path.exists()  # only a temporary file while recording
        rec.log_window(100, 2, {1: 0.1, 2: 0.5, 3: 0.2})
        for t in range(num):
            if t == 2:
                rec.log_window(102, 0)  # an unlabelled window: K = 0, no margin
            # 4x4-pixel blocks moving right: x264 would code some of these frames as B-frames.
            image = np.roll(blocks, 2 * t, axis=1)
            images.append(image)
            ids = np.array([1, 2, 3]) if t < 2 else np.array([2, 3, 7])
            labels = np.array([0, 1, 1]) if t < 3 else np.array([0, 1, 2])  # motion 3 appears late
            xy = rng.uniform(0, 23, (3, 2)).astype(np.float32)
            rec.log_frame(100 + t, image, xy, ids, labels, mask=np.ones((24, 32), np.uint8))
    assert [p.name for p in path.parent.iterdir()] == [path.name]
    return images


def test_video_recorder_streams_frames_and_grows_classes(tmp_path: Path) -> None:
    path = tmp_path / "video.rrd"
    _record_video(path, VizConfig(trail_frames=2, max_side_px=16))
    got = _read(path)
    assert got["rows"]["/video/frame"] == 4 and got["rows"]["/video/points"] == 4
    assert sorted(_column(got["batches"]["/video/points"], "frame")) == [100, 101, 102, 103]
    masks = got["batches"]["/video/mask"]
    formats = [f[0] for f in _column(masks, "SegmentationImage:format")]
    assert {(f["width"], f["height"]) for f in formats} == {(16, 12)}  # 32x24 downscaled
    # Trails hold at most trail_frames=2 points.
    strips = _column(got["batches"]["/video/tracks"], "LineStrips2D:strips")
    assert max(len(s) for frame in strips if frame for s in frame) == 2
    assert "motion 3" in str(got["batches"]["/"])  # every class named up front


def test_video_recorder_stores_frames_as_one_h264_asset(tmp_path: Path) -> None:
    path = tmp_path / "video.rrd"
    images = _record_video(path, VizConfig(trail_frames=2))
    got = _read(path)
    assert got["rows"]["/video/asset"] == 1  # static: the whole video once
    assert _column(got["batches"]["/video/asset"], "AssetVideo:media_type") == [["video/mp4"]]
    blob = bytes(_column(got["batches"]["/video/asset"], "AssetVideo:blob")[0][0])
    frames, stamps = _decode(blob)
    assert len(frames) == 4 and frames[0].shape == (24, 32, 3)
    assert [pts for pts, _ in stamps] == sorted(pts for pts, _ in stamps)  # no B-frames: decode order = display order
    # Each decoded frame is nearest to its own source frame (lossy, 4:2:0 chroma on a 32x24 image).
    errors = np.array([[np.abs(d.astype(int) - im).mean() for im in images] for d in frames])
    assert errors.argmin(axis=1).tolist() == [0, 1, 2, 3] and errors.diagonal().max() < 16

    refs = got["batches"]["/video/frame"]
    assert sorted(_column(refs, "frame")) == [100, 101, 102, 103]
    assert _column(refs, "VideoFrameReference:video_reference") == [["video/asset"]] * 4
    stamps_ns = [s[0] for s in _column(refs, "VideoFrameReference:timestamp")]
    assert stamps_ns == [0, 40_000_000, 80_000_000, 120_000_000]  # 25 fps
    assert not any("EncodedImage" in name for b in got["batches"].values() for c in b for name in c)


def test_video_recorder_jpeg_frames(tmp_path: Path) -> None:
    path = tmp_path / "video.rrd"
    _record_video(path, VizConfig(trail_frames=2, video_frames="jpeg"))
    got = _read(path)
    assert got["rows"]["/video/frame"] == 4 and "/video/asset" not in got["rows"]
    assert _column(got["batches"]["/video/frame"], "EncodedImage:media_type") == [["image/jpeg"]] * 4


def test_video_recorder_logs_k_per_window(tmp_path: Path) -> None:
    path = tmp_path / "video.rrd"
    _record_video(path, VizConfig())
    got = _read(path)["batches"]
    k_rows = [b for b in got["/windows/k"] if "frame" in b]
    series = sorted(zip(_column(k_rows, "frame"), _column(k_rows, "Scalars:scalars")))
    assert series == [(100, [2.0]), (102, [0.0])]
    margins = [b for b in got["/windows/k_margin"] if "frame" in b]
    assert list(zip(_column(margins, "frame"), _column(margins, "Scalars:scalars"))) == [(100, [pytest.approx(0.3)])]
    layout = _layout(path)
    assert layout["views"]["frame, tracks and masks"]["origin"] == "video"
    assert layout["views"]["K per window"]["class"] == "TimeSeries"
    assert layout["views"]["K per window"]["origin"] == "windows/k"
    assert layout["views"]["how clear K is (score lead)"]["origin"] == "windows/k_margin"
    assert layout["panels"] == {"blueprint_panel": 2, "selection_panel": 2, "time_panel": 3}


def test_video_layout(tmp_path: Path) -> None:
    path = tmp_path / "video.rrd"
    _record_video(path, VizConfig())
    assert_layout_first(path)
    layout = _layout(path)
    views = layout["views"]
    assert {name: (v["class"], v["origin"]) for name, v in views.items()} == {
        "frame, tracks and masks": ("2D", "video"),
        "K per window": ("TimeSeries", "windows/k"),
        "how clear K is (score lead)": ("TimeSeries", "windows/k_margin"),
        "legend (this window)": ("TextDocument", "legend"),
    }
    # The frame view shows everything under video/: the frames, the masks and the tracks.
    assert views["frame, tracks and masks"]["props"]["ViewContents"]["query"] == ["$origin/**"]
    rows = _read(path)["rows"]
    assert all(rows[f"/video/{e}"] for e in ("frame", "asset", "mask", "tracks", "points"))
    (root,) = [c for c in layout["containers"].values() if c["row_shares"]]
    assert root["contents"][0] == "frame, tracks and masks"
    assert root["row_shares"][0] / sum(root["row_shares"]) >= 0.75


def test_video_recorder_without_windows_or_margins(tmp_path: Path) -> None:
    from mosegpipe.viz import VideoRecorder

    path = tmp_path / "plain.rrd"
    with VideoRecorder(path, windows=False) as rec:
        rec.log_frame(0, np.zeros((8, 8, 3), np.uint8), np.zeros((1, 2)), np.array([0]), np.array([0]))
    assert set(_layout(path)["views"]) == {"frame, tracks and masks"}
    with VideoRecorder(path, margins=False) as rec:
        rec.log_window(0, 3)  # no scores (K forced): K per window only
        rec.log_frame(0, np.zeros((8, 8, 3), np.uint8), np.zeros((1, 2)), np.array([0]), np.array([0]))
    assert set(_layout(path)["views"]) == {"frame, tracks and masks", "K per window", "legend (this window)"}
    assert_layout_first(path)


def test_video_recorder_rejects_a_size_change_in_h264(tmp_path: Path) -> None:
    from mosegpipe.viz import VideoRecorder

    with pytest.raises(InputError, match="frame 1 is 16x8, earlier frames are 8x8"):
        with VideoRecorder(tmp_path / "v.rrd") as rec:
            rec.log_frame(0, np.zeros((8, 8, 3), np.uint8), np.zeros((0, 2)), np.zeros(0), np.zeros(0))
            rec.log_frame(1, np.zeros((8, 16, 3), np.uint8), np.zeros((0, 2)), np.zeros(0), np.zeros(0))
    assert list(tmp_path.iterdir()) == []


def test_video_recorder_abort_leaves_nothing(tmp_path: Path) -> None:
    from mosegpipe.viz import VideoRecorder

    with pytest.raises(ValueError, match="stop"):
        with VideoRecorder(tmp_path / "v.rrd") as rec:
            rec.log_frame(0, np.zeros((8, 8, 3), np.uint8), np.zeros((1, 2)), np.array([0]), np.array([0]))
            raise ValueError("stop")
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(InputError, match="already closed"):
        rec.log_frame(1, np.zeros((8, 8, 3), np.uint8), np.zeros((0, 2)), np.zeros(0), np.zeros(0))
    with pytest.raises(InputError, match="already closed"):
        rec.log_window(1, 2)


def test_video_recorder_failure_at_close_leaves_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from mosegpipe.viz import VideoRecorder

    def broken(self: VideoRecorder, rec: object) -> None:
        raise RuntimeError("asset exploded")

    monkeypatch.setattr(VideoRecorder, "_log_video_asset", broken)
    with pytest.raises(RuntimeError, match="asset exploded"):
        with VideoRecorder(tmp_path / "v.rrd") as rec:
            rec.log_frame(0, np.zeros((8, 8, 3), np.uint8), np.zeros((1, 2)), np.array([0]), np.array([0]))
    assert list(tmp_path.iterdir()) == []


def test_viz_config_rejects_an_unknown_video_mode() -> None:
    with pytest.raises(ValueError, match="^video_frames: 'png' must be h264 or jpeg$"):
        VizConfig(video_frames="png")  # type: ignore[arg-type]
