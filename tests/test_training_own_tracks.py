"""Own-front-end training data: motion-agreement label transfer and point-set augmentation."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np
import pytest

from mosegpipe.evaluation.label_transfer import (
    PairTransferConfig,
    TrackTransferConfig,
    transfer_match_labels,
    transfer_track_labels,
)
from mosegpipe.training.augment import TrackAugmentConfig, augment_point_set


def _grid_scene(frames: int = 5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ground truth on an 8 px grid: left half (label 0) moves +1 px/frame in x, right half (label 1) +3 px in y."""
    gx, gy = np.meshgrid(np.arange(0, 200, 8.0), np.arange(0, 100, 8.0))
    start = np.stack([gx.ravel(), gy.ravel()], axis=1)
    labels = (start[:, 0] >= 100).astype(np.int64)
    velocity = np.where(labels[:, None] == 0, [1.0, 0.0], [0.0, 3.0])
    xy = start[:, None, :] + velocity[:, None, :] * np.arange(frames)[None, :, None]
    return xy, np.ones(xy.shape[:2], dtype=bool), labels


def test_track_transfer_labels_by_motion_beyond_the_nearest_point_radius() -> None:
    gt_xy, vis, labels = _grid_scene()
    t = np.arange(5)[:, None]
    ours = np.stack(
        [
            np.array([45.0, 44.0]) + t * [1.0, 0.0],  # 5.7 px from the nearest seed, moves like label 0
            np.array([150.0, 52.0]) + t * [0.0, 3.0],  # label 1
            np.array([45.0, 44.0]) + t * [0.0, 3.0],  # in label 0's area, moves like label 1 (> 16 px away)
            np.array([500.0, 500.0]) + t * [1.0, 0.0],  # far from every ground-truth point
        ]
    )
    out = transfer_track_labels(ours, gt_xy, vis, labels)
    assert out.tolist() == [0, 1, -1, -1]


def test_track_transfer_is_ambiguous_when_two_labels_move_alike() -> None:
    gt_xy, vis, labels = _grid_scene()
    gt_xy = gt_xy[:, :1] + np.arange(5)[None, :, None] * np.array([1.0, 0.0])  # every point moves alike
    ours = gt_xy[labels == 0][-1:].copy()
    ours[0, :, 0] = 100.0 + np.arange(5)  # halfway between a label-0 and a label-1 column
    assert transfer_track_labels(ours, gt_xy, vis, labels).tolist() == [-1]
    # Without a margin the best candidate wins.
    cfg = TrackTransferConfig(margin_px=-1.0)
    assert transfer_track_labels(ours, gt_xy, vis, labels, cfg)[0] in (0, 1)


def test_track_transfer_ignores_frames_where_the_ground_truth_is_hidden() -> None:
    gt_xy, vis, labels = _grid_scene()
    ours = gt_xy[:1] + np.array([3.0, 3.0])
    gt_xy = gt_xy.copy()
    gt_xy[0, 3:] = 0.0  # garbage where not visible
    vis = vis.copy()
    vis[0, 3:] = False
    assert transfer_track_labels(ours, gt_xy, vis, labels).tolist() == [0]
    with pytest.raises(ValueError, match="shapes"):
        transfer_track_labels(ours[:, :4], gt_xy, vis, labels)


def test_match_transfer_exact_agreeing_outlier_and_unknown() -> None:
    rng = np.random.default_rng(0)
    g1 = rng.uniform(0, 200, size=(300, 2))
    g_lab = (g1[:, 0] > 100).astype(np.int64) + 1  # motions 1 and 2
    g2 = g1 + np.where(g_lab[:, None] == 1, [10.0, 0.0], [0.0, -15.0])
    g_lab[:5] = 0  # five gross outliers
    g2[:5] = rng.uniform(0, 200, size=(5, 2))
    xy1 = np.array([g1[0] + 1.0, [50.0, 50.5], [150.0, 50.0], [60.0, 60.0], [1000.0, 1000.0]])
    xy2 = np.array([g2[0] + 1.0, [60.0, 50.5], [150.0, 35.0], [160.0, 160.0], [1010.0, 1000.0]])
    out = transfer_match_labels(xy1, xy2, g1, g2, g_lab, PairTransferConfig())
    assert out.tolist() == [0, 1, 2, 0, -1]


def test_augment_is_seeded_keeps_labels_and_marks_added_points() -> None:
    rng = np.random.default_rng(1)
    traj = rng.uniform(0, 500, size=(800, 10)).astype(np.float32)
    labels = rng.integers(-1, 3, size=800)
    a = augment_point_set(traj, labels, np.random.default_rng(7))
    b = augment_point_set(traj, labels, np.random.default_rng(7))
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    assert a[0].shape[1] == 10 and a[0].dtype == np.float32 and a[1].shape == (a[0].shape[0],)
    assert set(np.unique(a[1])) <= {-1, 0, 1, 2}


