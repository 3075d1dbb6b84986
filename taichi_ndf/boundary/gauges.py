"""Gauge points: pinned points whose reaction the statics of the whole shell fix at zero.

A pinned point that only removes the rigid motions of a shell under self-equilibrated loads
(the pinched hemisphere's pin on the hole's rim, between four radial loads that sum to no
force and no moment) carries no reaction: nothing is concentrated there, so it is not a
singular feature of the solution, and a grid graded towards it spends its spans where
nothing happens (measured: the pinched hemisphere graded towards its pin, benchmarks/
RESULTS.md, issue 33).

The test is the virtual work of the whole shell on its rigid motions, at the reference
configuration (first order, as `rigid_motions`). Let V be the rigid motions (twists q) that
the OTHER constraints admit (`rigid_motions.free_motions` without this point; a point's held
slope counts as holding, so V is never larger than the constraints allow). The internal
forces do no work on a rigid motion, so on every q ∈ V the point's reaction r balances the
loads: r · (A q) = −W(q), A the point's rows on the twists (its held components and, with
rotation "held", its slope: `rigid_motions.constraint_rows`), W(q) the loads' work
(`rigid_motions.load_points`: gravity, body force, pressure, point and line loads). The
point is a **gauge** where

- the loads do no work on any q ∈ V (|W| ≤ `rigid_motions.WORK_TOL` × the loads' scale), and
- A maps V onto A's whole range (rank A V = rank A: every reaction the point can exert does
  rigid work on some q ∈ V),

for then r · (A q) = 0 on all of A's range: r = 0. Otherwise another support shares the load
(a clamped edge: V is empty), or a load works on a motion the point holds (a hanging sheet's
weight on its pin): the point is a support, a feature. Handles drive the shell (a prescribed
motion) and are never gauges. Left out: a reaction the point could exert that does no rigid
work (its held slope's stretching part: its stiffness vanishes as the grid is refined,
`rigid_motions`), and the second-order work of dead loads on a rotation that the slope holds
(`rigid_motions`' "second_order" finding: a moment of the order of the rotation).
"""

from __future__ import annotations

import logging

import numpy as np

from taichi_ndf.boundary.constraints import PinnedPoint
from taichi_ndf.boundary.rigid_motions import (
    WORK_TOL,
    constraint_rows,
    free_motions,
    load_points,
    rigid_work,
)

log = logging.getLogger(__name__)

RANK_TOL = 1e-7  # singular values below this times the largest: not in the range


def _rank(a: np.ndarray) -> int:
    if a.size == 0:
        return 0
    s = np.linalg.svd(a, compute_uv=False)
    return int((s > RANK_TOL * max(float(s.max()), 1e-300)).sum())


def gauge_points(model) -> tuple[PinnedPoint, ...]:
    """The pinned points of `model.boundary` that are gauges (module docstring): the
    constraint objects, in their order; () where there are none."""
    boundary, surface = model.boundary, model.surface
    pins = [c for c in boundary.constraints if isinstance(c, PinnedPoint)]
    if not pins:
        return ()
    x, forces = load_points(model)
    total = sum(forces.values()) if forces else np.zeros_like(x)
    scale = float(np.linalg.norm(total, axis=1).sum())
    gauges = []
    for pin in pins:
        basis, centre, size = free_motions(boundary, surface, point_slopes=True,
                                           leave_out=(pin,))
        if basis.shape[1] == 0:
            continue  # the other constraints hold every rigid motion: the pin shares the load
        work = np.array([rigid_work(total, q, x - centre, size) for q in basis.T])
        if scale > 0 and np.linalg.norm(work) > WORK_TOL * scale:
            continue  # a load works on a motion only the pin holds: its reaction
        rows = np.asarray(constraint_rows(pin, boundary, surface, centre, size, True))
        rows = rows / np.maximum(np.linalg.norm(rows, axis=1, keepdims=True), 1e-300)
        if _rank(rows @ basis) == _rank(rows):
            gauges.append(pin)
    if gauges:
        log.info("gauge points (no reaction under the loads, not graded towards): ξ = %s",
                 ", ".join(str(tuple(p.xi)) for p in gauges))
    return tuple(gauges)
