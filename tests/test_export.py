"""`moseg export` and `mosegpipe.apps.export.export_masks`: every format read back as a user's program reads it
(PIL for the PNGs, PyAV for the videos, numpy for the npz), on an output folder whose masks are known;
bad input is one error line and leaves nothing behind; `moseg run --outputs masks` writes the masks only."""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import av
import numpy as np
import pytest
from PIL import Image

from mosegpipe.apps.export import export_masks, parse_colour, parse_objects
from mosegpipe.apps.outputs import write_mask_png
from mosegpipe.errors import InputError, OutputExistsError
from mosegpipe.io.provenance import source_identity
from mosegpipe.io.read import read_palette_png

from helpers import moseg, one_error_line, write_frames

H, W, T, START = 48, 64, 4, 3


def frames_text() -> np.ndarray:
    rng = np.random.default_rng(0)
    return rng.integers(0, 256, (T, H, W, 3), dtype=np.uint8)


def _masks() -> np.ndarray:
    """World 0 everywhere; object 1 a box moving right, object 3 a fixed box, 254 and 255 a corner each."""
    masks = np.zeros((T, H, W), np.uint8)
    for t in range(T):
        masks[t, 10:20, 5 + 4 * t : 15 + 4 * t] = 1
        masks[t, 30:40, 40:50] = 3
        masks[t, 0:3, 0:3] = 254
        masks[t, -3:, -3:] = 255
    return masks


def _output_folder(root: Path) -> Path:
    """An output folder as `moseg run FRAMES --start 3` writes it (the masks named by source index)."""
    frames_dir = write_frames(root / "frames", np.concatenate([np.zeros((START, H, W, 3), np.uint8), frames_text()]))
    out = root / "run"
    (out / "masks").mkdir(parents=True)
    for t, mask in enumerate(_masks()):
        write_mask_png(out / "masks" / f"{START + t:06d}.png", mask)
    summary = {"kind": "clip", "source": str(frames_dir), "source_identity": source_identity(frames_dir)}
    (out / "summary.json").write_text(json.dumps({**summary, "start": START, "frames": T}), encoding="utf-8")
    return out


@pytest.fixture
def run(tmp_path: Path) -> Path:
    return _output_folder(tmp_path)


def test_binary_is_one_0_255_png_per_object_and_frame(run: Path) -> None:
    done = export_masks(run, "binary")
    assert done.path == run / "masks_by_object" and done.objects == (1, 3, 254)
    masks = _masks()
    for obj in (1, 3, 254):
        names = sorted(os.listdir(run / "masks_by_object" / str(obj)))
        assert names == [f"{START + t:06d}.png" for t in range(T)]
        for t, name in enumerate(names):
            image = Image.open(run / "masks_by_object" / str(obj) / name)
            assert image.mode == "L"
            np.testing.assert_array_equal(np.array(image), np.where(masks[t] == obj, 255, 0))


def test_alpha_keeps_the_frame_and_makes_the_chosen_objects_opaque(run: Path) -> None:
    export_masks(run, "alpha", objects=[3, 1])
    for t, frame in enumerate(frames_text()):
        rgba = np.array(Image.open(run / "alpha" / f"{START + t:06d}.png"))
        assert rgba.shape == (H, W, 4)
        np.testing.assert_array_equal(rgba[..., :3], frame)
        np.testing.assert_array_equal(rgba[..., 3], np.where(np.isin(_masks()[t], [1, 3]), 255, 0))


def test_cutout_mov_holds_the_objects_on_transparency(run: Path) -> None:
    done = export_masks(run, "cutout", objects=[1])
    assert done.path == run / "cutout.mov"
    with av.open(str(done.path)) as container:
        assert container.streams.video[0].codec_context.name == "png"
        decoded = [f.to_ndarray(format="rgba") for f in container.decode(video=0)]
    assert len(decoded) == T
    for t, (rgba, frame) in enumerate(zip(decoded, frames_text())):
        inside = _masks()[t] == 1
        np.testing.assert_array_equal(rgba[..., 3], np.where(inside, 255, 0))
        np.testing.assert_array_equal(rgba[inside][:, :3], frame[inside])  # lossless
        assert not rgba[~inside][:, :3].any()


def test_cutout_on_a_colour_is_h264_mp4(run: Path) -> None:
    done = export_masks(run, "cutout", objects=[3], background=parse_colour("#00ff00"))
    assert done.path == run / "cutout.mp4"
    with av.open(str(done.path)) as container:
        assert container.streams.video[0].codec_context.name == "h264"
        decoded = [f.to_ndarray(format="rgb24") for f in container.decode(video=0)]
    assert len(decoded) == T
    outside = decoded[1][2:8, 30:60].reshape(-1, 3).mean(axis=0)  # far from the box: the background
    assert outside[1] > 200 and outside[0] < 60 and outside[2] < 60


