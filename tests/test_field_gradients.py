"""Jets and weight gradients of the neural field against pure-torch autograd and finite
differences (float64), and the hand-written activation adjoint against Taichi's autodiff."""

import math

import pytest
import torch

from taichi_ndf.field import FieldConfig, NeuralField
from taichi_ndf.field.activation import _sine_jets, sine_jets, sine_jets_adjoint
from taichi_ndf.jets import CHANNEL_NAMES

F64 = torch.float64

CONFIGS = [
    pytest.param(FieldConfig(width=16, hidden_layers=1), 0, id="16x1"),
    pytest.param(FieldConfig(width=32, hidden_layers=3, output_scale=0.3), 1, id="32x3-scaled"),
    pytest.param(
        FieldConfig(
            width=24,
            hidden_layers=2,
            out_dim=2,
            domain=((0.0, 2 * math.pi), (-1.0, 0.5)),
            periodic=(True, False),
            conditioning=((0.0, 2.0),),
        ),
        2,
        id="24x2-periodic1-cond1",
    ),
    pytest.param(
        FieldConfig(
            width=20,
            hidden_layers=4,
            omega0=12.0,
            domain=((-0.5, 0.5), (1.0, 3.0)),
            periodic=(True, True),
            conditioning=((-1.0, 1.0), (0.0, 1.0)),
        ),
        3,
        id="20x4-periodic2-cond2",
    ),
]


def samples(config: FieldConfig, n: int, seed: int):
    g = torch.Generator().manual_seed(100 + seed)
    xi = torch.stack(
        [lo + (hi - lo) * torch.rand(n, generator=g, dtype=F64) for lo, hi in config.domain], 1
    )
    if not config.conditioning:
        return xi, None
    cond = torch.stack(
        [lo + (hi - lo) * torch.rand(n, generator=g, dtype=F64) for lo, hi in config.conditioning],
        1,
    )
    return xi, cond


def reference_forward(config, params, xi, cond):
    """u(ξ, c) written directly in torch, differentiable by autograd."""
    inputs = []
    for alpha in range(2):
        lo, hi = config.domain[alpha]
        x = xi[:, alpha]
        if config.periodic[alpha]:
            theta = 2 * math.pi * (x - lo) / (hi - lo)
            inputs += [torch.cos(theta), torch.sin(theta)]
        else:
            inputs.append(2 * (x - lo) / (hi - lo) - 1)
    for i, (lo, hi) in enumerate(config.conditioning):
        inputs.append(2 * (cond[:, i] - lo) / (hi - lo) - 1)
    h = torch.stack(inputs, 1)
    for layer in range(config.hidden_layers):
        w, b = params[2 * layer], params[2 * layer + 1]
        h = torch.sin(config.omega0 * (h @ w.T + b))
    return config.output_scale * (h @ params[-2].T + params[-1])


def reference_jets(config, params, xi, cond):
    """Jets (N, 6, out) by nested autograd, differentiable w.r.t. params."""
    x = xi.clone().requires_grad_(True)
    u = reference_forward(config, params, x, cond)
    components = []
    for j in range(config.out_dim):
        (du,) = torch.autograd.grad(u[:, j].sum(), x, create_graph=True)
        (d1u,) = torch.autograd.grad(du[:, 0].sum(), x, create_graph=True)
        (d2u,) = torch.autograd.grad(du[:, 1].sum(), x, create_graph=True)
        components.append(
            torch.stack([u[:, j], du[:, 0], du[:, 1], d1u[:, 0], d1u[:, 1], d2u[:, 1]], 1)
        )
    return torch.stack(components, 2)


def loss_weights(shape, seed):
    g = torch.Generator().manual_seed(seed)
    return torch.randn(shape, generator=g, dtype=F64), torch.rand(shape, generator=g, dtype=F64)


def loss(jets, linear, quadratic):
    """A non-trivial loss of all 18 channels: Σ K·y + ½ Σ M·y²."""
    return (linear * jets).sum() + 0.5 * (quadratic * jets * jets).sum()


def max_relative(a, b):
    return ((a - b).abs().max() / b.abs().max()).item()


@pytest.mark.parametrize(("config", "seed"), CONFIGS)
def test_jets_match_nested_autograd(config, seed):
    field = NeuralField(config, seed=seed)
    xi, cond = samples(config, 40, seed)
    ours = field.jets(xi, cond)
    params = [p.clone() for p in field.parameters]
    expected = reference_jets(config, params, xi, cond).detach()
    for channel, name in enumerate(CHANNEL_NAMES):
        error = max_relative(ours[:, channel], expected[:, channel])
        assert error <= 1e-9, f"channel {name}: relative error {error:.2e}"


