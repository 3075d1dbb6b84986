"""A garment's panels against obstacles (`MultiPatchDiscretisation` with `[[obstacles]]`): the
run's `NewtonContact` over the panels' joint chart (`panel_contact`) and the seams the contact
rounds evaluate on each round's points (`seams_at`)."""

from __future__ import annotations

import dataclasses

import torch

from taichi_ndf.contact.newton_contact import NewtonContact
from taichi_ndf.minimise.linearisation import GridLinearisation
from taichi_ndf.minimise.multipatch import MultiPatchGrid
from taichi_ndf.objective.seam import SeamTerm
from taichi_ndf.problem.multipatch import MultiPatchPlan, obstacle_refusal

DTYPE = torch.float64


def panel_contact(plan: MultiPatchPlan, model, grids: list[GridLinearisation]
                  ) -> tuple[tuple, list]:
    """((contact, chart, quadrature), points): the run's `NewtonContact` over the patches'
    joint chart (each patch checked: no obstacle at its reference surface or pins), the chart
    (`MultiPatchGrid`) and its quadrature (the patches' Gauss and seam points there); points:
    each patch's own samples (its grid's, to assemble it on again after the rounds). model:
    the garment's (its `contact`)."""
    config = model.contact
    if config.has_friction:
        raise ValueError("obstacles: friction is not supported on a garment's panels yet")
    refused = obstacle_refusal(plan)
    if refused:
        raise ValueError(refused)
    for patch in plan.patches:
        config.check(dataclasses.replace(patch.model, contact=config))
    chart = MultiPatchGrid(grids, [p.model.surface for p in plan.patches])
    points = [grid.assembly.samples for grid in grids]
    quadrature = chart.joint(points[0], 0)
    for i, own in enumerate(points[1:], start=1):
        quadrature = quadrature.joined(chart.joint(own, i))
    return (NewtonContact(config, model, DTYPE, surface=chart.surface), chart,
            quadrature), points


def seams_at(plan: MultiPatchPlan, seams: list[SeamTerm]):
    """terms_at(linearisation) of the contact rounds: the seams, their points looked up in
    each round's patch rows."""
    return lambda linear: tuple(term.between(linear.rows(s.a), linear.rows(s.b))
                                for s, term in zip(plan.seams, seams, strict=True))
