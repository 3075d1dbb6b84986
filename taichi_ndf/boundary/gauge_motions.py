"""Gauge motions: the free rigid motions that nothing fixes, and the probe readings they move.

A rigid motion the supports leave free (`rigid_motions.free_motions`: a point's held slope
does not count as holding, first order at the reference configuration, contact's resistance
removed) is a **gauge motion** of the model where the loads do not fix where the shell ends
along it:

- the loads do no work on it (first order), and
- their potential along it is neutral in every shape (`rigid_motions.neutral_in_every_shape`: a
  translation, a rotation about an axis along every force), or it is held only by a point's
  slope (free as `free_motions` counts, held as the constraints are stated) and the loads'
  potential falls along it at second order (dead self-equilibrated loads on a shell held at
  one point: it swings as the grid is refined, `rigid_motions`' "second_order" finding), or
  it is held only by the slope of a gauge point (`gauges`: a pin with no reaction under the
  loads, whose slope's stiffness vanishes as the grid is refined: the pinched hemisphere's
  three rotations about its pin).

Along such a motion each solve leaves the shell wherever its Newton iterations or the
vanishing stiffness of a point's slope put it (measured: the Scordelis–Lo roof's axial
translation, the pinched cylinder's, the pinched hemisphere's swing about its pin:
benchmarks/RESULTS.md, issue 33), so a probe component it moves changes between grids by an
amount no grid error sets. A motion the loads work on, whose potential rises along it, or
that is neutral only at the reference (a tilt of a flat sheet on a pin: the hanging shape
makes it stable), or free as stated and falling (a sheet on a free pin hangs), is fixed by
the loads and converges with the grid: not a gauge.

`ProbeGauge.relative` reads the probes relative to their best-fit gauge motion: the least-
squares twist q of the gauge subspace to the probe displacements (P, 3) is subtracted (first
order, v(x) = t + ω × (x − c) at the probes' reference points). A component no gauge motion
moves is unchanged to the bit, and so is every first-order rigid invariant of the probes
(a distance between two of them).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from taichi_ndf.boundary.gauges import gauge_points
from taichi_ndf.boundary.rigid_motions import (
    WORK_TOL,
    complement,
    contact_points,
    describe,
    free_motions,
    load_curvatures,
    load_points,
    neutral_in_every_shape,
    rigid_work,
    twist_velocities,
    unresisted,
)

MOVES = 1e-6  # a probe component moves with a unit twist where its velocity is above this


def gauge_motions(model, gauges=None) -> tuple[np.ndarray, np.ndarray, float]:
    """The gauge motions of `model` (module docstring): an orthonormal basis (6, k) of
    twists q = (t, L ω) about the centre c, c (3,) [m] and L [m] (`free_motions`). gauges:
    the model's gauge points (`gauge_points`, computed here where None)."""
    basis, centre, size = free_motions(model.boundary, model.surface)
    contact = getattr(model, "contact", None)
    if contact is not None and contact.obstacles:
        basis = unresisted(contact_points(model, centre), basis, size)
    if basis.shape[1] == 0:
        return basis, centre, size
    stated, _, _ = free_motions(model.boundary, model.surface, point_slopes=True)
    x, forces = load_points(model)
    y = x - centre
    total = sum(forces.values()) if forces else np.zeros_like(y)
    scale = max(float(np.linalg.norm(total, axis=1).sum()), 1e-300)
    tol = WORK_TOL * scale * size

    def unworked(sub):  # the part of span(sub) the loads do no work on
        work = np.array([rigid_work(total, q, y, size) for q in sub.T])
        if sub.shape[1] == 0 or np.linalg.norm(work) <= WORK_TOL * scale:
            return sub
        return complement(sub, (sub @ work)[:, None])

    kept = [q for value, q in load_curvatures(total, unworked(basis), y, size)
            if abs(value) <= tol and neutral_in_every_shape(total, q, size, scale)]
    kept += [q for value, q in load_curvatures(
        total, unworked(complement(basis, stated)), y, size) if value < -tol]
    gauges = gauge_points(model) if gauges is None else gauges
    for pin in gauges:  # what only a gauge pin's slope holds
        without, _, _ = free_motions(model.boundary, model.surface, point_slopes=True,
                                     leave_out=(pin,))
        kept += list(unworked(_intersection(basis, without)).T)
    if not kept:
        return np.zeros((6, 0)), centre, size
    return complement(np.stack(kept, axis=1), np.zeros((6, 0))), centre, size


def _intersection(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """An orthonormal basis of span(a) ∩ span(b) (orthonormal columns a (6, i), b (6, j))."""
    if a.shape[1] == 0 or b.shape[1] == 0:
        return np.zeros((6, 0))
    _, s, vt = np.linalg.svd(a - b @ (b.T @ a), full_matrices=True)
    s = np.concatenate((s, np.zeros(a.shape[1] - len(s))))
    return a @ vt[s <= 1e-6].T


@dataclass(frozen=True)
class ProbeGauge:
    """The gauge motions at the probes: names (P,), velocities (P, 3, k) [m per unit twist]
    of the k gauge motions at the probes' reference points, motions: each in words."""

    names: tuple[str, ...]
    velocities: np.ndarray
    motions: tuple[str, ...]

    def components(self) -> tuple[str, ...]:
        """The probe components a gauge motion moves, "name:axis" (axis 0, 1, 2: x, y, z)."""
        moved = np.linalg.norm(self.velocities, axis=2) > MOVES
        return tuple(f"{name}:{axis}" for p, name in enumerate(self.names)
                     for axis in range(3) if moved[p, axis])

    def relative(self, probes: dict[str, list[float]]) -> dict[str, list[float]]:
        """Displacements (name -> u (3,) [m]) less their best-fit gauge motion (module
        docstring); components no gauge motion moves come back unchanged."""
        names = [n for n in self.names if n in probes]
        a = np.concatenate([self.velocities[self.names.index(n)] for n in names])
        u = np.concatenate([np.asarray(probes[n], dtype=np.float64) for n in names])
        fit = a @ np.linalg.lstsq(a, u, rcond=None)[0]
        moved = np.linalg.norm(a, axis=1) > MOVES
        rest = np.where(moved, u - fit, u)
        out = dict(probes)
        out.update({n: rest[3 * i:3 * i + 3].tolist() for i, n in enumerate(names)})
        return out

    def line(self) -> str:
        """One line for the console and result.json."""
        moved = ", ".join(self.components())
        return (f"the probe components {moved} move with {' and '.join(self.motions)}, which "
                "nothing fixes (a gauge, not a grid error): --tolerance reads the probes "
                "relative to their best-fit motion in that subspace")


def probe_gauge(model, gauges=None) -> ProbeGauge | None:
    """The gauge motions at `model.probes` (`ProbeGauge`); None where there is no gauge
    motion or it moves no probe component. gauges: as `gauge_motions`'."""
    if not model.probes:
        return None
    basis, centre, size = gauge_motions(model, gauges)
    if basis.shape[1] == 0:
        return None
    xi = torch.tensor([p.xi for p in model.probes], dtype=torch.float64)
    y = model.surface.jets(xi)[:, 0].numpy() - centre
    velocities = np.stack([twist_velocities(q, y, size) for q in basis.T], axis=2)  # (P, 3, k)
    gauge = ProbeGauge(tuple(p.name for p in model.probes), velocities,
                       tuple(describe(q, centre, size) for q in basis.T))
    return gauge if gauge.components() else None

