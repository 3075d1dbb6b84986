"""The frames the material estimate uses: the sheet's acceleration from the reconstruction and
the quasi-static choice (`inverse.sft.material_frames`)."""

import numpy as np
import pytest

from inverse.sft.material_frames import STENCIL, chosen_frames, sheet_accelerations, used_frames
from inverse.sft.settings import MaterialFromVideoConfig


def _sheet(frames: int, accelerations) -> list[np.ndarray]:
    """A 4-vertex sheet moving along x with the per-frame acceleration a(t) [m/s²] (a list,
    one value per frame interval's second difference), at 30 fps."""
    dt = 1.0 / 30.0
    x, v, out = 0.0, 0.0, []
    base = np.array([[0, 0, 1], [0.1, 0, 1], [0, 0.1, 1], [0.1, 0.1, 1]], dtype=np.float64)
    for f in range(frames):
        out.append(base + [x, 0.0, 0.0])
        v += accelerations[f] * dt
        x += v * dt
    return out


def test_sheet_acceleration_is_the_second_difference_over_the_stencil():
    """A sheet under a constant acceleration a: every frame's value is a (the stencil
    divides by (k / fps)²); a sequence shorter than 2k + 1 frames has none."""
    a = 0.4  # m/s²
    x0 = [np.zeros((4, 3)) + [0.5 * a * (f / 30.0) ** 2, 0, 0] for f in range(12)]
    values = sheet_accelerations(x0, 30.0)
    assert values.shape == (12,) and np.allclose(values, a, rtol=1e-9)
    assert sheet_accelerations(x0[:2 * STENCIL], 30.0) is None


def test_quasi_static_frames_leave_out_the_accelerating_ones():
    """Frames 0–11 at rest, then the sheet accelerates at 2 m/s² (0.2 g): with a limit of
    0.05 g only the frames whose stencil does not reach the motion are used, frame 0 always;
    without a limit every frame is (as before: evenly spread)."""
    sheet = _sheet(24, [0.0] * 12 + [2.0] * 12)
    frames, record = used_frames(sheet, 0, 30.0, 9.81, 0.05)
    # the push a_12 enters frame f's difference with weight (k − |12 − f|) / k²: frame 10 at
    # 2/9 m/s² = 0.023 g is kept, frame 11 at 6/9 m/s² = 0.068 g is not
    assert STENCIL == 3 and frames == list(range(11))
    assert record["eligible"] == frames and record["limit_over_g"] == 0.05
    assert max(record["sheet_acceleration_over_g"][f] for f in frames) <= 0.05
    spread, _ = used_frames(sheet, 4, 30.0, 9.81, 0.05)
    assert spread == [0, 3, 7, 10] and spread[0] == 0
    every, record = used_frames(sheet, 8, 30.0, 9.81, None)
    assert every == chosen_frames(24, 8) and record["limit_over_g"] is None
    # frame 0 is kept even when it moves: its shape gives the flat sheet's size
    moving_start = _sheet(12, [3.0] * 12)
    assert used_frames(moving_start, 0, 30.0, 9.81, 0.05)[0] == [0]


def test_quasi_static_limit_is_checked():
    with pytest.raises(ValueError, match="quasi_static_limit must be positive"):
        MaterialFromVideoConfig(quasi_static_limit=0.0)
    assert MaterialFromVideoConfig().quasi_static_limit is None
