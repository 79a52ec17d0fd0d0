"""Label helpers of the benchmark readers: contiguous label ids, dropping groups too small to score.

Cutting F-frame windows of complete trajectories is `mosegpipe.points.trajectories` (one window cutter for
the pipeline, the readers and the training sources).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt


def remap_labels(labels: npt.ArrayLike) -> tuple[npt.NDArray[np.int64], list[int]]:
    """Map integer labels to contiguous ids 0..K-1, in increasing order of the original id.

    Args:
        labels: (N,) integer labels as found in a file (e.g. 1..K, or {0, 2, 5}).

    Returns:
        (N,) int64 labels in 0..K-1, and the K original ids: new label j was original_ids[j].
    """
    arr = np.asarray(labels).reshape(-1)
    original_ids, new = np.unique(arr, return_inverse=True)
    return new.astype(np.int64).reshape(-1), [int(v) for v in original_ids]


def drop_small_groups(
    labels: npt.NDArray[np.int64], rows: npt.NDArray[np.int64], min_group: int
) -> npt.NDArray[np.int64]:
    """Keep only the rows whose group has at least `min_group` members among `rows`.

    Args:
        labels: (N,) group of every track.
        rows: (M,) candidate row indices into labels.
        min_group: smallest group size kept.

    Returns:
        (M',) int64 subset of rows, order preserved.
    """
    if min_group <= 1 or rows.size == 0:
        return rows
    ids, counts = np.unique(labels[rows], return_counts=True)
    big = ids[counts >= min_group]
    return rows[np.isin(labels[rows], big)]
