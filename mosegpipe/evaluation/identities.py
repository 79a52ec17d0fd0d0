"""Objects through a whole video, as DAVIS-2017 scores them: one predicted label per true object for the video
(`match_objects_video`, Hungarian on the IoU over all frames), J per object matched per video or per frame
(`object_j`), and each object's identities frame by frame and their switches (`object_identities`,
`identity_switches`). Pure NumPy plus SciPy's Hungarian solver; label arrays are (T, H, W) ints."""

from __future__ import annotations

from collections.abc import Iterator, Sequence

import numpy as np
import numpy.typing as npt
from scipy.optimize import linear_sum_assignment

from mosegpipe.evaluation.metrics import jaccard


def _object_labels(p: npt.NDArray[np.int64], ignore: Sequence[int]) -> npt.NDArray[np.int64]:
    vals = np.unique(p)
    return vals[~np.isin(vals, list(ignore))]


def _match_by_iou(
    p: npt.NDArray[np.int64], g: npt.NDArray[np.int64], object_ids: Sequence[int], ignore: Sequence[int]
) -> dict[int, int | None]:
    """Objects -> labels by the Hungarian method on the IoU over all of `p`'s pixels (None: IoU 0 or no label left)."""
    labels = _object_labels(p, ignore)
    out: dict[int, int | None] = {int(o): None for o in object_ids}
    if labels.size == 0 or not out:
        return out
    iou = np.zeros((len(out), labels.size))
    for i, oid in enumerate(out):
        gm = g == oid
        for j, lab in enumerate(labels):
            pm = p == lab
            union = np.count_nonzero(gm | pm)
            iou[i, j] = np.count_nonzero(gm & pm) / union if union else 0.0
    rows, cols = linear_sum_assignment(iou, maximize=True)
    keys = list(out)
    for r, c in zip(rows, cols):
        if iou[r, c] > 0:
            out[keys[r]] = int(labels[c])
    return out


def _video_pair(pred: npt.ArrayLike, gt: npt.ArrayLike) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    p, g = np.asarray(pred, dtype=np.int64), np.asarray(gt, dtype=np.int64)
    if p.shape != g.shape or p.ndim != 3:
        raise ValueError(f"pred has shape {p.shape} but gt has shape {g.shape} (need the same (T, H, W))")
    return p, g


def match_objects_video(
    pred: npt.ArrayLike, gt: npt.ArrayLike, object_ids: Sequence[int], ignore: Sequence[int] = (0, 255)
) -> dict[int, int | None]:
    """One predicted label per true object for the whole video, as DAVIS-2017 matches them.

    The Hungarian method maximises the total IoU over the video (intersections and unions summed over
    all frames); labels in `ignore` (the world, unknown) are never matched.

    Args:
        pred: (T, H, W) int predicted labels.
        gt: (T, H, W) int true ids.
        object_ids: the true objects scored (ids in gt).
        ignore: predicted values never matched to an object.

    Returns:
        {object id: label, or None when no label is left for it or its IoU with each one left is 0}.

    Raises:
        ValueError: shapes differ or are not (T, H, W).
    """
    p, g = _video_pair(pred, gt)
    return _match_by_iou(p, g, object_ids, ignore)


