"""Helpers shared by the test modules: scenes, clip folders, models with known behaviour, recordings."""

from __future__ import annotations

import csv
from collections import Counter
from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt
import torch
from scipy.optimize import linear_sum_assignment
from typer.testing import CliRunner

from mosegpipe.embed.model import ModelConfig, SubspaceNet
from mosegpipe.io.read import write_video
from mosegpipe.synth.render import ObjectSpec, RenderConfig, RenderedClip, render_clip

# Two planes in front of a static wall, moving right and up at about 3 and 2.4 px per frame.
OBJECTS = (
    ObjectSpec(shape="plane", centre_m=(-0.9, -0.1, 4.0), size_m=(1.1, 1.0, 1.0), velocity_m=(0.045, 0.0, 0.0)),
    ObjectSpec(shape="plane", centre_m=(1.0, 0.15, 4.0), size_m=(1.0, 0.9, 1.0), velocity_m=(0.0, -0.035, 0.0)),
)


def motion_checkpoint(path: Path, frames: int) -> Path:
    """Saves a SubspaceNet (in_dim = 2 * frames, width 16, 2 blocks, E = 5) that embeds displacement.

    Input layer: channels 0/1 = +(x_F - x_1), +(y_F - y_1), channels 2/3 the negatives (so that the
    ReLU keeps both signs); the residual blocks add zero; the head copies channels 0..3 and adds a
    constant fifth coordinate. After context normalisation, tracks with equal displacement get
    equal unit embeddings and different motions point in different directions.
    """
    net = SubspaceNet(tiny_config(frames))
    with torch.no_grad():
        for p in net.parameters():
            p.zero_()
        w = net.input.weight  # (16, 2F)
        last = 2 * (frames - 1)
        # 100x: the input is normalised by the clip's spread (~100 px), displacements are a few px.
        w[0, last], w[0, 0] = 100.0, -100.0
        w[1, last + 1], w[1, 1] = 100.0, -100.0
        w[2], w[3] = -w[0], -w[1]
        for i in range(4):
            net.head.weight[i, i] = 1.0
        net.head.bias[4] = 1.0
    return net.save(path, recipe={"name": f"test-displacement-f{frames}"})


def tiny_config(frames: int) -> ModelConfig:
    """The tiny architecture of the tests: in_dim = 2 * frames, width 16, 2 blocks, E = 5."""
    return ModelConfig(in_dim=2 * frames, width=16, num_blocks=2, embed_dim=5)


def tiny_model(frames: int = 2, seed: int = 0) -> SubspaceNet:
    """A randomly initialised tiny SubspaceNet (torch seeded with `seed`), in eval mode."""
    torch.manual_seed(seed)
    return SubspaceNet(tiny_config(frames)).eval()


def tiny_checkpoint(path: Path, frames: int) -> Path:
    """Saves tiny_model(frames) and returns its path."""
    return tiny_model(frames).save(path)


def render_scene(frames: int, seed: int = 0) -> RenderedClip:
    """240x320 frames, static camera, the two OBJECTS (ground truth: 0 wall, 1 and 2 the planes)."""
    return render_clip(RenderConfig(size_hw=(240, 320), frames=frames, seed=seed, objects=OBJECTS))


