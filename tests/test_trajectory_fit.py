"""Bending stiffness fitted to observed motion (`inverse.material.trajectory_fit`) and
`ndf-fit-material --trajectory`: recovery, a run's own probes as observations, refusals."""

import json

import pytest
import torch

import taichi_ndf
from inverse.cli.fit_material import main
from inverse.material.trajectory_fit import (
    TrajectoryData,
    TrajectoryFitConfig,
    fit_trajectory,
    observe,
)
from taichi_ndf.scene.reader import load_scene
from taichi_ndf.solve.dynamics import TimeStepper
from taichi_ndf.solve.dynamics_adjoint import record

B_TRUE = 100.0
# A clamped strip falling under gravity (the benchmark's, 4 × 1 spans, 4 Newmark steps of 0.1 s:
# a large rotation, tip z −1.08 m at 0.4 s); D as E = 1.2e6 Pa, h = 0.1 m, ν = 0.3.
STRIP = """
name = "strip"
[geometry]
type = "plane"
bounds = [[0.0, 4.0], [0.0, 1.0]]
[material]
type = "linear"
membrane_stiffness = 131868.13186813187
bending_stiffness = {bending}
poisson_ratio = 0.3
areal_density = 1.0
[boundary]
length = 1.0
[[boundary.constraint]]
type = "clamped_edge"
edge = "xi1_min"
[loads]
gravity = [0.0, 0.0, -9.81]
[field]
type = "spline"
spans = [4, 1]
[training]
method = "newton"
[dynamics]
integrator = "newmark"
dt = 0.1
duration = 0.4
{extra}
[[probes]]
name = "tip"
xi = [4.0, 0.5]
[[probes]]
name = "middle"
xi = [2.0, 0.5]
[[probes]]
name = "corner"
xi = [4.0, 0.0]
[output]
resolution = [8, 4]
"""
XI = torch.tensor([[4.0, 0.5], [2.0, 0.5], [4.0, 0.0]], dtype=torch.float64)


def _scene(tmp_path, bending=B_TRUE, extra="", dynamic=True, name="strip.toml"):
    text = STRIP.format(bending=bending, extra=extra)
    if not dynamic:
        text = text.replace("[dynamics]\nintegrator = \"newmark\"\ndt = 0.1\nduration = 0.4\n",
                            "")
    path = tmp_path / name
    path.write_text(text)
    return path


def _stepper_at(scene):
    def stepper_at(value):
        model = scene.model
        material = model.material.with_stiffness(bending_stiffness=value)
        return TimeStepper(model.with_material(material), scene.field, scene.dynamics)
    return stepper_at


def _clean(scene, steps):
    """The displacements (F, 3, 3) [m] of XI at `steps` of the run at B_TRUE."""
    stepper = _stepper_at(scene)(B_TRUE)
    states = record(stepper)
    return torch.stack([observe(stepper, XI, states[k].displacement).detach() for k in steps])


def test_fit_recovers_bending_stiffness_with_an_error_bar(tmp_path):
    taichi_ndf.init(arch="cpu", precision="f64", seed=0)
    scene = load_scene(_scene(tmp_path))
    steps = (1, 2, 3, 4)
    clean = _clean(scene, steps)
    sigma = 0.01 * float(clean.pow(2).mean().sqrt())
    noise = torch.randn(clean.shape, generator=torch.Generator().manual_seed(0),
                        dtype=torch.float64)
    data = TrajectoryData(XI, steps, clean + sigma * noise, sigma)
    fit = fit_trajectory(_stepper_at(scene), data, 1.5 * B_TRUE)
    assert fit.converged and fit.iterations <= 8
    assert abs(fit.value / B_TRUE - 1) < 0.02
    assert abs(fit.value - B_TRUE) <= 2 * fit.standard_error  # the s.e. covers the truth
    assert fit.noise == sigma and fit.noise_source == "stated"
    assert fit.goodness.explains and fit.goodness.dof == clean.numel() - 1
    assert fit.gradient_gap < 1e-8  # the adjoint's ∇J is the tangent's
    # σ unknown: estimated from the residuals, the same estimate, the test not claimed
    free = fit_trajectory(_stepper_at(scene), TrajectoryData(XI, steps, data.displacements),
                          fit.value)
    assert abs(free.value - fit.value) < 1e-6 * B_TRUE
    assert "not a test" in free.noise_source
    assert free.noise == pytest.approx(float((free.residuals**2).sum()
                                             / (len(free.residuals) - 1)) ** 0.5)
    # stopped once a step is below a tenth of the s.e.: fewer runs, the same answer within it
    early = fit_trajectory(_stepper_at(scene), data, 1.5 * B_TRUE,
                           TrajectoryFitConfig(error_tolerance=0.1))
    assert early.converged and early.iterations < fit.iterations
    assert abs(early.value - fit.value) < 0.1 * fit.standard_error


