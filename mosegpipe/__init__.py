"""mosegpipe: motion segmentation of tracked points with SubspaceNet."""

from __future__ import annotations

__version__ = "0.1.0"
