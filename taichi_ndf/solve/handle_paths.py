"""Handles that follow given paths in time: the dynamic path's boundary moved per handle.

A scene's `[dynamics.motion]` moves the whole prescribed boundary by one factor μ(t) (every
handle along its own fixed displacement, in step). A video's held corners move independently
in 3-D; `HandlePath` gives each handle of the model (its `Handle` constraints, in order) a
displacement [m] from the reference at given times, interpolated linearly between them (held
after the last), and `PathStepper` is the `TimeStepper` whose boundary at time t stands where
a static model with those handle displacements puts it: the boundary's part g(t) of
u = g(t) + J C is the composition's prescribed part of that model (`boundary.conditions`,
the same blend as a quasistatic run's), at the Gauss points. As with a scene's motion, g is
stepped by the scheme (`Motion.boundary`); the path's velocity at t = 0 (its first segment's
slope) is the boundary's initial velocity, so a path already moving at t = 0 starts without a
jerk (`initial_boundary`). The model's handles must be at the reference (zero displacement):
the path is the whole prescribed motion. The adjoint (`solve/dynamics_adjoint.py`) follows
these steps: g does not depend on the material.

The held spots may also turn (`HandlePath.turns`: a rotation vector per time, shared by every
handle — a held edge that the hands turn about the line through its corners): each handle's
spot (or patch) then turns about its reference point as it translates (`Handle.turn`), its
held slope with it. g stays the sum of the translations' part (linear in them) and the turn's,
so `units` (the turn at zero) is still dg per unit displacement; the boundary's initial
velocity is the first segment's slope of both (`boundary_velocity`).

The paths themselves may be unknowns (a video's held corners, reconstructed with an error):
`HandlePath.basis` (T, H, 3, p) is the displacements' derivative by p path unknowns q (the
displacements affine in q, e.g. a B-spline's coefficients per corner coordinate). g is linear
in the handles' displacements (g = Σ_h b_h(ξ) d_h, the blend b_h of handle h:
`inverse.material.handles`), so dg/dq at time t is `PathStepper.units` (dg per unit
displacement of each handle coordinate, exact) times `HandlePath.derivative_at(t)`; the tangent
(`dynamics_adjoint.tangent`) and the rest start (`dynamics_adjoint.rest_start`) then carry the
columns of q beside the stiffness parameter's.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import torch
from scipy.interpolate import BSpline

from taichi_ndf import jets
from taichi_ndf.boundary import BoundaryConditions
from taichi_ndf.boundary.constraints import Handle
from taichi_ndf.problem.dynamics import DynamicsConfig
from taichi_ndf.problem.model import ShellModel
from taichi_ndf.problem.operator import DisplacementOperator
from taichi_ndf.problem.spline_grid import SplinePlan
from taichi_ndf.solve.dynamics import TimeStepper
from taichi_ndf.solve.dynamics_trajectory import Checkpoint, Motion


@dataclass(frozen=True)
class HandlePath:
    """times: (T,) [s], T ≥ 2, from 0, increasing; displacements: (T, H, 3) [m] of the H
    handles from the reference at those times (the first may be non-zero: the start's shape
    then carries it); basis: None, or (T, H, 3, p) [m per unit]: the displacements'
    derivative by p path unknowns (module docstring); turns: None (no turn), or (T, 3) [rad]:
    the held spots' rotation vector at those times, shared by every handle (interpolated
    linearly as the displacements; `Handle.turn`)."""

    times: tuple[float, ...]
    displacements: np.ndarray
    basis: np.ndarray | None = None
    turns: np.ndarray | None = None

    def __post_init__(self):
        times = tuple(float(t) for t in self.times)
        values = np.asarray(self.displacements, dtype=np.float64)
        object.__setattr__(self, "times", times)
        object.__setattr__(self, "displacements", values)
        if len(times) < 2 or times[0] != 0.0 \
                or any(b <= a for a, b in zip(times, times[1:], strict=False)):
            raise ValueError(f"handle path: times must start at 0 and increase (at least two), "
                             f"got {list(times)[:5]}")
        if not np.isfinite(times).all():
            raise ValueError("handle path: times must be finite")
        if values.ndim != 3 or values.shape[0] != len(times) or values.shape[2] != 3:
            raise ValueError(f"handle path: displacements must be (T, H, 3) with T = "
                             f"{len(times)}, got {values.shape}")
        if not np.isfinite(values).all():
            raise ValueError("handle path: displacements must be finite")
        if self.basis is not None:
            basis = np.asarray(self.basis, dtype=np.float64)
            object.__setattr__(self, "basis", basis)
            if basis.ndim != 4 or basis.shape[:3] != values.shape or not np.isfinite(
                    basis).all():
                raise ValueError(f"handle path: basis must be finite (T, H, 3, p) with (T, H, "
                                 f"3) = {values.shape}, got {basis.shape}")
        if self.turns is not None:
            turns = np.asarray(self.turns, dtype=np.float64)
            object.__setattr__(self, "turns", turns)
            if turns.shape != (len(times), 3) or not np.isfinite(turns).all():
                raise ValueError(f"handle path: turns must be finite (T, 3) [rad] with T = "
                                 f"{len(times)}, got {turns.shape}")

    @property
    def handles(self) -> int:
        return self.displacements.shape[1]

    def at(self, t: float) -> np.ndarray:
        """(H, 3) [m] at time t [s] (linear between the times, held after the last)."""
        return _interpolated(self.times, self.displacements, t)

    def turn_at(self, t: float) -> np.ndarray:
        """The held spots' rotation vector (3,) [rad] at time t [s] (zero without turns;
        interpolated as `at`)."""
        return np.zeros(3) if self.turns is None else _interpolated(self.times, self.turns, t)

    def initial_velocity(self) -> np.ndarray:
        """(H, 3) [m/s]: the first segment's slope."""
        return (self.displacements[1] - self.displacements[0]) / self.times[1]

    @property
    def unknowns(self) -> int:
        """p: the number of path unknowns (0 without a basis)."""
        return 0 if self.basis is None else self.basis.shape[3]

    def derivative_at(self, t: float) -> np.ndarray:
        """d(displacements at t)/dq (3H, p) [m per unit], rows handle × 3 + axis: `at`'s
        interpolation of the basis (linear in it)."""
        times = np.asarray(self.times)
        flat = self.basis.reshape(len(times), -1)
        out = np.array([np.interp(t, times, column) for column in flat.T])
        return out.reshape(3 * self.handles, self.unknowns)

    def initial_velocity_derivative(self) -> np.ndarray:
        """d(initial_velocity)/dq (3H, p) [m/s per unit]."""
        return (self.basis[1] - self.basis[0]).reshape(3 * self.handles, -1) / self.times[1]


