"""A swing's capture unknowns with its material (`inverse.sft.swing_capture`): the time scale
put in as mass is the run's time scale; gravity's pitch and roll, the time scale and the
bending length of the model's own swing come back from a start away from them; the residual's
correlation length over frames, the profile's one-sided bound; the data's smoothing kept; bad
input refused."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import taichi_ndf
from inverse.material.trajectory_fit import TrajectoryFitConfig, fit_trajectory
from inverse.sft.gravity_direction import tilted_gravity
from inverse.sft.held_motion import smoothed
from inverse.sft.swing import SwingConfig, swing_problem
from inverse.sft.swing_capture import (
    CaptureFitConfig,
    CaptureProblem,
    SwingCapture,
    capture_residuals,
    fit_capture,
    frame_correlation_length,
    model_sequence,
    upper_bound,
)

SIZE, N, FRAMES, DT = 0.55, 5, 10, 1.0 / 30.0
CONFIG = SwingConfig(spans=(3, 3), size=(SIZE, SIZE), start="rest")
TRUTH = SwingCapture(6.0, 2.0, 0.5, 0.12)
TOP = np.array([[-SIZE / 2, -0.3, 1.0], [SIZE / 2, -0.3, 1.0]])  # the corners at rest [m]


def corners(t: np.ndarray) -> np.ndarray:
    """The held corners (T, 2, 3) [m] at data times t (T,) [s]: both pushed away from the
    camera (+z) by 4 cm × (t / T)², corner b also 1 cm up: the sheet lags behind."""
    ramp = (np.asarray(t, dtype=np.float64) / (DT * (FRAMES - 1))) ** 2
    return TOP[None] + ramp[:, None, None] * np.array([[0.0, 0.0, 0.04], [0.0, -0.01, 0.04]])


def sequence() -> tuple[np.ndarray, np.ndarray]:
    """A flat N × N vertex grid at the corners' rest (row 0 held) for every frame, and its
    triangles: the template the model's own swing is written onto."""
    i, j = np.meshgrid(np.arange(N), np.arange(N), indexing="xy")
    flat = np.stack([i.ravel() / (N - 1) * SIZE - SIZE / 2, j.ravel() / (N - 1) * SIZE - 0.3,
                     np.ones(N * N)], axis=1)
    faces = []
    for r in range(N - 1):
        for c in range(N - 1):
            v = r * N + c
            faces += [[v, v + 1, v + N + 1], [v, v + N + 1, v + N]]
    return np.repeat(flat[None], FRAMES, axis=0), np.array(faces)


@pytest.fixture(scope="module")
def truth():
    taichi_ndf.init(arch="cpu", precision="f64", seed=0)
    vertices, faces = sequence()
    problem = CaptureProblem(vertices, faces, (0, N - 1), DT, CONFIG, corners=corners)
    return dataclasses.replace(problem, vertices=model_sequence(problem, TRUTH))


def test_the_time_scale_as_mass_is_the_runs_time_scale(truth):
    """The run at frame interval s Δt under ρ_A and g (the corners on the data's clock) and
    the run at Δt under ρ_A / s² and s² g have the same residuals, to Newton's tolerance."""
    r, dr, _ = capture_residuals(truth, TRUTH)
    s = TRUTH.time_scale
    direct = swing_problem(truth.vertices, truth.faces, truth.held, s * DT,
                           tilted_gravity(truth.vertices[0, [0, N - 1]], TRUTH.pitch, TRUTH.roll),
                           CONFIG, corners=lambda t: corners(np.asarray(t) / s))
    bending = CONFIG.areal_density * 9.81 * TRUTH.bending_length ** 3
    run = fit_trajectory(direct.stepper_at, direct.data, bending,
                         TrajectoryFitConfig(max_iterations=1), initial=direct.start)
    assert np.abs(r).max() < 1e-9  # the truth's own swing
    moved = capture_residuals(truth, dataclasses.replace(TRUTH, pitch=7.0))[0]
    assert np.abs(moved).max() > 1e-3
    other = capture_residuals(truth, dataclasses.replace(TRUTH, time_scale=0.6))[0]
    direct_other = swing_problem(truth.vertices, truth.faces, truth.held, 0.6 * DT,
                                 tilted_gravity(truth.vertices[0, [0, N - 1]], 6.0, 2.0),
                                 CONFIG, corners=lambda t: corners(np.asarray(t) / 0.6))
    run_other = fit_trajectory(direct_other.stepper_at, direct_other.data, bending,
                               TrajectoryFitConfig(max_iterations=1), initial=direct_other.start)
    assert np.abs(other).max() > 1e-3
    assert other == pytest.approx(run_other.residuals, abs=1e-8)
    assert 3 * bending * run.sensitivity == pytest.approx(dr, rel=1e-6, abs=1e-12)


