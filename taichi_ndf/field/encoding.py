"""Jets of the network inputs: normalised surface coordinates, periodic embedding, conditioning.

The network sees, in order: per coordinate ξ^α either n = 2(ξ^α - lo)/(hi - lo) - 1 or, if
periodic, (cos θ, sin θ) with θ = 2π(ξ^α - lo)/(hi - lo); then each conditioning input mapped
from its range to [-1, 1]. Each input depends on at most one coordinate, so its only
non-zero derivative channels are d/dξ^α and (periodic only) d²/dξ^α².
"""

from __future__ import annotations

import math

import torch

from taichi_ndf.field.config import FieldConfig
from taichi_ndf.jets import D1, D2, D11, D22, VALUE

_FIRST = (D1, D2)
_SECOND = (D11, D22)


def input_jets(
    config: FieldConfig, xi: torch.Tensor, conditioning: torch.Tensor | None, channels: int
) -> torch.Tensor:
    """Jets of the network inputs, channel-major: shape (channels, N, config.in_dim).

    xi: surface coordinates, shape (N, 2). conditioning: shape (N, k) or None when k = 0.
    channels: 1 (value), 3 (value and first derivatives) or 6 (full jets).
    """
    n = xi.shape[0]
    out = xi.new_zeros(channels, n, config.in_dim)
    col = 0
    for alpha in range(2):
        lo, hi = config.domain[alpha]
        x = xi[:, alpha]
        if config.periodic[alpha]:
            k = 2.0 * math.pi / (hi - lo)
            theta = (x - lo) * k
            cos, sin = torch.cos(theta), torch.sin(theta)
            out[VALUE, :, col] = cos
            out[VALUE, :, col + 1] = sin
            if channels > 1:
                out[_FIRST[alpha], :, col] = -k * sin
                out[_FIRST[alpha], :, col + 1] = k * cos
            if channels > 3:
                out[_SECOND[alpha], :, col] = -k * k * cos
                out[_SECOND[alpha], :, col + 1] = -k * k * sin
            col += 2
        else:
            k = 2.0 / (hi - lo)
            out[VALUE, :, col] = (x - lo) * k - 1.0
            if channels > 1:
                out[_FIRST[alpha], :, col] = k
            col += 1
    for i, (lo, hi) in enumerate(config.conditioning):
        out[VALUE, :, col] = (conditioning[:, i] - lo) * (2.0 / (hi - lo)) - 1.0
        col += 1
    return out
