from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from mosegpipe.errors import InputError
from mosegpipe.synth.render import ObjectSpec, RenderConfig, render_clip, write_clip

FRONT = ObjectSpec("plane", centre_m=(0.0, 0.0, 3.0), size_m=(1.0, 1.0, 0.0))
BEHIND = ObjectSpec("box", centre_m=(0.3, 0.0, 5.0), size_m=(2.0, 2.0, 1.0), rotation=(0.0, 0.4, 0.0))
OFF_SCREEN = ObjectSpec("plane", centre_m=(100.0, 0.0, 4.0))  # keeps BEHIND's id at 2


def test_shapes_dtypes_and_declared_ids() -> None:
    clip = render_clip(RenderConfig(num_objects=3, ground=True, camera_motion="handheld"))
    assert clip.frames.shape == (5, 240, 320, 3) and clip.frames.dtype == np.uint8
    assert clip.masks.shape == (5, 240, 320) and clip.masks.dtype == np.uint8
    assert clip.object_ids == (1, 2, 3)
    assert set(np.unique(clip.masks)) <= {0, 1, 2, 3}
    assert (clip.masks == 0).any()
    assert clip.intrinsics.shape == (3, 3) and clip.intrinsics[0, 2] == pytest.approx(159.5)
    frames = clip.to_frames()
    assert frames.num_frames == 5 and frames.size_hw == (240, 320)


def test_same_config_same_clip() -> None:
    cfg = RenderConfig(seed=3, camera_motion="pan", num_objects=2)
    a, b = render_clip(cfg), render_clip(cfg)
    np.testing.assert_array_equal(a.frames, b.frames)
    np.testing.assert_array_equal(a.masks, b.masks)
    c = render_clip(RenderConfig(seed=4, camera_motion="pan", num_objects=2))
    assert not np.array_equal(a.frames, c.frames)


def test_static_camera_background_still_while_objects_move() -> None:
    cfg = RenderConfig(seed=1, num_objects=2, camera_motion="static", object_speed_px=(3.0, 4.0))
    clip = render_clip(cfg)
    first, last = clip.masks[0], clip.masks[-1]
    for i in clip.object_ids:
        changed = np.count_nonzero((first == i) != (last == i))
        assert changed > 100  # ~3.5 px/frame over 4 frames along an edge of ~50+ px
    both_background = (first == 0) & (last == 0)
    assert both_background.mean() > 0.3
    np.testing.assert_array_equal(clip.frames[0][both_background], clip.frames[-1][both_background])


def test_moving_camera_moves_the_background() -> None:
    clip = render_clip(RenderConfig(seed=1, num_objects=0, camera_motion="pan"))
    assert (clip.masks == 0).all()
    diff = np.abs(clip.frames[0].astype(int) - clip.frames[-1].astype(int))
    assert diff.mean() > 10


@pytest.mark.parametrize("texture", ["blobs", "checker"])
def test_frames_have_trackable_corners(texture: str) -> None:
    clip = render_clip(RenderConfig(seed=2, texture=texture))
    grey = cv2.cvtColor(clip.frames[0], cv2.COLOR_RGB2GRAY)
    corners = cv2.goodFeaturesToTrack(grey, maxCorners=1000, qualityLevel=0.01, minDistance=5)
    assert corners is not None and len(corners) >= 100


def test_klt_tracks_stay_on_their_surface() -> None:
    # End to end: corners tracked by KLT from the first to the last frame land mostly on the
    # surface they started on, and the static background does not move.
    clip = render_clip(RenderConfig(seed=0, num_objects=2, camera_motion="static"))
    grey = [cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in (clip.frames[0], clip.frames[-1])]
    p0 = cv2.goodFeaturesToTrack(grey[0], maxCorners=500, qualityLevel=0.01, minDistance=5)
    p1, status, _ = cv2.calcOpticalFlowPyrLK(grey[0], grey[1], p0, None, winSize=(15, 15), maxLevel=3)
    ok = status[:, 0] == 1
    p0, p1 = p0[ok, 0], p1[ok, 0]
    assert len(p0) >= 200
    before, after = clip.label_at(0, p0), clip.label_at(clip.num_frames - 1, p1)
    assert (before == after).mean() > 0.85
    still = np.linalg.norm(p1 - p0, axis=1)[(before == 0) & (after == 0)]
    assert np.median(still) < 0.05
    assert {1, 2} <= set(before.tolist())


def test_nearer_object_hides_the_one_behind() -> None:
    # FRONT is listed first: depth, not list order, must decide what is drawn on top.
    both = render_clip(RenderConfig(frames=1, objects=(FRONT, BEHIND), seed=5))
    alone = render_clip(RenderConfig(frames=1, objects=(FRONT,), seed=5))
    behind_alone = render_clip(RenderConfig(frames=1, objects=(OFF_SCREEN, BEHIND), seed=5))
    front_px = alone.masks[0] == 1
    behind_px = behind_alone.masks[0] == 2
    overlap = front_px & behind_px
    assert overlap.sum() > 1000
    assert (both.masks[0][overlap] == 1).all()
    np.testing.assert_array_equal(both.frames[0][front_px], alone.frames[0][front_px])
    visible_behind = behind_px & ~front_px
    assert visible_behind.sum() > 1000 and (both.masks[0][visible_behind] == 2).all()
    h, w = both.size_hw
    assert both.label_at(0, [[(w - 1) / 2, (h - 1) / 2]])[0] == 1


