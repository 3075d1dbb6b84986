"""The silhouette allowance fading with motion (inverse.sft.silhouette.faded_allowance,
`SplinePriorConfig.allowance_fade`): the fade itself, and what the driver hands each frame."""

import cv2
import numpy as np
import pytest
import torch
from test_sft_reconstruct import bent_pair
from test_sft_sequential import STEP, run

from inverse.sft.outline import border_vertices
from inverse.sft.sequential import DataWeights
from inverse.sft.settings import SplinePriorConfig
from inverse.sft.silhouette import faded_allowance, silhouette_allowance, silhouette_distance
from inverse.sft.synth import default_camera


def test_the_allowance_fades_linearly_with_the_pixels_moved():
    allowance = np.array([4.0, 4.0, 4.0, 2.0])
    first = np.zeros((4, 2))
    previous = np.array([[0.0, 0.0], [3.0, 4.0], [20.0, 0.0], [0.0, 5.0]])
    faded = faded_allowance(allowance, first, previous, 10.0)
    assert faded == pytest.approx([4.0, 2.0, 0.0, 1.0])


def test_the_setting_is_checked():
    assert SplinePriorConfig().allowance_fade is None
    for bad in (0.0, -1.0, float("inf")):
        with pytest.raises(ValueError, match="allowance_fade"):
            SplinePriorConfig(allowance_fade=bad)


def test_the_driver_fades_each_frames_allowance_by_the_previous_frames_motion():
    """A mask 3 px inside the template's outline; the fake fit moves the sheet STEP (1 cm
    away) per frame. Frame 1 starts from the template (no motion: the full allowance), frame 2
    from frame 1: each border vertex's allowance times 1 − its pixel motion / (fade × the mean
    projected edge of frame 0)."""
    camera = default_camera()
    template, _ = bent_pair()
    pixels = camera.project(torch.from_numpy(template.vertices)).numpy()
    image = np.zeros((camera.height, camera.width), np.uint8)
    for triangle in np.rint(pixels[template.faces]).astype(np.int32):
        cv2.fillConvexPoly(image, triangle, 1)
    mask = cv2.erode(image, np.ones((7, 7), np.uint8)).astype(bool)
    border = border_vertices(template.faces, len(template.vertices))
    full = silhouette_allowance(silhouette_distance(mask), pixels, border)
    edge_px = float(np.mean(np.linalg.norm(
        pixels[template.faces] - pixels[np.roll(template.faces, 1, 1)], axis=2)))
    fade = 0.5
    _, _, fit, _ = run(DataWeights(2.0, 0.1, 1.0, 1.0, silhouette_allowance=True,
                                   allowance_fade=fade), masks=[mask] * 3)
    first, second = fit.frames
    np.testing.assert_allclose(first.silhouette_allowance.numpy(), full)
    moved = np.linalg.norm(camera.project(template.vertices + STEP) - pixels, axis=1)
    factor = np.clip(1 - moved / (fade * edge_px), 0, 1)
    assert 0.05 < factor[border].min() and factor[border].max() < 0.95  # a partial fade
    np.testing.assert_allclose(second.silhouette_allowance.numpy(), full * factor)
    # without the setting the allowance does not fade
    _, _, plain, _ = run(DataWeights(2.0, 0.1, 1.0, 1.0, silhouette_allowance=True),
                         masks=[mask] * 3)
    np.testing.assert_allclose(plain.frames[1].silhouette_allowance.numpy(), full)
