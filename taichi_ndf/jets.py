"""Jets: a function's value with its first and second derivatives at sample points.

A jet tensor has shape (N, 6, C): N samples, the 6 channels below, C components. Derivatives
are taken with respect to the physical surface coordinates ξ = (ξ¹, ξ²).
"""

from __future__ import annotations

import torch

VALUE, D1, D2, D11, D12, D22 = range(6)
CHANNELS = 6
CHANNEL_NAMES = ("value", "d1", "d2", "d11", "d12", "d22")


def product(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Jet of the pointwise product a·b (Leibniz rule), shapes broadcast over (N, 6, C)."""
    a0, a1, a2, a11, a12, a22 = a.unbind(1)
    b0, b1, b2, b11, b12, b22 = b.unbind(1)
    return torch.stack(
        (
            a0 * b0,
            a1 * b0 + a0 * b1,
            a2 * b0 + a0 * b2,
            a11 * b0 + 2 * a1 * b1 + a0 * b11,
            a12 * b0 + a1 * b2 + a2 * b1 + a0 * b12,
            a22 * b0 + 2 * a2 * b2 + a0 * b22,
        ),
        dim=1,
    )


def product_adjoint(a: torch.Tensor, grad: torch.Tensor) -> torch.Tensor:
    """Gradient with respect to b of <grad, product(a, b)> for fixed a."""
    a0, a1, a2, a11, a12, a22 = a.unbind(1)
    g0, g1, g2, g11, g12, g22 = grad.unbind(1)
    return torch.stack(
        (
            a0 * g0 + a1 * g1 + a2 * g2 + a11 * g11 + a12 * g12 + a22 * g22,
            a0 * g1 + 2 * a1 * g11 + a2 * g12,
            a0 * g2 + a1 * g12 + 2 * a2 * g22,
            a0 * g11,
            a0 * g12,
            a0 * g22,
        ),
        dim=1,
    )


def constant(values: torch.Tensor) -> torch.Tensor:
    """Jet of a function constant in ξ: values (N, C) -> (N, 6, C)."""
    out = values.new_zeros(values.shape[0], CHANNELS, values.shape[1])
    out[:, VALUE] = values
    return out
