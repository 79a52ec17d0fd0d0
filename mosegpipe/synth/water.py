"""Rippling water with no object in it: a procedural dynamic texture (`water_clip`), every pixel the world.

A seeded smooth texture (blue-green, with foam specks) warped every frame by a sum of travelling waves (random
directions, wavelengths 12-60 px, speeds 0.5-2.5 px a frame, amplitudes 0.5-2.5 px), its brightness modulated by
the waves' slope (glints), with sensor noise; the camera holds still, pans or shakes (a whole-frame translation
the world's camera model explains). Scored by benchmarks/dynamic_texture.py (seeds 0-9); the mask network's
recipe trains on clips of other seeds (`learned.data.DataConfig.water_seed`).
"""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt

CAMERAS = ("still", "pan", "shake")
"""The camera motions of the water clips: held still, a steady pan, a shake."""

SCORED_SEEDS = range(0, 100)
"""Seeds the benchmark may score (benchmarks/dynamic_texture.py uses 0-9); training clips take seeds above."""


def water_clip(seed: int, frames: int, size_hw: tuple[int, int], camera: str) -> npt.NDArray[np.uint8]:
    """(frames, H, W, 3) uint8 RGB frames of rippling water with no object, a pure function of the seed."""
    rng = np.random.default_rng(seed)
    h, w = size_hw
    margin = 40  # the texture is larger than the frame: the camera's pan and the waves never leave it
    big_h, big_w = h + 2 * margin, w + 2 * margin
    # A smooth random base: noise blurred at two scales, coloured blue-green, with sparse foam specks.
    base = np.zeros((big_h, big_w), np.float32)
    for sigma, weight in ((12.0, 0.7), (3.0, 0.3)):
        base += weight * cv2.GaussianBlur(rng.standard_normal((big_h, big_w)).astype(np.float32), (0, 0), sigma)
    base = (base - base.mean()) / (base.std() + 1e-6)
    foam = cv2.GaussianBlur((rng.random((big_h, big_w)) > 0.997).astype(np.float32), (0, 0), 1.2) * 6.0
    colour = np.array([40.0, 110.0, 130.0], np.float32) + rng.uniform(-20, 20, 3).astype(np.float32)
    waves = [
        (
            rng.uniform(0, 2 * np.pi),  # direction
            rng.uniform(12.0, 60.0),  # wavelength, px
            rng.uniform(0.5, 2.5),  # speed, px a frame
            rng.uniform(0.5, 2.5),  # amplitude, px
            rng.uniform(0, 2 * np.pi),  # phase
        )
        for _ in range(int(rng.integers(4, 8)))
    ]
    ys, xs = np.mgrid[0:big_h, 0:big_w].astype(np.float32)
    pan = rng.uniform(-1.5, 1.5, 2) if camera == "pan" else np.zeros(2)
    out = np.empty((frames, h, w, 3), np.uint8)
    for t in range(frames):
        dx = np.zeros((big_h, big_w), np.float32)
        dy = np.zeros((big_h, big_w), np.float32)
        slope = np.zeros((big_h, big_w), np.float32)
        for angle, length, speed, amp, phase in waves:
            ux, uy = np.cos(angle), np.sin(angle)
            arg = (2 * np.pi / length) * (ux * xs + uy * ys - speed * t) + phase
            dx += amp * ux * np.sin(arg)
            dy += amp * uy * np.sin(arg)
            slope += np.cos(arg)
        warped = cv2.remap(base, xs + dx, ys + dy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        warped_foam = cv2.remap(foam, xs + dx, ys + dy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        glint = np.clip(slope / len(waves), 0, None) ** 3 * 90.0
        shade = 28.0 * warped + glint + 120.0 * np.clip(warped_foam, 0, 1)
        image = colour[None, None, :] + shade[..., None] + rng.normal(0, 2.0, (big_h, big_w, 1)).astype(np.float32)
        ox, oy = margin + pan * t
        if camera == "shake":
            ox, oy = margin + rng.uniform(-3, 3), margin + rng.uniform(-3, 3)
        crop = cv2.getRectSubPix(np.clip(image, 0, 255).astype(np.float32), (w, h), (ox + w / 2, oy + h / 2))
        out[t] = np.clip(crop, 0, 255).astype(np.uint8)
    return out
