"""Pixel helpers of the SfT tracker (`inverse.sft.image`)."""

import numpy as np

from inverse.sft.image import REMAP_COLUMNS, bilinear


def _ramp(h=60, w=80):
    y, x = np.mgrid[0:h, 0:w]
    return (2.0 * x + 3.0 * y).astype(np.float32)


def test_bilinear_samples_any_number_of_points():
    """Issue 18: cv2.remap asserts on maps of ≥ SHRT_MAX columns; 40 000 samples in the
    tracker's (n, k, 2) layout must work and equal the same points sampled a few at a time."""
    image = _ramp()
    points = np.random.default_rng(0).uniform([0, 0], [79, 59], size=(4000, 10, 2))
    assert points[..., 0].size >= 40_000 > REMAP_COLUMNS
    values = bilinear(image, points)
    assert values.shape == (4000, 10) and values.dtype == np.float32
    few = np.concatenate([bilinear(image, points[i:i + 100]) for i in range(0, 4000, 100)])
    np.testing.assert_array_equal(values, few)
    # A linear image is reproduced up to OpenCV's 1/32 px quantisation of the coordinates.
    exact = 2.0 * points[..., 0] + 3.0 * points[..., 1]
    assert np.abs(values - exact).max() <= (2.0 + 3.0) / 32


def test_bilinear_replicates_the_border():
    image = _ramp()
    values = bilinear(image, np.array([[-5.0, -5.0], [200.0, 100.0]]))
    np.testing.assert_allclose(values, [0.0, 2.0 * 79 + 3.0 * 59])
