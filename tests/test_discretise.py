"""One discretisation object per field type from one factory (`taichi_ndf.discretise`):
the classes implement the whole protocol, the factory is keyed on the field specification,
and what exists for one field type only (grids to refine, an output scale) is answered by
its class. The solves through it are covered end to end by test_simulation,
test_spline_scene and test_validation (the same Π as before the protocol, to all digits)."""

from __future__ import annotations

import inspect

import pytest
from test_cli import SMALL_NAPKIN, write_scene

from taichi_ndf.cli import sim, validate
from taichi_ndf.discretise import (
    DISCRETISATIONS,
    Discretisation,
    SirenDiscretisation,
    SplineDiscretisation,
    discretisation,
    of_scene,
)
from taichi_ndf.discretise.protocol import Solution
from taichi_ndf.field import FieldConfig, NeuralField
from taichi_ndf.problem.field_types import FIELD_TYPES, of_field, of_spec
from taichi_ndf.scene.field import READERS
from taichi_ndf.scene.reader import load_scene


@pytest.fixture
def scenes(tmp_path):
    path = write_scene(tmp_path, SMALL_NAPKIN.format(lr=1e-3))
    return load_scene(path), load_scene(path, field="spline")


def _protocol_methods() -> set[str]:
    return {name for name, member in vars(Discretisation).items()
            if inspect.isfunction(member) and not name.startswith("_")}


@pytest.mark.parametrize("kind", sorted(DISCRETISATIONS.values(), key=lambda k: k.name),
                         ids=lambda k: k.name)
def test_every_discretisation_implements_the_whole_protocol(kind):
    missing = {name for name in _protocol_methods() if not callable(getattr(kind, name, None))}
    assert not missing, f"{kind.__name__} lacks {sorted(missing)}"
    for name in _protocol_methods():  # the same keyword arguments as the protocol
        assert (inspect.signature(getattr(kind, name)).parameters.keys()
                == inspect.signature(getattr(Discretisation, name)).parameters.keys()), name
    assert kind.name in FIELD_TYPES and FIELD_TYPES[kind.name] is kind.field_type


def test_one_registry_of_field_types_for_every_layer():
    """Each field type of `FIELD_TYPES` has its [field] reader, its discretisation (keyed on
    its specification class) and a checkpoint tag that round-trips its field class."""
    assert set(READERS) == set(FIELD_TYPES)
    assert {kind.field_type.name for kind in DISCRETISATIONS.values()} == set(FIELD_TYPES)
    for spec, kind in DISCRETISATIONS.items():
        assert kind.field_type.spec is spec
    assert of_field(NeuralField(FieldConfig(width=8, hidden_layers=1))).name == "siren"
    with pytest.raises(TypeError, match="no field type of a dict"):
        of_spec({})


def test_the_factory_is_keyed_on_the_field_specification(scenes):
    siren, spline = scenes
    assert isinstance(of_scene(siren), SirenDiscretisation)
    assert isinstance(of_scene(spline), SplineDiscretisation)
    assert of_scene(spline).spec is spline.field and of_scene(siren).model is siren.model
    assert of_scene(spline).uses_newton(spline.solver)
    assert not of_scene(siren).uses_newton(siren.solver)  # SMALL_NAPKIN: Adam only
    with pytest.raises(TypeError, match="no discretisation of a dict"):
        discretisation({}, siren.model)


def test_refinement_exists_on_grids_only(scenes):
    siren, spline = scenes
    assert of_scene(spline).refined(3).spec.levels == 3
    assert of_scene(spline).refined(3).spec.config == spline.field.config
    with pytest.raises(ValueError, match="--refine must be >= 1"):
        of_scene(spline).refined(0)
    with pytest.raises(ValueError, match="--refine needs a spline field"):
        of_scene(siren).refined(3)


def test_a_linearised_unit_scales_a_siren_output_only(scenes):
    siren, spline = scenes
    scaled = of_scene(siren).with_displacement_unit(1e3)
    assert scaled.spec.output_scale == siren.field.output_scale * 1e3
    assert of_scene(spline).with_displacement_unit(1e3).spec is spline.field


def test_case_settings(scenes):
    siren, spline = scenes
    d, config = of_scene(siren).for_case(siren.solver, siren.quick_solver, quick=False,
                                         solver=None, iterations=3, seed=5, levels=3)
    assert config.iterations == 3 and config.seed == 5 and d.spec == siren.field
    d, config = of_scene(spline).for_case(spline.solver, spline.quick_solver, quick=True,
                                          solver=None, iterations=None, seed=5, levels=3)
    assert d.spec.levels == 1 and config == spline.solver
    with pytest.raises(ValueError, match="--iterations sets Adam"):
        of_scene(spline).for_case(spline.solver, spline.quick_solver, quick=False,
                                  solver=None, iterations=3, seed=None, levels=3)


