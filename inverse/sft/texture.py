"""Procedural images for synthetic sequences: a trackable sheet texture and a cluttered background.

Both are deterministic functions of their seed. The texture mixes value-noise octaves (detail at
every scale), a checkerboard (strong corners) and random colour blobs (distinctive features for
descriptor matching), so that corner detectors, Lucas–Kanade and SIFT all find plenty to hold on
to. BGR uint8 images, as OpenCV reads and writes them.
"""

from __future__ import annotations

import cv2
import numpy as np


def value_noise(
    width: int, height: int, *, cell: int, channels: int, rng: np.random.Generator
) -> np.ndarray:
    """Smooth random field in [-1, 1], shape (height, width, channels), feature size ~cell [px]."""
    grid = rng.uniform(-1.0, 1.0, size=(height // cell + 3, width // cell + 3, channels))
    big = cv2.resize(
        grid.astype(np.float32), ((grid.shape[1] - 1) * cell, (grid.shape[0] - 1) * cell),
        interpolation=cv2.INTER_CUBIC,
    )
    big = big.reshape(big.shape[0], big.shape[1], channels)
    y0, x0 = rng.integers(0, cell, size=2)
    return np.clip(big[y0:y0 + height, x0:x0 + width], -1.0, 1.0)


def sheet_texture(width: int = 1024, height: int = 768, *, seed: int = 0) -> np.ndarray:
    """High-frequency texture for a sheet: noise octaves + checkerboard + blobs, BGR uint8."""
    rng = np.random.default_rng(seed)
    image = np.full((height, width, 3), 0.5, dtype=np.float32)
    for octave, cell in enumerate((96, 48, 24, 12, 6, 3)):
        image += 0.22 * 0.75**octave * value_noise(width, height, cell=cell, channels=3, rng=rng)
    square = max(8, min(width, height) // 16)
    rows, cols = np.mgrid[0:height, 0:width]
    checker = ((rows // square + cols // square) % 2).astype(np.float32) * 2.0 - 1.0
    image += 0.12 * checker[..., None]
    image = np.clip(image, 0.0, 1.0)
    canvas = (image * 255).astype(np.uint8)
    scale = min(width, height)
    for _ in range(int(0.00025 * width * height)):
        centre = (int(rng.integers(0, width)), int(rng.integers(0, height)))
        axes = tuple(int(a) for a in rng.integers(scale // 200 + 2, scale // 40 + 4, size=2))
        colour = tuple(int(c) for c in rng.integers(0, 256, size=3))
        cv2.ellipse(canvas, centre, axes, float(rng.uniform(0, 180)), 0, 360, colour, -1,
                    cv2.LINE_AA)
    return canvas


def cluttered_background(width: int, height: int, *, seed: int = 0) -> np.ndarray:
    """Cluttered scene behind the sheet: shaded noise with random shapes and lines, BGR uint8."""
    rng = np.random.default_rng(seed)
    base = 0.45 + 0.25 * value_noise(width, height, cell=80, channels=3, rng=rng)
    base += 0.08 * value_noise(width, height, cell=10, channels=3, rng=rng)
    canvas = (np.clip(base, 0.0, 1.0) * 255).astype(np.uint8)
    for _ in range(60):
        colour = tuple(int(c) for c in rng.integers(0, 256, size=3))
        x, y = int(rng.integers(0, width)), int(rng.integers(0, height))
        size = int(rng.integers(10, 80))
        kind = rng.integers(0, 3)
        if kind == 0:
            cv2.rectangle(canvas, (x, y), (x + size, y + int(rng.integers(10, 80))), colour, -1)
        elif kind == 1:
            cv2.circle(canvas, (x, y), size // 2, colour, -1, cv2.LINE_AA)
        else:
            end = (int(rng.integers(0, width)), int(rng.integers(0, height)))
            cv2.line(canvas, (x, y), end, colour, int(rng.integers(1, 5)), cv2.LINE_AA)
    return canvas
