"""Whole-video mode: windows, labels consistent across windows, streaming memory, outputs."""

from __future__ import annotations

import json
import time
import tracemalloc
import weakref
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from mosegpipe.apps.video_outputs import WINDOWS_AHEAD, write_video_outputs
from mosegpipe.apps.window_log import WindowLog
from mosegpipe.cli.main import app
from mosegpipe.embed.model import SubspaceNet
from mosegpipe.errors import InputError, TooFewTracksError
from mosegpipe.io.read import iter_video, read_palette_png
from mosegpipe.pipeline import LabelBook, PipelineConfig, WindowResult, match_labels
from mosegpipe.pipeline import video as video_module
from mosegpipe.synth.render import RenderedClip

from helpers import best_permutation_accuracy, motion_checkpoint, read_rrd, render_scene, write_frames

runner = CliRunner(env={"COLUMNS": "200"})
T = 15  # windows of 5 share their boundary frame: 0-4, 4-8, 8-12, 12-14 (a short last window)


@pytest.fixture(scope="module")
def model_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return motion_checkpoint(tmp_path_factory.mktemp("models") / "motion5.pt", 5)


@pytest.fixture(scope="module")
def scene() -> RenderedClip:
    return render_scene(T)


@pytest.fixture(scope="module")
def frames_dir(tmp_path_factory: pytest.TempPathFactory, scene: RenderedClip) -> Path:
    return write_frames(tmp_path_factory.mktemp("video") / "frames", scene.frames)


# ---------------------------------------------------------------------------------------------
# Label matching across windows (hand-computed)
# ---------------------------------------------------------------------------------------------


def test_match_labels_follows_shared_tracks() -> None:
    book = LabelBook(next_label=2)
    prev = {10: 0, 11: 0, 12: 0, 20: 1, 21: 1}
    ids = np.array([10, 11, 12, 20, 21, 30, 31])
    clusters = np.array([1, 1, 1, 0, 0, 2, 2])  # K-means numbers clusters anew in every window
    labels = match_labels(prev, ids, clusters, 3, book, window=1)
    assert labels.tolist() == [0, 0, 0, 1, 1, 2, 2]  # tracks 30, 31 are new: a new motion
    assert book.next_label == 3 and book.last_window == {0: 1, 1: 1, 2: 1}


def test_match_labels_gives_a_split_a_new_label_only_when_it_recurs() -> None:
    book = LabelBook(next_label=2)
    prev = {1: 0, 2: 0, 3: 0, 4: 1, 5: 0, 6: 0}
    ids, clusters = np.array([1, 2, 3, 4, 5, 6, 7]), np.array([0, 0, 0, 1, 1, 1, 1])
    # Overlaps: cluster 0 = {motion 0: 3}, cluster 1 = {motion 0: 2, motion 1: 1}. The best pairing
    # is 0 -> 0, 1 -> 1, but only 1 of cluster 1's 3 shared tracks was motion 1: cluster 1 split off
    # motion 0, and keeps its label for now.
    labels = match_labels(prev, ids, clusters, 2, book)
    assert labels.tolist() == [0] * 7 and book.next_label == 2
    assert book.pending == {4: 1, 5: 1, 6: 1, 7: 1}
    # The same split in the next window: a motion of its own.
    labels = match_labels(dict(zip(ids.tolist(), labels.tolist())), ids, clusters, 2, book, window=1)
    assert labels.tolist() == [0, 0, 0, 2, 2, 2, 2] and book.pending == {}
    # A split that does not recur joins its motion again and leaves no candidate behind.
    book = LabelBook(next_label=2)
    labels = match_labels(prev, ids, clusters, 2, book)
    labels = match_labels(dict(zip(ids.tolist(), labels.tolist())), ids, np.zeros(7, dtype=np.int64), 1, book, window=1)
    assert labels.tolist() == [0] * 7 and book.pending == {} and book.next_label == 2


def test_label_book_reuses_the_least_recently_used_label() -> None:
    book = LabelBook(max_label=2)
    assert [book.new_label(set()) for _ in range(3)] == [0, 1, 2]
    book.last_window = {0: 5, 1: 3, 2: 4}
    assert book.new_label(busy={1}) == 2 and book.num_reused == 1
    with pytest.raises(InputError, match="more than 3 motions live at once"):
        book.new_label(busy={0, 1, 2})
    # a video's labels stop below the unclustered mover's mask value
    from mosegpipe.masks import MOVING_UNCLUSTERED

    full = LabelBook()
    assert max(full.new_label(set()) for _ in range(MOVING_UNCLUSTERED)) == MOVING_UNCLUSTERED - 1
    full.last_window = {0: 0}
    assert full.new_label(set()) == 0 and full.num_reused == 1


