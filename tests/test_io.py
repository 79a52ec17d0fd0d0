from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from mosegpipe.errors import InputError
from mosegpipe.io.read import (
    atomic_write,
    default_palette,
    iter_video,
    read_image,
    read_palette_png,
    read_video,
    video_info,
    write_json,
    write_npz,
    write_palette_png,
    write_video,
)


def _rgb(h: int, w: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (h, w, 3), dtype=np.uint8)


def _write_png(path: Path, rgb_or_gray: np.ndarray) -> None:
    img = rgb_or_gray if rgb_or_gray.ndim == 2 else cv2.cvtColor(rgb_or_gray, cv2.COLOR_RGB2BGR)
    assert cv2.imwrite(str(path), img)


def _block_frames(num: int = 5, h: int = 48, w: int = 64) -> list[np.ndarray]:
    """Frames that survive MJPG: flat blocks whose brightness encodes the frame index."""
    frames = []
    for t in range(num):
        f = np.zeros((h, w, 3), np.uint8)
        f[:, : w // 2] = (40 * t + 20, 100, 200 - 30 * t)
        f[:, w // 2 :] = (200, 40 * t + 30, 60)
        frames.append(f)
    return frames


# --- frame folders ---------------------------------------------------------------------------


def test_read_video_folder_sorted_by_name_gray_becomes_rgb(tmp_path: Path) -> None:
    a, c = _rgb(16, 20, 0), _rgb(16, 20, 2)
    gray = np.arange(16 * 20, dtype=np.uint8).reshape(16, 20)
    _write_png(tmp_path / "b.png", gray)
    _write_png(tmp_path / "a.png", a)
    _write_png(tmp_path / "c.bmp", c)
    (tmp_path / "notes.txt").write_text("not an image")

    frames = read_video(tmp_path)

    assert frames.images.shape == (3, 16, 20, 3) and frames.images.dtype == np.uint8
    np.testing.assert_array_equal(frames.images[0], a)
    np.testing.assert_array_equal(frames.images[1], np.repeat(gray[:, :, None], 3, axis=2))
    np.testing.assert_array_equal(frames.images[2], c)
    assert frames.fps == 0.0 and frames.start == 0 and frames.source == str(tmp_path)


def test_read_video_folder_start_and_max_frames(tmp_path: Path) -> None:
    imgs = [_rgb(8, 8, s) for s in range(5)]
    for i, img in enumerate(imgs):
        _write_png(tmp_path / f"{i:03d}.png", img)
    frames = read_video(tmp_path, max_frames=2, start=2)
    assert frames.start == 2 and frames.num_frames == 2
    np.testing.assert_array_equal(frames.images, np.stack(imgs[2:4]))
    info = video_info(tmp_path)
    assert info == {"kind": "folder", "num_frames": 5, "fps": 0.0, "size_hw": (8, 8)}


def test_read_video_folder_errors(tmp_path: Path) -> None:
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "readme.txt").write_text("x")
    with pytest.raises(InputError, match="no images") as exc:
        read_video(empty)
    assert str(empty) in str(exc.value)

    mixed = tmp_path / "mixed"
    mixed.mkdir()
    _write_png(mixed / "0.png", _rgb(8, 8, 0))
    _write_png(mixed / "1.png", _rgb(8, 9, 1))
    with pytest.raises(InputError, match=r"1\.png.*9x8.*8x8"):
        read_video(mixed)
    with pytest.raises(InputError, match="start=3 but the folder has only 2 images"):
        read_video(mixed, start=3)


def test_read_video_missing_path(tmp_path: Path) -> None:
    missing = tmp_path / "nope.mp4"
    with pytest.raises(InputError, match="no such file") as exc:
        read_video(missing)
    assert str(missing) in str(exc.value)


def test_read_video_garbage_file(tmp_path: Path) -> None:
    bad = tmp_path / "x.mp4"
    bad.write_bytes(np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8).tobytes())
    with pytest.raises(InputError) as exc:
        read_video(bad)
    assert str(bad) in str(exc.value)
    with pytest.raises(InputError):
        video_info(bad)


def test_read_video_truncated_avi(tmp_path: Path) -> None:
    good = tmp_path / "good.avi"
    write_video(good, _block_frames(), fps=10)
    cut = tmp_path / "cut.avi"
    cut.write_bytes(good.read_bytes()[:300])  # header only, no complete frame
    with pytest.raises(InputError) as exc:
        read_video(cut)
    assert str(cut) in str(exc.value)


# --- video files -----------------------------------------------------------------------------


