"""The self-contact step test: a conservative continuous collision bound for pairs of points.

A line-search trial moves every self-contact point linearly from `start` to `end` (M, 3) [m]
(the field is affine in its parameters, so x(α) = x₀ + α Δx along the step). For a pair the
separation p(α) = p₀ + α v is linear too, and its smallest length over α ∈ [0, 1] has a
closed form (α* = clamp(−p₀·v / |v|², 0, 1)). Each point's gap to the rest of the sheet
(the smallest over the pairs that are not excluded: rest distance ≥ ρ) must stay, all along
the step, above (1 − s) × its gap at the start (s = `SelfContactConfig.step_fraction`): no
point closes its gap in one step, so no distance reaches the offset o, and no sample passes
through the other layer's sample lattice (`taichi_ndf.objective.self_contact`, resolution).
Per point rather than per pair: a layer sliding over another at a constant gap passes close
to points that were far at the start, and is allowed. Only what comes within the barrier's
reach o + ĝ is tested. Pairs are searched among the midpoints (x₀ + x₁)/2 within o + ĝ +
max |Δx|: a segment pair closer than o + ĝ has midpoints closer than that, so none is
missed, and every pair closer than o + ĝ at the start is among them (a point's start gap
taken over the pairs found is exact where it is below ĝ, else at least ĝ: conservative).
"""

from __future__ import annotations

import numpy as np
import torch

from taichi_ndf.contact.self_pairs import SelfContactConfig, candidate_pairs


def closest_along_step(p0: np.ndarray, v: np.ndarray) -> np.ndarray:
    """min over α ∈ [0, 1] of |p0 + α v| (P,) [m] for separations p0 (P, 3) moving by v."""
    vv = (v * v).sum(axis=1)
    alpha = np.where(vv > 0, -(p0 * v).sum(axis=1) / np.where(vv > 0, vv, 1.0), 0.0)
    alpha = np.clip(alpha, 0.0, 1.0)
    return np.linalg.norm(p0 + alpha[:, None] * v, axis=1)


def self_step_allowed(config: SelfContactConfig, rest: torch.Tensor, start: torch.Tensor,
                      end: torch.Tensor) -> bool:
    """Whether the step from `start` to `end` (M, 3) [m] of the self-contact points (rest
    positions `rest` (M, 3)) keeps every point's gap above (1 − s) × its start gap (module
    docstring)."""
    x0 = start.detach().cpu().numpy()
    x1 = end.detach().cpu().numpy()
    move = x1 - x0
    reach = config.offset + config.activation
    largest = float(np.linalg.norm(move, axis=1).max(initial=0.0))
    pairs = candidate_pairs(0.5 * (x0 + x1), reach + largest, rest.detach().cpu().numpy(),
                            config.exclusion)
    if not len(pairs):
        return True
    a, b = pairs[:, 0], pairs[:, 1]
    p0 = x0[a] - x0[b]
    closest = closest_along_step(p0, move[a] - move[b])
    start_gap = np.full(len(x0), np.inf)
    path_gap = np.full(len(x0), np.inf)
    for ends in (a, b):
        np.minimum.at(start_gap, ends, np.linalg.norm(p0, axis=1) - config.offset)
        np.minimum.at(path_gap, ends, closest - config.offset)
    near = path_gap < config.activation
    return bool((path_gap[near] >= (1 - config.step_fraction) * start_gap[near]).all())
