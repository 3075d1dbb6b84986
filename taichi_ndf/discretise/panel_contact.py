"""A garment's panels against obstacles (`MultiPatchDiscretisation` with `[[obstacles]]`): the
run's `NewtonContact` over the panels' joint chart (`panel_contact`), the seams the contact
rounds evaluate on each round's points (`seams_at`: sewn from where the panels start where
some panel is cut flat), the test that a state the load steps move the held edges to
starts outside the obstacles (`check_outside`, `inside`) and the load step cut until it does
(`outside_step`).

Flat-cut panels (`Patch.start`, `Patch.held`) go through the rounds as through the plain load
steps: each round's linearisation is the chart's `join` of the patches' grids, the
`HeldEdges` map that clamps their held edges (gradient Tᵀ g, Hessian Tᵀ K T, step T z); its
seams are `SewnFromStart` with the start displacement at the round's own points; a held
target's move of the held rows (`held_moves`, a gathered waist) is set before the step's
first round, and that state must be outside the obstacles (the rounds' step test starts
from it). Where it is not (the held rows moved onto their next target with the rest where the
last load step left it: a panel pulled onto the body below a gathered band), the load step is
cut: halved from the last solved load factor until its start is outside, at most MAX_CUTS
times (each cut logged; the next step tries the scene's load step again), the smaller move
leaving the rounds to carry the rest of the panel along; only a step whose smallest cut still
starts inside is refused, ValueError naming the obstacle, the panel and the load factor.

Self-contact (`[self_contact]` in a garment file): the rounds' self-contact term acts between
the Gauss points of all panels (pairs within a panel and across panels, found in the joint
samples; no edge points: a panel's free edge carries none, as on a masked chart). Two points
are neighbours, and never repel, when they START closer than the exclusion radius ρ
(`StartPositions`: r + u of the start coefficients, the placement): a flat-cut panel's rest
shape is its flat pattern, and the patterns of several panels lie on top of each other in
3-D (so rest distances say nothing across panels), while the placement puts the two edges of
a seam next to each other, so points neighbouring across a seam start within ρ. It asks that
the panels start apart by more than ρ where they are not sewn, and that a seam's edges start
closer than ρ − (o + ĝ) (`check_seams_start_close`). The step bound
(`taichi_ndf.contact.self_step`) is over the same points, measured the same way."""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable

import torch

from taichi_ndf.contact.config import check_pins, check_reference
from taichi_ndf.contact.newton_contact import NewtonContact, PointMap
from taichi_ndf.discretise.panel_energy import SewnFromStart
from taichi_ndf.minimise.linearisation import GridLinearisation
from taichi_ndf.minimise.multipatch import MultiPatchGrid
from taichi_ndf.objective.seam import SeamTerm
from taichi_ndf.problem.multipatch import MultiPatchPlan

DTYPE = torch.float64
# The most halvings of a load step whose held edges' move starts inside an obstacle
# (`outside_step`): its smallest cut is 1/64 of the scene's load step.
MAX_CUTS = 6

log = logging.getLogger(__name__)


