"""The recipe, stage by stage: frames -> tracks -> trajectories -> embeddings -> clusters -> masks.

Compute only: `segment_frames` / `segment_clip` / `segment_pair` / `segment_tracks` return immutable
results with their timings, and `segment_video` walks a whole video as a stream of window results.
Writing any of them into an output folder is `mosegpipe.apps.outputs`. `decode_errors` turns whatever
OpenCV or the OS raise on a broken input into an InputError.

Modules: config (PipelineConfig and its checked loading), common (the model, the shared checks),
clip (clips), pair (image pairs), tracks (tracks made elsewhere), video (whole videos, window by
window), window (what a whole video yields: WindowResult, VideoFrame, frame_mask) and labels (motion
labels kept across windows). Every public name is re-exported here.
"""

from __future__ import annotations

from mosegpipe.embed.numpy_net import load_model
from mosegpipe.group.labels import LabelBook, LabelConfig, match_labels
from mosegpipe.group.refine import check_rigid
from mosegpipe.pipeline.clip import ClipResult, clip_masks, segment_clip, segment_frames
from mosegpipe.pipeline.common import decode_errors, embed_at_model_frames, model_info
from mosegpipe.pipeline.config import PRESETS, PipelineConfig
from mosegpipe.pipeline.pair import PairResult, segment_pair
from mosegpipe.pipeline.tracks import TracksResult, segment_tracks, tracks_clip
from mosegpipe.pipeline.video import (
    check_video_settings,
    segment_video,
    video_frames_to_read,
)
from mosegpipe.pipeline.window import AMBIGUOUS_K_NOTE, VideoFrame, WindowResult, frame_mask

__all__ = [
    "AMBIGUOUS_K_NOTE",
    "PRESETS",
    "ClipResult",
    "LabelBook",
    "LabelConfig",
    "PairResult",
    "PipelineConfig",
    "TracksResult",
    "VideoFrame",
    "WindowResult",
    "check_rigid",
    "check_video_settings",
    "clip_masks",
    "decode_errors",
    "embed_at_model_frames",
    "frame_mask",
    "load_model",
    "match_labels",
    "model_info",
    "segment_clip",
    "segment_frames",
    "segment_pair",
    "segment_tracks",
    "segment_video",
    "tracks_clip",
    "video_frames_to_read",
]