def write_frames(folder: Path, images: npt.NDArray[np.uint8]) -> Path:
    """Writes (T, H, W, 3) RGB frames as 000000.png, ... (lossless) into `folder`."""
    folder.mkdir(parents=True, exist_ok=True)
    for t, image in enumerate(images):
        assert cv2.imwrite(str(folder / f"{t:06d}.png"), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
    return folder


def write_avi(path: Path, images: npt.NDArray[np.uint8]) -> Path:
    """Writes (T, H, W, 3) RGB frames as an MJPG .avi."""
    write_video(path, iter(images), 10.0)
    return path


def best_permutation_accuracy(pred: npt.NDArray[np.int64], gt: npt.NDArray[np.int64]) -> float:
    """Share of entries that agree after the best one-to-one relabelling of `pred` (Hungarian)."""
    table = np.zeros((int(pred.max()) + 1, int(gt.max()) + 1), dtype=np.int64)
    np.add.at(table, (pred, gt), 1)
    rows, cols = linear_sum_assignment(-table)
    return float(table[rows, cols].sum() / pred.size)


def read_rrd(path: Path) -> Counter[str]:
    """Rows per entity path of a recording, not counting the annotation contexts (a mask's colour
    table shares its entity); RrdReader.store() fails on a file that was not closed."""
    from rerun.chunk import RrdReader

    reader = RrdReader(path)
    reader.store()
    rows: Counter[str] = Counter()
    for chunk in reader.stream().to_chunks():
        names = chunk.to_record_batch().schema.names
        if chunk.entity_path != "/" and all(":" not in n or n.startswith("AnnotationContext:") for n in names):
            continue
        rows[chunk.entity_path] += chunk.num_rows
    return rows


def annotation_contexts(path: Path) -> dict[str, dict[int, tuple[str, tuple[int, int, int, int]]]]:
    """Entity -> class id -> (name, RGBA) of each annotation context in a recording (each logged once)."""
    from rerun.chunk import RrdReader

    out: dict[str, dict[int, tuple[str, tuple[int, int, int, int]]]] = {}
    for chunk in RrdReader(path).stream().to_chunks():
        batch = chunk.to_record_batch()
        if "AnnotationContext:context" not in batch.schema.names:
            continue
        rows = batch.column("AnnotationContext:context").to_pylist()
        assert len(rows) == 1 and chunk.entity_path not in out, f"{chunk.entity_path}: the context is logged once"
        classes = {}
        for c in rows[0][0]:  # the one row's one instance: the classes
            info = c["class_description"]["info"]
            r, g, b, a = ((info["color"] >> s) & 0xFF for s in (24, 16, 8, 0))
            classes[c["class_id"]] = (info["label"], (r, g, b, a))
        out[chunk.entity_path] = classes
    return out


_BLUEPRINT_ENTITIES = ("/view/", "/container/", "/viewport", "/blueprint_panel", "/selection_panel", "/time_panel")


def rrd_messages(path: Path) -> list[str]:
    """The messages of an .rrd in file order, as `rerun rrd print` lists them: "activate" for a
    blueprint made active and default, "blueprint" for a layout chunk, else the chunk's entity path.

    RrdReader gives the stores' chunks but neither their order in the file nor the activation.
    """
    import re
    import shutil
    import subprocess
    import sys

    beside = Path(sys.executable).with_name("rerun")
    exe = str(beside) if beside.is_file() else shutil.which("rerun")
    assert exe, "the rerun program of rerun-sdk is not installed"
    done = subprocess.run([exe, "rrd", "print", str(path)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    messages = []
    for line in done.stdout.splitlines():
        if line.startswith("BlueprintActivationCommand("):
            flags = dict(re.findall(r"(make_active|make_default): (true|false)", line))
            messages.append("activate" if flags == {"make_active": "true", "make_default": "true"} else line)
        elif line.startswith("Chunk("):
            entity = line.split(" - ")[1]
            messages.append("blueprint" if entity.startswith(_BLUEPRINT_ENTITIES) else entity)
    return messages


def assert_layout_first(path: Path) -> None:
    """The recording's layout is sent once, made active and default, before any of its data."""
    messages = rrd_messages(path)
    assert messages.count("activate") == 1, messages[:40]
    head = messages[: messages.index("activate")]
    assert head and set(head) <= {"blueprint", "/__properties"}, head
    assert "blueprint" not in messages[len(head) :]


_RUNNER = CliRunner(env={"COLUMNS": "200"})


def moseg(*args: object) -> tuple[int, str, str]:
    """Runs the CLI in-process: (exit code, stdout, stderr); a bug (not a SystemExit) is raised."""
    from mosegpipe.cli.main import app

    result = _RUNNER.invoke(app, [str(a) for a in args])
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        raise result.exception
    return result.exit_code, result.stdout, result.stderr


def one_error_line(stderr: str) -> str:
    """The single `moseg: error: ...` line stderr must hold."""
    lines = stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("moseg: error: "), stderr
    return lines[0]


# ---------------------------------------------------------------------------------------------
# Shared by several test modules (a test module never imports another)
# ---------------------------------------------------------------------------------------------

TEXTURE_H, TEXTURE_W = 160, 240
TEXTURE_PAD = 48


def smooth_texture(seed: int, h: int = TEXTURE_H + 2 * TEXTURE_PAD, w: int = TEXTURE_W + 2 * TEXTURE_PAD) -> np.ndarray:
    """(h, w) uint8 smoothed noise: texture KLT and the flow follow."""
    noise = np.random.default_rng(seed).random((h, w)).astype(np.float32)
    smooth = cv2.GaussianBlur(noise, (0, 0), 2.0)
    return cv2.normalize(smooth, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)


def shifted_view(base: np.ndarray, dx: float, dy: float) -> np.ndarray:
    """The (TEXTURE_H, TEXTURE_W) window of `base` with its content moved by (dx, dy) px; no wrap-around."""
    m = np.float32([[1, 0, dx - TEXTURE_PAD], [0, 1, dy - TEXTURE_PAD]])
    return cv2.warpAffine(base, m, (TEXTURE_W, TEXTURE_H), flags=cv2.INTER_LINEAR)


def gray_to_rgb(gray: np.ndarray) -> np.ndarray:
    return np.repeat(gray[:, :, None], 3, axis=2)


FAULTY_CLIPS = ["a.avi", "boom.avi", "crash.avi", "hang.avi", "z.avi"]
"""Batch clips by name (batch_faults.py): fine, raising, crashing its worker, hanging, fine."""


def batch_rows(out: Path) -> list[dict[str, str]]:
    """The rows of a batch's batch_summary.csv."""
    with (out / "batch_summary.csv").open() as fh:
        return list(csv.DictReader(fh))


def file_tree(root: Path, names: list[str], data: bytes) -> Path:
    """`root` holding a file of `data` at each relative name (folders made)."""
    for name in names:
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_bytes(data)
    return root
