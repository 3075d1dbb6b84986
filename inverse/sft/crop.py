"""Work on the part of the image where the sheet is: frames and masks cropped to the box that
holds every mask and the projected template, and the camera moved with them.

A crop is exact for a pinhole camera: the image's pixel (u, v) is the crop's (u − x0, v − y0)
with the principal point moved by the same amount, so the tracks, the fit and the output meshes
(camera coordinates [m]) are what they would be on the whole frames. It only saves time, and
much: the sheet of φ-SfT's R1 covers 11 % of its 1920 × 1080 frames, and contrast
normalisation, Lucas–Kanade pyramids and SIFT work on every pixel they are given. Without masks
the sheet's whereabouts in later frames are unknown and nothing is cropped.
"""

from __future__ import annotations

import dataclasses
import logging
import math

import numpy as np

from inverse.sft.inputs import SftInputs

log = logging.getLogger(__name__)

# Margin [px] kept around the masks and the template: Lucas–Kanade's window and SIFT's
# descriptors reach ~20 px beyond a point.
MARGIN_PX = 48


def sheet_box(inputs: SftInputs, margin: int = MARGIN_PX) -> tuple[int, int, int, int] | None:
    """(x0, y0, x1, y1), end exclusive, of the crop around every mask and the projected
    template plus `margin` [px], within the image; None without masks."""
    if inputs.masks is None:
        return None
    union = np.logical_or.reduce([np.asarray(m, bool) for m in inputs.masks])
    rows, cols = np.nonzero(union)
    pixels = inputs.camera.project(inputs.template.vertices)
    xs = np.concatenate([cols, pixels[:, 0]])
    ys = np.concatenate([rows, pixels[:, 1]])
    width, height = inputs.camera.size
    x0 = max(0, int(math.floor(xs.min())) - margin)
    y0 = max(0, int(math.floor(ys.min())) - margin)
    x1 = min(width, int(math.ceil(xs.max())) + margin + 1)
    y1 = min(height, int(math.ceil(ys.max())) + margin + 1)
    return x0, y0, x1, y1


def cropped_to_sheet(inputs: SftInputs, margin: int = MARGIN_PX) -> SftInputs:
    """The inputs with frames and masks cropped to `sheet_box` and the camera moved with them
    (its distortion dropped: the frames are undistorted on load); the inputs as they are when
    there is nothing to crop."""
    box = sheet_box(inputs, margin)
    width, height = inputs.camera.size
    if box is None or box == (0, 0, width, height):
        return inputs
    x0, y0, x1, y1 = box
    camera = dataclasses.replace(inputs.camera, cx=inputs.camera.cx - x0,
                                 cy=inputs.camera.cy - y0, width=x1 - x0, height=y1 - y0,
                                 dist=None)
    log.info("working on the crop x %d-%d, y %d-%d of the %dx%d frames (%.0f %% of the pixels)",
             x0, x1, y0, y1, width, height, 100 * (x1 - x0) * (y1 - y0) / (width * height))
    return dataclasses.replace(
        inputs, camera=camera,
        frames=[f[y0:y1, x0:x1] for f in inputs.frames],
        masks=[m[y0:y1, x0:x1] for m in inputs.masks])
