"""Adam: agreement with torch.optim.Adam, schedules, clipping, state round trip."""

import math

import pytest
import torch

from taichi_ndf.problem.optim import Adam, AdamConfig

F64 = torch.float64
SHAPES = [(4, 3), (4,), (2, 4)]


def make_problem(seed):
    g = torch.Generator().manual_seed(seed)
    params = [torch.randn(s, generator=g, dtype=F64) for s in SHAPES]
    grads = [torch.zeros(s, dtype=F64) for s in SHAPES]
    return params, grads, g


def fill_gradients(grads, g):
    for t in grads:
        t.copy_(torch.randn(t.shape, generator=g, dtype=F64))


def test_matches_torch_adam():
    params, grads, g = make_problem(0)
    reference = [p.clone().requires_grad_(True) for p in params]
    torch_adam = torch.optim.Adam(reference, lr=0.01, betas=(0.8, 0.99), eps=1e-6, foreach=False)
    ours = Adam(params, grads, config=AdamConfig(lr=0.01, betas=(0.8, 0.99), eps=1e-6))
    for _ in range(25):
        fill_gradients(grads, g)
        for r, grad in zip(reference, grads, strict=True):
            r.grad = grad.clone()
        ours.step()
        torch_adam.step()
    for p, r in zip(params, reference, strict=True):
        torch.testing.assert_close(p, r.detach(), rtol=1e-12, atol=1e-14)


def test_schedules():
    exponential = AdamConfig(lr=0.1, schedule="exponential", decay_rate=0.5, decay_steps=10)
    assert exponential.learning_rate(0) == 0.1
    assert math.isclose(exponential.learning_rate(10), 0.05)
    assert math.isclose(exponential.learning_rate(25), 0.1 * 0.5**2.5)
    cosine = AdamConfig(lr=0.1, schedule="cosine", total_steps=100, min_lr=0.01)
    assert cosine.learning_rate(0) == 0.1
    assert math.isclose(cosine.learning_rate(50), 0.055)
    assert math.isclose(cosine.learning_rate(100), 0.01)
    assert math.isclose(cosine.learning_rate(500), 0.01)
    params, grads, g = make_problem(1)
    adam = Adam(params, grads, config=exponential)
    fill_gradients(grads, g)
    used = [adam.step() for _ in range(11)]
    assert used[0] == 0.1 and math.isclose(used[10], 0.05)
    assert math.isclose(adam.learning_rate, exponential.learning_rate(11))


def test_gradient_clipping_scales_the_update_not_the_gradients():
    params, grads, g = make_problem(2)
    clipped = Adam(params, grads, config=AdamConfig(lr=0.01, grad_clip=0.5))
    scaled_params = [p.clone() for p in params]
    scaled_grads = [torch.zeros_like(t) for t in grads]
    plain = Adam(scaled_params, scaled_grads, config=AdamConfig(lr=0.01))
    for _ in range(5):
        fill_gradients(grads, g)
        before = [t.clone() for t in grads]
        norm = clipped.gradient_norm()
        assert norm > 0.5
        for s, t in zip(scaled_grads, grads, strict=True):
            s.copy_(t * (0.5 / norm))
        clipped.step()
        plain.step()
        assert all(torch.equal(a, b) for a, b in zip(grads, before, strict=True))
    for p, q in zip(params, scaled_params, strict=True):
        torch.testing.assert_close(p, q, rtol=1e-13, atol=1e-15)


def test_state_dict_round_trip_continues_identically():
    params, grads, g = make_problem(3)
    config = AdamConfig(lr=0.02, schedule="cosine", total_steps=20)
    adam = Adam(params, grads, config=config)
    for _ in range(5):
        fill_gradients(grads, g)
        adam.step()
    state = adam.state_dict()
    resumed_params = [p.clone() for p in params]
    resumed_grads = [torch.zeros_like(t) for t in grads]
    resumed = Adam(resumed_params, resumed_grads, config=config)
    resumed.load_state_dict(state)
    for _ in range(5):
        fill_gradients(grads, g)
        for r, t in zip(resumed_grads, grads, strict=True):
            r.copy_(t)
        adam.step()
        resumed.step()
    assert resumed.step_count == adam.step_count == 10
    assert all(torch.equal(p, q) for p, q in zip(params, resumed_params, strict=True))
    state["exp_avg"] = state["exp_avg"][:2]
    with pytest.raises(ValueError, match="optimiser state exp_avg"):
        resumed.load_state_dict(state)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"lr": 0.0}, "lr"),
        ({"betas": (0.9, 1.0)}, "betas"),
        ({"eps": 0.0}, "eps"),
        ({"schedule": "linear"}, "schedule"),
        ({"decay_rate": 1.5}, "decay_rate"),
        ({"decay_steps": 0}, "decay_steps"),
        ({"min_lr": 1.0}, "min_lr"),
        ({"grad_clip": -1.0}, "grad_clip"),
    ],
)
def test_config_rejects_bad_values(kwargs, message):
    with pytest.raises(ValueError, match=message):
        AdamConfig(**kwargs)


def test_lr_scale_scales_the_step_and_is_kept_in_the_state():
    params, grads, g = make_problem(5)
    fill_gradients(grads, g)
    start = [p.clone() for p in params]
    full = Adam([p.clone() for p in params], grads, config=AdamConfig(lr=0.02))
    halved = Adam(params, grads, config=AdamConfig(lr=0.02))
    halved.lr_scale = 0.5
    assert halved.learning_rate == pytest.approx(0.01)
    full.step()
    halved.step()
    for p0, p1, p2 in zip(start, full.parameters, halved.parameters, strict=True):
        torch.testing.assert_close(p2 - p0, 0.5 * (p1 - p0), rtol=1e-12, atol=0)
    state = halved.state_dict()
    assert state["lr_scale"] == 0.5
    restored = Adam([p.clone() for p in params], grads, config=AdamConfig(lr=0.02))
    restored.load_state_dict(state)
    assert restored.lr_scale == 0.5
    del state["lr_scale"]  # a checkpoint written before the backoff existed
    restored.load_state_dict(state)
    assert restored.lr_scale == 1.0