@pytest.mark.parametrize("suffix", [".avi", ".mp4"])
def test_write_video_then_read_back(tmp_path: Path, suffix: str) -> None:
    src = _block_frames()
    path = tmp_path / f"clip{suffix}"
    assert write_video(path, iter(src), fps=10) == 5
    assert [p.name for p in tmp_path.iterdir()] == [path.name]  # no temporary file left

    frames = read_video(path)
    assert frames.images.shape == (5, 48, 64, 3)
    assert frames.fps == pytest.approx(10.0)
    # Lossy codecs: compare block means, which encode the frame index and the colour order.
    got = frames.images.astype(float)
    for t, f in enumerate(src):
        assert np.abs(got[t, 8:40, 8:24].mean(axis=(0, 1)) - f[0, 0]).max() < 6
        assert np.abs(got[t, 8:40, 40:56].mean(axis=(0, 1)) - f[0, -1]).max() < 6

    info = video_info(path)
    assert info["kind"] == "video" and info["num_frames"] == 5 and info["size_hw"] == (48, 64)

    part = read_video(path, max_frames=2, start=3)
    assert part.start == 3 and part.num_frames == 2
    np.testing.assert_array_equal(part.images, frames.images[3:5])
    with pytest.raises(InputError, match="start=7"):
        read_video(path, start=7)


def test_iter_video_single_and_chunks(tmp_path: Path) -> None:
    path = tmp_path / "clip.avi"
    write_video(path, _block_frames(), fps=5)
    singles = list(iter_video(path, start=1))
    assert [i for i, _ in singles] == [1, 2, 3, 4]
    assert singles[0][1].shape == (48, 64, 3)
    chunks = list(iter_video(path, chunk=2))
    assert [(i, c.shape[0]) for i, c in chunks] == [(0, 2), (2, 2), (4, 1)]
    np.testing.assert_array_equal(chunks[1][1][0], singles[1][1])
    with pytest.raises(InputError, match="chunk=0"):
        list(iter_video(path, chunk=0))


def test_write_video_errors(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="unsupported video suffix"):
        write_video(tmp_path / "a.mkv", _block_frames(), fps=10)
    with pytest.raises(InputError, match="no frames"):
        write_video(tmp_path / "a.avi", [], fps=10)
    frames = _block_frames(2) + [np.zeros((10, 10, 3), np.uint8)]
    with pytest.raises(InputError, match="frame 2 is 10x10"):
        write_video(tmp_path / "b.avi", frames, fps=10)
    assert list(tmp_path.iterdir()) == []


# --- images ----------------------------------------------------------------------------------


def test_read_image(tmp_path: Path) -> None:
    rgb = _rgb(5, 7, 3)
    _write_png(tmp_path / "x.png", rgb)
    np.testing.assert_array_equal(read_image(tmp_path / "x.png"), rgb)
    frames = read_video(tmp_path / "x.png")
    np.testing.assert_array_equal(frames.images, rgb[None])
    (tmp_path / "bad.png").write_bytes(b"not a png")
    with pytest.raises(InputError, match="bad.png: not a readable image"):
        read_image(tmp_path / "bad.png")
    with pytest.raises(InputError, match="no such image"):
        read_image(tmp_path / "missing.png")


# --- atomic writes ---------------------------------------------------------------------------


def test_atomic_write_leaves_nothing_when_body_raises(tmp_path: Path) -> None:
    target = tmp_path / "out.json"
    with pytest.raises(RuntimeError, match="boom"):
        with atomic_write(target) as tmp:
            tmp.write_text("partial")
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []


def test_atomic_write_keeps_old_file_on_failure_and_replaces_on_success(tmp_path: Path) -> None:
    target = tmp_path / "sub" / "out.txt"
    with atomic_write(target) as tmp:
        assert tmp.parent == target.parent and tmp.suffix == ".txt" and not tmp.exists()
        tmp.write_text("v1")
    assert target.read_text() == "v1"
    with pytest.raises(ValueError):
        with atomic_write(target) as tmp:
            tmp.write_text("v2-partial")
            raise ValueError
    assert target.read_text() == "v1"
    assert sorted(p.name for p in target.parent.iterdir()) == ["out.txt"]
    with pytest.raises(FileNotFoundError):
        with atomic_write(tmp_path / "never.txt"):
            pass