def test_sizes_are_the_field_types_own(scenes, monkeypatch):
    siren, spline = scenes
    monkeypatch.setattr("taichi_ndf.problem.run_size.physical_memory", lambda: 1)
    with pytest.raises(ValueError, match="spline field: the finest grid"):
        of_scene(spline).check_size(spline.solver)
    with pytest.raises(ValueError, match="SIREN field 16 wide"):
        of_scene(siren).check_size(siren.solver, itemsize=8)


def test_a_solution_has_defaults_for_the_parts_one_field_type_lacks():
    solution = Solution(field=None, energy=0.0, iterations=0, wall_time=0.0, history=[],
                        probes={}, field_document={})
    assert solution.document == {} and solution.refinement is None
    assert solution.contact is None and solution.convergence == {}


def test_a_solver_can_be_written_against_the_protocol(scenes):
    """The displacement jets of the current parameters at the evaluation points are the
    linearisation's at the current parameters (a SIREN: no change of its output layer; a
    spline: its coefficients), before and after a solve."""
    import torch

    for scene in scenes:
        d = of_scene(scene)
        config = scene.quick_solver if d.name == "siren" else scene.solver
        d.start(config, seed=0)
        started = None
        for solved in (False, True):
            if solved:
                d.solve(config)
            samples = d.evaluation_points()
            u = d.displacement(samples.xi, 1.0)
            assert u.shape == (len(samples.xi), 6, 3)
            if solved:  # the solution's parameters, not those started from
                assert not torch.equal(u, started)
            started = u
            linear = d.linearisation(samples, 1.0)
            current = (torch.zeros(3, scene.field.width + 1, dtype=u.dtype)
                       if d.name == "siren" else d.field.coefficients)
            torch.testing.assert_close(linear.displacement(current), u, rtol=1e-10,
                                       atol=1e-12)


@pytest.mark.parametrize("tool", [sim, validate], ids=["ndf-sim", "ndf-validate"])
def test_the_tools_offer_every_field_type(tool):
    """`--field` lists its choices literally (so that --help imports neither torch nor
    Taichi): they must be the registry's."""
    (action,) = [a for a in tool.build_parser()._actions if "--field" in a.option_strings]
    assert tuple(action.choices) == tuple(FIELD_TYPES)


def test_the_siren_solvers_last_layer_newton_minimises_over_the_discretisations_linearisation(
        scenes):
    """The Newton phases of a SIREN run take the output layer's linearisation from the
    discretisation, at its evaluation points (the Newton samples); the field they reach is
    the one a solver building it itself reaches."""
    import dataclasses

    import torch

    from taichi_ndf.solve.solver import Solver

    scene = scenes[0]
    config = dataclasses.replace(scene.quick_solver, newton_iterations=2, newton_samples=64)
    d = of_scene(scene)
    asked = []
    own = d.linearisation
    d.linearisation = lambda samples, t: asked.append((samples, t)) or own(samples, t)
    d.start(config, seed=0)
    d.solve(config)
    assert asked and all(t == 1.0 for _, t in asked)
    assert all(s is d.evaluation_points() for s, _ in asked)  # no contact: the Newton samples
    field = NeuralField(d.field.config, seed=0)
    Solver(scene.model, field, config).run()
    for mine, theirs in zip(d.field.parameters, field.parameters, strict=True):
        torch.testing.assert_close(mine, theirs, rtol=0, atol=0)


def test_a_free_pin_without_probes_has_no_probes_to_evaluate():
    """A spline field with a free pin (its raw jets need at least one point) and no
    [[probes]]: no probe values, not a ValueError (the dynamic path asks at every frame)."""
    import tomllib
    from pathlib import Path

    from taichi_ndf.discretise import of_scene
    from taichi_ndf.scene.reader import parse_scene

    path = Path(__file__).resolve().parents[1] / "scenes" / "cloth_pendulum.toml"
    document = tomllib.loads(path.read_text())
    document.pop("probes")
    scene = parse_scene(document, base_dir=path.parent, path=path)
    assert not scene.model.probes
    spline = of_scene(scene)
    spline.start(scene.solver, seed=0)
    assert spline.probes(spline.field, 0.5) == {}
