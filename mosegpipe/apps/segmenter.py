"""One object, one call: `Segmenter` segments a clip, a whole video, an image pair or tracks made
elsewhere and, given `out`, writes every output at once (summary.json, labels.npz, masks/, overlays,
overlay.mp4, recording.rrd; docs/OUTPUTS.md). It joins the compute (`mosegpipe.pipeline`) and the
writing (`mosegpipe.apps.outputs`) and keeps each model loaded between calls."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy.typing as npt

from mosegpipe.apps.outputs import (
    check_output_dir,
    write_clip_outputs,
    write_pair_outputs,
    write_tracks_outputs,
    write_video_outputs,
)
from mosegpipe.embed.numpy_net import load_embedder
from mosegpipe.pipeline import (
    ClipResult,
    PairResult,
    PipelineConfig,
    TracksResult,
    segment_clip,
    segment_pair,
    segment_tracks,
    tracks_clip,
)

if TYPE_CHECKING:
    from mosegpipe.embed.numpy_net import Embedder


class Segmenter:
    """Segments inputs with one set of settings and writes their outputs in the same call.

        seg = Segmenter()                                  # 5 frames, the shipped weights
        result = seg("clip.mp4", out="clip_moseg")         # ClipResult; and the output folder
        summary = seg.video("long.mp4", out="long_moseg")  # a whole video, window by window
        result = seg.tracks(xy, visible, video="clip.mp4", out="tracks_moseg")  # CoTracker's tracks
        result = seg.pair("a.jpg", "b.jpg", out="pair_moseg")

    Without `out` nothing is written (the result alone, as `segment_clip` gives it). An `out`
    already holding results is refused before any work unless `overwrite`.

    Args:
        cfg: pipeline settings (frames, start, tracker, clustering, masks, ...).
        checkpoint: a model checkpoint (None = the shipped weights for each frame count).
        overwrite: replace an earlier moseg output folder at `out`.
        rrd: write the Rerun recording too.
    """

    def __init__(
        self,
        cfg: PipelineConfig | None = None,
        checkpoint: str | Path | None = None,
        overwrite: bool = False,
        rrd: bool = True,
    ) -> None:
        self.cfg = cfg or PipelineConfig()
        self.checkpoint = checkpoint
        self.overwrite = overwrite
        self.rrd = rrd
        self._models: dict[int, Embedder] = {}

    def model(self, frames: int) -> Embedder:
        """The model for trajectories of `frames` frames, loaded once."""
        if frames not in self._models:
            self._models[frames] = load_embedder(frames, self.checkpoint)
        return self._models[frames]

    def _settings(self, out: str | Path | None, **changes: Any) -> PipelineConfig:
        if out is not None:
            check_output_dir(out, self.overwrite)
        given = {k: v for k, v in changes.items() if v is not None}
        return replace(self.cfg, **given) if given else self.cfg

    def __call__(
        self, path: str | Path, out: str | Path | None = None, start: int | None = None, frames: int | None = None
    ) -> ClipResult:
        """Segments `frames` frames (default cfg.frames) of a video or frame folder from `start`
        (default cfg.start); with `out`, writes the clip's outputs there (write_clip_outputs)."""
        cfg = self._settings(out, start=start, frames=frames)
        result = segment_clip(path, cfg, self.model(cfg.frames))
        if out is not None:
            write_clip_outputs(result, out, cfg, overwrite=self.overwrite, rrd=self.rrd)
        return result

    clip = __call__

    def video(self, path: str | Path, out: str | Path, max_frames: int | None = None) -> dict[str, Any]:
        """Segments a whole video in windows of cfg.frames frames into `out` (write_video_outputs);
        returns the summary written."""
        cfg = self._settings(out)
        return write_video_outputs(
            path, out, cfg, self.model(cfg.frames), overwrite=self.overwrite, rrd=self.rrd, max_frames=max_frames
        )

    def pair(
        self,
        first: str | Path | npt.NDArray[Any],
        second: str | Path | npt.NDArray[Any],
        out: str | Path | None = None,
    ) -> PairResult:
        """Segments the motions between two images (segment_pair); with `out`, writes its outputs."""
        cfg = self._settings(out, frames=2)
        result = segment_pair(first, second, cfg, self.model(2))
        if out is not None:
            sources = tuple(str(s) if isinstance(s, (str, Path)) else "" for s in (first, second))
            write_pair_outputs(result, out, cfg, overwrite=self.overwrite, sources=sources, rrd=self.rrd)  # type: ignore[arg-type]
        return result

    def tracks(
        self,
        xy: npt.ArrayLike,
        visible: npt.ArrayLike | None = None,
        out: str | Path | None = None,
        video: str | Path | None = None,
        start: int = 0,
        frames: int | None = None,
        source: str = "",
    ) -> TracksResult:
        """Segments point tracks made elsewhere (segment_tracks; xy (N, T, 2), visible (N, T)); with
        `out`, writes summary.json and labels.npz, and with `video` (the video the tracks were made
        on, frame t of the tracks = its frame t) also masks, overlays and the recording."""
        cfg = self._settings(out, start=start)
        num_frames = int(getattr(xy, "shape", (0, 0))[1]) if getattr(xy, "ndim", 0) == 3 else 2
        window = frames if frames is not None else num_frames - start
        result = segment_tracks(xy, visible, cfg, self.model(max(2, window)), start=start, frames=frames)
        if out is not None:
            clip = None if video is None else tracks_clip(result, video, cfg)
            write_tracks_outputs(result, out, cfg, source=source, overwrite=self.overwrite, clip=clip, rrd=self.rrd)
        return result