def test_label_at_rounds_to_the_nearest_pixel_and_clamps() -> None:
    clip = render_clip(RenderConfig(num_objects=2, seed=6))
    masks = clip.masks
    xy = np.array([[10.4, 20.6], [10.6, 20.4], [-5.0, 3.0], [400.0, 239.9]])
    labels = clip.label_at(1, xy)
    assert labels.dtype == np.int64
    expected = [masks[1, 21, 10], masks[1, 20, 11], masks[1, 3, 0], masks[1, 239, 319]]
    assert labels.tolist() == expected
    ys, xs = np.nonzero(masks[2] == 1)
    assert (clip.label_at(2, np.c_[xs, ys]) == 1).all()
    with pytest.raises(InputError):
        clip.label_at(5, xy)


def test_write_clip_round_trip(tmp_path: Path) -> None:
    cfg = RenderConfig(frames=3, num_objects=2, seed=7, camera_motion="forward", ground=True)
    clip = render_clip(cfg)
    out = write_clip(clip, tmp_path / "clip", video=True)
    for k in range(3):
        frame = cv2.cvtColor(cv2.imread(str(out / f"{k:06d}.png")), cv2.COLOR_BGR2RGB)
        np.testing.assert_array_equal(frame, clip.frames[k])
        mask = cv2.imread(str(out / f"gt_{k:06d}.png"), cv2.IMREAD_UNCHANGED)
        np.testing.assert_array_equal(mask, clip.masks[k])
    saved = np.load(out / "masks.npz")
    np.testing.assert_array_equal(saved["masks"], clip.masks)
    assert saved["object_ids"].tolist() == [1, 2]
    video = cv2.VideoCapture(str(out / "clip.avi"))
    count = 0
    while video.read()[0]:
        count += 1
    video.release()
    assert count == 3


def test_noise_is_seeded_and_small() -> None:
    clean = render_clip(RenderConfig(seed=8, frames=2))
    noisy = render_clip(RenderConfig(seed=8, frames=2, noise_std=2.0))
    again = render_clip(RenderConfig(seed=8, frames=2, noise_std=2.0))
    np.testing.assert_array_equal(noisy.frames, again.frames)
    diff = noisy.frames.astype(float) - clean.frames.astype(float)
    assert diff.std() == pytest.approx(2.0, rel=0.15)
    np.testing.assert_array_equal(noisy.masks, clean.masks)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"size_hw": (8, 8)},
        {"camera_motion": "orbit"},
        {"texture": "plain"},
        {"frames": 0},
        {"object_speed_px": (3.0, 1.0)},
    ],
)
def test_bad_config_raises(kwargs: dict) -> None:
    with pytest.raises(InputError):
        RenderConfig(**kwargs)


def test_bad_object_spec_raises() -> None:
    with pytest.raises(InputError):
        ObjectSpec("cone")
    with pytest.raises(InputError):
        ObjectSpec("box", size_m=(1.0, 1.0, 0.0))


def _two_photos() -> list[np.ndarray]:
    """A red-ish and a blue-ish photograph with texture (seeded noise on a colour)."""
    rng = np.random.default_rng(0)
    red = np.clip(rng.normal(0, 20, (120, 160, 3)) + [200, 40, 40], 0, 255).astype(np.uint8)
    blue = np.clip(rng.normal(0, 20, (90, 200, 3)) + [40, 40, 200], 0, 255).astype(np.uint8)
    return [red, blue]


def test_photo_textures_come_from_the_photographs_and_are_seeded() -> None:
    photos = _two_photos()
    cfg = RenderConfig(seed=4, num_objects=2, texture="photo")
    clip = render_clip(cfg, photos)
    again = render_clip(cfg, photos)
    np.testing.assert_array_equal(clip.frames, again.frames)
    # Every surface is a crop of one photo (with a gain and offset per channel): one colour channel
    # dominates everywhere, never green, which neither photograph has.
    mean_rgb = clip.frames.reshape(-1, 3).astype(np.float64)
    dominant = mean_rgb.argmax(axis=1)
    assert (dominant != 1).mean() > 0.95
    blobs = render_clip(RenderConfig(seed=4, num_objects=2, texture="blobs"))
    assert not np.array_equal(blobs.frames, clip.frames)


def test_photo_texture_needs_rgb_photographs() -> None:
    with pytest.raises(InputError, match="needs photographs"):
        render_clip(RenderConfig(texture="photo"))
    with pytest.raises(InputError, match="RGB uint8"):
        render_clip(RenderConfig(texture="photo"), [np.zeros((10, 10), np.uint8)])


def test_near_static_boxes_are_the_static_world_in_front_of_the_rest() -> None:
    base = RenderConfig(size_hw=(60, 80), frames=6, seed=3, camera_motion="truck", ground=True, num_objects=1)
    plain = render_clip(base)
    near = render_clip(replace(base, near_static=3))
    # the same scene (the boxes are drawn from the generator after everything else) with boxes in front of it
    changed = np.any(plain.frames != near.frames, axis=-1)
    assert changed.mean() > 0.02
    assert (near.masks[changed] == 0).mean() > 0.9  # where the boxes are, the static world (up to edge pixels)
    assert set(np.unique(near.masks)) <= {0, 1}


def test_a_followed_object_moves_with_the_camera() -> None:
    base = RenderConfig(
        size_hw=(120, 160), frames=8, seed=1, camera_motion="truck", num_objects=1, object_speed_px=(0, 0)
    )
    still = render_clip(base)  # the object stands still: the trucking camera sweeps it across the image
    followed = render_clip(replace(base, follow=True))

    def travel(clip) -> float:
        ys, xs = np.nonzero(clip.masks[0] == 1)
        ye, xe = np.nonzero(clip.masks[-1] == 1)
        return float(np.hypot(xe.mean() - xs.mean(), ye.mean() - ys.mean()))

    assert travel(followed) < 0.3 * travel(still)
