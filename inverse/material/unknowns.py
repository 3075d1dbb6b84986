"""The unknowns of a material/force estimate and the energy terms they multiply.

Π is linear in every estimable quantity: Π(u; θ) = Π_known(u) + Σ_j θ_j T_j(u), with T_j a
per-parameter stiffness energy E_k (`ShellEnergy.stiffness_terms`) or a load potential per unit
load. Each unknown knows how to evaluate dT_j/du (through `ShellEnergy`, so there is one
physics code) and how to put a value back into a model.

Names accepted by `parse_unknowns` (comma separated):
- any stiffness name of the model's material (`membrane_stiffness`, `bending_stiffness`,
  `a11`, `a12`, `a22`, `G12`, `stiffness_scale`) and the aliases `stretch`
  (membrane_stiffness), `bending` (bending_stiffness);
- `scale`: one factor on all stiffness values of the scene's material (e.g. a Clyde preset);
- `young_modulus` (alias `E`), linear isotropic material only: Young's modulus E [Pa] at the
  scene's thickness and Poisson's ratio (D and B both ∝ E): the `scale` unknown expressed in Pa;
- `density`: areal density ρ_A [kg/m²] (acts through gravity);
- `gravity`: the gravity vector g [m/s²] (3 unknowns); `body_force` [N/m²] (3 unknowns);
- `pressure` [Pa];
- `point_load:NAME`: the force vector [N] of a point load (3 unknowns); NAME is the index of a
  point load of the scene (its given force is ignored) or the name of a probe (a load there).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import torch

from taichi_ndf.problem.loads import Loads, PointLoad
from taichi_ndf.problem.model import ShellModel
from taichi_ndf.problem.sampling import SurfaceSamples, with_point_loads
from taichi_ndf.shell.energy import ShellEnergy
from taichi_ndf.shell.materials import LinearIsotropic

ALIASES = {"stretch": "membrane_stiffness", "bending": "bending_stiffness", "E": "young_modulus"}
AXES = "xyz"


@dataclass(frozen=True)
class Unknown:
    """One scalar unknown.

    name: report name, e.g. "bending_stiffness", "gravity_z", "point_load:tip_x".
    kind: "stiffness", "scale", "density", "gravity", "body_force", "pressure", "point_load".
    key: stiffness name (kind "stiffness"), point-load index (kind "point_load").
    axis: vector component 0..2 for vector unknowns.
    positive: estimated in log space (stiffness, scale, density).
    unit: physical unit, for reports.
    reference: kind "scale": the value that means the scene's stiffness unchanged (1 for a
        plain factor, the scene's E [Pa] for `young_modulus`); the factor is value / reference.
    """

    name: str
    kind: str
    key: str | int | None = None
    axis: int | None = None
    positive: bool = True
    unit: str = ""
    reference: float = 1.0

    def value(self, model: ShellModel) -> float:
        """The unknown's value in `model` (the scene's value: a start or a ground truth)."""
        material, loads = model.material, model.loads
        if self.kind == "stiffness":
            return float(getattr(material, self.key))
        if self.kind == "scale":
            return self.reference
        if self.kind == "density":
            return material.areal_density
        if self.kind == "pressure":
            return loads.pressure
        if self.kind == "point_load":
            return loads.point_loads[self.key].force[self.axis]
        return getattr(loads, self.kind)[self.axis]


def parse_unknowns(spec: str | list[str], model: ShellModel) -> tuple[ShellModel, list[Unknown]]:
    """Unknowns from a comma-separated spec (see module docstring). Returns the model with a
    zero-force point load added for every `point_load:PROBE` and the unknowns."""
    items = spec.split(",") if isinstance(spec, str) else list(spec)
    items = [i.strip() for i in items if i.strip()]
    if not items:
        raise ValueError("nothing to estimate: give at least one unknown")
    unknowns: list[Unknown] = []
    material = model.material
    for item in items:
        name = ALIASES.get(item, item)
        if name in material.stiffness_names:
            unit = "N·m" if name == "bending_stiffness" else ("1" if name == "stiffness_scale"
                                                              else "N/m")
            unknowns.append(Unknown(name, "stiffness", key=name, unit=unit))
        elif name == "scale":
            unknowns.append(Unknown("stiffness_scale_factor", "scale", unit="1"))
        elif name == "young_modulus":
            if not isinstance(material, LinearIsotropic):
                raise ValueError(f"young_modulus needs the linear isotropic material, the scene "
                                 f"has {type(material).__name__}; estimate 'scale' instead")
            unknowns.append(Unknown("young_modulus", "scale", unit="Pa",
                                    reference=material.young_modulus))
        elif name == "density":
            unknowns.append(Unknown("areal_density", "density", unit="kg/m²"))
        elif name in ("gravity", "body_force"):
            unit = "m/s²" if name == "gravity" else "N/m²"
            unknowns += [Unknown(f"{name}_{a}", name, axis=i, positive=False, unit=unit)
                         for i, a in enumerate(AXES)]
        elif name == "pressure":
            unknowns.append(Unknown("pressure", "pressure", positive=False, unit="Pa"))
        elif name.startswith("point_load:"):
            label = name.split(":", 1)[1]
            model, index = _point_load_index(model, label)
            unknowns += [Unknown(f"point_load:{label}_{a}", "point_load", key=index, axis=i,
                                 positive=False, unit="N") for i, a in enumerate(AXES)]
        else:
            raise ValueError(
                f"unknown parameter {item!r} to estimate for {type(material).__name__}; choose "
                f"from {', '.join([*material.stiffness_names, *ALIASES])}, scale, "
                f"young_modulus (linear isotropic), density, gravity, body_force, pressure, "
                f"point_load:NAME")
    names = [u.name for u in unknowns]
    if len(set(names)) != len(names):
        raise ValueError(f"an unknown is listed twice: {names}")
    kinds = {u.kind for u in unknowns}
    if "scale" in kinds and "stiffness" in kinds:
        raise ValueError("estimate either 'scale' (or young_modulus) or individual stiffness "
                         "values, not both")
    if sum(u.kind == "scale" for u in unknowns) > 1:
        raise ValueError("'scale' and young_modulus are the same unknown: estimate one")
    if "density" in kinds and "gravity" in kinds:
        raise ValueError("areal density and gravity enter only as their product: estimate one")
    return model, unknowns


def _point_load_index(model: ShellModel, label: str) -> tuple[ShellModel, int]:
    loads = model.loads
    if label.isdigit():
        index = int(label)
        if index >= len(loads.point_loads):
            raise ValueError(f"point_load:{label}: the scene has {len(loads.point_loads)} "
                             f"point load(s)")
        return model, index
    probes = {p.name: p.xi for p in model.probes}
    if label not in probes:
        raise ValueError(f"point_load:{label}: no point load index or probe named {label!r} "
                         f"(probes: {sorted(probes)})")
    points = (*loads.point_loads, PointLoad(probes[label], (0.0, 0.0, 0.0)))
    return model.with_loads(dataclasses.replace(loads, point_loads=points)), len(points) - 1


def apply(model: ShellModel, unknowns: list[Unknown], values) -> ShellModel:
    """The model with the unknowns set to `values` (same order)."""
    material, loads = model.material, model.loads
    gravity, body = list(loads.gravity), list(loads.body_force)
    points = [list(p.force) for p in loads.point_loads]
    pressure = loads.pressure
    for u, v in zip(unknowns, values, strict=True):
        v = float(v)
        if u.kind == "stiffness":
            material = material.with_stiffness(**{u.key: v})
        elif u.kind == "scale":
            material = material.scaled(v / u.reference)
        elif u.kind == "density":
            material = dataclasses.replace(material, areal_density=v)
        elif u.kind == "gravity":
            gravity[u.axis] = v
        elif u.kind == "body_force":
            body[u.axis] = v
        elif u.kind == "pressure":
            pressure = v
        else:
            points[u.key][u.axis] = v
    loads = Loads(gravity=tuple(gravity), body_force=tuple(body), pressure=pressure,
                  point_loads=tuple(PointLoad(p.xi, tuple(f))
                                    for p, f in zip(loads.point_loads, points, strict=True)))
    return model.with_material(material).with_loads(loads)


def residual_samples(model: ShellModel, n: int) -> SurfaceSamples:
    """Tensor Gauss–Legendre quadrature (about n points, float64) of the parameter domain,
    plus a zero-weight sample at every point load. The integrands of the residual method are
    smooth (polynomial fit × virtual field), so Gauss points beat the solver's jittered
    Monte-Carlo samples by orders of magnitude (2k jittered samples leave 5 % errors in B).
    Points outside a masked domain are dropped."""
    (lo1, hi1), (lo2, hi2) = model.surface.domain.bounds
    per_axis = max(int(round(n**0.5)), 4)
    nodes, weights = np.polynomial.legendre.leggauss(per_axis)
    x1 = lo1 + (nodes + 1) * (hi1 - lo1) / 2
    x2 = lo2 + (nodes + 1) * (hi2 - lo2) / 2
    w = np.outer(weights, weights).ravel() * (hi1 - lo1) * (hi2 - lo2) / 4
    xi = torch.from_numpy(np.stack(np.meshgrid(x1, x2, indexing="ij"), -1).reshape(-1, 2))
    weight = torch.from_numpy(w)
    inside = model.surface.domain.contains(xi)
    return with_point_loads(model.surface, xi[inside], weight[inside], model.loads)


def _gradient(model: ShellModel, samples: SurfaceSamples, u_jets: torch.Tensor,
              stiffness: torch.Tensor, loads: Loads, point_force: torch.Tensor) -> torch.Tensor:
    """dΠ/du_jets for a given per-sample stiffness, distributed loads and point forces."""
    s = samples.with_point_force(point_force)
    return ShellEnergy(model.material, loads).evaluate(s, u_jets, stiffness=stiffness).grad_u_jets


def term_gradients(model: ShellModel, unknowns: list[Unknown], samples: SurfaceSamples,
                   u_jets: torch.Tensor) -> tuple[list[torch.Tensor], torch.Tensor]:
    """dT_j/du_jets for every unknown and dΠ_known/du_jets, each shape (N, 6, 3).

    Π_known is Π of the model with every unknown's contribution removed."""
    n = len(samples)
    material, loads = model.material, model.loads
    names = material.stiffness_names
    dtype = torch.float64
    stiffness = torch.tensor(material.stiffness, dtype=dtype).expand(n, -1).clone()
    no_stiffness = torch.zeros(n, len(names), dtype=dtype)
    no_points = torch.zeros_like(samples.point_force)
    # The point loads' samples come last, after any line-load nodes (`with_point_loads`).
    point_rows = torch.arange(n - len(loads.point_loads), n)
    known_points = samples.point_force.clone()
    kinds = {u.kind for u in unknowns}
    known = {"gravity": loads.gravity, "body_force": loads.body_force,
             "pressure": loads.pressure}
    if kinds & {"density", "gravity"}:
        known["gravity"] = (0.0, 0.0, 0.0)
    if "body_force" in kinds:
        known["body_force"] = (0.0, 0.0, 0.0)
    if "pressure" in kinds:
        known["pressure"] = 0.0
    if "scale" in kinds:
        stiffness.zero_()
    columns = []
    for u in unknowns:
        unit_stiffness, unit_loads, unit_points = no_stiffness, Loads(), no_points
        if u.kind == "stiffness":
            k = names.index(u.key)
            stiffness[:, k] = 0.0
            unit_stiffness = no_stiffness.clone()
            unit_stiffness[:, k] = 1.0
        elif u.kind == "scale":
            unit_stiffness = torch.tensor(material.stiffness, dtype=dtype).expand(n, -1) \
                / u.reference
        elif u.kind == "density":
            unit_loads = Loads(body_force=loads.gravity)
        elif u.kind == "gravity":
            unit_loads = Loads(body_force=tuple(material.areal_density * float(i == u.axis)
                                                for i in range(3)))
        elif u.kind == "body_force":
            unit_loads = Loads(body_force=tuple(float(i == u.axis) for i in range(3)))
        elif u.kind == "pressure":
            unit_loads = Loads(pressure=1.0)
        else:
            row = point_rows[u.key]
            known_points[row] = 0.0
            unit_points = no_points.clone()
            unit_points[row, u.axis] = 1.0
        columns.append(_gradient(model, samples, u_jets, unit_stiffness, unit_loads, unit_points))
    known_loads = Loads(gravity=known["gravity"], body_force=known["body_force"],
                        pressure=known["pressure"])
    rest = _gradient(model, samples, u_jets, stiffness, known_loads, known_points)
    return columns, rest
