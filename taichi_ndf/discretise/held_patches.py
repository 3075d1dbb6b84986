"""The quadrature of a spline grid whose boundary holds patches at the domain's corners: the
sheet outside the patches, its rims integrated exactly (issue 27, the swing's grip).

A `Handle` with a `radius` holds a disc of the domain (`boundary.conditions`): the vanishing
factor is 0 on it, so nothing that depends on the unknowns lives there (the patch moves
rigidly: no strain, and its gravity and inertia do not depend on the coefficients), and at its
rim φ's second derivatives jump (level max(ρ − r, 0)², C¹) — so does the bending strain.
Tensor Gauss points on the knot spans that the rim cuts integrate that jump at first order,
erratically with where the rim cuts each span: measured on the swing's rest (benchmarks/
RESULTS.md, wip-sftmat13) the total energy of uniform 40² moved by 5 % between 4² and 8²
points per span, and B's static bias from grid to grid by −14 % then −0.9 % (read with
`rest_start`'s dP/dB while the dynamics' stepper paired these points, not in the assembly's
order, with displacements in that order — 46 % rms off a central difference on graded 32²,
fixed in `solve.dynamics.TimeStepper` — so these two B figures are indicative only; the
energy's are not affected).

`held_patch_points` integrates over the domain minus the quarter discs of the handles that
sit at its corners, by the trimmed quadrature of a panel's outline
(`discretise.trimmed.trimmed_points`: each rim a concave circular arc, cut at the knot
lines; the spans it does not cut keep their tensor Gauss points), exact to rounding in the
area. It applies where every patch is a quarter disc at a corner and a circle in ξ (a disc
in the normalised coordinates of a square domain); otherwise None, and the caller keeps the
spans' own points (their first-order rim).
"""

from __future__ import annotations

import math

import torch

from taichi_ndf.boundary import BoundaryConditions, Handle
from taichi_ndf.discretise.trimmed import trimmed_points
from taichi_ndf.field.spline import SplineConfig
from taichi_ndf.problem.outline import Outline

QUARTER = -math.tan(math.pi / 8)  # the bulge of a quarter circle turning clockwise (a notch)


def corner_patches(boundary: BoundaryConditions | None, config: SplineConfig
                   ) -> dict[tuple[int, int], float] | None:
    """The held patches at the grid's domain corners: {(i, j): radius [ξ units]} with i, j
    0 (lower bound) or 1 (upper) per direction; {} where no handle holds a patch; None where a
    patch is not a circle in ξ at a corner (another place, or a non-square domain)."""
    if boundary is None:
        return {}
    (lo1, hi1), (lo2, hi2) = config.domain
    l1, l2 = hi1 - lo1, hi2 - lo2
    patches = {}
    for con in boundary.constraints:
        if not isinstance(con, Handle) or con.radius == 0:
            continue
        if abs(l1 - l2) > 1e-12 * max(l1, l2) or any(config.periodic):
            return None
        corner = []
        for value, lo, hi in ((con.xi[0], lo1, hi1), (con.xi[1], lo2, hi2)):
            at = [k for k, bound in enumerate((lo, hi)) if abs(value - bound) <= 1e-12 * l1]
            if not at:
                return None
            corner.append(at[0])
        patches[tuple(corner)] = con.radius * l1
    return patches


def held_patch_outline(config: SplineConfig, patches: dict[tuple[int, int], float]) -> Outline:
    """The domain's rectangle (counter-clockwise) with each corner (i, j) of `patches` cut by
    the quarter circle of its radius about it."""
    (lo1, hi1), (lo2, hi2) = config.domain
    points, bulges = [], []
    for corner, (x, y), (dx, dy) in (((0, 0), (lo1, lo2), (1, 1)), ((1, 0), (hi1, lo2), (-1, 1)),
                                     ((1, 1), (hi1, hi2), (-1, -1)), ((0, 1), (lo1, hi2), (1, -1))):
        r = patches.get(corner)
        if r is None:
            points.append((x, y))
            bulges.append(0.0)
            continue
        # arriving along one side, leaving along the next (counter-clockwise)
        first, second = ((x, y + dy * r), (x + dx * r, y)) if corner in ((0, 0), (1, 1)) \
            else ((x + dx * r, y), (x, y + dy * r))
        points += [first, second]
        bulges += [QUARTER, 0.0]
    return Outline(tuple(points), tuple(bulges))


def held_patch_points(boundary: BoundaryConditions | None, config: SplineConfig
                      ) -> tuple[torch.Tensor, torch.Tensor] | None:
    """Quadrature points ξ (N, 2) and weights (N,) of the domain outside the corner patches
    (module docstring), float64; None where no handle holds a patch or a patch is not a
    corner's circle in ξ."""
    patches = corner_patches(boundary, config)
    if not patches:
        return None
    return trimmed_points(held_patch_outline(config, patches), config)
