"""PNG files written atomically."""

import os

import numpy as np

from taichi_ndf.io.output_dir import atomic_path

__all__ = ["save_png"]


def save_png(path: str | os.PathLike, image: np.ndarray) -> None:
    """Write an image as PNG (atomically): uint8 or uint16, (H, W) grey or (H, W, 3|4) BGR(A)."""
    import cv2  # on first use: not on ndf-sim's solve path (issue 28)

    image = np.asarray(image)
    if image.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"PNG images must be uint8 or uint16, got {image.dtype}")
    if not (image.ndim == 2 or (image.ndim == 3 and image.shape[2] in (1, 3, 4))):
        raise ValueError(f"image must have shape (H, W) or (H, W, 1|3|4), got {image.shape}")
    ok, encoded = cv2.imencode(".png", image)
    if not ok:
        raise RuntimeError(f"OpenCV could not encode a PNG of shape {image.shape} for {path}")
    with atomic_path(path) as temporary:
        temporary.write_bytes(encoded.tobytes())