def _interpolated(times: tuple[float, ...], values: np.ndarray, t: float) -> np.ndarray:
    """values (T, …) at time t [s]: linear between the times, held before the first and
    after the last."""
    flat = values.reshape(len(times), -1)
    return np.array([np.interp(t, times, column) for column in flat.T]).reshape(values.shape[1:])


def spline_basis(times: np.ndarray, handles: int, spans: int) -> np.ndarray:
    """A `HandlePath.basis` (T, H, 3, p) at times (T,) [s]: each handle coordinate a cubic
    B-spline in time with `spans` uniform spans over the times (clamped knots), p = 3 H
    (spans + 3); unknown (handle × 3 + axis) × (spans + 3) + j is that coordinate's j-th
    coefficient [m]."""
    times = np.asarray(times, dtype=np.float64)
    knots = np.concatenate([[times[0]] * 3, np.linspace(times[0], times[-1], spans + 1),
                            [times[-1]] * 3])
    design = BSpline.design_matrix(times, knots, 3).toarray()  # (T, spans + 3)
    coordinates, count = 3 * handles, design.shape[1]
    basis = np.zeros((len(times), coordinates, coordinates * count))
    for a in range(coordinates):
        basis[:, a, a * count:(a + 1) * count] = design
    return basis.reshape(len(times), handles, 3, -1)


def moved_boundary(boundary: BoundaryConditions, displacements: np.ndarray,
                   turn: np.ndarray | None = None) -> BoundaryConditions:
    """The same conditions with the handles (in order) moved by `displacements` (H, 3) [m],
    each turned by the rotation vector `turn` (3,) [rad] (None: zero; `Handle.turn`)."""
    handles = [i for i, c in enumerate(boundary.constraints) if isinstance(c, Handle)]
    if len(handles) != len(displacements):
        raise ValueError(f"handle path: {len(displacements)} handles' displacements for "
                         f"{len(handles)} handles of the boundary")
    constraints = list(boundary.constraints)
    turn = (0.0, 0.0, 0.0) if turn is None else tuple(float(v) for v in turn)
    for i, d in zip(handles, displacements, strict=True):
        constraints[i] = dataclasses.replace(constraints[i],
                                             displacement=tuple(float(v) for v in d), turn=turn)
    return BoundaryConditions(constraints, boundary.domain, surface=boundary.surface,
                              length=boundary.length, frame=boundary.frame)


