"""The bending stiffness from a sheet's swing (`inverse.sft.swing`): the model follows the
observed corners and starts at rest in its static equilibrium near the observed frame 0 (or,
with start "data", at frame 0's fit); the fit through the moving corners, with the rest
start's derivative dC₀/dB in its tangent and adjoint, recovers B from the model's own motion;
bad input is refused."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

import taichi_ndf
from inverse.material.trajectory_fit import (
    TrajectoryData,
    TrajectoryFit,
    TrajectoryFitConfig,
    fit_trajectory,
    observe,
)
from inverse.sft import swing
from inverse.sft.swing import SwingConfig, fit_swing, resolving_spans, swing_problem
from taichi_ndf import jets
from taichi_ndf.solve.dynamics_adjoint import record

SIZE, N, FRAMES, DT = 0.55, 5, 5, 1.0 / 30.0
CONFIG = SwingConfig(spans=(3, 3), size=(SIZE, SIZE))
FAKE = TrajectoryFit(1.0, 0.01, 3, True, np.zeros(3), np.ones(3), 1e-3, "stated", None, 0.0, 0.0)


def rigid_sequence():
    """A flat N × N vertex grid hanging in the x-y plane (gravity +y), row 0 held, turned
    about the vertical axis through its middle by 0.02 rad per frame: corner 0 moves towards
    the camera (−z), corner N − 1 away."""
    i, j = np.meshgrid(np.arange(N), np.arange(N), indexing="xy")
    flat = np.stack([i.ravel() / (N - 1) * SIZE - SIZE / 2, j.ravel() / (N - 1) * SIZE - 0.3,
                     np.ones(N * N)], axis=1)
    frames = []
    for f in range(FRAMES):
        a = 0.02 * f
        turn = np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0],
                         [-np.sin(a), 0.0, np.cos(a)]])
        centre = np.array([0.0, 0.0, 1.0])
        frames.append((flat - centre) @ turn.T + centre)
    faces = []
    for r in range(N - 1):
        for c in range(N - 1):
            v = r * N + c
            faces += [[v, v + 1, v + N + 1], [v, v + N + 1, v + N]]
    return np.stack(frames), np.array(faces)


@pytest.fixture(scope="module")
def problem():
    taichi_ndf.init(arch="cpu", precision="f64", seed=0)
    vertices, faces = rigid_sequence()
    return vertices, swing_problem(vertices, faces, (0, N - 1), DT, np.array([0.0, 9.81, 0.0]),
                                   CONFIG)


def test_the_handles_follow_the_observed_corners_and_the_start_is_frame_0(problem):
    vertices, p = problem
    corners = vertices[:, [0, N - 1]]
    reference = corners[0, 0] + np.array([[0.0, 0.0, 0.0], [SIZE, 0.0, 0.0]])
    # a rigid turn by a small angle per frame: the smoothed corners within 1e-4 m of them
    for f in range(FRAMES):
        assert p.path.at(f * DT) == pytest.approx(corners[f] - reference, abs=1e-4)
    # frame 0 is the flat sheet, not an equilibrium: the rest start (the sheet held at two
    # points sags between them and stretches under gravity: 7.4 mm rms) is near it, not on
    # it; frame 0's fit is on it
    assert 1e-3 < p.start_misfit(2e-5) < 2e-2
    data_start = swing_problem(vertices, rigid_sequence()[1], (0, N - 1), DT,
                               np.array([0.0, 9.81, 0.0]), SwingConfig(
                                   spans=(3, 3), size=(SIZE, SIZE), start="data"))
    assert data_start.start_misfit(2e-5) < 1e-4
    assert p.data.steps == (1, 2, 3, 4) and p.data.displacements.shape == (4, N * N, 3)
    assert p.model.material.membrane_stiffness == CONFIG.membrane_stiffness


def test_the_fit_through_moving_corners_recovers_the_models_own_bending(problem):
    _, p = problem
    b_true = 2e-5
    stepper = p.stepper_at(b_true)
    start = p.start(stepper)
    assert start.derivative is not None and float(start.velocity.abs().max()) == 0.0
    states = record(stepper, start.displacement, start.velocity)
    clean = torch.stack([observe(stepper, p.data.xi, states[k].displacement, states[k].time)
                         for k in p.data.steps])
    data = TrajectoryData(p.data.xi, p.data.steps, clean, 1e-4)
    fit = fit_trajectory(p.stepper_at, data, 2 * b_true,
                         TrajectoryFitConfig(max_iterations=12, tolerance=1e-9),
                         initial=p.start)
    assert fit.value == pytest.approx(b_true, rel=1e-5)
    assert fit.gradient_gap < 1e-8
    # the boundary's part is in the observations: the corners are where the path puts them
    corners = torch.tensor([[0.0, 0.0], [SIZE, 0.0]], dtype=torch.float64)
    u = observe(stepper, corners, states[2].displacement, states[2].time)
    assert u.numpy() == pytest.approx(p.path.at(states[2].time), abs=1e-12)


def test_the_corners_as_unknowns_recover_the_models_own_motion_and_b(problem):
    """Clean data of the model itself whose corners stand 3–4 mm off the start's paths (two
    B-spline coefficients moved): B and the paths fitted together come back to rounding; B
    alone on the start's paths is biased by them (−1.1 %); B's marginal s.e. is the larger."""
    vertices, _ = problem
    p = swing_problem(vertices, rigid_sequence()[1], (0, N - 1), DT,
                      np.array([0.0, 9.81, 0.0]),
                      dataclasses.replace(CONFIG, corners="fitted", corner_spans=2))
    assert p.path_start.shape == (2 * 3 * 5,)
    b_true, q_true = 2e-5, p.path_start.copy()
    q_true[2] += 0.004  # corner a, x, the middle coefficient
    q_true[27] -= 0.003  # corner b, z
    stepper = p.stepper_at(b_true, q_true)
    start = p.start(stepper)
    assert start.derivative[0].shape[-1] == 1 + len(q_true)
    states = record(stepper, start.displacement, start.velocity)
    clean = torch.stack([observe(stepper, p.data.xi, states[k].displacement, states[k].time)
                         for k in p.data.steps])
    data = TrajectoryData(p.data.xi, p.data.steps, clean, 1e-4)
    settings = TrajectoryFitConfig(max_iterations=12, tolerance=1e-9)
    joint = fit_trajectory(p.stepper_at, data, 2 * b_true, settings, initial=p.start,
                           path_start=p.path_start)
    assert joint.value == pytest.approx(b_true, rel=1e-8)
    assert joint.path_values == pytest.approx(q_true, abs=1e-9)
    assert joint.gradient_gap < 1e-8 and 0 < joint.correlation < 1
    alone = fit_trajectory(lambda b: p.stepper_at(b, p.path_start), data, 2 * b_true,
                           settings, initial=p.start)
    assert abs(alone.value / b_true - 1) > 5e-3
    assert joint.standard_error > alone.standard_error
    with pytest.raises(ValueError, match="corners must be smoothed or fitted"):
        SwingConfig(corners="true")
    with pytest.raises(ValueError, match="corner_spans"):
        SwingConfig(corner_spans=0)


def test_graded_knots_put_the_same_unknowns_towards_the_held_points(problem):
    """knots "graded": the stepper's field has the uniform grid's unknowns, its knots graded
    towards the held points ξ = (0, 0) and (W, 0) (dη/dξ, the spans per metre, larger there
    than between them along ξ¹ and falling away from them along ξ²); other knots refused."""
    vertices, uniform = problem
    _, faces = rigid_sequence()
    graded = swing_problem(vertices, faces, (0, N - 1), DT, np.array([0.0, 9.81, 0.0]),
                           dataclasses.replace(CONFIG, knots="graded"))
    field = graded.stepper_at(1e-5).field
    assert field.coefficients.shape == uniform.stepper_at(1e-5).field.coefficients.shape
    assert uniform.stepper_at(1e-5).field.config.grading == (None, None)
    along, down = field.config.graded_maps()
    at = torch.tensor([0.0, SIZE / 2, SIZE], dtype=torch.float64)
    along, down = along.jets(at)[1], down.jets(at)[1]
    assert min(float(along[0]), float(along[2])) > 1.05 * float(along[1])  # 3 spans: mild
    assert float(down[0]) > 1.05 * float(down[1]) > 1.05 * float(down[2])
    with pytest.raises(ValueError, match="knots must be one of"):
        SwingConfig(knots="fine")


@pytest.mark.parametrize(("change", "message"), [
    (lambda v: v[:4], "F >= 5"),
    (lambda v: np.where(np.isnan(v), 0, v) * np.nan, "finite"),
])
def test_bad_sequences_are_refused(problem, change, message):
    vertices, _ = problem
    _, faces = rigid_sequence()
    with pytest.raises(ValueError, match=message):
        swing_problem(change(vertices), faces, (0, N - 1), DT, np.array([0.0, 9.81, 0.0]),
                      CONFIG)
    with pytest.raises(ValueError, match="frame interval"):
        swing_problem(vertices, faces, (0, N - 1), 0.0, np.array([0.0, 9.81, 0.0]), CONFIG)
    with pytest.raises(ValueError, match="substeps"):
        SwingConfig(substeps=0)
    with pytest.raises(ValueError, match="start must be rest or data"):
        SwingConfig(start="frame0")


def test_the_grid_resolves_the_bending_length():
    # spans no longer than ratio × c on each side, at most the limit; no length: the limit
    assert resolving_spans((0.55, 0.55), 0.02, 1.0) == (28, 28)
    assert resolving_spans((0.55, 0.275), 0.02, 2.0) == (14, 7)
    assert resolving_spans((0.55, 0.55), 0.0, 1.0, limit=20) == (20, 20)
    assert resolving_spans((0.55, 0.55), 1e-4, 1.0, limit=20) == (20, 20)
    assert resolving_spans((0.1, 0.1), 1.0, 1.0) == (1, 1)
    with pytest.raises(ValueError, match="span_ratio"):
        SwingConfig(span_ratio=0.0)


def test_the_grid_follows_the_estimate_and_is_checked_on_a_finer_one(monkeypatch):
    # each fit stubbed by the estimate it would give on its grid (the real fit: the test above
    # and benchmarks/sft_swing.py): B = ρ_A g c³ at the c stated per grid, s.e. 1 % of B
    vertices, faces = rigid_sequence()
    gravity, g = np.array([0.0, 9.81, 0.0]), 9.81
    rho = SwingConfig().areal_density
    b_on = {(3, 3): 0.11 / 5, (5, 5): 0.11 / 4.5, (4, 4): 0.11 / 4.5}  # a grid's estimate's c
    b_on = {spans: rho * g * c ** 3 for spans, c in b_on.items()}
    b_on[7, 7] = 1.05 * b_on[5, 5]  # one step on 7²: 5 s.e. from 5²'s
    b_on[10, 10] = 1.005 * b_on[7, 7]  # on 10²: 0.5 s.e. from 7²'s
    calls = []

    def fit_on_grid(stepper_at, data, start, config, *, initial, path_start=None):
        spans = tuple(stepper_at(1e-5).field.config.spans)
        calls.append((spans, start, config.max_iterations))
        return dataclasses.replace(FAKE, value=b_on[spans], standard_error=0.01 * b_on[spans])

    monkeypatch.setattr(swing, "fit_trajectory", fit_on_grid)
    config = SwingConfig(size=(SIZE, SIZE), span_ratio=5.0, grid_check=False)
    start = rho * g * (0.11 / 2.5) ** 3  # c = 4.4 cm: 0.55 m / (5 c) → 3 spans
    result = fit_swing(vertices, faces, (0, N - 1), DT, gravity, config, start)
    # 3²'s estimate asks for 5², whose estimate asks for 5 (not 6): done there, resolved;
    # each refit starts at the level before's estimate
    assert [level[0] for level in result.levels] == [(3, 3), (5, 5)] and result.resolved
    assert calls[0][1] == start and calls[1][1] == b_on[3, 3]
    # an estimate that asks for more than max_spans: the last fit at the limit, not resolved
    capped = fit_swing(vertices, faces, (0, N - 1), DT, gravity,
                       dataclasses.replace(config, max_spans=4), start)
    assert [level[0] for level in capped.levels] == [(3, 3), (4, 4)] and not capped.resolved
    # spans given: one fit on them
    assert [lv[0] for lv in fit_swing(vertices, faces, (0, N - 1), DT, gravity,
                                      dataclasses.replace(config, spans=(4, 4)),
                                      start).levels] == [(4, 4)]
    # checked on a finer grid (× 4/3): one step on 7² moves B by 5 s.e. → the fit goes on on
    # 7² (from that step's value); one step on 10² moves it by 0.5 s.e. → done, resolved
    calls.clear()
    checked = fit_swing(vertices, faces, (0, N - 1), DT, gravity,
                        dataclasses.replace(config, grid_check=True), start)
    assert [(lv[0], lv[4]) for lv in checked.levels] == [
        ((3, 3), "fit"), ((5, 5), "fit"), ((7, 7), "check"), ((7, 7), "fit"),
        ((10, 10), "check")]
    assert checked.resolved and checked.grid_change == pytest.approx(0.5, rel=1e-6)
    assert checked.fit.value == b_on[7, 7]
    assert [c[2] for c in calls] == [15, 15, 1, 15, 1]  # the checks: one step each
    assert calls[2][1] == b_on[5, 5] and calls[3][1] == b_on[7, 7]
    # a check at max_spans is not possible: not resolved
    unchecked = fit_swing(vertices, faces, (0, N - 1), DT, gravity,
                          dataclasses.replace(config, grid_check=True, max_spans=5), start)
    assert [lv[0] for lv in unchecked.levels] == [(3, 3), (5, 5)] and not unchecked.resolved


def test_a_fit_stopped_at_its_iteration_cap_is_not_resolved(monkeypatch):
    # the same levels as the test above, every fit stopped at its cap (converged False): the
    # grid check may pass, but a fit that did not converge holds no estimate (R1's swing fits,
    # benchmarks/RESULTS.md wip-sftr1swing: every level at its cap)
    vertices, faces = rigid_sequence()
    gravity, g = np.array([0.0, 9.81, 0.0]), 9.81
    rho = SwingConfig().areal_density
    b_on = {spans: rho * g * c ** 3 for spans, c in
            {(3, 3): 0.11 / 5, (5, 5): 0.11 / 4.5, (4, 4): 0.11 / 4.5}.items()}
    b_on[7, 7] = 1.005 * b_on[5, 5]  # one step on 7²: 0.5 s.e.: the check passes

    def fit_on_grid(stepper_at, data, start, config, *, initial, path_start=None):
        spans = tuple(stepper_at(1e-5).field.config.spans)
        return dataclasses.replace(FAKE, value=b_on[spans], standard_error=0.01 * b_on[spans],
                                   converged=False)

    monkeypatch.setattr(swing, "fit_trajectory", fit_on_grid)
    config = SwingConfig(size=(SIZE, SIZE), span_ratio=5.0, grid_check=True)
    start = rho * g * (0.11 / 2.5) ** 3
    checked = fit_swing(vertices, faces, (0, N - 1), DT, gravity, config, start)
    assert [(lv[0], lv[4]) for lv in checked.levels] == [
        ((3, 3), "fit"), ((5, 5), "fit"), ((7, 7), "check")]
    assert checked.grid_change == pytest.approx(0.5, rel=1e-6) and not checked.resolved
    unchecked = fit_swing(vertices, faces, (0, N - 1), DT, gravity,
                          dataclasses.replace(config, grid_check=False), start)
    assert not unchecked.resolved
    given = fit_swing(vertices, faces, (0, N - 1), DT, gravity,
                      dataclasses.replace(config, spans=(4, 4)), start)
    assert not given.resolved


def test_with_fitted_corners_the_refits_and_the_check_start_from_the_last_corners(monkeypatch):
    # the corners' spline does not depend on the grid: a refit and the check's one step start
    # from the last fit's q̂, so the check measures the grid, not the corners' start (before,
    # every level restarted from the smoothed tracks' q₀)
    vertices, faces = rigid_sequence()
    gravity, g = np.array([0.0, 9.81, 0.0]), 9.81
    rho = SwingConfig().areal_density
    b_on = {(3, 3): rho * g * (0.11 / 2.5) ** 3}  # c asks for 3 spans at span_ratio 5
    b_on[4, 4] = 1.05 * b_on[3, 3]  # the check on 4² moves B by 5 s.e.: a fit there
    b_on[5, 5] = 1.001 * b_on[4, 4]
    starts = []

    def fit_on_grid(stepper_at, data, start, config, *, initial, path_start=None):
        spans = tuple(stepper_at(1e-5).field.config.spans)
        starts.append((spans, None if path_start is None else path_start.copy()))
        return dataclasses.replace(FAKE, value=b_on[spans], standard_error=0.01 * b_on[spans],
                                   path_values=np.full_like(path_start, spans[0]))

    monkeypatch.setattr(swing, "fit_trajectory", fit_on_grid)
    config = SwingConfig(size=(SIZE, SIZE), span_ratio=5.0, corners="fitted", corner_spans=2,
                         max_spans=5)
    start = rho * g * (0.11 / 2.5) ** 3
    result = fit_swing(vertices, faces, (0, N - 1), DT, gravity, config, start)
    assert [(lv[0], lv[4]) for lv in result.levels] == [
        ((3, 3), "fit"), ((4, 4), "check"), ((4, 4), "fit"), ((5, 5), "check")]
    first = starts[0][1]
    assert first is not None and not np.all(first == 3.0)  # the smoothed tracks' q₀
    assert [np.all(q == value) for (_, q), value in zip(starts[1:], (3.0, 4.0, 4.0),
                                                          strict=True)] == [True] * 3


def test_the_benchmarks_linearised_bias_is_nil_on_the_models_own_run_and_one_step_off_it(
        problem):
    """benchmarks/sft_swing.py --bias: one Gauss–Newton step from the true B with the true
    corners. On the model's own run at B the bias is nil; on its run at 1.1 B it is the step
    to ≈ +10 % (first order: within 1 % of B); its parts per frame and point sum to it."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    import sft_swing

    _, p = problem
    _, faces = rigid_sequence()
    held = torch.tensor([[0.0, 0.0], [SIZE, 0.0]], dtype=torch.float64)
    reference = p.model.surface.jets(held)[:, jets.VALUE].double().numpy()

    def corners(t):  # the paths the model follows, as positions
        return np.stack([reference + p.path.at(float(s)) for s in np.atleast_1d(t)])

    grid = torch.from_numpy(p.grid.xi).double()
    flat = p.model.surface.jets(grid)[:, jets.VALUE].double().numpy()
    b_true = 2e-5
    for factor, expected in ((1.0, 0.0), (1.1, 0.1)):
        stepper = p.stepper_at(factor * b_true)
        start = p.start(stepper)
        states = record(stepper, start.displacement, start.velocity)
        run = np.stack([flat + observe(stepper, grid, s.displacement, s.time).numpy()
                        for s in states])
        found = sft_swing.linearised_bias(run, faces, (0, N - 1), 1 / DT, CONFIG, b_true,
                                          corners)
        assert found.bias / b_true == pytest.approx(expected, abs=1e-2 if factor > 1 else 1e-8)
        assert found.parts.shape == (FRAMES - 1, N * N)
        assert found.parts.sum() == pytest.approx(found.bias, rel=1e-12)
        assert found.standard_error(1e-3) == pytest.approx(1e-3 / np.sqrt(found.h))
    assert found.misfit > 1e-5


