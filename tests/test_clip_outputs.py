"""Clips write overlay.mp4 too; tracks from another tracker get masks, overlays and a recording with
their video (`moseg tracks --video`); `Segmenter` segments and writes everything in one call."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from mosegpipe import Segmenter
from mosegpipe.errors import InputError, OutputExistsError
from mosegpipe.io.read import read_palette_png, read_video
from mosegpipe.pipeline import ClipResult, PipelineConfig, TracksResult
from mosegpipe.points.klt import track_klt
from mosegpipe.synth.render import RenderedClip
from mosegpipe.types import Frames

from helpers import moseg, motion_checkpoint, one_error_line, read_rrd, render_scene, write_avi

VIEWS = ["labels.npz", "masks", "overlay", "overlay.mp4", "recording.rrd", "summary.json"]


@pytest.fixture(scope="module")
def scene() -> RenderedClip:
    return render_scene(6)


@pytest.fixture(scope="module")
def model5(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return motion_checkpoint(tmp_path_factory.mktemp("models") / "motion5.pt", 5)


@pytest.fixture(scope="module")
def clip_avi(tmp_path_factory: pytest.TempPathFactory, scene: RenderedClip) -> Path:
    return write_avi(tmp_path_factory.mktemp("clip") / "scene.avi", scene.frames)


@pytest.fixture(scope="module")
def tracks_npz(tmp_path_factory: pytest.TempPathFactory, scene: RenderedClip) -> Path:
    """KLT tracks of the six frames saved as another tracker's (N, T, 2) + visible."""
    tracks = track_klt(Frames(scene.frames))
    path = tmp_path_factory.mktemp("tracks") / "tracks.npz"
    np.savez(path, xy=tracks.xy, visible=tracks.visible)
    return path


def _frames_of(video: Path) -> np.ndarray:
    cap = cv2.VideoCapture(str(video))
    frames = []
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        frames.append(frame[..., ::-1])
    cap.release()
    return np.stack(frames)


def _check_overlay_video(out: Path, indices: list[int]) -> None:
    """overlay.mp4 holds the overlay JPEGs, frame for frame (both lossy: each is nearest its own)."""
    video = _frames_of(out / "overlay.mp4")
    jpegs = np.stack([cv2.imread(str(out / "overlay" / f"{i:06d}.jpg"))[..., ::-1] for i in indices])
    assert video.shape == jpegs.shape
    diff = np.abs(video[:, None].astype(np.int16) - jpegs[None].astype(np.int16)).mean(axis=(2, 3, 4))
    assert np.array_equal(diff.argmin(axis=1), np.arange(len(indices))), diff  # each frame is its own overlay


def test_a_clip_writes_overlay_mp4(tmp_path: Path, clip_avi: Path, model5: Path) -> None:
    out = tmp_path / "out"
    code, stdout, stderr = moseg("run", clip_avi, "--model", model5, "--start", "1", "-o", out)
    assert code == 0, stderr
    assert f"wrote {out}/ (summary.json, labels.npz, masks/, overlay/, overlay.mp4, recording.rrd)" in stdout
    assert sorted(p.name for p in out.iterdir()) == VIEWS
    _check_overlay_video(out, [1, 2, 3, 4, 5])