def object_j(
    pred: npt.ArrayLike,
    gt: npt.ArrayLike,
    object_ids: Sequence[int],
    per_video: bool = True,
    ignore: Sequence[int] = (0, 255),
) -> dict[int, float]:
    """Each true object's J: the mean over frames of `jaccard` against the label it is matched to.

    With `per_video`, one label per object for the whole video (`match_objects_video`): a label switch
    part-way costs the frames after it. Without, each frame is matched on its own (Hungarian on that
    frame's IoU), which forgives switches. An object matched to no label scores 0 where it shows and 1
    where it does not (DAVIS: both masks empty).

    Args:
        pred: (T, H, W) int predicted labels.
        gt: (T, H, W) int true ids.
        object_ids: the true objects scored.
        per_video: one matching for the video (True) or one per frame (False).
        ignore: predicted values never matched (the world, unknown).

    Returns:
        {object id: J in [0, 1]}.

    Raises:
        ValueError: shapes differ or are not (T, H, W).
    """
    p, g = _video_pair(pred, gt)
    scores: dict[int, list[float]] = {int(o): [] for o in object_ids}
    video = _match_by_iou(p, g, object_ids, ignore) if per_video else {}
    for pf, gf in zip(p, g):
        match = video if per_video else _match_by_iou(pf[None], gf[None], object_ids, ignore)
        for oid, lab in match.items():
            pm = pf == lab if lab is not None else np.zeros(pf.shape, dtype=bool)
            scores[oid].append(jaccard(pm, gf == oid))
    return {oid: float(np.mean(js)) if js else float("nan") for oid, js in scores.items()}


def object_identities(
    pred: npt.ArrayLike,
    gt: npt.ArrayLike,
    object_ids: Sequence[int],
    min_px: int = 1,
    share: float = 0.1,
    ignore: Sequence[int] = (0, 255),
) -> dict[int, list[int]]:
    """Each true object's identity frame by frame: the label (not in `ignore`) covering most of its pixels.

    Only the frames where the object shows at least `min_px` pixels and that label covers at least `share`
    of them have an identity; the others are left out of the list.

    Args:
        pred: (T, H, W) int predicted labels.
        gt: (T, H, W) int true ids.
        object_ids: the true objects.
        min_px: frames where an object shows fewer pixels are skipped.
        share: the least share of the object's pixels its identity must cover.
        ignore: predicted values that are no identity (the world, unknown).

    Returns:
        {object id: its identities in frame order}.

    Raises:
        ValueError: shapes differ or are not (T, H, W).
    """
    p, g = _video_pair(pred, gt)
    out: dict[int, list[int]] = {}
    for oid in object_ids:
        seq = []
        for vals, counts, n in labels_on_object(p, g, oid, min_px):
            keep = ~np.isin(vals, list(ignore))
            if keep.any() and counts[keep].max() >= share * n:
                seq.append(int(vals[keep][int(np.argmax(counts[keep]))]))
        out[int(oid)] = seq
    return out


def labels_on_object(
    pred: npt.NDArray[np.integer], gt: npt.NDArray[np.integer], oid: int, min_px: float = 1
) -> Iterator[tuple[npt.NDArray[np.integer], npt.NDArray[np.intp], int]]:
    """Per frame where true object `oid` shows at least `min_px` pixels (and one at least): the predicted labels
    on its pixels, how many pixels each covers, and the object's pixel count.

    Args:
        pred, gt: (T, H, W) predicted labels and true ids.
    """
    for pf, gf in zip(pred, gt):
        on = gf == oid
        n = int(np.count_nonzero(on))
        if n == 0 or n < min_px:
            continue
        vals, counts = np.unique(pf[on], return_counts=True)
        yield vals, counts, n


def identity_switches(
    pred: npt.ArrayLike,
    gt: npt.ArrayLike,
    object_ids: Sequence[int],
    min_px: int = 1,
    share: float = 0.1,
    ignore: Sequence[int] = (0, 255),
) -> dict[int, int]:
    """How many times each true object's identity (`object_identities`) changes over the video.

    A switch is a frame whose identity differs from the last one the object had (frames without one are
    skipped): A A - B A counts 2, one label throughout 0. The arguments are `object_identities`'.

    Returns:
        {object id: switches, >= 0}.

    Raises:
        ValueError: shapes differ or are not (T, H, W).
    """
    seqs = object_identities(pred, gt, object_ids, min_px, share, ignore)
    return {oid: sum(a != b for a, b in zip(seq, seq[1:])) for oid, seq in seqs.items()}
