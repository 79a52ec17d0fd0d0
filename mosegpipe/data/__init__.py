"""Benchmark readers (KT3DMoSeg, Hopkins155, AdelaideRMF, FBMS59). Each takes a root folder and never downloads.

Generated data lives in `mosegpipe.synth`.
"""

from __future__ import annotations

from mosegpipe.data.adelaidermf import AdelaidePair, list_adelaide, load_adelaide, read_adelaide_pair
from mosegpipe.data.fbms import fbms_track_labels, fbms_windows, read_fbms_groundtruth, read_fbms_tracks
from mosegpipe.data.hopkins155 import list_hopkins_sequences, load_hopkins, read_hopkins
from mosegpipe.data.kt3dmoseg import (
    KT3DSequence,
    kt3d_frame_paths,
    kt3d_test_clips,
    kt3d_windows,
    list_kt3d_sequences,
    read_kt3d_sequence,
)

__all__ = [
    "AdelaidePair",
    "KT3DSequence",
    "fbms_track_labels",
    "fbms_windows",
    "kt3d_frame_paths",
    "kt3d_test_clips",
    "kt3d_windows",
    "list_adelaide",
    "list_hopkins_sequences",
    "list_kt3d_sequences",
    "load_adelaide",
    "load_hopkins",
    "read_adelaide_pair",
    "read_fbms_groundtruth",
    "read_fbms_tracks",
    "read_hopkins",
    "read_kt3d_sequence",
]