class StartPositions:
    """Where a garment's Gauss points start, x₀ = r + u(start) [m]: the positions
    self-contact's exclusion radius is measured at on a garment (`SelfContactTerm.rest_at`;
    module docstring). Asked for the self-contact points of a round (xi (M, 2), r (M, 3)):
    the Gauss points of every panel, panel after panel (in the round's samples at each
    panel's own ξ, in the step test at the joint ξ), each found by its reference position in
    its panel's block (by r, not ξ: the rounds' samples carry each panel's own ξ, which
    panels of one size share). chart: the `MultiPatchGrid`; points: each panel's Gauss-point
    samples (its own ξ); start: the joint start coefficients (Σ n_i, 3) at load factor 0."""

    def __init__(self, chart: MultiPatchGrid, points: list, start: torch.Tensor):
        self.tables, self.counts = [], []
        for i, own in enumerate(points):
            gauss = own.weight > 0
            joint = chart.joint(own, i)
            r = own.r_jets[gauss, 0].to(DTYPE)
            x0 = r + PointMap(chart, joint.xi[gauss].to(DTYPE), 0.0)(start.detach())
            self.tables.append(({row.tobytes(): k for k, row in enumerate(r.numpy())}, x0))
            self.counts.append(int(gauss.sum()))
        self._kept: tuple[bytes, torch.Tensor] | None = None

    def __call__(self, xi: torch.Tensor, r: torch.Tensor) -> torch.Tensor:
        rows = r.detach().to(DTYPE).cpu().numpy()
        key = rows.tobytes()
        if self._kept is not None and self._kept[0] == key:
            return self._kept[1]
        if len(rows) != sum(self.counts):
            raise ValueError(f"self-contact on a garment: {len(rows)} points, not the panels' "
                             f"{sum(self.counts)} Gauss points")
        out, first = [], 0
        for (table, x0), count in zip(self.tables, self.counts, strict=True):
            index = [table[row.tobytes()] for row in rows[first:first + count]]
            out.append(x0[index])
            first += count
        self._kept = (key, torch.cat(out).to(r))
        return self._kept[1]


def panel_contact(plan: MultiPatchPlan, model, grids: list[GridLinearisation], join,
                  start: torch.Tensor, seams: list[SeamTerm] = ()) -> tuple[tuple, list]:
    """((contact, chart, quadrature), points): the run's `NewtonContact` over the patches'
    joint chart, the chart (`MultiPatchGrid`, its linearisations `join(grids, t)`: the
    held edges' `HeldEdges`) and its quadrature (the patches' Gauss and seam points there);
    points: each patch's own samples (its grid's, to assemble it on again after the rounds).
    model: the garment's (its `contact`); start: the joint start coefficients (Σ n_i, 3);
    seams: the seams' terms (before `between`; with self-contact `check_seams_start_close`).
    Checked: no obstacle at a pin (`check_pins`), at a placed panel's reference surface
    (`check_reference`) or where a flat-cut panel starts (`check_outside` at load factor 0:
    its rest shape is the flat pattern, not where it is on the body)."""
    config = model.contact
    if config.has_friction:
        raise ValueError("obstacles: friction is not supported on a garment's panels yet")
    for patch in plan.patches:
        patch_model = dataclasses.replace(patch.model, contact=config)
        check_pins(config, patch_model)
        if patch.start is None:
            check_reference(config, patch_model)
    chart = MultiPatchGrid(grids, [p.model.surface for p in plan.patches], join=join)
    points = [grid.assembly.samples for grid in grids]
    quadrature = chart.joint(points[0], 0)
    for i, own in enumerate(points[1:], start=1):
        quadrature = quadrature.joined(chart.joint(own, i))
    contact = NewtonContact(config, model, DTYPE, surface=chart.surface)
    if contact.self_contact is not None:  # neighbours: near where the panels start
        contact.self_contact.rest_at = StartPositions(chart, points, start)
        check_seams_start_close(plan, seams, chart, start, config.self_contact)
    if any(p.start is not None for p in plan.patches):
        check_outside(plan, contact, chart, start, 0.0, "where the panels start")
    return (contact, chart, quadrature), points


def check_seams_start_close(plan: MultiPatchPlan, seams: list[SeamTerm],
                            chart: MultiPatchGrid, start: torch.Tensor, config) -> None:
    """ValueError naming the seam where its two edges start (the joint `start` coefficients)
    more than ρ − (o + ĝ) apart at some seam point (config: the `SelfContactConfig`): points
    across it would not be neighbours by their start distance (module docstring) and would
    repel as the seam is sewn. A guard on the seam points, not a proof for every pair."""
    allowed = config.exclusion - config.offset - config.activation
    for seam, term in zip(plan.seams, seams, strict=True):
        ends = []
        for side, patch in enumerate((seam.a, seam.b)):
            points = chart.joint(term.points(side), patch)
            xi = points.xi.to(DTYPE)
            ends.append(points.r_jets[:, 0].to(DTYPE) + PointMap(chart, xi, 0.0)(start))
        gap = max((float(g) for g in (ends[0] - ends[1]).norm(dim=1)), default=0.0)
        if gap > allowed:
            raise ValueError(f"self_contact: seam {seam.spec.name!r} starts {gap:.4g} m open, "
                             f"more than exclusion − offset − distance = {allowed:.4g} m (its "
                             "sides would repel as it is sewn): place the panels closer or "
                             "raise self_contact.exclusion")


