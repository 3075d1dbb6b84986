"""The spline prior's inertia (`SplinePriorConfig.frame_interval`): the incremental potential's
½ λ ρ_A/Δt² ‖u − û‖²_M towards the constant-velocity prediction of the coefficients, its value
against the sheet's mass, its coefficient gradient and assembled Hessian against central
differences, and what it does to a frame fit."""

import dataclasses

import numpy as np
import pytest
import torch
from test_sft_reconstruct import bent_pair, exact_tracks

import inverse.sft.spline_prior as spline_prior
from inverse.sft.frame_fits import reconstruct_sequence
from inverse.sft.reconstruct import FrameReconstructor
from inverse.sft.sequential import reconstruct_frames
from inverse.sft.settings import SplinePriorConfig
from inverse.sft.synth import default_camera
from taichi_ndf.objective import Objective

DT = 1.0 / 30.0
CONFIG = SplinePriorConfig(span_edges=2.0, max_iterations=3)
MINIMISE = spline_prior.minimise  # unpatched


def sheet_area(template) -> float:
    corners = template.vertices[template.faces]
    return 0.5 * float(np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0],
                                               corners[:, 2] - corners[:, 0]), axis=1).sum())


def captured_frame(monkeypatch, config):
    """The (linearisation, potential, start) of the last frame's Newton solve, and the fit."""
    camera = default_camera()
    template, bent = bent_pair()
    shapes = [template.vertices, 0.5 * (template.vertices + bent), bent]
    tracks = [exact_tracks(template, v, camera) for v in shapes]
    seen = []

    def capture(linearisation, potential, start, newton):
        seen.append((linearisation, potential, start.clone()))
        return MINIMISE(linearisation, potential, start, newton)

    monkeypatch.setattr(spline_prior, "minimise", capture)
    fit = FrameReconstructor(template, config=config)
    result = reconstruct_frames(template, camera, tracks, fit)
    return seen, fit, template, result


def energy(linearisation, potential, coefficients) -> float:
    """The potential's value at spline coefficients (n, 3)."""
    assembly = linearisation.assembly
    return potential(assembly.samples, assembly.displacement(coefficients), False).total


def test_config_checks_the_frame_interval():
    with pytest.raises(ValueError, match="frame_interval"):
        SplinePriorConfig(frame_interval=0.0)
    with pytest.raises(ValueError, match="frame_interval"):
        SplinePriorConfig(frame_interval=-0.1)
    with pytest.raises(ValueError, match="physics_weight"):
        SplinePriorConfig(frame_interval=DT, physics_weight=0.0)


def test_inertia_value_is_the_sheets_mass_times_the_gap(monkeypatch):
    """A uniform shift δ of every coefficient (B-splines sum to 1: u shifts by δ everywhere)
    from the prediction 2 C_{t−1} − C_{t−2} costs ½ λ ρ_A A |δ|² / Δt² (A the sheet's area)
    in the frame's potential; the prediction itself costs nothing; without frame_interval
    there is no such term."""
    seen, fit, template, _ = captured_frame(
        monkeypatch, dataclasses.replace(CONFIG, frame_interval=DT))
    lin, potential, start = seen[-1]
    # The last frame starts from C_{t−1}, the frame before it from C_{t−2}.
    predicted = 2.0 * start - seen[-2][2]
    lam = CONFIG.physics_weight / fit.energy_reference
    objective = potential.objective
    inertia = [t for t in objective.extra if isinstance(t, spline_prior.InertiaTerm)]
    assert len(inertia) == 1
    others = Objective(objective.shell, tuple(t for t in objective.extra
                                              if t is not inertia[0])).potential(1.0)
    delta = torch.tensor([0.004, -0.002, 0.003], dtype=torch.float64)
    area = sheet_area(template)
    for c in (predicted, predicted + delta):
        extra = energy(lin, potential, c) - energy(lin, others, c)
        gap = float((c - predicted)[0].norm() ** 2)
        expected = 0.5 * lam * fit.frame_field.areal_density * area * gap / DT**2
        assert extra == pytest.approx(expected, rel=1e-6, abs=1e-9)
    assert extra > 0
    plain, _, _, _ = captured_frame(monkeypatch, CONFIG)
    assert not any(isinstance(t, spline_prior.InertiaTerm)
                   for t in plain[-1][1].objective.extra)


