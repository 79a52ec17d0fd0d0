"""The pipeline API: segment_clip / segment_frames / segment_pair and the output folders they write.

The shipped weights are not needed: the tests build their own checkpoints. `motion_checkpoint`
writes a SubspaceNet whose weights are set by hand so that it embeds a track by its displacement
between the first and the last frame (a perfect "motion model" for a static camera), which makes
segmentation results predictable (it lives in tests/helpers.py with the other shared helpers).
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from mosegpipe import pipeline
from mosegpipe.apps.outputs import check_output_dir, write_clip_outputs, write_pair_outputs
from mosegpipe.embed.model import SubspaceNet
from mosegpipe.errors import InputError, OutputExistsError, TooFewTracksError
from mosegpipe.io.read import read_palette_png, read_video
from mosegpipe.masks import MaskConfig, overlay_image, overlay_mask
from mosegpipe.pipeline import PipelineConfig, segment_clip, segment_frames, segment_pair
from mosegpipe.synth.render import RenderedClip, render_clip

from helpers import best_permutation_accuracy, motion_checkpoint, read_rrd, render_scene, write_frames

SAMPLES = Path(__file__).resolve().parents[1] / "samples"

# ---------------------------------------------------------------------------------------------
# Fixtures
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def model5(tmp_path_factory: pytest.TempPathFactory) -> SubspaceNet:
    return SubspaceNet.from_checkpoint(motion_checkpoint(tmp_path_factory.mktemp("models") / "motion5.pt", 5))


@pytest.fixture(scope="module")
def model2(tmp_path_factory: pytest.TempPathFactory) -> SubspaceNet:
    return SubspaceNet.from_checkpoint(motion_checkpoint(tmp_path_factory.mktemp("models") / "motion2.pt", 2))


@pytest.fixture(scope="module")
def scene() -> RenderedClip:
    return render_scene(6)


@pytest.fixture(scope="module")
def clip_result(
    scene: RenderedClip, tmp_path_factory: pytest.TempPathFactory, model5: SubspaceNet
) -> pipeline.ClipResult:
    folder = write_frames(tmp_path_factory.mktemp("scene") / "frames", scene.frames)
    return segment_clip(folder, PipelineConfig(frames=5), model5)


# ---------------------------------------------------------------------------------------------
# Segmentation
# ---------------------------------------------------------------------------------------------


def test_segment_clip_reads_the_frames_next_to_the_clip_as_evidence(
    clip_result: pipeline.ClipResult, scene: RenderedClip, tmp_path: Path, model5: SubspaceNet
) -> None:
    # Frames 0-4 of 6: the 6th is the evidence after; nothing before frame 0.
    assert clip_result.frames.num_frames == 5 and clip_result.frames.before is None
    np.testing.assert_array_equal(clip_result.frames.after, scene.frames[5])
    folder = write_frames(tmp_path / "frames", scene.frames)
    late = segment_clip(folder, PipelineConfig(frames=5, start=1), model5)  # frames 1-5: the last of the source
    np.testing.assert_array_equal(late.frames.images, scene.frames[1:6])
    np.testing.assert_array_equal(late.frames.before, scene.frames[0])
    assert late.frames.after is None and late.frames.start == 1 and late.masks.shape[0] == 5
    watershed = PipelineConfig(frames=5, mask=MaskConfig(method="watershed"))
    plain = segment_clip(folder, watershed, model5)  # masks that take no flow read no neighbours
    assert plain.frames.before is None and plain.frames.after is None


def test_segment_clip_separates_the_moving_objects(clip_result: pipeline.ClipResult, scene: RenderedClip) -> None:
    r = clip_result
    assert r.frames.num_frames == 5 and r.frames.images.shape == (5, 240, 320, 3)
    assert r.clustering.k == 3  # wall + two planes, chosen automatically
    n = r.trajectories.num_points
    assert n >= 100 and r.embeddings.shape == (n, 5) and r.clustering.labels.shape == (n,)
    gt = scene.label_at(0, r.tracks.xy[r.trajectories.track_ids, 0])
    # Misses are corners on an object's border that the tracker follows with the object.
    assert best_permutation_accuracy(r.clustering.labels, gt) >= 0.9
    assert r.masks.shape == (5, 240, 320) and r.masks.dtype == np.uint8
    assert set(np.unique(r.masks)) == {0, 1, 2}  # the labels; every pixel has a track within 40 px
    assert set(r.timings) == {"read", "flow", "track", "embed", "cluster", "masks"}  # model given: no load_model


def test_segment_frames_forced_k_and_too_large_k(scene: RenderedClip, model5: SubspaceNet) -> None:
    frames = scene.to_frames()
    r = segment_frames(frames, PipelineConfig(k=2), model5)
    assert r.clustering.k == 2 and r.clustering.method == "fixed" and r.clustering.scores == {}
    with pytest.raises(InputError, match=r"render: --k 5000 is larger than the number of tracks \(\d+\)"):
        segment_frames(frames, PipelineConfig(k=5000), model5)


def test_blank_frames_are_too_few_tracks(tmp_path: Path, model5: SubspaceNet) -> None:
    folder = write_frames(tmp_path / "blank", np.full((5, 240, 320, 3), 128, np.uint8))
    with pytest.raises(TooFewTracksError, match=r"blank: only 0 tracks survived 5 frames; need at least 10"):
        segment_clip(folder, PipelineConfig(), model5)


def test_short_and_truncated_inputs(tmp_path: Path, scene: RenderedClip, model5: SubspaceNet) -> None:
    folder = write_frames(tmp_path / "three", scene.frames[:3])
    with pytest.raises(InputError, match=r"three: only 3 frames could be read; --frames needs 5"):
        segment_clip(folder, PipelineConfig(), model5)
    (tmp_path / "x.mp4").write_bytes(bytes(range(256)) * 20)
    with pytest.raises(InputError, match="x.mp4: not a readable video"):
        segment_clip(tmp_path / "x.mp4", PipelineConfig(), model5)


def test_opencv_exceptions_become_input_errors(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, model5: SubspaceNet
) -> None:
    def broken(*_args: object, **_kwargs: object) -> None:
        raise cv2.error("OpenCV(4.10) error: (-215:Assertion failed) !buf.empty() in function 'imdecode_'")

    monkeypatch.setattr(pipeline.clip, "read_video", broken)
    with pytest.raises(InputError, match=r"clip.avi: cannot read it \(.*imdecode_"):
        segment_clip(tmp_path / "clip.avi", PipelineConfig(), model5)
    monkeypatch.setattr(pipeline.pair, "read_image", broken)
    with pytest.raises(InputError, match="a.png: cannot read it"):
        segment_pair(tmp_path / "a.png", tmp_path / "b.png", model=model5)


def test_segment_pair_with_images_of_different_sizes(scene: RenderedClip, model2: SubspaceNet) -> None:
    im1 = scene.frames[0]
    im2 = cv2.resize(scene.frames[4], (256, 192), interpolation=cv2.INTER_AREA)  # 0.8x
    r = segment_pair(im1, im2, PipelineConfig(frames=2), model2)
    n = r.matches.num_matches
    assert n >= 50 and r.labels.shape == (n,) and r.clustering.labels.shape == (n,)
    assert r.masks[0].shape == (240, 320) and r.masks[1].shape == (192, 256)
    assert r.images[1].shape == (192, 256, 3)
    assert (r.matches.xy2[:, 0] < 256).all() and (r.matches.xy2[:, 1] < 192).all()
    # Outliers are -1 and the motions are numbered 0..m-1 without gaps.
    motions = np.unique(r.labels[r.labels >= 0])
    assert motions.tolist() == list(range(motions.size))
    assert int(r.masks[0][r.masks[0] != 255].max()) == motions.size - 1


def test_blank_pair_is_too_few_matches(tmp_path: Path, model2: SubspaceNet) -> None:
    grey = np.full((120, 160, 3), 128, np.uint8)
    for name in ("a.png", "b.png"):
        cv2.imwrite(str(tmp_path / name), grey)
    with pytest.raises(TooFewTracksError, match=r"a.png and .*b.png: only 0 SIFT matches; need at least 10"):
        segment_pair(tmp_path / "a.png", tmp_path / "b.png", model=model2)


def test_overlay_image_blends_with_masks_overlay_mask(scene: RenderedClip) -> None:
    from mosegpipe.io.read import default_palette

    image, mask = scene.frames[0], scene.masks[0]
    empty = np.zeros((0, 2), np.float32), np.zeros(0, np.int64)
    assert np.array_equal(overlay_image(image, mask, *empty), overlay_mask(image, mask, default_palette(), 0.45))
    dotted = overlay_image(image, None, np.array([[50.0, 60.0]], np.float32), np.array([2]))
    assert tuple(dotted[60, 50]) == tuple(default_palette()[2])  # dot centre in motion 2's colour
    assert np.array_equal(dotted[0:40], image[0:40])  # nothing else touched


# ---------------------------------------------------------------------------------------------
# Output folders
# ---------------------------------------------------------------------------------------------


def test_clip_outputs(tmp_path: Path, clip_result: pipeline.ClipResult) -> None:
    cfg = PipelineConfig(frames=5)
    out = tmp_path / "out"
    summary = write_clip_outputs(clip_result, out, cfg)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # no temporary folder left
    assert sorted(p.name for p in out.iterdir()) == [
        "labels.npz",
        "masks",
        "overlay",
        "overlay.mp4",
        "recording.rrd",
        "summary.json",
    ]

    on_disk = json.loads((out / "summary.json").read_text())
    assert on_disk == json.loads(json.dumps(summary))
    n = clip_result.trajectories.num_points
    assert on_disk["schema"] == "mosegpipe.summary/2" and on_disk["kind"] == "clip"
    assert on_disk["frames"] == 5 and on_disk["start"] == 0 and on_disk["size_hw"] == [240, 320]
    assert on_disk["k"] == 3 and on_disk["k_method"] == "silhouette"
    assert on_disk["num_tracks_segmented"] == n <= on_disk["num_tracks_detected"]
    assert sum(on_disk["tracks_per_motion"]) == n and len(on_disk["tracks_per_motion"]) == 3
    assert {str(k) for k in range(2, 9)} <= set(on_disk["k_scores"])  # the candidates of --k-max 8
    assert set(on_disk["timings_s"]) == {"read", "flow", "track", "embed", "cluster", "masks", "rrd"}
    assert on_disk["model"]["recipe"] == "test-displacement-f5" and on_disk["model"]["model_frames"] == 5
    assert on_disk["config"]["frames"] == 5 and on_disk["config"]["cluster"]["method"] == "silhouette"

    with np.load(out / "labels.npz") as z:
        assert sorted(z.files) == ["embeddings", "labels", "track_ids", "xy"]
        assert z["track_ids"].shape == (n,) and z["labels"].shape == (n,)
        assert z["xy"].shape == (n, 5, 2) and z["embeddings"].shape == (n, 5)
        assert np.array_equal(z["labels"], clip_result.clustering.labels)
        assert np.isfinite(z["xy"]).all()

    masks = [read_palette_png(out / "masks" / f"{t:06d}.png") for t in range(5)]
    assert np.array_equal(np.stack(masks), clip_result.masks)
    assert max(int(m.max()) for m in masks) == 2
    for t in range(5):
        overlay = cv2.imread(str(out / "overlay" / f"{t:06d}.jpg"))
        assert overlay is not None and overlay.shape == (240, 320, 3)

    rows = read_rrd(out / "recording.rrd")
    for entity in ("/video/frame", "/video/mask", "/video/points"):
        assert rows[entity] == 5, entity


def test_pair_outputs(tmp_path: Path, scene: RenderedClip, model2: SubspaceNet) -> None:
    im2 = cv2.resize(scene.frames[3], (256, 192), interpolation=cv2.INTER_AREA)
    result = segment_pair(scene.frames[0], im2, PipelineConfig(frames=2), model2)
    out = tmp_path / "pair"
    summary = write_pair_outputs(result, out, PipelineConfig(frames=2), sources=("a.png", "b.png"), rrd=False)
    assert sorted(p.name for p in out.iterdir()) == ["labels.npz", "masks", "overlay", "summary.json"]
    assert summary["kind"] == "pair" and summary["source"] == ["a.png", "b.png"]
    assert summary["size_hw"] == [[240, 320], [192, 256]]
    n = result.matches.num_matches
    assert summary["num_matches"] == n == sum(summary["matches_per_motion"]) + summary["num_outliers"]
    assert summary["num_motions"] == len(summary["matches_per_motion"])
    with np.load(out / "labels.npz") as z:
        assert sorted(z.files) == ["clusters", "embeddings", "labels", "xy1", "xy2"]
        assert z["xy1"].shape == z["xy2"].shape == (n, 2) and z["labels"].shape == (n,)
        assert z["embeddings"].shape == (n, 5)
    m0, m1 = (read_palette_png(out / "masks" / f"{i:06d}.png") for i in (0, 1))
    assert m0.shape == (240, 320) and m1.shape == (192, 256)
    assert max(int(m0.max()), int(m1.max())) <= summary["num_motions"]
    assert cv2.imread(str(out / "overlay" / "000001.jpg")).shape == (192, 256, 3)


def test_existing_output_is_refused_then_replaced(tmp_path: Path, clip_result: pipeline.ClipResult) -> None:
    out = tmp_path / "out"
    write_clip_outputs(clip_result, out, rrd=False)
    (out / "stale.txt").write_text("from an older run")
    with pytest.raises(OutputExistsError, match="out: already holds results; pass --overwrite"):
        write_clip_outputs(clip_result, out, rrd=False)
    assert (out / "stale.txt").exists()
    write_clip_outputs(clip_result, out, overwrite=True, rrd=False)
    assert not (out / "stale.txt").exists() and (out / "summary.json").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_check_output_dir_protects_other_folders(tmp_path: Path) -> None:
    check_output_dir(tmp_path / "new", overwrite=False)
    (tmp_path / "empty").mkdir()
    check_output_dir(tmp_path / "empty", overwrite=False)
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="file: exists and is not a folder"):
        check_output_dir(tmp_path / "file", overwrite=True)
    (tmp_path / "photos").mkdir()
    (tmp_path / "photos" / "a.jpg").write_bytes(b"")
    with pytest.raises(InputError, match="photos: holds files but no summary.json"):
        check_output_dir(tmp_path / "photos", overwrite=True)


def test_a_failed_write_leaves_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, clip_result: pipeline.ClipResult
) -> None:
    from mosegpipe import viz

    def broken(*_args: object, **_kwargs: object) -> None:
        raise RuntimeError("disk on fire")

    monkeypatch.setattr(viz, "write_recording", broken)
    with pytest.raises(RuntimeError, match="disk on fire"):
        write_clip_outputs(clip_result, tmp_path / "out")
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------------------------
# Samples
# ---------------------------------------------------------------------------------------------


def test_samples_are_small_documented_and_reproducible() -> None:
    files = sorted(p for p in SAMPLES.rglob("*") if p.is_file() and "__pycache__" not in p.parts)
    assert sum(p.stat().st_size for p in files) < 2_000_000
    readme = (SAMPLES / "README.md").read_text()
    for p in files:
        name = p.relative_to(SAMPLES).as_posix()
        if p.parent.name in ("frames", "gt"):  # numbered files are described as a range from 000000
            name = f"{p.parent.relative_to(SAMPLES).as_posix()}/000000"
        assert name == "README.md" or name in readme, f"samples/README.md does not describe {name}"
    # The rendered ground truth is what the render module draws for the recorded settings.
    import importlib.util

    spec = importlib.util.spec_from_file_location("make_samples", SAMPLES / "make_samples.py")
    assert spec is not None and spec.loader is not None
    make_samples = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(make_samples)
    clip = render_clip(make_samples.RENDER)
    gt = np.stack([read_palette_png(SAMPLES / "rendered" / "gt" / f"{t:06d}.png") for t in range(clip.num_frames)])
    assert np.array_equal(gt, clip.masks), "samples/rendered is out of date: run python samples/make_samples.py"
    frames = read_video(SAMPLES / "rendered" / "frames")
    assert frames.images.shape == clip.frames.shape
    # JPEG quality 95 keeps the brightness the tracker sees within ~1 grey level on average (the
    # colours lose more: chroma is subsampled).
    grey = [
        np.stack([cv2.cvtColor(im, cv2.COLOR_RGB2GRAY) for im in ims]).astype(np.int16)
        for ims in (frames.images, clip.frames)
    ]
    assert np.abs(grey[0] - grey[1]).mean() < 2.0


@pytest.mark.slow
def test_the_quick_start_sample_writes_each_mover_with_a_label_of_its_own() -> None:
    # The README's quick start (static camera, 3 objects; the slowest one's flow is under the frame's threshold of
    # moving pixels, set by the two fast ones): each object's most written label is a moving one, all three differ.
    result = segment_clip(SAMPLES / "rendered" / "frames", PipelineConfig(frames=5))
    gt = np.stack([read_palette_png(SAMPLES / "rendered" / "gt" / f"{t:06d}.png") for t in range(5)])
    written = []
    for obj in (1, 2, 3):
        values, counts = np.unique(result.masks[gt == obj], return_counts=True)
        written.append(int(values[counts.argmax()]))
    assert 0 not in written and len(set(written)) == 3, written
