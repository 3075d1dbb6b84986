"""What a validation case is: published shell benchmarks (`../shared/spec/benchmarks.md`).

A *case* is a scene file plus what to read from the trained field: one or more *quantities*
(a displacement component at a probe, a change of distance between two probes, the rotation
of the chord between two probes about an axis, or the mean of several such reads), each at a
load factor, with its published reference value, source and tolerance. Cases are written as
case files (`taichi_ndf.validation.case_file`); the built-in ones are `validation/cases/*.toml`,
their scenes `validation/scenes/*.toml`.

Two protocols beyond the scene itself:

- Linear references (plate, roof, cylinder, hemisphere) are values of *linear* shell theory,
  while the solver's kinematics are exact (geometrically nonlinear). A linear case is therefore
  solved in the linear regime: loads × 1/ε and stiffnesses × 1/ε² with ε = `LINEARISATION`
  (1e-3) give displacements ε times the linear ones (~1e-3 of the thickness, so nonlinear terms
  are ~1e-6 of the linear ones) at an unchanged potential energy — which keeps Π, its gradient
  and the optimisers' absolute tolerances as in the scene — and the read displacements are
  divided by ε; the field's output scale is multiplied by ε. At the nominal load the
  immovable-edge plate (w ≈ h/2) stiffens by membrane action, which is physics, not error.
- The end moment of the roll-up cantilever is not a scene load. It is added here as the
  potential of a conservative moment about the y axis: Π_M = −M θ_end, where θ_end, the end
  rotation of the strip's tangent in the xz plane, is measured exactly for any size of rotation
  as ∫ θ_,1 dξ¹ (averaged over the width), θ_,1 = (t_x t′_z − t_z t′_x)/|t|² with
  t = x_,1, t′ = x_,11; θ = 0 at the clamped root. About a fixed axis this "follower" moment is
  exactly conservative, so M θ_end is its work at any rotation (a pair of dead point loads
  would not be). No prescribed end rotation is needed and the tip displacement stays free.
  For a tangent in the xz plane |t|² = t_x² + t_z², the exact rotation rate. Out of that
  plane the full |t|² keeps the rate at most the curvature |t × t′|/|t|² (for a unit tangent
  at angle α to the y axis it is sin α × the curvature); with t_x² + t_z² it would be the
  winding of the tangent's projection, 1/sin α × the curvature, so tilting the strip out of
  its plane would gain moment work cheaply: at λ = 1 Newton found such a state, tip
  u_y = 1.29, Π 1.2 % below the exact circle's.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # annotations only: the catalogue (and ndf-validate --help) stays light
    from taichi_ndf.problem.model import ShellModel

SCENES_DIR = Path(__file__).resolve().parents[2] / "validation" / "scenes"
CASES_DIR = SCENES_DIR.parent / "cases"
# Displacement scale ε of the linear-regime solve of a linear case (module docstring).
LINEARISATION = 1e-3

# Probe displacements u [m] (3,) and reference positions r [m] (3,) by probe name.
Readings = dict[str, np.ndarray]


@dataclass(frozen=True)
class Quantity:
    """A scalar read from the field at a load factor and its published reference.

    name: short label, e.g. "W" or "w_centre".
    description: what it is, in words.
    reference: published value.
    tolerance: admissible relative error (0.01 = 1 %).
    read: function (displacements, reference positions) -> value, both by probe name.
    level: load factor (of the case's load steps) at which it is read.
    source: where the reference comes from (publication, formula).
    probes: the probe names `read` uses (checked against the scene before a run).
    """

    name: str
    description: str
    reference: float
    tolerance: float
    read: Callable[[Readings, Readings], float]
    level: float = 1.0
    source: str = ""
    probes: tuple[str, ...] = ()

    def __post_init__(self):
        if not (math.isfinite(self.reference) and self.reference != 0.0):
            raise ValueError(f"quantity {self.name}: reference must be finite and non-zero")
        if not 0 < self.tolerance < 1:
            raise ValueError(f"quantity {self.name}: tolerance must be in (0, 1)")


@dataclass(frozen=True)
class Case:
    """A benchmark: a scene file and the quantities checked on its solution.

    scene: scene file, relative to the runner's `scenes_dir` (default `validation/scenes/`) or
        absolute.
    load_scale: factor on every scene load (e.g. a single load level of a nonlinear case).
    linear: whether the reference is a linear-theory value, solved in the linear regime
        (module docstring).
    end_moment: the roll-up moment at load factor 1 [N·m] as a function of the model, or None.
    membrane_scale: factor on the membrane stiffness of a linear isotropic material, keeping
        the bending stiffness: a thicker shell of the same B. Kirchhoff–Love bending solutions
        of a flat plate (linear) or an inextensible strip (elastica) depend on B alone, so the
        reference holds, while the optimisation is better conditioned (the stiffness ratio
        D L² / B falls by the factor); used by the quick tests.
    """

    name: str
    scene: str
    quantities: tuple[Quantity, ...]
    load_scale: float = 1.0
    linear: bool = False
    end_moment: Callable[[ShellModel], float] | None = None
    membrane_scale: float = 1.0

    def __post_init__(self):
        for name in ("load_scale", "membrane_scale"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"case {self.name}: {name} must be positive, got {value!r}")
        if not self.quantities:
            raise ValueError(f"case {self.name}: needs at least one quantity")


# -- the end moment of the roll-up ---------------------------------------------------------------


def roll_up_moment(model: ShellModel) -> float:
    """Mmax = 2π B b / L [N·m]: the moment that rolls a strip of length L and width b into a
    full circle (B is the bending stiffness per width, ν = 0)."""
    (lo1, hi1), (lo2, hi2) = model.surface.domain.bounds
    return 2 * math.pi * model.material.bending_stiffness * (hi2 - lo2) / (hi1 - lo1)


# -- quantities ---------------------------------------------------------------------------------


def component_read(probe: str, axis: int, sign: float = 1.0):
    """sign × the displacement component `axis` (0, 1, 2) at a probe."""
    def read(u: Readings, r: Readings) -> float:
        return sign * float(u[probe][axis])
    return read


def distance_change_read(first: str, second: str, sign: float = 1.0):
    """sign × half the change of the distance between two probes: invariant under rigid
    motion, equal to the radial displacement of each for a symmetric deformation."""
    def read(u: Readings, r: Readings) -> float:
        before = np.linalg.norm(r[first] - r[second])
        after = np.linalg.norm(r[first] + u[first] - r[second] - u[second])
        return sign * 0.5 * float(after - before)
    return read


def rotation_read(first: str, second: str, axis, sign: float = 1.0):
    """sign × the rotation [rad] about `axis` (3,) of the chord from probe `first` to probe
    `second` between the reference and the deformed state: the signed angle, in (−π, π],
    from the chord's reference projection on the plane normal to the axis to its deformed
    one (right-hand rule about the axis). Invariant under translation; for close probes on
    an edge it is the rotation of the edge's tangent, on a line across the surface that of
    the surface about the axis."""
    axis = np.asarray(axis, dtype=np.float64)
    norm = float(np.linalg.norm(axis))
    if not (np.all(np.isfinite(axis)) and norm > 0):
        raise ValueError(f"rotation axis must be a finite non-zero vector, got {axis.tolist()}")
    axis = axis / norm

    def read(u: Readings, r: Readings) -> float:
        before = r[second] - r[first]
        after = before + u[second] - u[first]
        p0, p1 = (d - np.dot(d, axis) * axis for d in (before, after))
        return sign * float(np.arctan2(np.dot(axis, np.cross(p0, p1)), np.dot(p0, p1)))
    return read


def mean_read(*reads):
    """The mean of several reads."""
    def read(u: Readings, r: Readings) -> float:
        return sum(f(u, r) for f in reads) / len(reads)
    return read


def roll_up_references(level: float, length: float = 12.0) -> tuple[float, float]:
    """Analytic (−U, W) of the tip of a strip rolled by λ = M/Mmax (ν = 0)."""
    angle = 2 * math.pi * level
    return length * (1 - math.sin(angle) / angle), length * (1 - math.cos(angle)) / angle
