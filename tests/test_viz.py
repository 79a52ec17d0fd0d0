from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from mosegpipe import viz
from mosegpipe.errors import InputError
from mosegpipe.masks import MaskConfig, labels_to_masks
from mosegpipe.types import Frames, Tracks
from mosegpipe.viz import VizConfig, class_names, embedding_to_3d, write_recording

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
    for entity in ("/video/frame", "/video/mask", "/video/tracks", "/video/points"):
        assert rows[entity] == T, entity
    for entity in ("/", "/embedding", "/k_scores", "/summary"):
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


def test_recording_without_masks_and_with_raw_frames(tmp_path: Path) -> None:
    inputs = _inputs() | {"masks": None, "k_scores": {}}
    path = write_recording(tmp_path / "raw.rrd", **inputs, cfg=VizConfig(jpeg_quality=0, trail_frames=2))
    rows = _read(path)["rows"]
    assert "/video/mask" not in rows and "/k_scores" not in rows
    assert rows["/video/frame"] == T and rows["/summary"] == 1


def test_failed_write_leaves_no_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def broken(*_args, **_kwargs):
        raise RuntimeError("encoder exploded")

    monkeypatch.setattr(viz, "_image_archetype", broken)
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
    assert class_names(2) == {0: "motion 0 (dominant)", 1: "motion 1", 255: "unknown"}


def test_pair_recording(tmp_path: Path) -> None:
    from mosegpipe.types import Matches
    from mosegpipe.viz import write_pair_recording

    rng = np.random.default_rng(3)
    img1 = rng.integers(0, 256, (20, 30, 3), dtype=np.uint8)
    img2 = rng.integers(0, 256, (24, 28, 3), dtype=np.uint8)
    xy1 = rng.uniform(0, 19, (6, 2)).astype(np.float32)
    matches = Matches(xy1=xy1, xy2=xy1 + 1, score=np.zeros(6, np.float32), size1_hw=(20, 30), size2_hw=(24, 28))
    labels = np.array([0, 0, 1, 1, -1, 2])
    masks = [np.zeros((20, 30), np.uint8), np.ones((24, 28), np.uint8)]
    path = write_pair_recording(
        tmp_path / "pair.rrd", (img1, img2), matches, labels, rng.normal(size=(6, 2)), masks, {2: 0.1, 3: 0.2}, 3
    )

    got = _read(path)
    for entity in ("/image1/frame", "/image1/mask", "/image1/points", "/image2/frame", "/image2/points", "/embedding"):
        assert got["rows"][entity] == 1, entity
    class_ids = _column(got["batches"]["/image2/points"], "Points2D:class_ids")[0]
    assert class_ids == [0, 0, 1, 1, 255, 2]  # outlier -> class 255 (unknown)
    assert "unknown / outlier" in str(got["batches"]["/"])
    with pytest.raises(InputError, match="sizes do not match"):
        write_pair_recording(tmp_path / "bad.rrd", (img2, img1), matches, labels, np.zeros((6, 2)), None, {}, 3)


def test_video_recorder_streams_frames_and_grows_classes(tmp_path: Path) -> None:
    from mosegpipe.viz import VideoRecorder

    rng = np.random.default_rng(4)
    path = tmp_path / "video.rrd"
    with VideoRecorder(path, cfg=VizConfig(trail_frames=2, max_side_px=16)) as rec:
        assert not path.exists()  # only a temporary file while recording
        for t in range(4):
            image = rng.integers(0, 256, (24, 32, 3), dtype=np.uint8)
            ids = np.array([1, 2, 3]) if t < 2 else np.array([2, 3, 7])
            labels = np.array([0, 1, 1]) if t < 3 else np.array([0, 1, 2])  # motion 3 appears late
            xy = rng.uniform(0, 23, (3, 2)).astype(np.float32)
            rec.log_frame(100 + t, image, xy, ids, labels, mask=np.ones((24, 32), np.uint8))
    assert [p.name for p in tmp_path.iterdir()] == ["video.rrd"]

    got = _read(path)
    assert got["rows"]["/video/frame"] == 4 and got["rows"]["/video/points"] == 4
    assert sorted(_column(got["batches"]["/video/points"], "frame")) == [100, 101, 102, 103]
    masks = got["batches"]["/video/mask"]
    formats = [f[0] for f in _column(masks, "SegmentationImage:format")]
    assert {(f["width"], f["height"]) for f in formats} == {(16, 12)}  # 32x24 downscaled
    # Trails hold at most trail_frames=2 points.
    strips = _column(got["batches"]["/video/tracks"], "LineStrips2D:strips")
    assert max(len(s) for frame in strips if frame for s in frame) == 2
    assert "motion 2" in str(got["batches"]["/"]) and "motion 3" not in str(got["batches"]["/"])


def test_video_recorder_abort_leaves_nothing(tmp_path: Path) -> None:
    from mosegpipe.viz import VideoRecorder

    with pytest.raises(ValueError, match="stop"):
        with VideoRecorder(tmp_path / "v.rrd") as rec:
            rec.log_frame(0, np.zeros((8, 8, 3), np.uint8), np.zeros((1, 2)), np.array([0]), np.array([0]))
            raise ValueError("stop")
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(InputError, match="already closed"):
        rec.log_frame(1, np.zeros((8, 8, 3), np.uint8), np.zeros((0, 2)), np.zeros(0), np.zeros(0))
