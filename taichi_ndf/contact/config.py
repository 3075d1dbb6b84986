"""Contact settings of a model: obstacles, offset, activation distance, barrier stiffness.

Rules (docs/contact.md):
- offset = h/2 + margin: the mid-surface keeps h/2 (the material's thickness) plus a margin
  [m] from every obstacle; by default margin = MARGIN_FRACTION × ĝ, which absorbs the sag of
  the surface between the points of the dense check grid.
- activation distance ĝ: by default ACTIVATION_FRACTION × the surface's characteristic length
  √A.
- barrier stiffness κ [N/m³]: by default the one that carries the scene's load per area q at a
  gap of ĝ/2 when the whole load rests on the obstacle: κ |b'(ĝ/2)| = q with |b'(ĝ/2)| =
  (ln 2 + 1/2) ĝ, q = `taichi_ndf.problem.scaling.load_per_area` (|ρ_A g + body force| + |pressure|
  + Σ|P_k| / A). A scene without loads
  (driven by prescribed motions only) must give κ.
- friction: the Coulomb coefficient μ ≥ 0 of each obstacle (0: frictionless); its smoothing
  distance ε = FRICTION_SMOOTHING × ĝ (`taichi_ndf.contact.friction`).
- self-contact (optional): the barrier between points of the sheet itself, its own settings
  (`taichi_ndf.contact.self_pairs.SelfContactConfig`: its own ĝ, offset and κ rule), solved
  in the same contact rounds. It needs no obstacle: `ContactConfig.self_only` is the contact
  of a sheet with self-contact alone (no obstacle, so the obstacle barrier acts nowhere: its
  stiffness is 0, its activation distance the self-contact's ĝ, its check grid the smallest,
  2², since no grid point can come near an obstacle).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from taichi_ndf.boundary import Handle, PinnedPoint
from taichi_ndf.contact.barrier import ContactTerm, barrier_slope_at_half
from taichi_ndf.problem.scaling import load_per_area

ACTIVATION_FRACTION = 5e-3
MARGIN_FRACTION = 0.1
DEFAULT_CHECK_RESOLUTION = 64
FRICTION_SMOOTHING = 1e-2


@dataclass(frozen=True)
class ContactConfig:
    """obstacles: the rigid obstacles; thickness: h [m]; margin [m] added to h/2;
    activation: ĝ [m]; stiffness: κ [N/m³]; check_resolution: points per surface coordinate
    of the dense check grid; friction: μ per obstacle (empty: 0 for all); self_contact: a
    `SelfContactConfig` or None (no self-contact)."""

    obstacles: tuple
    thickness: float
    activation: float
    stiffness: float
    margin: float = 0.0
    check_resolution: int = DEFAULT_CHECK_RESOLUTION
    friction: tuple = ()
    self_contact: object = None

    def __post_init__(self):
        if not self.obstacles and self.self_contact is None:
            raise ValueError("contact needs at least one obstacle (or self-contact)")
        names = [o.name for o in self.obstacles]
        if len(set(names)) != len(names):
            raise ValueError(f"obstacle names must be unique, got {names}")
        for name in ("thickness", "activation", "stiffness", "margin"):
            value = getattr(self, name)
            # without obstacles the obstacle barrier's stiffness is 0 (`self_only`)
            zero = name == "margin" or (name == "stiffness" and not self.obstacles)
            if not math.isfinite(value) or value < 0 or (not zero and value == 0):
                raise ValueError(f"contact {name} must be finite and "
                                 f"{'>= 0' if zero else '> 0'}, got {value!r}")
        friction = tuple(float(m) for m in self.friction) or (0.0,) * len(self.obstacles)
        if len(friction) != len(self.obstacles):
            raise ValueError(f"contact friction: one coefficient per obstacle "
                             f"({len(self.obstacles)}), got {len(friction)}")
        for obstacle, mu in zip(self.obstacles, friction, strict=True):
            if not (math.isfinite(mu) and mu >= 0):
                raise ValueError(f"obstacle {obstacle.name!r}: friction must be finite and "
                                 f">= 0, got {mu!r}")
        object.__setattr__(self, "friction", friction)
        if self.check_resolution < 2:
            raise ValueError(f"contact check_resolution must be >= 2, got "
                             f"{self.check_resolution}")

    @property
    def has_friction(self) -> bool:
        return any(mu > 0 for mu in self.friction)

    @property
    def offset(self) -> float:
        """h/2 + margin [m]."""
        return 0.5 * self.thickness + self.margin

    def term(self) -> ContactTerm:
        return ContactTerm(self.obstacles, offset=self.offset, activation=self.activation,
                           stiffness=self.stiffness)

    @classmethod
    def resolve(cls, obstacles, model, *, margin: float | None = None,
                activation: float | None = None, stiffness: float | None = None,
                check_resolution: int = DEFAULT_CHECK_RESOLUTION,
                friction: tuple = ()) -> ContactConfig:
        """Settings for `model` (a `ShellModel`) with the default rules of the module
        docstring for what is not given."""
        if activation is None:
            activation = ACTIVATION_FRACTION * model.characteristic_length()
        if margin is None:
            margin = MARGIN_FRACTION * activation
        if stiffness is None:
            stiffness = load_per_area(model) / (barrier_slope_at_half() * activation)
            if stiffness == 0:
                raise ValueError("the scene has no load to set the contact stiffness from; "
                                 "give it (contact stiffness [N/m³])")
        return cls(tuple(obstacles), float(model.material.thickness), float(activation),
                   float(stiffness), float(margin), int(check_resolution), tuple(friction))

    @classmethod
    def self_only(cls, model, self_contact) -> ContactConfig:
        """The contact of `model` (a `ShellModel`) with self-contact (a `SelfContactConfig`)
        and no obstacle (module docstring): obstacle stiffness 0, activation distance the
        self-contact's ĝ, the 2² check grid."""
        return cls((), float(model.material.thickness), float(self_contact.activation), 0.0,
                   0.0, 2, (), self_contact)

    def check(self, model) -> None:
        """ValueError naming the obstacle when it intersects the reference surface or a
        pinned point or handle (`check_reference`, `check_pins`); needs the Taichi runtime
        (mesh obstacles), so the solver calls it rather than the scene parser."""
        check_pins(self, model)
        check_reference(self, model)


