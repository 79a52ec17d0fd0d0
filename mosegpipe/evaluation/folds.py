"""How labelled clips group into leave-one-out folds: `sequence_of` (KT3DMoSeg folds hold out a whole
sequence). Shared by the protocol registry, the benchmark runner and the studies; imports nothing heavy."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from mosegpipe.types import LabeledClip


def sequence_of(clip: LabeledClip) -> str:
    """The sequence a clip was cut from (KT3DMoSeg folds hold out a whole sequence)."""
    return str(clip.meta.get("sequence", clip.name.split("/")[0]))