def _window(i: int, n: int) -> WindowResult:
    ids = np.arange(i * n, (i + 1) * n, dtype=np.int64)
    return WindowResult(
        start=4 * i, num_frames=5, num_tracks=n, k=2 if n else 0, track_ids=ids, labels=ids % 3, frames=(),
        num_motions=3, num_labels_reused=i, num_frames_read=4 * i + 5, k_note="the K choice is ambiguous" * (i % 2),
        shot_start=i == 3,
    )  # fmt: skip


def test_the_window_log_spools_the_labels_and_keeps_the_records(tmp_path: Path) -> None:
    windows = [_window(i, 0 if i == 2 else 40 + i) for i in range(6)]
    log = WindowLog(tmp_path)
    for w in windows:
        log.add(w)
    assert log.records() == [w.record() for w in windows]
    assert (log.num_windows, log.num_frames_read, log.num_labels_reused) == (6, 25, 5)
    log.write_labels(tmp_path / "labels.npz")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["labels.npz"]  # the spool files are gone
    labelled = [(i, w) for i, w in enumerate(windows) if w.is_labelled]
    with np.load(tmp_path / "labels.npz") as z:
        assert np.array_equal(z["track_ids"], np.concatenate([w.track_ids for _, w in labelled]))
        assert np.array_equal(z["labels"], np.concatenate([w.labels for _, w in labelled]))
        assert np.array_equal(z["window"], np.concatenate([np.full(w.num_tracks, i) for i, w in labelled]))


def test_the_window_log_holds_no_labels_in_memory(tmp_path: Path) -> None:
    # A live run adds windows for hours: what it keeps of each is a few integers, not its tracks' arrays.
    log = WindowLog(tmp_path)
    windows = [_window(i, 1000) for i in range(300)]  # 16 kB of ids and labels each, 4.8 MB in all
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        for w in windows:
            log.add(w)
        grown = tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()
    log.write_labels(tmp_path / "labels.npz")
    assert grown < 200_000, grown
    with np.load(tmp_path / "labels.npz") as z:
        assert z["track_ids"].shape == (300_000,)


# ---------------------------------------------------------------------------------------------
# A whole rendered video
# ---------------------------------------------------------------------------------------------


def test_whole_video_keeps_each_object_on_one_label(
    tmp_path: Path, frames_dir: Path, scene: RenderedClip, model_path: Path
) -> None:
    out = tmp_path / "out"
    summary = write_video_outputs(frames_dir, out, PipelineConfig(frames=5), SubspaceNet.from_checkpoint(model_path))
    assert sorted(p.name for p in out.iterdir()) == [
        "labels.npz",
        "masks",
        "overlay.mp4",
        "recording.rrd",
        "summary.json",
    ]
    assert summary == json.loads((out / "summary.json").read_text())
    assert summary["kind"] == "video" and summary["frames"] == T and summary["size_hw"] == [240, 320]
    assert [(w["start"], w["frames"]) for w in summary["windows"]] == [(0, 5), (4, 5), (8, 5), (12, 3)]
    assert summary["num_windows"] == summary["num_windows_labelled"] == 4
    assert all(w["k"] == 3 for w in summary["windows"][:3])

    masks = np.stack([read_palette_png(out / "masks" / f"{t:06d}.png") for t in range(T)])
    assert sorted(p.name for p in (out / "masks").iterdir()) == [f"{t:06d}.png" for t in range(T)]
    known = masks != 255
    assert known.mean() > 0.95
    # One relabelling for the whole video: a swap between windows would break it.
    assert best_permutation_accuracy(masks[known].astype(np.int64), scene.masks[known].astype(np.int64)) >= 0.85
    # Each object's pixels carry the same mask value in every frame.
    for obj in (0, 1, 2):
        majority = {int(np.bincount(masks[t][(scene.masks[t] == obj) & known[t]]).argmax()) for t in range(T)}
        assert len(majority) == 1, f"object {obj} changes label across frames: {majority}"

    with np.load(out / "labels.npz") as z:
        assert sorted(z.files) == ["labels", "track_ids", "window"]
        n = sum(w["num_tracks"] for w in summary["windows"])
        assert z["track_ids"].shape == z["labels"].shape == z["window"].shape == (n,)
        assert set(np.unique(z["window"])) == {0, 1, 2, 3}
        assert z["labels"].max() + 1 <= summary["num_motions"]
    cap = cv2.VideoCapture(str(out / "overlay.mp4"))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == T
    cap.release()
    rows = read_rrd(out / "recording.rrd")
    assert rows["/video/frame"] == T and rows["/video/mask"] == T