def check_reference(config: ContactConfig, model, resolution: int = 129) -> None:
    """ValueError naming the obstacle when the undeformed reference surface (a grid of
    resolution² points) lies within h/2 + margin of it at load factor 0: the solve must start
    from a state without contact penetration."""
    (lo1, hi1), (lo2, hi2) = model.surface.domain.bounds
    s = torch.linspace(0, 1, resolution, dtype=torch.float64)
    g1, g2 = torch.meshgrid(lo1 + (hi1 - lo1) * s, lo2 + (hi2 - lo2) * s, indexing="ij")
    xi = torch.stack((g1.reshape(-1), g2.reshape(-1)), dim=1)
    xi = xi[model.surface.domain.contains(xi)]
    gaps, _ = config.term().gaps(model.surface.jets(xi)[:, 0], 0.0)
    for k, obstacle in enumerate(config.obstacles):
        worst = int(gaps[:, k].argmin())
        if float(gaps[worst, k]) <= 0:
            raise ValueError(
                f"obstacle {obstacle.name!r} intersects the reference surface (at ξ="
                f"{tuple(round(float(v), 6) for v in xi[worst])}, distance "
                f"{float(gaps[worst, k]) + config.offset:.4g} m, needs more than h/2 + margin "
                f"= {config.offset:.4g} m)")


def check_pins(config: ContactConfig, model) -> None:
    """ValueError naming the obstacle and the constraint when a pinned point or a handle lies
    within h/2 + margin of an obstacle (or inside it) at rest or at full load."""
    term = config.term()
    pins = [c for c in model.boundary.constraints if isinstance(c, (PinnedPoint, Handle))]
    for pin in pins:
        xi = torch.tensor([pin.xi], dtype=torch.float64)
        x0 = model.surface.jets(xi)[:, 0]
        moved = getattr(pin, "displacement", (0.0, 0.0, 0.0))
        for load_factor in (0.0, 1.0):
            x = x0 + load_factor * x0.new_tensor(moved)
            gaps, _ = term.gaps(x, load_factor)
            for k, obstacle in enumerate(config.obstacles):
                if float(gaps[0, k]) <= 0:
                    raise ValueError(
                        f"obstacle {obstacle.name!r} intersects the {type(pin).__name__} at "
                        f"ξ={pin.xi} (load factor {load_factor:g}): its distance "
                        f"{float(gaps[0, k]) + config.offset:.4g} m is not more than "
                        f"h/2 + margin = {config.offset:.4g} m")


def contact_summary(config: ContactConfig, points, load_factor: float = 1.0) -> dict:
    """For result.json: the smallest signed distance [m] of the shell's faces (mid-surface
    distance − h/2) and the smallest gap (also − margin) over points (N, 3) [m] (the output
    mesh's vertices), per obstacle and overall."""
    x = torch.as_tensor(points, dtype=torch.float64)
    gaps, _ = config.term().gaps(x, load_factor)
    per = {o.name: float(gaps[:, k].min()) + config.margin
           for k, o in enumerate(config.obstacles)}
    nearest = min(per.values()) if per else None  # None: no obstacle (`self_only`)
    return {"min_signed_distance": nearest,
            "min_gap": None if nearest is None else nearest - config.margin,
            "min_signed_distance_per_obstacle": per, "offset": config.offset,
            "activation_distance": config.activation, "stiffness": config.stiffness}


def write_obstacles(config: ContactConfig, out, load_factor: float = 1.0) -> list[str]:
    """obstacles/<name>.obj of every obstacle at the load factor in the run directory `out`
    (an `OutputDir`); returns the file names."""
    from taichi_ndf.io import write_obj

    names = []
    for obstacle in config.obstacles:
        vertices, faces = obstacle.triangles(load_factor)
        name = f"obstacles/{obstacle.name}.obj"
        write_obj(out.file(name), vertices, faces)
        names.append(name)
    return names