def test_inertia_gradient_and_hessian_match_central_differences(monkeypatch):
    seen, _, _, _ = captured_frame(monkeypatch, dataclasses.replace(CONFIG, frame_interval=DT))
    lin, potential, start = seen[-1]
    rng = np.random.default_rng(0)
    c = start + torch.from_numpy(rng.normal(0, 1e-3, start.shape))
    assembly = lin.assembly
    inertia = next(t for t in potential.objective.extra
                   if isinstance(t, spline_prior.InertiaTerm))

    def value_and_grad(coefficients):
        u = assembly.displacement(coefficients)
        v, g = inertia.evaluate(assembly.samples, u, grad=True)
        return v, assembly.gradient(g)

    _, grad = value_and_grad(c)
    step = 1e-6
    hessian = assembly.hessian(inertia.hessian_blocks(
        assembly.samples, assembly.displacement(c)).reshape(-1, 18, 18)).toarray()
    for k in rng.choice(c.numel(), 8, replace=False):
        i, j = divmod(int(k), 3)
        plus, minus = c.clone(), c.clone()
        plus[i, j] += step
        minus[i, j] -= step
        (vp, gp), (vm, gm) = value_and_grad(plus), value_and_grad(minus)
        assert grad[i, j].item() == pytest.approx((vp - vm) / (2 * step), rel=1e-5, abs=1e-8)
        column = ((gp - gm) / (2 * step)).reshape(-1).numpy()
        np.testing.assert_allclose(hessian[:, k], column, rtol=1e-5,
                                   atol=1e-6 * np.abs(hessian).max())


def test_strong_inertia_holds_the_constant_velocity_prediction():
    """With a tiny Δt frame 1 (prediction: the template, no velocity yet) stays at the template
    whatever its tracks show; without inertia the fit follows the tracks."""
    camera = default_camera()
    template, bent = bent_pair()
    tracks = [exact_tracks(template, v, camera) for v in (template.vertices, bent)]
    free = reconstruct_sequence(template, camera, tracks, config=CONFIG).vertices[1]
    held = reconstruct_sequence(template, camera, tracks, config=dataclasses.replace(
        CONFIG, frame_interval=1e-5)).vertices[1]
    moved = np.abs(bent - template.vertices).max()
    assert np.abs(free - template.vertices).max() > 0.5 * moved
    assert np.abs(held - template.vertices).max() < 0.05 * moved


def test_inertia_part_is_reported_and_small_at_constant_velocity():
    """A translating sheet: frame 2 meets the constant-velocity prediction when the sheet
    keeps its velocity (positions 0, d, 2d), not when it stops (0, d, d); the reported
    inertia part says so."""
    camera = default_camera()
    template, _ = bent_pair()
    d = np.array([0.004, -0.003, 0.002])
    parts = {}
    for name, steps in (("keeps", (0, 1, 2)), ("stops", (0, 1, 1))):
        tracks = [exact_tracks(template, template.vertices + k * d, camera) for k in steps]
        result = reconstruct_sequence(template, camera, tracks, config=dataclasses.replace(
            CONFIG, frame_interval=0.2))
        parts[name] = [result.losses[i]["inertia"] for i in (1, 2)]
    assert parts["keeps"][0] > 0
    assert parts["keeps"][0] == pytest.approx(parts["stops"][0])  # the same frame 1
    assert parts["keeps"][1] < 0.05 * parts["stops"][1], parts


def test_cli_frame_interval_reaches_the_settings_and_refuses_bad_values(tmp_path, capsys):
    from inverse.cli import sft as sft_cli
    from inverse.cli.sft_run import method_config

    args = sft_cli.build_parser().parse_args(
        ["--capture", str(tmp_path), "--out", str(tmp_path / "o"), "--frame-interval", "0.04"])
    assert method_config(args).frame_interval == 0.04
    args = sft_cli.build_parser().parse_args(["--capture", str(tmp_path), "--out", "o"])
    assert method_config(args).frame_interval is None
    with pytest.raises(SystemExit) as bad:
        sft_cli.build_parser().parse_args(["--capture", "x", "--out", "o",
                                           "--frame-interval", "0"])
    assert bad.value.code == 2 and "--frame-interval" in capsys.readouterr().err
    status = sft_cli.main(["--capture", str(tmp_path), "--out", str(tmp_path / "o"),
                           "--field", "siren", "--frame-interval", "0.04"])
    assert status == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--frame-interval" in err