def test_augment_identity_when_every_operation_is_off() -> None:
    off = TrackAugmentConfig(
        prob_subsample=0,
        prob_uneven=0,
        prob_drop_region=0,
        prob_small_object=0,
        noise_px=(0.0, 0.0),
        prob_drift=0,
        prob_outliers=0,
    )
    traj = np.arange(40, dtype=np.float32).reshape(4, 10)
    labels = np.array([0, 1, 1, -1])
    out, lab = augment_point_set(traj, labels, np.random.default_rng(0), off)
    np.testing.assert_allclose(out, traj)
    assert lab.tolist() == labels.tolist()


def test_augment_subsamples_thins_objects_and_adds_outliers_as_context() -> None:
    rng = np.random.default_rng(2)
    traj = rng.uniform(0, 500, size=(1000, 10)).astype(np.float32)
    labels = np.zeros(1000, dtype=np.int64)
    labels[:300] = 1
    cfg = TrackAugmentConfig(
        num_points=(100, 100),
        prob_subsample=1,
        prob_uneven=0,
        prob_drop_region=0,
        prob_small_object=0,
        prob_drift=0,
        prob_outliers=1,
        outlier_fraction=(0.1, 0.1),
    )
    out, lab = augment_point_set(traj, labels, np.random.default_rng(3), cfg)
    assert out.shape[0] == 110 and int((lab == -1).sum()) == 10
    small = TrackAugmentConfig(
        prob_subsample=0,
        prob_uneven=0,
        prob_drop_region=0,
        prob_small_object=1,
        small_object_points=(20, 20),
        prob_drift=0,
        prob_outliers=0,
    )
    out, lab = augment_point_set(traj, labels, np.random.default_rng(3), small)
    assert int((lab == 1).sum()) == 20 and int((lab == 0).sum()) == 700


def test_augment_never_drops_every_labelled_point() -> None:
    traj = np.zeros((5, 4), dtype=np.float32)
    traj[:, 0] = np.arange(5)
    labels = np.array([0, -1, -1, -1, -1])
    cfg = TrackAugmentConfig(
        num_points=(1, 1),
        prob_subsample=1,
        prob_uneven=0,
        prob_drop_region=0,
        prob_small_object=0,
        prob_drift=0,
        prob_outliers=0,
    )
    for seed in range(20):
        _, lab = augment_point_set(traj, labels, np.random.default_rng(seed), cfg)
        assert (lab >= 0).any()


# ---------------------------------------------------------------- real data (skipped without it)


