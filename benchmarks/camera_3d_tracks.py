"""How much of the static world and of the mover one camera model holds, on KLT tracks of DAVIS dev clips.

    python benchmarks/camera_3d_tracks.py                 # frames 0 -> 4, 1 px, the 20 dev clips
    python benchmarks/camera_3d_tracks.py --gap 8 --px 1.5

Per clip: corners of frame 0 (OpenCV, 3000 at most) tracked by pyramidal LK to frame --gap, kept where the
flow back agrees within 1 px at every step; a track is the mover's where the human mask of frame 0 covers its
start. Over all tracks (not only those already called the world), fitted by MAGSAC++ (`mosegpipe.group.twoview`):
a homography (inliers: transfer error <= 2 x --px), a fundamental matrix frame 0 -> gap (Sampson distance <=
--px), and plane + parallax over every frame 1..gap (one projective depth per track, residual <=
2 x --px x sqrt(gap); `twoview.shared_depth_residual`). Printed per clip: each model's share of the static and of
the mover's tracks it holds, and which model GRIC prefers at the longest gap. The validation clips are never read.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from mosegpipe.data.davis import DAVIS_DEV, read_davis_clip
from mosegpipe.group import twoview

_DEFAULT_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "davis2016-train"


def _tracks(images: np.ndarray) -> np.ndarray:
    """(N, T, 2) float64 LK tracks of frame 0's corners through all frames, checked by the flow back."""
    gray = [cv2.cvtColor(im, cv2.COLOR_RGB2GRAY) for im in images]
    p = cv2.goodFeaturesToTrack(gray[0], 3000, 0.01, 7).reshape(-1, 2)
    ok = np.ones(len(p), bool)
    positions = [p]
    for t in range(len(gray) - 1):
        q, st, _ = cv2.calcOpticalFlowPyrLK(gray[t], gray[t + 1], p, None, winSize=(21, 21), maxLevel=3)
        b, st2, _ = cv2.calcOpticalFlowPyrLK(gray[t + 1], gray[t], q, None, winSize=(21, 21), maxLevel=3)
        ok &= (st.ravel() == 1) & (st2.ravel() == 1) & (np.linalg.norm(b - p, axis=1) < 1.0)
        p = q
        positions.append(q)
    return np.stack(positions, axis=1)[ok].astype(np.float64)


def _shares(held: np.ndarray, mover: np.ndarray) -> tuple[float, float]:
    return float(held[~mover].mean()), float(held[mover].mean()) if mover.any() else float("nan")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data-root", type=Path, default=_DEFAULT_DATA)
    parser.add_argument("--gap", type=int, default=4)
    parser.add_argument("--px", type=float, default=1.0)
    parser.add_argument("--clips", default=",".join(DAVIS_DEV))
    args = parser.parse_args()
    rows = []
    print(f"frames 0 -> {args.gap}, {args.px} px; held static / mover")
    for name in args.clips.split(","):
        if name not in DAVIS_DEV:
            raise SystemExit(f"{name} is not a development clip")
        clip = read_davis_clip(args.data_root, name, max_frames=args.gap + 1)
        xy = _tracks(clip.images)
        ij = np.round(xy[:, 0]).astype(np.int64)
        mover = clip.gt[0][ij[:, 1], ij[:, 0]]
        a, far = xy[:, 0], xy[:, args.gap]
        fun, _ = twoview.fit_with_inliers("fundamental", a, far, args.px)
        hom, _ = twoview.fit_with_inliers("homography", a, far, 2 * args.px)
        if fun is None or hom is None:
            print(f"{name:18s} no fit")
            continue
        samp, transfer = twoview.sampson_px(fun, a, far), twoview.transfer_px(hom, a, far)
        sigma = args.px / 2
        prefers = (
            "F" if twoview.gric(np.square(samp), sigma, 3, 7) < twoview.gric(np.square(transfer), sigma, 2, 8) else "H"
        )
        parallax, basis = [], []
        for u in range(args.gap, 0, -1):  # the farthest first: the depths' reference
            fu, f_in = twoview.fit_with_inliers("fundamental", a, xy[:, u], args.px)
            hu, h_in = twoview.fit_with_inliers("homography", a, xy[:, u], 2 * args.px)
            if fu is None or hu is None:
                continue
            plane = twoview.compatible_homography(fu, hu, a[h_in & f_in], xy[h_in & f_in, u])
            mapped, v = twoview.parallax_basis(plane, twoview.epipole(fu), a)
            parallax.append(xy[:, u] - mapped)
            basis.append(v)
        static = samp <= args.px
        ref = np.sum(parallax[0] * basis[0], axis=1) / np.maximum(np.sum(basis[0] ** 2, axis=1), 1e-12)
        scales = [twoview.depth_scale(r[static], b[static], ref[static]) for r, b in zip(parallax, basis)]
        _, residual = twoview.shared_depth_residual(parallax, basis, scales)
        row = (
            *_shares(transfer <= 2 * args.px, mover),
            *_shares(samp <= args.px, mover),
            *_shares(residual <= 2 * args.px * np.sqrt(args.gap), mover),
        )
        rows.append(row)
        print(
            f"{name:18s} tracks {len(xy):4d} (mover {mover.mean():.2f})  GRIC {prefers}  H {row[0]:.2f} / {row[1]:.2f}"
            f"  F {row[2]:.2f} / {row[3]:.2f}  plane+parallax {row[4]:.2f} / {row[5]:.2f}"
        )
    m = np.nanmean(np.array(rows), axis=0)
    print(f"mean: H {m[0]:.3f} / {m[1]:.3f}  F {m[2]:.3f} / {m[3]:.3f}  plane+parallax {m[4]:.3f} / {m[5]:.3f}")


if __name__ == "__main__":
    main()
