"""Gravity's direction in a camera's frame (`inverse.sft.gravity_direction`)."""

import numpy as np
import pytest

from inverse.sft.gravity_direction import pendulum_swing, sheet_pitch, tilted_gravity

CORNERS = np.array([[-0.28, -0.3, 1.0], [0.28, -0.3, 1.0]])  # a corner line along +x


def test_gravity_is_image_down_turned_by_its_pitch_and_roll():
    assert tilted_gravity(CORNERS, 0.0) == pytest.approx([0.0, 9.81, 0.0])
    assert tilted_gravity(CORNERS, 30.0) == pytest.approx([0.0, 9.81 * np.cos(np.pi / 6),
                                                           9.81 * 0.5])
    assert tilted_gravity(CORNERS, 0.0, 30.0) == pytest.approx([9.81 * 0.5,
                                                                9.81 * np.cos(np.pi / 6), 0])
    tilted_line = np.array([[0.0, 0.0, 1.0], [0.5, 0.5, 1.0]])  # down made ⊥ the line
    g = tilted_gravity(tilted_line, 0.0, magnitude=1.0)
    assert g @ (tilted_line[1] - tilted_line[0]) == pytest.approx(0.0, abs=1e-15)
    assert np.linalg.norm(g) == pytest.approx(1.0)
    for bad in ((90.0, 0.0), (0.0, float("nan")), (-95.0, 0.0)):
        with pytest.raises(ValueError, match="must be finite and in"):
            tilted_gravity(CORNERS, *bad)


def swinging_plate(alpha, amplitude, frequency, phase, frames=50, noise=0.0, seed=0):
    """A flat 0.55 m square plate of 9 × 9 vertices (row 0 the corner line, vertices 0 and 8
    its ends) turned about its corner line by α + A cos(Ω n + φ) [deg] at frame n."""
    i, j = np.meshgrid(np.linspace(-0.275, 0.275, 9), np.linspace(0, 0.55, 9), indexing="xy")
    rng = np.random.default_rng(seed)
    out = []
    for n in range(frames):
        a = np.radians(alpha + amplitude * np.cos(frequency * n + phase))
        points = np.stack([i.ravel(), -0.3 + np.cos(a) * j.ravel(),
                           1.0 + np.sin(a) * j.ravel()], axis=1)
        out.append(points + noise * rng.standard_normal(points.shape))
    return np.stack(out)


def test_the_sheets_pitch_is_its_turn_about_the_corner_line():
    plate = swinging_plate(5.0, 10.0, 0.1, 0.3, frames=8)
    expected = 5.0 + 10.0 * np.cos(0.1 * np.arange(8) + 0.3)
    assert sheet_pitch(plate, (0, 8)) == pytest.approx(expected, abs=1e-10)


def test_a_swinging_plate_gives_back_its_equilibrium_and_frequency_within_their_se():
    truth = (9.0, 10.4, 0.065, 3.0)  # about R1's swing: half a period in 50 frames
    found = pendulum_swing(swinging_plate(*truth), (0, 8))
    assert found.equilibrium == pytest.approx(9.0, abs=1e-6)
    assert found.frequency == pytest.approx(0.065, abs=1e-8)
    noisy = pendulum_swing(swinging_plate(*truth, noise=0.002, seed=1), (0, 8))
    assert abs(noisy.equilibrium - 9.0) < 3 * noisy.equilibrium_se
    assert abs(noisy.frequency - 0.065) < 3 * noisy.frequency_se
    assert abs(noisy.amplitude - 10.4) < 3 * noisy.amplitude_se
    assert 0 < noisy.rms < 1.0


def test_too_few_frames_are_refused():
    with pytest.raises(ValueError, match="F >= 6"):
        pendulum_swing(swinging_plate(0.0, 1.0, 0.1, 0.0, frames=5), (0, 8))


def test_the_benchmarks_bad_gravity_angles_are_refused_in_one_line():
    import subprocess
    import sys
    from pathlib import Path
    script = Path(__file__).resolve().parents[1] / "benchmarks" / "sft_swing.py"
    for bad in (["90", "0"], ["0", "nan"]):
        done = subprocess.run([sys.executable, str(script), "--part", "r1", "--r1-gravity",
                               *bad], capture_output=True, text=True, timeout=120)
        assert done.returncode == 2 and done.stderr.strip().splitlines() == [
            "sft_swing.py: --r1-gravity PITCH ROLL must be finite angles in (-90, 90) degrees"]