def test_trajectory_data_is_checked():
    xi = torch.zeros(2, 2, dtype=torch.float64)
    with pytest.raises(ValueError, match="steps must be increasing"):
        TrajectoryData(xi, (2, 1), torch.zeros(2, 2, 3, dtype=torch.float64))
    with pytest.raises(ValueError, match=r"\(F, P, 3\)"):
        TrajectoryData(xi, (1, 2), torch.zeros(2, 3, 3, dtype=torch.float64))
    with pytest.raises(ValueError, match="noise"):
        TrajectoryData(xi, (1,), torch.zeros(1, 2, 3, dtype=torch.float64), 0.0)


def _fit(capsys, scene, obs, out, *extra):
    code = main([str(scene), "--trajectory", str(obs), "--estimate", "bending", "--out",
                 str(out), *extra])
    return code, capsys.readouterr()


def _observations(tmp_path, document):
    path = tmp_path / "obs.json"
    path.write_text(json.dumps(document))
    return path


GOOD = {"points": ["tip", [2.0, 0.5]], "times": [0.2, 0.4],
        "displacements": [[[0.0, 0.0, -0.2], [0.0, 0.0, -0.05]]] * 2}


@pytest.mark.parametrize(("change", "message"), [
    ({"times": [0.2, 0.45]}, "time 0.45 s is not a step"),
    ({"times": [0.2, 0.5]}, "time 0.5 s is not a step"),
    ({"times": [0.4, 0.2]}, "steps must be increasing"),
    ({"points": ["tip", "elbow"]}, "unknown probe 'elbow'"),
    ({"displacements": [[[0.0, 0.0, -0.2]]]}, "must be finite, one [x, y, z]"),
])
def test_bad_observations_exit_2_in_one_line(tmp_path, capsys, change, message):
    taichi_ndf.init(arch="cpu", precision="f64", seed=0)
    obs = _observations(tmp_path, {**GOOD, **change})
    code, streams = _fit(capsys, _scene(tmp_path), obs, tmp_path / "out")
    assert code == 2 and message in streams.err and len(streams.err.splitlines()) == 1
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(("extra", "dynamic", "message"), [
    ("", False, "has no [dynamics] section"),
    ("[dynamics.wind]\nvelocity = [2.0, 0.0, 2.0]", True, "wind is not supported"),
    ("stiffness_damping = 0.01", True, "stiffness-proportional damping"),
    ("[[obstacles]]\ntype = \"sphere\"\nname = \"ball\"\ncentre = [2.0, 0.5, -3.0]\n"
     "radius = 0.5", True, "contact ([[obstacles]] or [self_contact]) is not supported"),
])
def test_scenes_the_adjoint_cannot_follow_exit_2(tmp_path, capsys, extra, dynamic, message):
    taichi_ndf.init(arch="cpu", precision="f64", seed=0)
    obs = _observations(tmp_path, GOOD)
    code, streams = _fit(capsys, _scene(tmp_path, extra=extra, dynamic=dynamic), obs,
                         tmp_path / "out")
    assert code == 2 and message in streams.err and len(streams.err.splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_shape_options_are_refused_with_a_trajectory(tmp_path, capsys):
    obs = _observations(tmp_path, GOOD)
    with pytest.raises(SystemExit) as exit_:
        main([str(_scene(tmp_path)), "--trajectory", str(obs), "--estimate", "bending",
              "--method", "residual", "--point-cloud", "--out", str(tmp_path / "out")])
    assert exit_.value.code == 2
    assert "--method, --point-cloud: for --observed shapes" in capsys.readouterr().err


def test_one_stiffness_unknown_only(tmp_path, capsys):
    obs = _observations(tmp_path, GOOD)
    code = main([str(_scene(tmp_path)), "--trajectory", str(obs), "--estimate",
                 "bending,density", "--out", str(tmp_path / "out")])
    assert code == 2 and "one stiffness parameter" in capsys.readouterr().err


def test_fit_to_a_runs_own_probes_end_to_end(tmp_path, capsys):
    """ndf-sim's result.json of the strip at B = 100 N·m read as observations (its probes at
    every step), fitted from a scene that says B = 150 N·m (10 s wall at load 11)."""
    from taichi_ndf.cli.sim import main as sim

    truth = _scene(tmp_path, name="truth.toml")
    assert sim([str(truth), "--no-pictures", "--out", str(tmp_path / "run")]) == 0
    code, streams = _fit(capsys, _scene(tmp_path, bending=1.5 * B_TRUE, name="start.toml"),
                         tmp_path / "run" / "result.json", tmp_path / "fit")
    assert code == 0, streams.err
    document = json.loads((tmp_path / "fit" / "estimate.json").read_text())
    entry = document["parameters"]["bending_stiffness"]
    assert document["method"] == "trajectory" and entry["determined"]
    assert entry["value"] == pytest.approx(B_TRUE, rel=1e-6)  # the same grid and steps
    assert document["trajectory"]["steps"] == [1, 2, 3, 4]
    assert "not a test" in document["goodness_of_fit"]["noise_source"]
    assert "bending_stiffness = 100" in streams.out


def test_the_tool_fits_a_scene_whose_clamped_end_moves(tmp_path, capsys):
    """`--trajectory` on a scene with a `[dynamics.motion]` (the clamped end lifted by a
    sinusoid): the observations are the run's own displacements at B_TRUE (the boundary's
    part included); the fit from the scene's 1.5 B_TRUE returns B_TRUE."""
    taichi_ndf.init(arch="cpu", precision="f64", seed=0)
    extra = "[dynamics.motion]\namplitude = 1.0\nfrequency = 1.25"
    path = _scene(tmp_path, bending=1.5 * B_TRUE, extra=extra)
    path.write_text(path.read_text().replace(
        'edge = "xi1_min"', 'edge = "xi1_min"\ndisplacement = [0.0, 0.1, 0.3]'))
    scene = load_scene(path)
    stepper = _stepper_at(scene)(B_TRUE)
    states = record(stepper)
    values = [observe(stepper, XI, states[k].displacement, states[k].time).tolist()
              for k in (1, 2, 3, 4)]
    free = observe(stepper, XI, states[1].displacement)  # J C alone
    assert abs(values[0][0][2] - float(free[0, 2])) > 0.1  # the end's lift is observed
    obs = _observations(tmp_path, {"points": ["tip", "middle", "corner"],
                                   "times": [0.1, 0.2, 0.3, 0.4], "displacements": values,
                                   "noise": 1e-3})
    code, streams = _fit(capsys, path, obs, tmp_path / "out")
    assert code == 0, streams.err
    estimate = json.loads((tmp_path / "out" / "estimate.json").read_text())
    assert estimate["trajectory"]["converged"]
    assert estimate["parameters"]["bending_stiffness"]["value"] == pytest.approx(B_TRUE,
                                                                                 rel=1e-6)