@pytest.mark.parametrize(("config", "seed"), CONFIGS)
def test_weight_gradients_match_torch(config, seed):
    field = NeuralField(config, seed=seed)
    xi, cond = samples(config, 30, seed)
    linear, quadratic = loss_weights((30, 6, config.out_dim), seed)
    jets = field.jets(xi, cond)
    field.backward(linear + quadratic * jets)

    params = [p.clone().requires_grad_(True) for p in field.parameters]
    expected = torch.autograd.grad(
        loss(reference_jets(config, params, xi, cond), linear, quadratic), params
    )
    for name, ours, ref in zip(field.parameter_names, field.gradients, expected, strict=True):
        error = max_relative(ours, ref)
        assert error <= 1e-8, f"{name}: relative error {error:.2e}"


@pytest.mark.parametrize(("config", "seed"), [CONFIGS[1], CONFIGS[3]])
def test_weight_gradients_match_central_differences(config, seed):
    field = NeuralField(config, seed=seed)
    xi, cond = samples(config, 25, seed)
    linear, quadratic = loss_weights((25, 6, config.out_dim), seed)
    field.backward(linear + quadratic * field.jets(xi, cond))
    gradient = field.get_flat_gradient()
    base = field.get_flat()
    g = torch.Generator().manual_seed(seed)
    for _ in range(3):
        direction = torch.randn(base.shape, generator=g, dtype=F64)
        direction /= direction.norm()
        step = 1e-6
        field.set_flat(base + step * direction)
        plus = loss(field.jets(xi, cond), linear, quadratic)
        field.set_flat(base - step * direction)
        minus = loss(field.jets(xi, cond), linear, quadratic)
        field.set_flat(base)
        numeric = (plus - minus).item() / (2 * step)
        analytic = (gradient @ direction).item()
        assert abs(numeric - analytic) <= 1e-6 * gradient.norm().item(), (numeric, analytic)


def test_activation_adjoint_matches_taichi_autodiff():
    """The hand-written adjoint equals Taichi's reverse-mode autodiff of the forward kernel."""
    g = torch.Generator().manual_seed(7)
    channels, n, width = 6, 7, 5
    m = n * width
    pre = (3 * torch.randn(channels * m, generator=g, dtype=F64)).requires_grad_(True)
    sin = torch.sin(pre.detach()[:m]).requires_grad_(True)
    cos = torch.cos(pre.detach()[:m]).requires_grad_(True)
    post = torch.zeros(channels * m, dtype=F64, requires_grad=True)
    _sine_jets(pre, sin, cos, post)
    upstream = torch.randn(channels * m, generator=g, dtype=F64)
    pre.grad, sin.grad, cos.grad = (torch.zeros_like(t) for t in (pre, sin, cos))
    post.grad = upstream.clone()
    _sine_jets.grad(pre, sin, cos, post)
    # The kernel sees sin and cos as inputs; chain them to a₀ (post[0] = sin is set by torch).
    expected = pre.grad.clone()
    expected[:m] += (upstream[:m] + sin.grad) * cos.detach() - cos.grad * sin.detach()

    pre3 = pre.detach().view(channels, n, width)
    post3 = torch.empty_like(pre3)
    cos3 = torch.empty(n, width, dtype=F64)
    sine_jets(pre3, post3, cos3)
    assert torch.equal(post3.view(-1)[m:], post.detach()[m:])
    ours = upstream.clone().view(channels, n, width)
    sine_jets_adjoint(pre3, post3, cos3, ours)
    assert max_relative(ours.view(-1), expected) <= 1e-14


def test_float32_agrees_with_float64():
    config = CONFIGS[3].values[0]
    f64 = NeuralField(config, seed=3)
    f32 = NeuralField(config, seed=3, dtype=torch.float32)
    xi, cond = samples(config, 200, 3)
    linear, quadratic = loss_weights((200, 6, config.out_dim), 3)
    j64, j32 = f64.jets(xi, cond), f32.jets(xi.float(), cond.float())
    assert j32.dtype == torch.float32
    for channel, name in enumerate(CHANNEL_NAMES):
        error = max_relative(j32[:, channel].double(), j64[:, channel])
        assert error <= 3e-5, f"channel {name}: float32 relative error {error:.2e}"
    f64.backward(linear + quadratic * j64)
    f32.backward((linear + quadratic * j64).float())
    for name, a, b in zip(f64.parameter_names, f32.gradients, f64.gradients, strict=True):
        error = max_relative(a.double(), b)
        assert error <= 3e-5, f"{name}: float32 relative error {error:.2e}"
