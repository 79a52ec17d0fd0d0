"""What a run's input was: the identity of a source file or frame folder, recorded in summary.json.

`moseg replay` reads a run's input again from its recorded path. A relative path names another file
from another working folder, and a file may be replaced under the same name; the identity (the
absolute path plus a cheap fingerprint of the content) lets a replay find the run's input and refuse
one that changed. Standard library only: the CLI checks it before the heavy imports.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path
from typing import Any

IMAGE_SUFFIXES: frozenset[str] = frozenset({".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff"})
"""File name endings (lower case) treated as images, in a frame folder or as a single image."""

HASHED_BYTES = 1 << 20
"""Bytes of a file hashed for its identity (the first MiB): enough to tell videos apart, cheap on long ones."""

FOLDER_FILES = 8
"""Image files of a frame folder recorded (by name and size) in its identity: the first ones, by name."""


def source_identity(path: object) -> dict[str, Any] | None:
    """The identity of a source as it is now.

    Args:
        path: a video, image or tracks file, or a frame folder (str or PathLike; relative to the
            working folder); anything else (frames passed from Python) has no identity.

    Returns:
        None when `path` is not a path, is empty or names nothing; else a JSON-ready dict:
        `path` (str, absolute), and for a file `size` (int, bytes) and `sha256_first_mib` (str, 64 hex
        digits of the SHA-256 of its first HASHED_BYTES bytes), for a folder `files` (the first
        FOLDER_FILES image files by name: [{"name": str, "size": int bytes}, ...]).
    """
    if not isinstance(path, (str, os.PathLike)) or not os.fspath(path):
        return None
    where = Path(os.path.abspath(path))  # abspath, not resolve(): "..", not the links, are taken out
    if where.is_file():
        with where.open("rb") as f:
            head = f.read(HASHED_BYTES)
        return {"path": str(where), "size": where.stat().st_size, "sha256_first_mib": hashlib.sha256(head).hexdigest()}
    if where.is_dir():
        images = sorted(f.name for f in where.iterdir() if f.is_file() and f.suffix.lower() in IMAGE_SUFFIXES)
        files = [{"name": name, "size": (where / name).stat().st_size} for name in images[:FOLDER_FILES]]
        return {"path": str(where), "files": files}
    return None


def identity_differences(recorded: dict[str, Any], now: dict[str, Any]) -> list[str]:
    """What differs between a recorded identity and the source's identity now (both from source_identity).

    Returns:
        Short phrases, empty when they agree: "a folder now" / "a file now", "size", "first MiB", "files".
    """
    if ("files" in recorded) != ("files" in now):
        return ["a folder now" if "files" in now else "a file now"]
    if "files" in recorded:
        return [] if recorded["files"] == now["files"] else ["files"]
    differ = []
    if recorded.get("size") != now.get("size"):
        differ.append("size")
    if recorded.get("sha256_first_mib") != now.get("sha256_first_mib"):
        differ.append("first MiB")
    return differ
