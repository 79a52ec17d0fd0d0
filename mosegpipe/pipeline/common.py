"""What the segment_* functions share: the model (its default, its summary record, embedding), the --k check,
and `decode_errors` (a broken input's OpenCV / OS errors as InputError). The grouping is `mosegpipe.group.refine`.

`load_model` lives in mosegpipe.embed.numpy_net beside `load_embedder` (the NumPy copy of the same weights)
and is re-exported by mosegpipe.pipeline.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from mosegpipe.embed.numpy_net import Embedder, load_embedder
from mosegpipe.errors import InputError
from mosegpipe.types import Trajectories


def model_info(model: Embedder) -> dict[str, Any]:
    """The model's recipe name, input frame count, configuration and checkpoint file, as recorded in
    summary.json ("checkpoint": the file given to load_model, None for the shipped weights or a
    model built in memory)."""
    recipe = getattr(model, "recipe", None) or {}
    return {
        "recipe": recipe.get("name", "unknown"),
        "model_frames": model.num_frames,
        "model_config": model.cfg.to_dict(),
        "checkpoint": getattr(model, "checkpoint_path", None),
    }


def embed_at_model_frames(model: Embedder, traj: Trajectories) -> npt.NDArray[np.float32]:
    """(N, E) embeddings of trajectories of any length, resampled in time to the model's F first."""
    return model.embed(traj)


def check_k(k: int | None, n: int, source: str, what: str = "tracks") -> None:
    if k is not None and k < 1:
        raise InputError(f"--k {k} must be >= 1")
    if k is not None and k > n:
        raise InputError(f"{source}: --k {k} is larger than the number of {what} ({n})")


def model_or_default(model: Embedder | None, frames: int, timings: dict[str, float]) -> Embedder:
    if model is not None:
        return model
    t0 = time.perf_counter()
    model = load_embedder(frames)
    timings["load_model"] = time.perf_counter() - t0
    return model


@contextlib.contextmanager
def decode_errors(source: str | Path) -> Iterator[None]:
    """Turns what OpenCV or the OS raise while reading a broken input into an InputError naming it.

    The readers raise InputError for the failures they foresee; a corrupt stream can still make an
    OpenCV decoder throw cv2.error, and an unreadable file raise OSError (permissions, I/O errors).
    Wrap reads only: an OSError while writing outputs is not the input's fault.

    Raises:
        InputError: in place of cv2.error or OSError raised in the block.
    """
    try:
        yield
    except (cv2.error, OSError) as exc:
        lines = str(exc).strip().splitlines()
        detail = " ".join(lines[-1].split())[:200] if lines else type(exc).__name__
        raise InputError(f"{source}: cannot read it ({detail})") from exc


def frames_text(n: int) -> str:
    return "1 frame" if n == 1 else f"{n} frames"
