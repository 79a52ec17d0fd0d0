from __future__ import annotations

import numpy as np
import pytest

from mosegpipe.errors import InputError
from mosegpipe.points.trajectories import build_trajectories, iter_windows, resample_frames, trajectories_from_matches
from mosegpipe.types import Matches, Tracks, Trajectories


def _tracks() -> Tracks:
    # 4 tracks over 3 frames; x = 10 * n + t, y = 100 + n - t.
    n, t = np.meshgrid(np.arange(4), np.arange(3), indexing="ij")
    xy = np.stack([10.0 * n + t, 100.0 + n - t], axis=2).astype(np.float32)
    visible = np.array(
        [
            [True, True, True],
            [True, False, True],  # a gap in frame 1
            [True, True, True],
            [False, True, True],  # appears in frame 1
        ]
    )
    xy[~visible] = np.nan
    return Tracks(xy=xy, visible=visible, size_hw=(120, 200))


def test_build_trajectories_keeps_tracks_visible_in_all_frames() -> None:
    traj = build_trajectories(_tracks())
    np.testing.assert_array_equal(traj.track_ids, [0, 2])
    assert traj.track_ids.dtype == np.int64 and traj.data.dtype == np.float32
    np.testing.assert_array_equal(
        traj.data,
        [
            [0, 100, 1, 99, 2, 98],
            [20, 102, 21, 101, 22, 100],
        ],
    )
    assert traj.num_frames == 3 and traj.num_points == 2


def test_build_trajectories_window() -> None:
    traj = build_trajectories(_tracks(), frames=2, start=1)
    np.testing.assert_array_equal(traj.track_ids, [0, 2, 3])
    np.testing.assert_array_equal(traj.data[2], [31, 102, 32, 101])
    one = build_trajectories(_tracks(), frames=1, start=2)
    np.testing.assert_array_equal(one.track_ids, [0, 1, 2, 3])


def test_build_trajectories_rejects_non_finite_and_bad_windows() -> None:
    tracks = _tracks()
    xy = tracks.xy.copy()
    xy[2, 1, 0] = np.inf  # visible but broken
    traj = build_trajectories(Tracks(xy=xy, visible=tracks.visible, size_hw=tracks.size_hw))
    np.testing.assert_array_equal(traj.track_ids, [0])
    with pytest.raises(InputError, match="start=1, frames=3 does not fit in 3"):
        build_trajectories(tracks, frames=3, start=1)
    with pytest.raises(InputError):
        build_trajectories(tracks, frames=0)


def test_build_trajectories_empty_tracks() -> None:
    empty = Tracks(xy=np.zeros((0, 5, 2), np.float32), visible=np.zeros((0, 5), bool), size_hw=(10, 10))
    traj = build_trajectories(empty)
    assert traj.data.shape == (0, 10) and traj.track_ids.shape == (0,)


def test_iter_windows_covers_the_end() -> None:
    xy = np.zeros((2, 7, 2), np.float32)
    tracks = Tracks(xy=xy, visible=np.ones((2, 7), bool), size_hw=(5, 5))
    assert [s for s, _ in iter_windows(tracks, 3)] == [0, 3, 4]
    assert [s for s, _ in iter_windows(tracks, 3, stride=2)] == [0, 2, 4]
    assert all(t.num_frames == 3 for _, t in iter_windows(tracks, 3))
    with pytest.raises(InputError):
        list(iter_windows(tracks, 8))


def test_trajectories_from_matches() -> None:
    m = Matches(
        xy1=np.array([[1, 2], [3, 4]], np.float32),
        xy2=np.array([[5, 6], [7, 8]], np.float32),
        score=np.array([0.1, 0.2], np.float32),
        size1_hw=(10, 10),
        size2_hw=(12, 12),
    )
    traj = trajectories_from_matches(m)
    np.testing.assert_array_equal(traj.data, [[1, 2, 5, 6], [3, 4, 7, 8]])
    np.testing.assert_array_equal(traj.track_ids, [0, 1])
    assert traj.num_frames == 2


def _linear(num_frames: int) -> Trajectories:
    # Point n moves linearly from (n, 2n) to (n + 8, 2n - 4) over the clip.
    s = np.linspace(0.0, 1.0, num_frames)
    n = np.arange(3)[:, None]
    x, y = n + 8 * s, 2 * n - 4 * s
    data = np.stack([x, y], axis=2).reshape(3, 2 * num_frames).astype(np.float32)
    return Trajectories(data=data, track_ids=np.array([4, 7, 9], np.int64))


@pytest.mark.parametrize(("source", "target"), [(10, 5), (5, 10), (5, 2), (3, 7)])
def test_resample_frames_is_exact_on_linear_motion(source: int, target: int) -> None:
    out = resample_frames(_linear(source), target)
    np.testing.assert_allclose(out.data, _linear(target).data, atol=1e-5)
    np.testing.assert_array_equal(out.track_ids, [4, 7, 9])


def test_resample_frames_interpolates_piecewise() -> None:
    # x: 0, 10, 0 over 3 frames -> 5 frames at times 0, .5, 1, 1.5, 2.
    traj = Trajectories(data=np.array([[0, 0, 10, 1, 0, 2]], np.float32), track_ids=np.array([0]))
    out = resample_frames(traj, 5)
    np.testing.assert_allclose(out.data, [[0, 0, 5, 0.5, 10, 1, 5, 1.5, 0, 2]])
    first = resample_frames(traj, 1)
    np.testing.assert_allclose(first.data, [[0, 0]])
    assert resample_frames(traj, 3) is traj
    with pytest.raises(InputError, match="target_frames=0"):
        resample_frames(traj, 0)