def test_the_benchmarks_bias_without_a_fit_grid_is_refused_in_one_line():
    script = Path(__file__).resolve().parents[1] / "benchmarks" / "sft_swing.py"
    done = subprocess.run([sys.executable, str(script), "--part", "synthetic", "--bias"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        "sft_swing.py: --bias needs --part synthetic and the fit's grid --spans N >= 1"]
    for bad in (["--part", "r1", "--turn", "true"], ["--part", "synthetic",
                                                   "--turn-degrees", "nan"]):
        done = subprocess.run([sys.executable, str(script), *bad], capture_output=True,
                              text=True, timeout=120)
        assert done.returncode == 2 and done.stderr.strip().splitlines() == [
            "sft_swing.py: --turn-degrees must be finite, and --turn true needs --part "
            "synthetic (a truth's turn)"]


def edge_turned_sequence(rate: float):
    """rigid_sequence's flat frame 0 turned about its held edge (row 0, the line y = −0.3,
    z = 1 along x) by `rate` rad per frame: the rows below it swing towards +z."""
    vertices, faces = rigid_sequence()
    offset = vertices[0] - np.array([0.0, -0.3, 1.0])
    frames = []
    for f in range(FRAMES):
        a = rate * f
        turn = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(a), -np.sin(a)],
                         [0.0, np.sin(a), np.cos(a)]])
        frames.append(offset @ turn.T + np.array([0.0, -0.3, 1.0]))
    return np.stack(frames), faces


