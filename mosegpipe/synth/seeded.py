"""A lazily generated, fixed-length sequence of clips: item i is a pure function of (seeds, i)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import overload

from mosegpipe.types import LabeledClip


class SeededClips(Sequence[LabeledClip]):
    """Base of generated datasets: indexing (negative indices, slices) over `_make(i)`.

    Subclasses set `self.length` and implement `_make(i)` for 0 <= i < length, deterministic in i,
    so that any item can be drawn on any worker without materialising the others.
    """

    length: int
    what = "clip"

    def __len__(self) -> int:
        return self.length

    @overload
    def __getitem__(self, index: int) -> LabeledClip: ...

    @overload
    def __getitem__(self, index: slice) -> list[LabeledClip]: ...

    def __getitem__(self, index: int | slice) -> LabeledClip | list[LabeledClip]:
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(self.length))]
        i = int(index)
        if i < 0:
            i += self.length
        if not 0 <= i < self.length:
            raise IndexError(f"{self.what} {index} out of range for a dataset of {self.length}")
        return self._make(i)

    def _make(self, i: int) -> LabeledClip:
        raise NotImplementedError