def test_kt3d_own_clips_track_label_and_cache(data_root: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from mosegpipe.data.kt3dmoseg import list_kt3d_sequences
    from mosegpipe.training import own_tracks

    keep = "Seq009_Clip01"
    others = [n for n in list_kt3d_sequences(data_root) if n != keep]
    clips = own_tracks.kt3d_own_clips(data_root, frames=5, exclude=others, cache_dir=tmp_path)
    assert clips and all(c.meta["sequence"] == keep for c in clips)
    assert clips[0].name == f"{keep}/f1-5" and clips[0].traj.shape[1] == 10
    labels = np.concatenate([c.labels for c in clips])
    assert (labels == -1).any() and (labels >= 0).mean() > 0.2  # context points and labelled points
    assert set(np.unique(labels)) <= {-1, 0, 1, 2, 3, 4}

    def no_tracking(*args: object, **kwargs: object) -> None:
        raise AssertionError("tracked again although the windows are cached")

    monkeypatch.setattr(own_tracks, "track_klt", no_tracking)
    again = own_tracks.kt3d_own_clips(data_root, frames=5, exclude=others, cache_dir=tmp_path)
    assert [c.name for c in again] == [c.name for c in clips]
    np.testing.assert_array_equal(again[0].labels, clips[0].labels)
    with pytest.raises(AssertionError, match="tracked again"):  # other settings: another cache entry
        own_tracks.kt3d_own_clips(data_root, frames=4, exclude=others, cache_dir=tmp_path)


def test_adelaide_own_clips_outliers_first(data_root: Path, tmp_path: Path) -> None:
    from mosegpipe.data.adelaidermf import list_adelaide
    from mosegpipe.training.own_tracks import adelaide_own_clips

    others = [n for n in list_adelaide(data_root) if n != "breadcube"]
    (clip,) = adelaide_own_clips(data_root, exclude=others, cache_dir=tmp_path)
    assert clip.name == "breadcube" and clip.traj.shape[1] == 4
    known = clip.labels[clip.labels >= 0]
    assert known.size > 0.5 * clip.num_points and set(np.unique(known)) <= {0, 1, 2, 3}


# ---------------------------------------------------------------- rendered clips through our tracker


def test_rendered_labels_follow_the_masks_and_drop_boundaries() -> None:
    from mosegpipe.synth.render import ObjectSpec, RenderConfig, render_clip
    from mosegpipe.training.own_tracks import label_rendered_tracks

    plane = ObjectSpec("plane", centre_m=(0.0, 0.0, 4.0), size_m=(2.0, 2.0, 0.0), velocity_m=(0.05, 0.0, 0.0))
    clip = render_clip(RenderConfig(objects=(plane,), frames=3))
    ys, xs = np.nonzero(clip.masks[0] == 1)
    cx, cy = xs.mean(), ys.mean()
    left = xs.min()
    step = clip.label_at(0, [[cx, cy]])[0]
    assert step == 1
    # The object's image speed: where its left edge went between frames 0 and 2.
    dx = (np.nonzero(clip.masks[2] == 1)[1].min() - left) / 2
    t = np.arange(3)[None, :, None]
    xy = np.stack(
        [
            np.array([[cx, cy]]) + t[0] * [dx, 0.0],  # on the object, moving with it
            np.array([[5.0, 5.0]]) + t[0] * 0.0,  # on the still wall
            np.array([[left + 1.0, cy]]) + t[0] * [dx, 0.0],  # on the object but at its border
            np.array([[left + 5.0, cy]]) + t[0] * [0.0, 0.0],  # on the object, stays put: the wall by frame 2
        ]
    )
    assert label_rendered_tracks(clip, xy, boundary_px=3).tolist() == [1, 0, -1, -1]


def test_rendered_own_clips_label_track_and_cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from PIL import Image

    from mosegpipe.training import own_tracks

    root = tmp_path / "data"
    (root / "videos").mkdir(parents=True)
    rng = np.random.default_rng(1)
    for i in range(2):
        photo = cv2.resize(
            rng.integers(0, 256, (30, 40, 3), dtype=np.uint8), (320, 240), interpolation=cv2.INTER_NEAREST
        )
        Image.fromarray(photo).save(root / "videos" / f"p{i}.png")
    assert [n for n, _ in own_tracks.texture_photos(root)] == ["videos/p0.png", "videos/p1.png"]
    cfg = own_tracks.RenderedTracksConfig(num_clips=3, sizes_hw=((120, 160),), objects=(1, 2))
    cache = tmp_path / "cache"
    clips = own_tracks.rendered_own_clips(root, frames=4, cfg=cfg, cache_dir=cache)
    assert clips and all(c.traj.shape[1] == 8 and c.dataset == "rendered-own" for c in clips)
    for c in clips:
        known = c.labels[c.labels >= 0]
        assert known.size >= own_tracks.MIN_LABELLED and np.unique(known).size >= 2 and 0 in known

    def no_rendering(*args: object, **kwargs: object) -> None:
        raise AssertionError("tracked again although the clips are cached")

    monkeypatch.setattr(own_tracks, "track_klt", no_rendering)
    again = own_tracks.rendered_own_clips(root, frames=4, cfg=cfg, cache_dir=cache)
    assert [c.name for c in again] == [c.name for c in clips]
    (root / "videos" / "p1.png").unlink()  # other textures: another cache entry
    with pytest.raises(AssertionError, match="tracked again"):
        own_tracks.rendered_own_clips(root, frames=4, cfg=cfg, cache_dir=cache)


# ---------------------------------------------------------------- composites through our tracker


def _two_object_composite(frames: int = 7):  # type: ignore[no-untyped-def]
    """A panning textured plate (2 px/frame to the left) with two pasted 50 px squares: object 1 moves 4 px/frame
    to the right over the scene (2 px/frame on the screen), object 2 holds still in the scene (it pans with the
    plate)."""
    from mosegpipe.synth.composite import Composite, ObjectPath, compose, sprite_from

    h, w = 120, 200
    rng = np.random.default_rng(0)
    noise = rng.integers(0, 256, (h // 4, (w + 40) // 4, 3), dtype=np.uint8)
    big = cv2.GaussianBlur(cv2.resize(noise, (w + 40, h), interpolation=cv2.INTER_CUBIC), (3, 3), 0)
    plate = np.stack([big[:, 2 * t : 2 * t + w] for t in range(frames)])
    camera = np.stack([np.array([[1, 0, -2.0 * t], [0, 1, 0], [0, 0, 1]]) for t in range(frames)])
    sprites = []
    for seed in (1, 2):
        tex = cv2.resize(
            np.random.default_rng(seed).integers(0, 256, (20, 20, 3), dtype=np.uint8),
            (60, 60),
            interpolation=cv2.INTER_CUBIC,
        )
        mask = np.zeros((60, 60), dtype=bool)
        mask[5:55, 5:55] = True
        sprites.append(sprite_from(tex[None], mask[None]))
    paths = [
        ObjectPath("translation", (60.0, 60.0), (60.0 + 4 * (frames - 1), 60.0)),
        ObjectPath("translation", (150.0, 60.0), (150.0, 60.0)),
    ]
    images, masks = compose(plate, None, sprites, paths, camera)
    moving = np.stack([np.ones(frames, dtype=bool), np.zeros(frames, dtype=bool)], axis=1)
    return Composite("dev-00", images, masks, (1, 2), moving, sources=("a", "b"), plate="p", camera=camera)


def test_composite_labels_by_object_still_objects_are_the_world() -> None:
    from mosegpipe.training.own_tracks import label_composite_tracks

    comp = _two_object_composite()
    t = np.arange(5)[None, :, None]
    xy = np.concatenate(
        [
            np.array([[[68.0, 60.0]]]) + t * [2.0, 0.0],  # on object 1, moving with it
            np.array([[[150.0, 60.0]]]) + t * [-2.0, 0.0],  # on object 2, carried by the camera
            np.array([[[20.0, 105.0]]]) + t * [-2.0, 0.0],  # on the plate
            np.array([[[36.0, 60.0]]]) + t * [2.0, 0.0],  # at object 1's left edge (35.5 = 60 - 24.5)
        ]
    )
    # From frame 2 on, a point 8 px further right (object 1 has moved 4 px, object 2 4 px the other way).
    assert label_composite_tracks(comp, xy, 0, boundary_px=3).tolist() == [1, 0, 0, -1]
    assert label_composite_tracks(comp, xy + [8.0, 0.0], 2, boundary_px=3).tolist()[:3] == [1, 0, 0]
    moving = comp.moving.copy()
    moving[2:, 1] = True  # object 2 "starts" in frame 2: neither the world nor an object in frames 0-4
    started = dataclasses.replace(comp, moving=moving)
    assert label_composite_tracks(started, xy, 0, boundary_px=3).tolist() == [1, -1, 0, -1]
    assert label_composite_tracks(started, xy + [8.0, 0.0], 2, boundary_px=3).tolist()[:3] == [1, 2, 0]


def test_composite_own_clips_track_every_window_and_cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from mosegpipe.errors import ConfigError
    from mosegpipe.synth import composite
    from mosegpipe.training import own_tracks

    made: list[tuple[int, list[str] | None]] = []

    def tiny_set(root: object, part: str, count: int = 10, seed: int = 41, cfg: object = None, names=None):  # type: ignore[no-untyped-def]
        assert part == "dev"
        made.append((seed, names))
        return [_two_object_composite()]

    monkeypatch.setattr(composite, "composite_set", tiny_set)
    cfg = own_tracks.CompositeTracksConfig(num_clips=2, seed=7)
    cache = tmp_path / "cache"
    clips = own_tracks.composite_own_clips(tmp_path, frames=5, cfg=cfg, cache_dir=cache)
    assert made == [(7, ["dev-00"]), (7, ["dev-01"])]
    assert [c.name for c in clips] == [f"composite/{i:02d}/f{s + 1}-{s + 5}" for i in range(2) for s in range(3)]
    for c in clips:
        assert c.traj.shape[1] == 10 and c.dataset == "composite-own"
        assert set(np.unique(c.labels)) == {-1, 0, 1}  # the still object is the world
        assert int((c.labels == 1).sum()) >= 10 and int((c.labels == 0).sum()) > int((c.labels == 1).sum())

    def no_tracking(*args: object, **kwargs: object) -> None:
        raise AssertionError("tracked again although the windows are cached")

    monkeypatch.setattr(own_tracks, "track_klt", no_tracking)
    again = own_tracks.composite_own_clips(tmp_path, frames=5, cfg=cfg, cache_dir=cache)
    assert [c.name for c in again] == [c.name for c in clips]
    np.testing.assert_array_equal(again[-1].labels, clips[-1].labels)
    assert own_tracks.composite_own_clips(tmp_path, frames=5, exclude=["b"], cfg=cfg, cache_dir=cache) == []
    with pytest.raises(ConfigError, match="scored"):
        own_tracks.composite_own_clips(tmp_path, cfg=own_tracks.CompositeTracksConfig(seed=composite.SEED))


@pytest.mark.parametrize("name", ["clip-f5-variety", "clip-f5-composites"])
def test_variety_recipes_draw_composites_from_known_sources(name: str) -> None:
    from mosegpipe.training.recipes import RECIPES, SOURCES

    recipe = RECIPES[name]
    assert dict(recipe.sources)["composite-own"] > 0 and recipe.init == "base-f5"
    assert recipe.train == RECIPES["clip-f5"].train and recipe.model == RECIPES["clip-f5"].model
    for r in RECIPES.values():
        assert {name for name, _ in r.sources} <= set(SOURCES), r.name
    assert SOURCES["composite-own"].augment is not None
