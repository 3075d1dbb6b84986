"""Neural field: configuration, initialisation, determinism, evaluation mode, periodicity."""

import math

import pytest
import torch

from taichi_ndf.field import FieldConfig, NeuralField
from taichi_ndf.field.network import INITIAL_DISPLACEMENT_RMS

F64 = torch.float64


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"width": 0}, "width"),
        ({"hidden_layers": 2.5}, "hidden_layers"),
        ({"out_dim": -1}, "out_dim"),
        ({"omega0": 0.0}, "omega0"),
        ({"output_scale": float("nan")}, "output_scale"),
        ({"domain": ((0, 1), (2, 1))}, r"domain\[1\]"),
        ({"domain": ((0, 1),)}, "domain"),
        ({"periodic": (True,)}, "periodic"),
        ({"conditioning": ((0, 1), (1, 1))}, r"conditioning\[1\]"),
    ],
)
def test_config_rejects_bad_values(kwargs, message):
    with pytest.raises(ValueError, match=message):
        FieldConfig(**kwargs)


def test_config_dict_round_trip():
    config = FieldConfig(
        width=8, domain=((0, 2), (-1, 1)), periodic=(True, False), conditioning=((0, 5),)
    )
    assert config.in_dim == 4
    assert FieldConfig.from_dict(config.to_dict()) == config
    with pytest.raises(ValueError, match="unknown FieldConfig keys"):
        FieldConfig.from_dict({**config.to_dict(), "depth": 3})


def test_parameter_shapes_and_siren_init():
    config = FieldConfig(width=64, hidden_layers=3, conditioning=((0, 1),), output_scale=0.5)
    field = NeuralField(config, seed=0)
    shapes = [tuple(p.shape) for p in field.parameters]
    assert shapes == [(64, 3), (64,), (64, 64), (64,), (64, 64), (64,), (3, 64), (3,)]
    assert field.num_parameters == sum(math.prod(s) for s in shapes)
    assert all(p.dtype == F64 for p in field.parameters + field.gradients)
    w = field.parameters
    assert w[0].abs().max() <= 1 / 3
    assert w[2].abs().max() <= math.sqrt(6 / 64) / 30
    assert w[2].abs().max() > 0.9 * math.sqrt(6 / 64) / 30
    assert torch.all(w[-1] == 0)
    values = field.evaluate(torch.rand(2000, 2, dtype=F64), torch.rand(2000, 1, dtype=F64))
    rms = values.pow(2).mean().sqrt().item()
    assert 0.3 < rms / (INITIAL_DISPLACEMENT_RMS * config.output_scale) < 3


def test_same_seed_gives_identical_field_and_other_seed_differs():
    config = FieldConfig(width=16, hidden_layers=2)
    xi = torch.rand(30, 2, dtype=F64)
    a, b, c = (NeuralField(config, seed=s) for s in (5, 5, 6))
    assert all(torch.equal(p, q) for p, q in zip(a.parameters, b.parameters, strict=True))
    assert torch.equal(a.jets(xi), b.jets(xi))
    assert not torch.equal(a.parameters[0], c.parameters[0])


def test_evaluate_matches_jets_in_chunks():
    config = FieldConfig(width=16, hidden_layers=3, periodic=(False, True), conditioning=((0, 1),))
    field = NeuralField(config, seed=1)
    xi, cond = torch.rand(101, 2, dtype=F64), torch.rand(101, 1, dtype=F64)
    jets = field.jets(xi, cond)
    values, first = field.evaluate(xi, cond, derivatives=True, chunk=32)
    assert values.shape == (101, 3) and first.shape == (101, 2, 3)
    torch.testing.assert_close(values, jets[:, 0], rtol=1e-13, atol=0)
    torch.testing.assert_close(first, jets[:, 1:3], rtol=1e-13, atol=1e-16)
    # another chunk size may change the matrix products' summation order: rounding only
    torch.testing.assert_close(field.evaluate(xi, cond, chunk=7), values, rtol=1e-13,
                               atol=1e-16)


def test_evaluate_keeps_the_tape_of_the_last_jets_call():
    field = NeuralField(FieldConfig(width=8, hidden_layers=2), seed=2)
    xi = torch.rand(20, 2, dtype=F64)
    grad = torch.randn(20, 6, 3, dtype=F64)
    field.jets(xi)
    field.backward(grad)
    expected = [g.clone() for g in field.gradients]
    field.evaluate(torch.rand(50, 2, dtype=F64), derivatives=True)
    field.backward(grad)
    assert all(torch.equal(g, e) for g, e in zip(field.gradients, expected, strict=True))


def test_periodic_field_is_periodic_in_all_channels():
    config = FieldConfig(
        width=16, hidden_layers=2, domain=((0.0, 2 * math.pi), (0, 1)), periodic=(True, False)
    )
    field = NeuralField(config, seed=3)
    xi = torch.rand(10, 2, dtype=F64)
    shifted = xi.clone()
    shifted[:, 0] += 2 * math.pi
    a, b = field.jets(xi), field.jets(shifted)
    torch.testing.assert_close(a, b, rtol=1e-10, atol=1e-12)


def test_flat_parameters_round_trip():
    field = NeuralField(FieldConfig(width=8, hidden_layers=2), seed=0)
    flat = field.get_flat()
    assert flat.shape == (field.num_parameters,)
    field.set_flat(2 * flat)
    torch.testing.assert_close(field.get_flat(), 2 * flat, rtol=0, atol=0)
    with pytest.raises(ValueError, match="flat parameters must have shape"):
        field.set_flat(flat[:-1])


def test_state_dict_round_trip_and_mismatch():
    config = FieldConfig(width=8, hidden_layers=2)
    a, b = NeuralField(config, seed=0), NeuralField(config, seed=1)
    b.load_state_dict(a.state_dict())
    assert torch.equal(a.get_flat(), b.get_flat())
    state = NeuralField(FieldConfig(width=9, hidden_layers=2), seed=0).state_dict()
    with pytest.raises(
        ValueError, match=r"layer0.weight: shape \(9, 2\) given, field has \(8, 2\)"
    ):
        a.load_state_dict(state)


def test_input_validation():
    field = NeuralField(FieldConfig(width=8, hidden_layers=1, conditioning=((0, 1),)), seed=0)
    with pytest.raises(ValueError, match=r"xi must have shape \(N, 2\)"):
        field.jets(torch.zeros(5, 3, dtype=F64), torch.zeros(5, 1, dtype=F64))
    with pytest.raises(ValueError, match=r"conditioning must have shape \(5, 1\)"):
        field.jets(torch.zeros(5, 2, dtype=F64))
    with pytest.raises(RuntimeError, match="backward needs a preceding jets call"):
        field.backward(torch.zeros(5, 6, 3, dtype=F64))
    field.jets(torch.zeros(5, 2, dtype=F64), torch.zeros(5, 1, dtype=F64))
    with pytest.raises(ValueError, match=r"grad_jets must have shape \(5, 6, 3\)"):
        field.backward(torch.zeros(4, 6, 3, dtype=F64))