def test_the_joint_fit_recovers_the_models_own_pitch_roll_time_scale_and_length(truth):
    fit = fit_capture(truth, SwingCapture(0.0, 0.0, 0.8, 0.08),
                      CaptureFitConfig(max_evaluations=25, tolerance=1e-10))
    assert fit.point.pitch == pytest.approx(TRUTH.pitch, abs=1e-3)
    assert fit.point.roll == pytest.approx(TRUTH.roll, abs=1e-3)
    assert fit.point.time_scale == pytest.approx(TRUTH.time_scale, rel=1e-4)
    assert fit.point.bending_length == pytest.approx(TRUTH.bending_length, rel=1e-3)
    assert fit.rms < 1e-6 and fit.free == ("pitch", "roll", "time_scale", "bending_length")
    assert fit.residuals.shape == (FRAMES - 1, 3 * N * N) and not fit.at_bound
    # a fixed unknown stays where it is put; the rest fits around it
    held = fit_capture(truth, dataclasses.replace(TRUTH, bending_length=0.2),
                       CaptureFitConfig(fixed=("bending_length",), max_evaluations=3))
    assert held.point.bending_length == 0.2 and held.free == ("pitch", "roll", "time_scale")
    assert held.rms > 1e-5


def test_the_correlation_length_over_frames():
    rng = np.random.default_rng(0)
    white = rng.normal(size=(400, 30))
    assert frame_correlation_length(white) == pytest.approx(1.0, abs=0.3)
    phi, series = 0.8, np.zeros((2000, 30))  # AR(1): L = (1 + φ) / (1 − φ) = 9
    for f in range(1, len(series)):
        series[f] = phi * series[f - 1] + rng.normal(size=30)
    assert 6.0 < frame_correlation_length(series) < 12.0


def test_the_profiles_one_sided_bound():
    lengths = [0.01, 0.02, 0.04, 0.08]
    # n_eff 2 ln(rms / best) with n_eff 5: 0, 0, 0.953, 4.055; 2.706 crossed between 4 and 8
    bound = upper_bound(lengths, [1.0, 1.0, 1.1, 1.5], 1.0, 5.0)
    t = (2.706 - 10 * np.log(1.1)) / (10 * np.log(1.5) - 10 * np.log(1.1))
    assert bound == pytest.approx(0.04 * 2 ** t, rel=1e-9)
    assert upper_bound(lengths, [1.0, 1.0, 1.1, 1.2], 1.0, 5.0) is None


def test_the_smoothing_is_kept_for_the_same_data():
    values = np.sin(np.linspace(0, 3, 12))[:, None] * np.ones((1, 4))
    times = np.linspace(0, 1, 12)
    first = smoothed(values, times)
    assert smoothed(values.copy(), times.copy()) is first
    assert smoothed(values + 1e-3, times) is not first


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match="time_scale"):
        SwingCapture(0.0, 0.0, 0.0, 0.02)
    with pytest.raises(ValueError, match="pitch"):
        SwingCapture(95.0, 0.0, 1.0, 0.02)
    with pytest.raises(ValueError, match="fixed"):
        CaptureFitConfig(fixed=("stiffness",))
    with pytest.raises(ValueError, match="length_bounds"):
        CaptureFitConfig(length_bounds=(0.1, 0.01))
    script = Path(__file__).resolve().parent.parent / "benchmarks" / "sft_swing.py"
    done = subprocess.run([sys.executable, str(script), "--part", "r1", "--run", "/nonexistent",
                           "--r1-joint", "9", "0", "0", "0.02"], capture_output=True, text=True)
    assert done.returncode == 2 and "time_scale" in done.stderr
    done = subprocess.run([sys.executable, str(script), "--part", "synthetic",
                           "--r1-joint", "9", "0", "0.3", "0.02"], capture_output=True, text=True)
    assert done.returncode == 2 and "--r1-joint needs" in done.stderr