def test_the_held_edge_turns_by_the_angle_read_off_its_band_and_b_comes_back():
    """SwingConfig.turn "read": a sheet turned about its held edge by 0.03 rad per frame reads
    that angle (smoothed: a line is kept); the handles turn the held slope with it (the
    boundary's slope across the edge at corner a is (R(θ) − I) a₂); a sheet turned about
    another axis (rigid_sequence: the corner line turns with it) reads no turn; and the fit
    recovers B from the turning model's own motion. Without a turn the path has none."""
    vertices, faces = edge_turned_sequence(0.03)
    gravity = np.array([0.0, 9.81, 0.0])
    p = swing_problem(vertices, faces, (0, N - 1), DT, gravity,
                      dataclasses.replace(CONFIG, turn="read"))
    for f in range(FRAMES):
        assert p.path.turn_at(f * DT) == pytest.approx([0.03 * f, 0.0, 0.0], abs=1e-6)
    stepper = p.stepper_at(2e-5)
    corner = torch.tensor([[0.0, 0.0]], dtype=torch.float64)
    slope = stepper.boundary_at(corner, 3 * DT, torch.float64)[0, jets.D2].numpy()
    assert slope == pytest.approx([0.0, np.cos(0.09) - 1, np.sin(0.09)], abs=1e-9)
    assert swing_problem(vertices, faces, (0, N - 1), DT, gravity, CONFIG).path.turns is None
    rigid = swing_problem(*rigid_sequence(), (0, N - 1), DT, gravity,
                          dataclasses.replace(CONFIG, turn="read"))
    assert np.abs(rigid.path.turns).max() < 1e-4  # the smoothed corners: 1e-4 m off
    b_true = 2e-5
    start = p.start(stepper)
    states = record(stepper, start.displacement, start.velocity)
    clean = torch.stack([observe(stepper, p.data.xi, states[k].displacement, states[k].time)
                         for k in p.data.steps])
    fit = fit_trajectory(p.stepper_at, TrajectoryData(p.data.xi, p.data.steps, clean, 1e-4),
                         2 * b_true, TrajectoryFitConfig(max_iterations=12, tolerance=1e-9),
                         initial=p.start)
    assert fit.value == pytest.approx(b_true, rel=1e-5) and fit.gradient_gap < 1e-8
    with pytest.raises(ValueError, match="turn must be none or read"):
        SwingConfig(turn="fitted")