def test_tracks_with_their_video_get_masks_overlays_and_a_recording(
    tmp_path: Path, clip_avi: Path, tracks_npz: Path, model5: Path
) -> None:
    out = tmp_path / "t"
    # The embedding's grouping, pinned: the outputs are what is tested here, with the test model's K (3).
    args = ("tracks", tracks_npz, "--video", clip_avi, "--start", "1", "--frames", "5", "--model", model5)
    code, stdout, stderr = moseg(*args, "--method", "subspacenet", "-o", out)
    assert code == 0, stderr
    assert f"wrote {out}/ (summary.json, labels.npz, masks/, overlay/, overlay.mp4, recording.rrd)" in stdout
    assert f"open it with `moseg view {out / 'recording.rrd'}`" in stdout
    assert sorted(p.name for p in out.iterdir()) == VIEWS
    summary = json.loads((out / "summary.json").read_text())
    assert summary["kind"] == "tracks" and summary["video"] == str(clip_avi.absolute()) and summary["k"] == 3
    _check_overlay_video(out, [1, 2, 3, 4, 5])
    assert read_rrd(out / "recording.rrd")["/video/mask"] == 5
    # The masks carry the tracks' own labels where the tracks are.
    saved = np.load(tracks_npz)
    labels = np.load(out / "labels.npz")["labels"]
    for t in (1, 5):
        mask = read_palette_png(out / "masks" / f"{t:06d}.png")
        x, y = np.round(saved["xy"][labels >= 0, t]).astype(int).T
        inside = (x >= 0) & (x < mask.shape[1]) & (y >= 0) & (y < mask.shape[0])
        assert np.mean(mask[y[inside], x[inside]] == labels[labels >= 0][inside]) > 0.9

    code, stdout, stderr = moseg("replay", out / "summary.json", "-o", tmp_path / "again")
    assert code == 0 and "K = 3 as recorded" in stdout, stderr
    assert sorted(p.name for p in (tmp_path / "again").iterdir()) == VIEWS
    for t in range(1, 6):
        name = f"{t:06d}.png"
        assert np.array_equal(
            read_palette_png(out / "masks" / name), read_palette_png(tmp_path / "again" / "masks" / name)
        )

    code, stdout, stderr = moseg(*args, "-o", tmp_path / "plain", "--no-rrd")  # as before, plus the views
    assert code == 0 and not (tmp_path / "plain" / "recording.rrd").exists() and "moseg view" not in stdout


def test_tracks_of_another_video_are_one_error_line(
    tmp_path: Path, clip_avi: Path, tracks_npz: Path, model5: Path, scene: RenderedClip, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)  # where the default output folder would go
    saved = np.load(tracks_npz)
    np.savez(tmp_path / "big.npz", xy=saved["xy"] * 4, visible=saved["visible"])
    code, out, stderr = moseg("tracks", tmp_path / "big.npz", "--video", clip_avi, "--model", model5, "-f", "5")
    assert code == 1 and out == ""
    assert one_error_line(stderr).startswith(f"moseg: error: {clip_avi}: the tracks reach x = ")
    assert "far beyond the 320x240 frames" in stderr and not (tmp_path / "big_moseg").exists()
    code, _, stderr = moseg("tracks", tracks_npz, "--video", tmp_path / "none.avi", "-o", tmp_path / "o")
    assert code == 1 and one_error_line(stderr) == f"moseg: error: {tmp_path / 'none.avi'}: no such file or folder"
    short = write_avi(tmp_path / "short.avi", scene.frames[:4])
    code, _, stderr = moseg("tracks", tracks_npz, "--video", short, "--model", model5, "-o", tmp_path / "o")
    assert code == 1 and one_error_line(stderr) == (
        f"moseg: error: {short}: 4 frames from frame 0; the tracks' window is 6 frames from frame 0"
    )
    assert not (tmp_path / "o").exists()


def test_segmenter_writes_everything_in_one_call(
    tmp_path: Path, clip_avi: Path, tracks_npz: Path, model5: Path, scene: RenderedClip
) -> None:
    seg = Segmenter(checkpoint=model5)
    result = seg(clip_avi, out=tmp_path / "clip")
    assert isinstance(result, ClipResult) and result.clustering.k == 3
    assert sorted(p.name for p in (tmp_path / "clip").iterdir()) == VIEWS
    assert seg(clip_avi).clustering.k == 3  # no out: the result alone, as segment_clip gives it
    assert list(seg._models) == [5]  # loaded once
    with pytest.raises(OutputExistsError):
        seg(tmp_path / "missing.avi", out=tmp_path / "clip")  # refused before reading the input

    saved = np.load(tracks_npz)
    tracks = seg.tracks(saved["xy"], saved["visible"], out=tmp_path / "tracks", video=clip_avi, frames=5)
    assert isinstance(tracks, TracksResult) and tracks.clustering.k == 3
    assert sorted(p.name for p in (tmp_path / "tracks").iterdir()) == VIEWS

    summary = Segmenter(PipelineConfig(frames=5, k=3), checkpoint=model5, rrd=False).video(
        clip_avi, out=tmp_path / "video"
    )
    assert summary["kind"] == "video" and (tmp_path / "video" / "overlay.mp4").is_file()
    assert not (tmp_path / "video" / "recording.rrd").exists()
    with pytest.raises(InputError, match="the tracks' window is 5 frames"):
        from mosegpipe.pipeline import tracks_clip

        tracks_clip(tracks, read_video(clip_avi, max_frames=3), PipelineConfig())