def check_outside(plan: MultiPatchPlan, contact: NewtonContact, chart: MultiPatchGrid,
                  coefficients: torch.Tensor, load_factor: float, when: str) -> None:
    """ValueError (`inside`'s message) where the contact's check grid is inside an obstacle's
    reach at the joint `coefficients` (Σ n_i, 3) and load factor t (`inside`)."""
    message = inside(plan, contact, chart, coefficients, load_factor, when)
    if message is not None:
        raise ValueError(message)


def inside(plan: MultiPatchPlan, contact: NewtonContact, chart: MultiPatchGrid,
           coefficients: torch.Tensor, load_factor: float, when: str) -> str | None:
    """The line naming the obstacle and the panel where a point of the contact's check grid
    (every panel's, edges included) is within h/2 + margin of an obstacle at the joint
    `coefficients` (Σ n_i, 3) and load factor t; `when` says which state it is. None: every
    point is outside."""
    points = contact.points
    xi = points.grid_xi.to(DTYPE)
    x = points.grid_r.to(DTYPE) + PointMap(chart, xi, load_factor)(coefficients)
    gaps = points.term.gaps(x, load_factor)[0]  # (N, obstacles)
    if not gaps.shape[1] or float(gaps.min()) > 0:
        return None
    worst = int(gaps.min(dim=1).values.argmin())
    obstacle = int(gaps[worst].argmin())
    panel = plan.patches[int(chart.patch_of(xi[worst:worst + 1])[0])].name
    config = contact.config
    distance = float(gaps[worst, obstacle]) + config.offset
    return (f"obstacle {config.obstacles[obstacle].name!r} intersects panel {panel!r} "
            f"{when} (load factor {load_factor:g}: distance {distance:.4g} m, needs "
            f"more than h/2 + margin = {config.offset:.4g} m)")


def outside_step(previous: float, goal: float, span: float,
                 refused: Callable[[float], str | None], cuts: int = MAX_CUTS) -> float:
    """The load factor of the next load step from `previous` (the last one solved) towards
    `goal` (the next of the scene's load steps, `span` after the one before it): `goal`
    where the state the step starts from is outside the obstacles (`refused(t)`: None, else
    the line naming where it is inside), else the step from `previous` halved until it is,
    each cut logged, down to span / 2^cuts; ValueError with `refused`'s line where the
    smallest cut still starts inside. The steps are at least span / 2^cuts long, so a
    scene's load step is reached in at most 2^cuts of them."""
    smallest = span / 2 ** cuts
    t = goal
    while (message := refused(t)) is not None:
        cut = previous + 0.5 * (t - previous)
        if cut - previous < smallest * (1.0 - 1e-9):
            raise ValueError(f"{message}; the load step cut {cuts} times, to "
                             f"{smallest:.3g}, still starts inside")
        log.info("load factor %g: %s; the load step cut to %g", t, message, cut)
        t = cut
    return t


def seams_at(plan: MultiPatchPlan, seams: list[SeamTerm], start: torch.Tensor | None):
    """terms_at(linearisation) of the contact rounds: the seams, their points looked up in
    each round's patch rows; start: the joint start coefficients where the seams are sewn
    from where the panels start (`SewnFromStart`, its start displacement at the round's
    samples), None: from their rest shapes."""
    def terms(linear):
        between = [term.between(linear.rows(s.a), linear.rows(s.b))
                   for s, term in zip(plan.seams, seams, strict=True)]
        if start is None:
            return tuple(between)
        u = linear.displacement(start)
        return tuple(SewnFromStart(term, u) for term in between)
    return terms
