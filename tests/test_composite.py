"""Composites (issue 41): the generator is deterministic with exact masks, the scores match hand-computed
cases, and the protocol runs end to end on a small synthetic composite (no DAVIS data needed)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from mosegpipe.errors import ConfigError
from mosegpipe.evaluation.composite import (
    composite_rows,
    j_per_object,
    labels_per_object,
    match_objects,
    pick_folds,
    track_error,
    window_k,
)
from mosegpipe.evaluation.protocols import PROTOCOLS
from mosegpipe.synth.composite import (
    CompositeConfig,
    ObjectPath,
    compose,
    make_composite,
    speed_profile,
    sprite_from,
)


def _texture(seed: int, h: int, w: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    noise = rng.integers(0, 256, (h // 4, w // 4, 3), dtype=np.uint8)
    return cv2.GaussianBlur(cv2.resize(noise, (w, h), interpolation=cv2.INTER_CUBIC), (3, 3), 0)


# ---------------------------------------------------------------------------------------------
# Generator


def test_compose_places_a_square_exactly_along_its_path() -> None:
    t_len, h, w = 4, 40, 60
    plate = np.zeros((t_len, h, w, 3), dtype=np.uint8)
    plate_mask = np.zeros((t_len, h, w), dtype=bool)
    plate_mask[:, 18:22, 20:30] = True  # the plate's object, under the pasted one
    src = np.full((1, 10, 10, 3), 7, dtype=np.uint8)
    src[0, 2:7, 2:7] = (200, 100, 50)
    mask = np.zeros((1, 10, 10), dtype=bool)
    mask[0, 2:7, 2:7] = True
    sprite = sprite_from(src, mask)
    assert tuple(sprite.anchors_xy[0]) == (4.0, 4.0) and sprite.height_px == 5
    path = ObjectPath("translation", start_xy=(20.0, 20.0), end_xy=(26.0, 20.0))
    frames, ids = compose(plate, plate_mask, [sprite], [path])
    for t in range(t_len):
        cx = 20 + 2 * t  # progress t / 3 of 6 px
        want = np.zeros((h, w), dtype=np.uint8)
        want[18:22, 20:30] = 1
        want[18:23, cx - 2 : cx + 3] = 2
        np.testing.assert_array_equal(ids[t], want)
        assert (frames[t][ids[t] == 2] == (200, 100, 50)).all()
        assert (frames[t][ids[t] != 2] == 0).all()
    again = compose(plate, plate_mask, [sprite], [path])
    np.testing.assert_array_equal(again[0], frames)
    np.testing.assert_array_equal(again[1], ids)


def test_paths_speed_and_perspective() -> None:
    rng = np.random.default_rng(0)
    v = speed_profile("stops", 25, rng)
    assert v.shape == (24,) and v[0] == 1 and v[-1] == 0 and ((v >= 0) & (v <= 1)).all()
    path = ObjectPath("perspective", (10.0, 10.0), (50.0, 30.0), tilt_deg=(40.0, 0.0), speed=tuple(v))
    u = path.progress(25)
    assert u[0] == 0 and u[-1] == pytest.approx(1) and (np.diff(u) >= 0).all()
    moving = path.moving(25)
    assert moving[0] and not moving[-1]
    m = path.matrix(1.0)
    centre = m @ [0, 0, 1]
    np.testing.assert_allclose(centre[:2] / centre[2], (50, 30))
    assert m[2, 0] != 0  # a true perspective, not an affine map
    with pytest.raises(ConfigError):
        speed_profile("sometimes", 25, rng)


def _synthetic_composite(seed: int, frames: int = 8, size_hw: tuple[int, int] = (120, 160)):  # type: ignore[no-untyped-def]
    h, w = size_hw
    big = _texture(seed, h + 40, w + 40)
    plate = np.stack([big[10 : 10 + h, 5 + 2 * t : 5 + 2 * t + w] for t in range(frames)])  # a 2 px/frame pan
    plate_mask = np.zeros((frames, h, w), dtype=bool)
    for t in range(frames):
        plate_mask[t, 70:100, 10 + 3 * t : 40 + 3 * t] = True
        plate[t][plate_mask[t]] = _texture(seed + 1, h, w)[plate_mask[t]]
    sources = []
    for j in range(2):
        img = _texture(seed + 10 + j, 60, 60)[None].repeat(frames, 0)
        mk = np.zeros((frames, 60, 60), dtype=bool)
        mk[:, 15:45, 10:50] = True
        sources.append((f"obj{j}", img, mk))
    cfg = CompositeConfig(size_hw=size_hw, frames=frames, live_share=0.0)
    return make_composite("dev-00", plate, plate_mask, sources, seed, cfg, plate_name="synthetic")


def test_make_composite_is_deterministic_and_labels_every_object() -> None:
    a, b = _synthetic_composite(3), _synthetic_composite(3)
    np.testing.assert_array_equal(a.frames, b.frames)
    np.testing.assert_array_equal(a.masks, b.masks)
    np.testing.assert_array_equal(a.camera, b.camera)
    assert a.object_ids == (1, 2, 3) and a.masks.dtype == np.uint8 and 255 not in a.masks
    assert set(np.unique(a.masks)) <= {0, 1, 2, 3} and a.moving.shape == (8, 3)
    assert a.kinds[0] == "plate" and a.sources == ("synthetic", "obj0", "obj1")
    # The pan is found: the plate moves 2 px left per frame.
    centre = a.camera[-1] @ [80, 60, 1]
    np.testing.assert_allclose(centre[:2] / centre[2], (66, 60), atol=1.0)
    assert not np.array_equal(_synthetic_composite(4).masks, a.masks)


# ---------------------------------------------------------------------------------------------
# Scores (hand-computed)

GT = np.array([[[1, 1, 2, 2], [0, 0, 0, 0]]] * 2, dtype=np.uint8)
PRED = np.array([[[3, 3, 0, 0], [0, 0, 0, 255]], [[3, 5, 5, 5], [0, 0, 0, 0]]], dtype=np.uint8)


def test_objects_matched_by_clip_iou_and_scored_per_frame() -> None:
    # IoU over the clip: object 1 vs 3: 3/4, vs 5: 1/6; object 2 vs 3: 0, vs 5: 2/5.
    assert match_objects(PRED, GT, (1, 2)) == {1: 3, 2: 5}
    j, _ = j_per_object(PRED, GT, (1, 2))
    assert j[1] == pytest.approx((1 + 1 / 2) / 2)
    assert j[2] == pytest.approx((0 + 2 / 3) / 2)
    # World and unknown are never matched: an object covered only by 0 is unmatched and scores 0.
    only_world = np.where(GT == 2, 0, PRED).astype(np.uint8)
    only_world[only_world == 5] = 0
    j, match = j_per_object(only_world, GT, (1, 2))
    assert match[2] is None and j[2] == 0


def test_labels_per_object_windows_k_and_track_error() -> None:
    assert labels_per_object(PRED, GT, (1, 2), share=0.1, min_share=0.0) == {1: 2, 2: 1}
    moving = np.ones((2, 2), dtype=bool)
    assert window_k(PRED, GT, (1, 2), moving, [(0, 1), (1, 1)], min_share=0.1) == [(1, 2), (2, 2)]
    moving[1, 1] = False  # object 2 stands still in frame 1: not a motion there
    assert window_k(PRED, GT, (1, 2), moving, [(0, 2)], min_share=0.1) == [(2, 2)]
    assert window_k(PRED, GT, (1, 2), moving, [(1, 1)], min_share=0.1) == [(2, 1)]
    assert track_error([1, 1, 2, 2], [0, 0, 1, 1]) == 0
    assert track_error([1, 2, 2, 2], [0, 0, 1, 1]) == pytest.approx(25)
    assert np.isnan(track_error([], []))


# ---------------------------------------------------------------------------------------------
# Protocol


def test_registry_and_fold_choice() -> None:
    assert {"composite", "composite-clip5"} <= set(PROTOCOLS)
    assert pick_folds(None) == [("dev", None)]
    assert pick_folds(["val", "dev-03"]) == [("val", None), ("dev", ["dev-03"])]
    assert pick_folds(["all"]) == [("dev", None), ("val", None)]
    with pytest.raises(ConfigError, match="bear"):
        pick_folds(["bear"])


@pytest.mark.parametrize("mode", ["clip5", "whole"])
def test_protocol_rows_on_a_synthetic_composite(mode: str) -> None:
    from mosegpipe.pipeline import PipelineConfig

    clip = _synthetic_composite(5)
    rows = composite_rows([clip], mode, PipelineConfig(frames=5))
    (row,) = rows
    assert row["name"] == "dev-00" and row["objects"] == 3 and row["error"] == ""
    assert 0 <= row["j_object"] <= 1 and 0 <= row["correct_k"] <= 1 and row["num_tracks"] > 0
    assert 0 <= row["track_error"] <= 100
    assert len(row["j_per_object"].split()) == 3


def test_protocol_on_the_davis_clips(tmp_path: Path) -> None:
    from mosegpipe.evaluation.protocols import EvalRequest

    root = Path("../shared/data")
    if not (root / "davis2016-train" / "bear").is_dir():
        pytest.skip("the DAVIS clips are not here (../shared/data/davis2016-train)")
    proto = PROTOCOLS["composite-clip5"]
    result = proto.run(proto, EvalRequest(out_dir=tmp_path, data_root=root, folds=("dev-00",)))
    assert [r["name"] for r in result.rows] == ["dev-00"] and (tmp_path / "results.md").is_file()
    assert result.summary["dev"]["clips"] == 1


def test_validation_composites_use_validation_clips_only() -> None:
    from mosegpipe.data.davis import DAVIS_VAL
    from mosegpipe.synth.composite import composite_set

    root = Path("../shared/data")
    if not (root / "davis2016-train" / "boat").is_dir():
        pytest.skip("the DAVIS clips are not here (../shared/data/davis2016-train)")
    (clip,) = composite_set(root, "val", names=["val-00"])
    assert clip.plate in DAVIS_VAL and set(clip.sources) <= set(DAVIS_VAL)
    assert clip.frames.shape == (25, 240, 427, 3) and set(np.unique(clip.masks)) <= {0, *clip.object_ids}