class PathStepper(TimeStepper):
    """A `TimeStepper` whose handles follow `path` (module docstring); `config.motion` must
    be None and the model's handles at the reference. ValueError otherwise, or where the
    boundary prescribes by something else than handles (a moved edge, a rim rotation)."""

    def __init__(self, model: ShellModel, plan: SplinePlan, config: DynamicsConfig,
                 path: HandlePath, **options):
        if config.motion is not None:
            raise ValueError("handle path: give either [dynamics.motion] or a handle path")
        boundary = model.boundary
        if boundary is None or not any(isinstance(c, Handle) for c in boundary.constraints):
            raise ValueError("handle path: the model has no handle to move")
        if any(np.any(c.displacement) for c in boundary.constraints
               if hasattr(c, "displacement") and not isinstance(c, Handle)) \
                or any(hasattr(c, "angle") for c in boundary.constraints):
            raise ValueError("handle path: only handles may prescribe displacements")
        if any(np.any(c.displacement) or any(c.turn) for c in boundary.constraints
               if isinstance(c, Handle)):
            raise ValueError("handle path: the model's handles must be at the reference "
                             "(zero displacement and turn); the path is their motion")
        moved_boundary(boundary, np.zeros((path.handles, 3)))  # the count checked
        self.path = path
        self._offsets: dict[float, torch.Tensor] = {}
        super().__init__(model, plan, config, **options)

    def boundary_at(self, xi: torch.Tensor, t: float, dtype: torch.dtype) -> torch.Tensor:
        """g(t): the boundary's displacement jets (P, 6, 3) [m] at ξ (P, 2), time t [s]."""
        boundary = moved_boundary(self.model.boundary, self.path.at(t), self.path.turn_at(t))
        return DisplacementOperator(self.field, boundary).prescribed(xi, t=1.0, dtype=dtype)

    def boundary_velocity(self, xi: torch.Tensor, dtype: torch.dtype) -> torch.Tensor:
        """ġ(0): the boundary's velocity jets (P, 6, 3) [m/s] at ξ (P, 2), the path's first
        segment's slope: the translations' (linear in them) plus the turn's secant."""
        velocity = moved_boundary(self.model.boundary, self.path.initial_velocity())
        gv = DisplacementOperator(self.field, velocity).prescribed(xi, t=1.0, dtype=dtype)
        if self.path.turns is None:
            return gv
        still = np.zeros((self.path.handles, 3))
        turned = [DisplacementOperator(self.field, moved_boundary(
            self.model.boundary, still, turn)).prescribed(xi, t=1.0, dtype=dtype)
            for turn in self.path.turns[:2]]
        return gv + (turned[1] - turned[0]) / self.path.times[1]

    def units(self, xi: torch.Tensor, dtype: torch.dtype) -> torch.Tensor:
        """dg/dd: the boundary's displacement jets (P, 6, 3, 3H) [m/m] at ξ (P, 2) per unit
        displacement of each handle's world coordinate (column handle × 3 + axis): g of that
        handle moved by e_axis, every other at the reference (g is linear in them)."""
        columns = []
        for column in range(3 * self.path.handles):
            unit = np.zeros((self.path.handles, 3))
            unit.flat[column] = 1.0
            boundary = moved_boundary(self.model.boundary, unit)
            columns.append(DisplacementOperator(self.field, boundary).prescribed(
                xi, t=1.0, dtype=dtype))
        return torch.stack(columns, dim=-1)

    def _at(self, t: float):
        """The linearisation at the Gauss points with the handles at path(t) (its offset g(t)
        set on the grid's one assembly, as `GridLinearisation.linearisation` sets a load
        factor's: the last time asked holds for every linearisation of it)."""
        linear = self._grid.linearisation(1.0)
        assembly = self._grid.assembly
        key = float(t)
        if key not in self._offsets:
            if len(self._offsets) > 8:
                self._offsets.pop(next(iter(self._offsets)))
            self._offsets[key] = self.boundary_at(assembly.samples.xi, key,
                                                  assembly.offset.dtype)
        assembly.offset = self._offsets[key]
        return linear

    def initial_boundary(self) -> Motion:
        """(g, ġ, g̈) at t = 0 at the Gauss points: the path's start, its first slope, 0."""
        g = self.offset_of(self._at(0.0))
        gv = self.boundary_velocity(self._grid.assembly.samples.xi, g.dtype)
        return Motion(0.0, g, gv, torch.zeros_like(g))

    def start(self, displacement=None, velocity=None) -> Checkpoint:
        """`TimeStepper.start` with the boundary on its path (`initial_boundary`)."""
        checkpoint = super().start(displacement, velocity)
        state = dataclasses.replace(checkpoint.state, boundary=self.initial_boundary())
        return dataclasses.replace(checkpoint, state=state)


def boundary_displacement(stepper: TimeStepper, xi: torch.Tensor, t: float,
                          dtype: torch.dtype = torch.float64) -> torch.Tensor:
    """The boundary's part of the displacement (P, 3) [m] at ξ (P, 2) and time t [s] of any
    stepper: a path's g(t), else the scene's prescribed part at μ(t) (μ = 1 without a motion)."""
    if isinstance(stepper, PathStepper):
        return stepper.boundary_at(xi.to(dtype), t, dtype)[:, jets.VALUE]
    operator = DisplacementOperator(stepper.field, stepper.model.boundary)
    return operator.prescribed(xi.to(dtype), t=stepper.config.boundary_factor(t),
                               dtype=dtype)[:, jets.VALUE]
