"""Dense flow correspondences: accuracy against known motion."""

import cv2
import numpy as np
import pytest

from inverse.sft.camera import Camera
from inverse.sft.flow import DenseFlow, FlowConfig, merged
from inverse.sft.surface import surface_positions
from tests.test_sft_tracking import pixel_errors, render


def flat_sheet(camera: Camera, depth: float = 1.0, half: float = 0.2, cells: int = 10):
    """A flat square sheet facing the camera: vertices (V, 3) [m], triangles (F, 3)."""
    s = np.linspace(-half, half, cells + 1)
    x, y = np.meshgrid(s, s)
    vertices = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, depth)])
    n = cells + 1
    faces = []
    for r in range(cells):
        for c in range(cells):
            a = r * n + c
            faces += [[a, a + 1, a + n], [a + 1, a + n + 1, a + n]]
    return vertices, np.array(faces)


def test_flow_points_follow_a_known_translation():
    camera = Camera(fx=500.0, fy=500.0, cx=319.5, cy=239.5, width=640, height=480)
    rng = np.random.default_rng(0)
    image = cv2.GaussianBlur(rng.uniform(0, 255, (480, 640)).astype(np.float32), (0, 0), 2.0)
    image = cv2.normalize(image, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    shift = np.array([2.6, -1.7])  # px
    moved = cv2.warpAffine(image, np.float32([[1, 0, shift[0]], [0, 1, shift[1]]]), (640, 480),
                           flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    vertices, faces = flat_sheet(camera)
    flow = DenseFlow([image, moved], camera, faces, config=FlowConfig(working_px=2000))
    corr = flow.correspondences(1, vertices)
    assert len(corr) > 550  # a 200 x 200 px sheet, 8 px grid: 625 points
    seen = camera.project(surface_positions(vertices, faces, corr.face, corr.bary))
    error = np.linalg.norm(corr.xy - (seen + shift), axis=1)
    assert np.median(error) < 0.1  # measured 0.065 px
    assert np.percentile(error, 95) < 0.3
    assert ((corr.confidence > 0) & (corr.confidence <= FlowConfig().confidence)).all()


def test_flow_points_follow_a_rendered_fold():
    seq = render("fold", frames=3)
    flow = DenseFlow(seq["frames"], seq["camera"], seq["template"].faces, masks=seq["masks"])
    for i in (1, 2):
        corr = flow.correspondences(i, seq["vertices"][i - 1])
        assert len(corr) > 500
        errors = pixel_errors(seq, i, corr)
        # Measured: median 0.08 px, 95 % 0.35 px (noise, blur, JPEG, clutter, gain drift).
        assert np.median(errors) < 0.2
        assert np.percentile(errors, 95) < 1.0


def test_merged_keeps_both_sets_in_order():
    camera = Camera(fx=500.0, fy=500.0, cx=319.5, cy=239.5, width=640, height=480)
    vertices, faces = flat_sheet(camera)
    image = np.zeros((480, 640), np.uint8)
    corr = DenseFlow([image, image], camera, faces).correspondences(1, vertices)
    both = merged(corr, corr)
    assert len(both) == 2 * len(corr)
    np.testing.assert_array_equal(both.xy[len(corr):], corr.xy)


def test_flow_config_is_validated():
    with pytest.raises(ValueError, match="fb_threshold"):
        FlowConfig(fb_threshold=0.0)
    with pytest.raises(ValueError, match="confidence"):
        FlowConfig(confidence=2.0)
