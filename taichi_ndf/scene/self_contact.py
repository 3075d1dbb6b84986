"""The `[self_contact]` table of a scene file: the sheet cannot pass through itself
(docs/scenes.md, "Self-contact"); in a garment file (a `MultiPatchPlan`) its panels cannot
pass through themselves or each other, the defaults (offset, κ) from the coarsest panel
grid, the thickest material and the largest load per area of any panel."""

from __future__ import annotations

import math
from dataclasses import replace

import torch

from taichi_ndf.contact.config import ContactConfig
from taichi_ndf.contact.self_pairs import (
    SelfContactConfig,
    default_stiffness,
    hole_radius,
)
from taichi_ndf.problem.multipatch import MultiPatchPlan
from taichi_ndf.problem.scaling import load_per_area
from taichi_ndf.problem.spline_grid import SplinePlan
from taichi_ndf.scene.schema import SceneError, Table, checked

# The default offset: this × the coarsest grid's sample hole radius (the sag of the surface
# over a cell comes on top of the half-diagonal).
AUTO_OFFSET_FACTOR = 1.25


def parse_self_contact(top: Table, model, field):
    """`model` with the `[self_contact]` settings on its contact (`ContactConfig.self_contact`),
    or `model` unchanged where the scene has no such table. field: the scene's field
    specification (a `SplinePlan`, or a garment's `MultiPatchPlan`, is required)."""
    if not top.has("self_contact"):
        return model
    t = top.table("self_contact")
    if isinstance(field, MultiPatchPlan):  # a garment: every panel's grid, material, load
        models = [p.model for p in field.patches]
        holes = [_hole_radius(p.model.surface, p.config, p.config.degree + 1)
                 for p in field.patches]
    elif isinstance(field, SplinePlan):
        models, holes = [model], [sample_hole_radius(model.surface, field)]
    else:
        raise SceneError("self_contact: needs a spline field ([field] type = \"spline\", "
                         "projected Newton)")
    activation = t.number("distance", positive=True)
    hole = max(holes)
    offset = _auto(t, "offset")
    if offset is None:
        offset = max(max(float(m.material.thickness) for m in models),
                     AUTO_OFFSET_FACTOR * hole)
    elif offset < hole:
        raise SceneError(f"{t.key('offset')}: {offset:.4g} m is below the coarsest grid's "
                         f"sample hole radius {hole:.4g} m (a layer could pass between the "
                         "samples): raise it, or use more spans")
    stiffness = _auto(t, "stiffness")
    if stiffness is None:
        stiffness = default_stiffness(max(load_per_area(m) for m in models), activation,
                                      offset)
        if stiffness == 0:
            raise SceneError(f"{t.key('stiffness')}: the scene has no load to set it from; "
                             "give it [N/m⁵]")
    exclusion = _auto(t, "exclusion")
    t.close()
    config = checked(lambda: SelfContactConfig(activation, offset, stiffness, exclusion),
                     "self_contact")
    if model.contact is None:  # no [[obstacles]]: the contact rounds with self-contact alone
        return replace(model, contact=ContactConfig.self_only(model, config))
    return replace(model, contact=replace(model.contact, self_contact=config))


def sample_hole_radius(surface, plan: SplinePlan, samples: int = 33) -> float:
    """`hole_radius` [m] of the plan's coarsest grid: its knot spacing times the largest
    |r_,1|, |r_,2| of the surface over a grid of samples² points (uniform knots)."""
    return _hole_radius(surface, plan.config,
                        plan.quadrature_points or plan.config.degree + 1, samples)


def _hole_radius(surface, config, points: int, samples: int = 33) -> float:
    """`hole_radius` [m] of the grid `config` (a `SplineConfig`) with `points` Gauss points
    per span on `surface` (`sample_hole_radius`)."""
    (lo1, hi1), (lo2, hi2) = config.domain
    s = torch.linspace(0, 1, samples, dtype=torch.float64)
    g1, g2 = torch.meshgrid(lo1 + (hi1 - lo1) * s, lo2 + (hi2 - lo2) * s, indexing="ij")
    r = surface.jets(torch.stack((g1.reshape(-1), g2.reshape(-1)), dim=1))
    stretch = (float(r[:, 1].norm(dim=1).max()), float(r[:, 2].norm(dim=1).max()))
    spacing = ((hi1 - lo1) / config.spans[0] * stretch[0],
               (hi2 - lo2) / config.spans[1] * stretch[1])
    return hole_radius(spacing, points)


def _auto(t: Table, name: str) -> float | None:
    """A positive number, or None for "auto" (the default)."""
    if t._get(name, "auto") == "auto":
        return None
    value = t.number(name, positive=True)
    if not math.isfinite(value):
        raise SceneError(f"{t.key(name)}: must be finite, got {value!r}")
    return value