def test_write_json_and_npz(tmp_path: Path) -> None:
    obj = {"k": np.int64(3), "scores": np.array([0.5, 0.25]), "path": tmp_path / "a", "x": np.float32(1.5)}
    write_json(tmp_path / "r.json", obj)
    assert json.loads((tmp_path / "r.json").read_text()) == {
        "k": 3,
        "scores": [0.5, 0.25],
        "path": str(tmp_path / "a"),
        "x": 1.5,
    }
    labels = np.array([0, 1, 1], np.int64)
    write_npz(tmp_path / "r.npz", labels=labels, xy=np.ones((3, 2), np.float32))
    with np.load(tmp_path / "r.npz") as data:
        np.testing.assert_array_equal(data["labels"], labels)
        assert data["xy"].dtype == np.float32
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.json", "r.npz"]


# --- palette PNGs ----------------------------------------------------------------------------


def test_default_palette_is_the_voc_davis_palette() -> None:
    pal = default_palette()
    assert pal.shape == (256, 3) and pal.dtype == np.uint8
    np.testing.assert_array_equal(
        pal[:9],
        [
            [0, 0, 0],
            [128, 0, 0],
            [0, 128, 0],
            [128, 128, 0],
            [0, 0, 128],
            [128, 0, 128],
            [0, 128, 128],
            [128, 128, 128],
            [64, 0, 0],
        ],
    )
    assert len({tuple(c) for c in pal}) == 256


def test_palette_png_round_trip_and_opencv_sees_colours(tmp_path: Path) -> None:
    mask = np.zeros((30, 41), np.uint8)
    mask[5:20, 3:30] = 1
    mask[22:, :] = 2
    mask[0, 40] = 255
    path = tmp_path / "00000.png"
    write_palette_png(path, mask, default_palette())

    np.testing.assert_array_equal(read_palette_png(path), mask)
    assert path.read_bytes()[25] == 3  # IHDR colour type: indexed
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    assert bgr is not None and bgr.shape == (30, 41, 3)
    np.testing.assert_array_equal(bgr[:, :, ::-1], default_palette()[mask])


@pytest.mark.parametrize("png_filter", ["NONE", "SUB", "UP", "AVG", "PAETH"])
def test_read_palette_png_undoes_each_png_filter(tmp_path: Path, png_filter: str) -> None:
    # OpenCV writes 8-bit gray PNGs with a chosen scanline filter; read_palette_png returns gray
    # values as they are, so this checks the unfiltering against libpng.
    yy, xx = np.mgrid[0:24, 0:40]
    gray = ((xx * 5 + yy * 3 + (xx * yy) % 7) % 256).astype(np.uint8)
    flag = getattr(cv2, f"IMWRITE_PNG_FILTER_{png_filter}")
    assert cv2.imwrite(str(tmp_path / "g.png"), gray, [cv2.IMWRITE_PNG_FILTER, flag])
    np.testing.assert_array_equal(read_palette_png(tmp_path / "g.png"), gray)


def test_read_palette_png_rejects_corrupt_files(tmp_path: Path) -> None:
    path = tmp_path / "m.png"
    write_palette_png(path, np.ones((4, 4), np.uint8))
    data = bytearray(path.read_bytes())
    data[40] ^= 0xFF  # inside the PLTE chunk
    (tmp_path / "bad.png").write_bytes(bytes(data))
    with pytest.raises(InputError, match="CRC"):
        read_palette_png(tmp_path / "bad.png")
    (tmp_path / "text.png").write_text("hello")
    with pytest.raises(InputError, match="not a PNG"):
        read_palette_png(tmp_path / "text.png")


def test_write_palette_png_validates(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="uint8"):
        write_palette_png(tmp_path / "a.png", np.zeros((3, 3), np.int32))
    with pytest.raises(ValueError, match="palette"):
        write_palette_png(tmp_path / "a.png", np.zeros((3, 3), np.uint8), np.zeros((300, 3), np.uint8))
    assert list(tmp_path.iterdir()) == []


# --- real data (skipped without the benchmark folder) ---------------------------------------


def test_real_video_and_frame_folder(data_root: Path) -> None:
    vtest = data_root / "videos" / "vtest.avi"
    info = video_info(vtest)
    assert info["kind"] == "video" and info["size_hw"] == (576, 768) and info["fps"] == pytest.approx(10.0)
    assert info["num_frames"] == 795
    frames = read_video(vtest, max_frames=2, start=100)
    assert frames.images.shape == (2, 576, 768, 3) and frames.start == 100

    folder = data_root / "kt3dmoseg" / "frames" / "Seq005_Clip01"
    clip = read_video(folder, max_frames=5)
    assert clip.images.shape == (5, 375, 1242, 3)
    # Grayscale JPEGs: all three channels equal.
    assert (clip.images[..., 0] == clip.images[..., 2]).all()