def test_davis_renumbers_the_objects_and_npz_holds_the_labels(run: Path) -> None:
    export_masks(run, "davis", objects=[3, 1])
    assert json.loads((run / "davis" / "objects.json").read_text()) == {"1": 3, "2": 1}
    image = Image.open(run / "davis" / f"{START:05d}.png")
    assert image.mode == "P"
    expected = np.select([_masks()[0] == 3, _masks()[0] == 1], [1, 2], 0)
    np.testing.assert_array_equal(np.array(image), expected)
    export_masks(run, "npz")
    with np.load(run / "masks.npz") as data:
        np.testing.assert_array_equal(data["masks"], _masks())
        np.testing.assert_array_equal(data["frames"], np.arange(START, START + T))
        np.testing.assert_array_equal(data["objects"], [1, 3, 254])
    export_masks(run, "npz", objects=[1], overwrite=True)
    with np.load(run / "masks.npz") as data:
        np.testing.assert_array_equal(data["masks"], np.where(_masks() == 1, 1, 0))


def test_to_writes_elsewhere_and_overwrite_replaces(run: Path, tmp_path: Path) -> None:
    export_masks(run, "binary", objects=[1], to=tmp_path / "exports")
    assert sorted(os.listdir(tmp_path / "exports" / "masks_by_object")) == ["1"]
    with pytest.raises(OutputExistsError, match="pass --overwrite"):
        export_masks(run, "binary", objects=[3], to=tmp_path / "exports")
    export_masks(run, "binary", objects=[3], to=tmp_path / "exports", overwrite=True)
    assert sorted(os.listdir(tmp_path / "exports" / "masks_by_object")) == ["3"]
    assert sorted(os.listdir(tmp_path / "exports")) == ["masks_by_object"]  # no temporary folder left


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--as", "binary", "--objects", "2"], "object 2: not in the masks of .* \\(objects there: 1, 3, 254\\)"),
        (["--as", "binary", "--objects", "0"], "object 0 is the world"),
        (["--as", "binary", "--objects", "1,x"], "--objects '1,x': expected object numbers"),
        (["--as", "npz", "--background", "#000000"], "--background applies to --as cutout only"),
        (["--as", "cutout", "--background", "green"], "--background 'green': expected a colour"),
    ],
)
def test_bad_choices_are_one_line_and_write_nothing(run: Path, args: list[str], message: str) -> None:
    before = sorted(os.listdir(run))
    code, _, err = moseg("export", run, *args)
    assert code == 1
    assert re.search(message, one_error_line(err)), err
    assert sorted(os.listdir(run)) == before


def test_not_an_output_folder_and_an_unknown_format(tmp_path: Path, run: Path) -> None:
    code, _, err = moseg("export", tmp_path / "nowhere", "--as", "npz")
    assert code == 1 and "no such folder" in one_error_line(err)
    (tmp_path / "plain").mkdir()
    code, _, err = moseg("export", tmp_path / "plain", "--as", "npz")
    assert code == 1 and "not a moseg output folder" in one_error_line(err)
    code, _, err = moseg("export", run, "--as", "gif")
    assert code == 2 and "'gif' is not one of" in one_error_line(err)  # a usage error, as every bad choice
    with pytest.raises(InputError, match="--as 'gif'"):
        export_masks(run, "gif")


def test_alpha_of_a_changed_source_is_refused_before_writing(run: Path, tmp_path: Path) -> None:
    frame = tmp_path / "frames" / f"{START:06d}.png"
    frame.write_bytes(frame.read_bytes() + b"\0")  # its size changed since the run
    code, _, err = moseg("export", run, "--as", "alpha")
    assert code == 1 and "changed since the run" in one_error_line(err)
    assert not (run / "alpha").exists() and not (run / ".alpha.partial").exists()


def test_parse_objects() -> None:
    assert parse_objects("1, 3") == (1, 3)
    with pytest.raises(InputError, match="named twice"):
        parse_objects("1,1")


def test_run_masks_only_then_export(tmp_path: Path) -> None:
    """The real pipeline: `moseg run --outputs masks` writes no overlays or recording; export reads it."""
    from helpers import render_scene

    frames = write_frames(tmp_path / "frames", render_scene(5).frames)
    code, out, err = moseg("run", frames, "-o", tmp_path / "run", "--outputs", "masks")
    assert code == 0, err
    assert sorted(os.listdir(tmp_path / "run")) == ["labels.npz", "masks", "summary.json"]
    assert "wrote" in out and "overlay" not in out
    code, out, err = moseg("export", tmp_path / "run", "--as", "binary")
    assert code == 0, err
    objects = sorted(os.listdir(tmp_path / "run" / "masks_by_object"))
    assert objects, out
    mask = read_palette_png(tmp_path / "run" / "masks" / "000000.png")
    first = np.array(Image.open(tmp_path / "run" / "masks_by_object" / objects[0] / "000000.png"))
    np.testing.assert_array_equal(first > 0, mask == int(objects[0]))
