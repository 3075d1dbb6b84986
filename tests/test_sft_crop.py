"""The crop to the sheet: the same pixels and the same projections as the whole frames."""

import numpy as np

from inverse.sft.camera import Camera
from inverse.sft.crop import MARGIN_PX, cropped_to_sheet, sheet_box
from inverse.sft.inputs import SftInputs, Template


def inputs_with_masks(masks):
    camera = Camera(fx=500.0, fy=500.0, cx=319.5, cy=239.5, width=640, height=480)
    vertices = np.array([[-0.05, -0.05, 1.0], [0.05, -0.05, 1.0], [0.0, 0.05, 1.0]])
    template = Template(vertices=vertices, faces=np.array([[0, 1, 2]]),
                        uvs=np.array([[0.0, 0.0], [1.0, 0.0], [0.5, 1.0]]))
    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 255, (480, 640, 3), dtype=np.uint8) for _ in masks]
    return SftInputs(frames=frames, camera=camera, template=template,
                     texture=np.zeros((8, 8, 3), np.uint8), masks=masks)


def test_crop_holds_every_mask_and_keeps_the_projection():
    masks = [np.zeros((480, 640), bool) for _ in range(2)]
    masks[0][200:260, 300:330] = True
    masks[1][220:300, 280:320] = True
    inputs = inputs_with_masks(masks)
    x0, y0, x1, y1 = sheet_box(inputs)
    assert (x0, y0) == (280 - MARGIN_PX, 200 - MARGIN_PX)
    # the template reaches x = 344.5 (beyond the masks), the masks' last row is 299
    assert (x1, y1) == (345 + MARGIN_PX + 1, 299 + MARGIN_PX + 1)
    work = cropped_to_sheet(inputs)
    assert work.camera.size == (x1 - x0, y1 - y0)
    for full, crop in zip(inputs.masks, work.masks, strict=True):
        assert crop.sum() == full.sum()
    point = np.array([[0.01, 0.02, 1.1]])
    np.testing.assert_allclose(work.camera.project(point) + [x0, y0],
                               inputs.camera.project(point), atol=1e-12)
    u, v = np.rint(inputs.camera.project(point)[0]).astype(int)
    np.testing.assert_array_equal(work.frames[1][v - y0, u - x0], inputs.frames[1][v, u])


def test_no_masks_means_no_crop():
    inputs = inputs_with_masks([np.ones((480, 640), bool)])
    inputs = SftInputs(frames=inputs.frames, camera=inputs.camera, template=inputs.template,
                       texture=inputs.texture)
    assert sheet_box(inputs) is None
    assert cropped_to_sheet(inputs) is inputs