def test_cli_whole_with_max_frames(tmp_path: Path, frames_dir: Path, model_path: Path) -> None:
    out = tmp_path / "out"
    args = ["run", frames_dir, "--whole", "--max-frames", 9, "--k", 3, "--no-rrd", "--model", model_path, "-o", out]
    result = runner.invoke(app, [str(a) for a in args])
    assert result.exit_code == 0, result.output
    assert result.stdout.startswith("9 frames in 2 windows of 5 (2 labelled) -> 3 motion labels\n")
    assert f"wrote {out}/ (summary.json, labels.npz, masks/, overlay.mp4)" in result.stdout
    summary = json.loads((out / "summary.json").read_text())
    assert summary["frames"] == 9 and summary["k_method"] == "fixed"
    assert len(list((out / "masks").iterdir())) == 9 and not (out / "recording.rrd").exists()


def test_memory_holds_one_window_of_frames(
    tmp_path: Path, frames_dir: Path, model_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    alive: list[weakref.ref[np.ndarray]] = []
    most = 0

    def tracked(path: Path, start: int = 0, max_frames: int | None = None) -> Iterator[tuple[int, np.ndarray]]:
        nonlocal most
        for t, frame in iter_video(path, start=start, max_frames=max_frames):
            alive.append(weakref.ref(frame))
            most = max(most, sum(r() is not None for r in alive))
            yield t, frame
            del frame

    monkeypatch.setattr(video_module, "iter_video", tracked)
    model3 = SubspaceNet.from_checkpoint(motion_checkpoint(tmp_path / "m3.pt", 3))
    held = 1  # windows held back for the labels that merge back (pipeline.merge_back)
    cfg = PipelineConfig(frames=3, k=3).with_settings([f"labels.merge_back_windows={held}"])
    write_video_outputs(frames_dir, tmp_path / "out", cfg, model3, rrd=False)
    assert len(alive) == T
    # The window being tracked, the full window held until the next frame's flows give its last frame
    # both directions (the motion masks), the windows held back for the merged labels, the windows queued for
    # the writer, the one being written and the frame being read: a bound set by the window length, never the
    # video (T frames). (Without the held window the bound is one window lower; a slow writer fills the queue
    # and reaches it.)
    assert most <= (3 - 1) * (WINDOWS_AHEAD + 3 + held) + 2 < T


def test_flows_held_for_at_most_two_windows(tmp_path: Path, frames_dir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from mosegpipe.points import flow as flow_module

    pairs: list[weakref.ref[Any]] = []
    most = 0
    make_pair, label_window = flow_module.FlowStream._pair, video_module._label_window

    def tracked_pair(self: Any, *args: Any) -> Any:
        pair = make_pair(self, *args)
        pairs.append(weakref.ref(pair))
        return pair

    def slow_label(*args: Any, **kwargs: Any) -> Any:
        nonlocal most
        time.sleep(0.2)  # a slow window: reading and the flows run as far ahead as they are let
        most = max(most, sum(r() is not None for r in pairs))
        result = label_window(*args, **kwargs)
        most = max(most, sum(r() is not None for r in pairs))
        return result

    monkeypatch.setattr(flow_module.FlowStream, "_pair", tracked_pair)
    monkeypatch.setattr(video_module, "_label_window", slow_label)
    model3 = SubspaceNet.from_checkpoint(motion_checkpoint(tmp_path / "m3.pt", 3))
    windows = list(video_module.segment_video(frames_dir, PipelineConfig(frames=3, k=3), model3, masks=True))
    assert sum(len(w.frames) for w in windows) == T and len(pairs) == T - 1
    # The window labelled (its 2 pairs, the pair before it, the one after it) and the next window read
    # (its second pair and the one after it), each pair its two flows and their evidence: about 30 MB at
    # 1280x720. Reading further ahead held 3 windows' pairs (13 at 5 frames a window).
    assert most <= 2 + 1 + 1 + 2 < T - 1


def test_failures_leave_nothing(tmp_path: Path, frames_dir: Path, scene: RenderedClip, model_path: Path) -> None:
    model = SubspaceNet.from_checkpoint(model_path)
    with pytest.raises(InputError, match=r"frames: only 4 frames could be read; --frames needs 5"):
        write_video_outputs(frames_dir, tmp_path / "a", PipelineConfig(frames=5), model, max_frames=4)
    blank = write_frames(tmp_path / "blank", np.full((6, 240, 320, 3), 128, np.uint8))
    with pytest.raises(TooFewTracksError, match="blank: no window had at least 10 tracks"):
        write_video_outputs(blank, tmp_path / "b", PipelineConfig(frames=5), model)
    with pytest.raises(InputError, match=r"^frames: 1 must lie in 2\.\.10000$"):  # windows of 2 frames at least
        PipelineConfig(frames=1)
    # A failure after some windows were written (frame 7 has another size) aborts the recording too.
    odd = write_frames(tmp_path / "odd", scene.frames[:8])
    cv2.imwrite(str(odd / "000007.png"), cv2.resize(scene.frames[7], (160, 120)))
    with pytest.raises(InputError, match="000007.png: image is 160x120 but earlier images in .* are 320x240"):
        write_video_outputs(odd, tmp_path / "d", PipelineConfig(frames=5, k=3), model)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["blank", "odd"]


def test_match_labels_after_a_cut_gives_the_dominant_motion_label_0() -> None:
    book = LabelBook(next_label=2)
    prev = {1: 0, 2: 0, 3: 1}
    ids = np.arange(1, 31)  # tracks 1, 2 survive the cut; 3..30 are new
    clusters = np.array([1, 1] + [0] * 18 + [1] * 10)  # cluster 0 (18 tracks) dominates the new shot
    labels = match_labels(prev, ids, clusters, 2, book)
    # Only 2 of cluster 1's 12 tracks carried a label: too few to continue motion 0 with it.
    assert labels.tolist() == [2, 2] + [0] * 18 + [2] * 10


def test_match_labels_small_clusters_join_or_stay_unlabelled() -> None:
    book = LabelBook(next_label=2)
    ids = np.arange(100)
    prev = {int(i): 0 for i in range(80)} | {int(i): 1 for i in range(80, 97)}
    clusters = np.array([0] * 80 + [1] * 13 + [2] * 4 + [3] * 3)  # 2: a fragment of motion 1; 3: new tracks
    labels = match_labels(prev, ids, clusters, 4, book)
    assert labels[:80].tolist() == [0] * 80 and set(labels[80:97].tolist()) == {1}
    assert labels[97:].tolist() == [-1] * 3  # 3 % of the tracks: not trusted as a new motion
    assert book.next_label == 2


def test_windows_carry_their_k_scores(frames_dir: Path, model_path: Path) -> None:
    from mosegpipe.pipeline import segment_video

    model = SubspaceNet.from_checkpoint(model_path)
    windows = list(segment_video(frames_dir, PipelineConfig(frames=5), model))
    margin = PipelineConfig().cluster.ambiguity_margin  # a near tie may keep the previous window's K
    assert windows and all(w.k_scores and w.k_scores[w.k] >= max(w.k_scores.values()) - margin for w in windows)
    forced = list(segment_video(frames_dir, PipelineConfig(frames=5, k=2), model))
    assert all(w.k == 2 and not w.k_scores for w in forced)


def test_whole_video_k_rises_by_at_most_video_k_step(frames_dir: Path, model_path: Path) -> None:
    from mosegpipe.pipeline import segment_video

    model = SubspaceNet.from_checkpoint(model_path)
    full = list(segment_video(frames_dir, PipelineConfig(frames=5, video_k_step=None), model))
    assert max(full[1].k_scores) > full[0].k + 1  # unlimited: the whole sweep in every window
    stepped = list(segment_video(frames_dir, PipelineConfig(frames=5, video_k_step=1), model))
    for before, window in zip(stepped, stepped[1:]):
        assert max(window.k_scores) <= max(before.k + 1, 2) and window.k <= before.k + 1
    with pytest.raises(InputError, match="video_k_step: 0 must be at least 1"):
        PipelineConfig(video_k_step=0)


def test_a_shot_cut_restarts_tracking_and_windows(tmp_path: Path, model_path: Path) -> None:
    from mosegpipe.pipeline import segment_video

    # Two independent renders: shot A is frames 0-10, shot B frames 11-19.
    frames = np.concatenate([render_scene(11, seed=0).frames, render_scene(9, seed=1).frames])
    folder = write_frames(tmp_path / "cut", frames)
    model = SubspaceNet.from_checkpoint(model_path)
    windows = list(segment_video(folder, PipelineConfig(frames=5), model))
    # The window before the cut ends on frame 10 (a short one), the next starts on the cut itself.
    assert [(w.start, w.num_frames) for w in windows] == [(0, 5), (4, 5), (8, 3), (11, 5), (15, 5)]
    assert [w.shot_start for w in windows] == [False, False, False, True, False]
    assert sorted(fr.index for w in windows for fr in w.frames) == list(range(20))  # every frame once
    assert all(w.is_labelled for w in windows)
    # No track crosses the cut: every track of the new shot was detected on or after frame 11.
    before = {int(i) for w in windows[:3] for i in w.track_ids}
    assert before and not before & {int(i) for w in windows[3:] for i in w.track_ids}
    assert windows[3].record()["shot_start"] is True
    # Without cut detection the windows run across it as if it were one shot.
    plain = list(segment_video(folder, PipelineConfig(frames=5, video_cut_survival=None), model))
    assert [(w.start, w.num_frames) for w in plain] == [(0, 5), (4, 5), (8, 5), (12, 5), (16, 4)]
    assert not any(w.shot_start for w in plain)
    summary = write_video_outputs(folder, tmp_path / "out", PipelineConfig(frames=5), model, rrd=False)
    assert summary["shot_cuts"] == [11]
    with pytest.raises(InputError, match="video_cut_survival: 1.5 must lie in"):
        PipelineConfig(video_cut_survival=1.5)
    recorded = summary["config"]
    assert PipelineConfig.from_dict(recorded) == PipelineConfig(frames=5)
    del recorded["video_cut_survival"]  # a summary written before the test existed: replayed without it
    assert PipelineConfig.from_dict(recorded).video_cut_survival is None


def _mask_calls(
    monkeypatch: pytest.MonkeyPatch, folder: Path, model: SubspaceNet, cfg: PipelineConfig, capture: Any
) -> tuple[list[Any], list[Any]]:
    """segment_video's windows of `folder` and, per call of moving_from_motion, `capture(its arguments by name)`
    (taken when called: the colour memory changes afterwards)."""
    from mosegpipe.masks import compose
    from mosegpipe.pipeline import segment_video

    calls: list[Any] = []
    original = compose.moving_from_motion

    def recorded(*args: object, **kwargs: object) -> np.ndarray:
        calls.append(capture(dict(zip(("images", "motion"), args)) | kwargs))
        return original(*args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(compose, "moving_from_motion", recorded)
    windows = list(segment_video(folder, cfg, model))
    monkeypatch.setattr(compose, "moving_from_motion", original)
    return windows, calls


def _two_shots(tmp_path: Path) -> Path:
    """A frame folder of two rendered shots, the cut at frame 11."""
    frames = np.concatenate([render_scene(11, seed=0).frames, render_scene(9, seed=1).frames])
    return write_frames(tmp_path / "cut", frames)


def test_the_colour_model_is_carried_from_window_to_window_and_starts_afresh_at_a_cut(
    tmp_path: Path, model_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    folder, model = _two_shots(tmp_path), SubspaceNet.from_checkpoint(model_path)

    def memory_state(kwargs: dict[str, Any]) -> tuple[int, bool]:
        """The memory's id and whether it held counts on entry."""
        memory = kwargs["colour"]
        return id(memory), memory is not None and memory.moving is not None

    windows, seen = _mask_calls(monkeypatch, folder, model, PipelineConfig(frames=5), memory_state)
    assert [w.start for w in windows] == [0, 4, 8, 11, 15]
    assert len({i for i, _ in seen}) == 1  # one memory for the video
    assert [held for _, held in seen] == [False, True, True, False, True]  # emptied at the cut (frame 11)
    mask = PipelineConfig().mask
    alone = PipelineConfig(frames=5, mask=replace(mask, motion=replace(mask.motion, colour_memory=0.0)))
    _, seen = _mask_calls(monkeypatch, folder, model, alone, memory_state)
    assert seen == [(id(None), False)] * 5


def test_a_windows_first_frame_takes_the_flow_back_to_the_frame_before_it_inside_a_shot(
    tmp_path: Path, model_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from mosegpipe.points.flow import frame_motion

    folder, model = _two_shots(tmp_path), SubspaceNet.from_checkpoint(model_path)
    frames = np.stack([image for _, image in iter_video(folder)])
    cfg = PipelineConfig(frames=5)
    windows, motions = _mask_calls(monkeypatch, folder, model, cfg, lambda kwargs: kwargs["motion"])
    assert [w.start for w in windows] == [0, 4, 8, 11, 15]
    flow = cfg.mask.motion.flow
    for window, motion in zip(windows, motions):
        t = window.start
        if window.shot_start or t == 0:  # no frame before it in the shot: the flow to the next frame only
            np.testing.assert_array_equal(motion.residual[0], frame_motion(frames[t : t + 2], flow).residual[0])
        else:  # as inside a longer stack: the smaller evidence of its flows to the frames before and after
            np.testing.assert_array_equal(motion.residual[0], frame_motion(frames[t - 1 : t + 2], flow).residual[1])
            assert not np.array_equal(motion.residual[0], frame_motion(frames[t : t + 2], flow).residual[0])


def test_each_window_hands_its_frames_tracks_and_the_motions_shown_before_to_the_masks(
    tmp_path: Path, model_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from mosegpipe.masks import MOVING_UNCLUSTERED, UNKNOWN

    folder, model = _two_shots(tmp_path), SubspaceNet.from_checkpoint(model_path)
    windows, handed = _mask_calls(
        monkeypatch, folder, model, PipelineConfig(frames=5), lambda kwargs: kwargs["anchors"]
    )
    assert [len(a) for a in handed] == [len(w.frames) for w in windows]
    last_mask = None
    for window, anchors in zip(windows, handed):
        for frame, (xy, labels, background, shown_here) in zip(window.frames, anchors):
            np.testing.assert_array_equal(xy, frame.xy)
            np.testing.assert_array_equal(labels, frame.labels)
            assert background == np.bincount(labels[labels >= 0]).argmax()
            np.testing.assert_array_equal(shown_here, anchors[0][3])  # one set for the window
        shown = anchors[0][3]
        if window.shot_start or last_mask is None:
            assert shown.size == 0  # a shot's first window: nothing was shown before
        else:
            on_mask = np.unique(last_mask)
            common = np.bincount(last_mask.ravel()).argmax()
            assert set(shown) == set(on_mask) - {common, UNKNOWN, MOVING_UNCLUSTERED}
        last_mask = window.frames[-1].mask
    assert any(a[0][3].size for a in handed)  # the scene's movers were shown and handed on


def test_tracks_that_end_inside_a_window_keep_their_last_label(frames_dir: Path, model_path: Path) -> None:
    from mosegpipe.pipeline import segment_video

    windows = list(segment_video(frames_dir, PipelineConfig(frames=5), SubspaceNet.from_checkpoint(model_path)))
    carried = 0
    for before, window in zip(windows, windows[1:]):
        last = dict(zip(before.track_ids.tolist(), before.labels.tolist()))
        clustered = set(window.track_ids.tolist())
        for fr in window.frames:
            for i, lab in zip(fr.track_ids.tolist(), fr.labels.tolist()):
                if i in clustered:
                    continue
                # Not live through this window: the label of the window before, or none if it had none.
                assert lab == last.get(i, -1)
                carried += i in last
    assert carried >= 5  # tracks do end inside windows here (14: the planes move over the wall)


def test_masks_left_to_the_caller_are_the_masks_computed_in_order(tmp_path: Path, model_path: Path) -> None:
    """With the motion masks a frame's labels depend on the frame before's mask (carried unclustered regions,
    the next window's anchors): segment_video(masks=False), as `moseg run --whole` calls it, gives them all the
    same, so the command writes what the protocols score."""
    from mosegpipe.pipeline import frame_mask, segment_video

    folder, model = _two_shots(tmp_path), SubspaceNet.from_checkpoint(model_path)
    cfg = PipelineConfig(frames=5)
    inline = [f.mask for w in segment_video(folder, cfg, model) for f in w.frames]
    deferred = [f for w in segment_video(folder, cfg, model, masks=False) for f in w.frames]
    assert len(inline) == len(deferred) == 20
    for mask, frame in zip(inline, deferred):
        assert frame.mask is not None  # computed in order, with the frame before's mask at hand
        np.testing.assert_array_equal(frame_mask(frame, cfg.mask), mask)
    watershed = replace(cfg, mask=replace(cfg.mask, method="watershed"))
    assert all(f.mask is None for w in segment_video(folder, watershed, model, masks=False) for f in w.frames)
