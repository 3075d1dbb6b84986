"""Contact on the spline + projected-Newton path (`method = "newton"`; docs/contact.md).

Each load step on each grid (`ContactMinimiser`, a `Minimiser` the drivers run through
`run_phases` as any other: the static spline solve's load steps, the dynamics' time steps) runs
in rounds:
1. the dense check grid (check_resolution² points of the run's `ContactHook`) is evaluated
   at the current coefficients; its points within the activation distance ĝ become check
   points for good;
2. the quadrature is the fixed Gauss points (shell energy and loads, barrier weight 0) and
   the check points (the barrier with the grid's trapezoidal weights, shell weight 0), as on
   the SIREN path; an `Assembly` is built on them and projected Newton minimises
   Π + Π_c (+ friction) there, with the barrier's PSD blocks in K;
3. the line search rejects a trial in which a Gauss point or *any* point of the dense grid
   could enter an obstacle (the hook's `feasible`, `ContactPoints.step_allowed`: each point
   outside moves by less than its gap, so, the signed distance being 1-Lipschitz, it cannot
   enter or tunnel);
   with self-contact (`ContactConfig.self_contact`) its barrier between the Gauss points and
   the chart's edge points (`taichi_ndf.objective.self_contact`, pairs found afresh at each
   evaluation, its pair blocks in K; the edge points join the round's samples with weight 0,
   `NewtonContact.edge_samples`) is one more term, and the trial must also keep every such
   pair's gap (`taichi_ndf.contact.self_step`);
4. after each accepted Newton iterate the grid is evaluated again (and κ raised if a point
   came closer than ĝ/10; the hook's `look_ahead`); when points came within ĝ (or within
   ĝ + LOOK_AHEAD × their last move: they could by the next steps), Newton stops there,
   they are added, the Assembly is rebuilt and the next round goes on from that state.
Rounds end when Newton converged and no point was added (and, with friction, the lagged
normal forces changed by less than LAG_TOLERANCE of their largest), at most MAX_ROUNDS.

Friction (`taichi_ndf.contact.friction`) is lagged per round: the normal forces and normals
of the round's starting state, the positions at the start of the load step.

A checkpoint inside a grid level holds the contact's state (`NewtonContact.to_dict`: the
check points, κ, the rounds so far and, inside a load step, its round: the round's index,
the coefficients and κ it started from (friction's lag is recomputed from them), whether the lag
changed, the step's Newton iterations of its finished rounds); `restore` and
`ContactMinimiser(..., resume=)` go on from there bit for bit
(`taichi_ndf.solve.spline_solver`).
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass
from typing import Protocol

import torch

from taichi_ndf import jets
from taichi_ndf.contact.config import FRICTION_SMOOTHING, ContactConfig
from taichi_ndf.contact.friction import FrictionTerm
from taichi_ndf.contact.hook import ContactHook
from taichi_ndf.contact.self_pairs import edge_points
from taichi_ndf.minimise.assembly import displacement_at
from taichi_ndf.minimise.linearisation import PointJacobian
from taichi_ndf.minimise.minimisers import Hooks, MinimiseResult, NewtonMinimiser
from taichi_ndf.minimise.newton import NewtonIteration
from taichi_ndf.minimise.newton_state import NewtonIterate
from taichi_ndf.objective import Objective
from taichi_ndf.objective.self_contact import SelfContactTerm
from taichi_ndf.problem.sampling import SurfaceSamples
from taichi_ndf.shell.hessian import JET_SIZE, project_psd

log = logging.getLogger(__name__)

MAX_ROUNDS = 50
LAG_TOLERANCE = 1e-3


class ContactGrid(Protocol):
    """What the contact rounds take of a discretisation's points: one grid's
    `GridLinearisation` and several patches' `minimise.multipatch.MultiPatchGrid` alike."""

    def at_points(self, xi: torch.Tensor, load_factor: float) -> PointJacobian:
        """The displacement jets at ξ (N, 2) (its chart) as an affine map of the
        coefficients: index (N, k) of the unknowns, offset, Jacobian, a free pin's part."""

    def linearisation(self, load_factor: float, samples: SurfaceSamples):
        """A new assembly on `samples` at load factor t (`samples`, `displacement`,
        `gradient`, `hessian`, `solve`: what `newton.minimise` takes)."""


class PointMap:
    """Displacement values u (N, 3) [m] at fixed ξ (N, 2) as a function of the coefficients
    (n, 3) of the grid's field, at a load factor (affine: precomputed once,
    `ContactGrid.at_points`)."""

    def __init__(self, grid: ContactGrid, xi: torch.Tensor, load_factor: float):
        at = grid.at_points(xi, load_factor)
        self.index, self.pin_index = at.index, at.pin_index
        self.offset = at.offset[:, jets.VALUE]
        self.jacobian = at.jacobian.channels([jets.VALUE])  # (3, N, 1, k)
        self.pin = None if at.pin is None else at.pin[:, 0, jets.VALUE]  # (3, k)

    def __call__(self, coefficients: torch.Tensor) -> torch.Tensor:
        u = self.offset + self.jacobian.apply(coefficients[self.index])[:, 0]
        if self.pin is not None:
            u = u + torch.einsum("ca,ac->c", self.pin, coefficients[self.pin_index])
        return u


def _subset(samples: SurfaceSamples, rows: torch.Tensor) -> SurfaceSamples:
    return SurfaceSamples(*(None if t is None else t[rows] for t in (
        samples.xi, samples.r_jets, samples.weight, samples.point_force,
        samples.barrier_weight)))


@dataclass(frozen=True)
class ContactPotential:
    """Π + the contact terms at a load factor, the form `minimise` takes. Its Hessian blocks
    are the contact terms' (analytic) at every sample plus `objective`'s (the shell's) only at
    the samples with shell weight or a point force: at the check points (shell weight 0) those
    are exactly zero, and skipping them saves most of the Hessian's time once the check points
    outnumber the Gauss points (a shell term of rows, `PanelEnergy`, `restricted` to them).
    A contact term with couplings (self-contact) gives its pair blocks (`coupled_blocks`)
    instead of per-point ones."""

    objective: Objective  # without the contact terms
    terms: tuple
    load_factor: float

    def __call__(self, samples: SurfaceSamples, u_jets: torch.Tensor, grad: bool):
        return self.objective.with_terms(*self.terms).evaluate(samples, u_jets,
                                                                 self.load_factor, grad=grad)

    def hessian_blocks(self, samples: SurfaceSamples, u_jets: torch.Tensor, *,
                       steps: torch.Tensor, psd: bool = False) -> torch.Tensor:
        """Per-point blocks (N, 6, 3, 6, 3), not projected (`Objective.hessian_blocks`); psd:
        positive semi-definite instead, the contact terms' clamped (`project_psd`) and the
        objective's through the strains (`Objective.hessian_blocks`' psd)."""
        blocks = sum(term.hessian_blocks(samples, u_jets, self.load_factor, steps=steps)
                     for term in self.terms if hasattr(term, "hessian_blocks"))
        if psd:
            blocks = project_psd(blocks.reshape(blocks.shape[0], JET_SIZE, JET_SIZE),
                                 overwrite=True)[0].reshape(blocks.shape)
        rows = (samples.weight > 0) | (samples.point_force != 0).any(dim=1)
        objective = self.objective
        if hasattr(objective.shell, "restricted"):  # a shell term of rows (`PanelEnergy`)
            objective = Objective(objective.shell.restricted(rows), objective.extra)
        blocks[rows] += objective.hessian_blocks(_subset(samples, rows), u_jets[rows],
                                                 self.load_factor, steps=steps, psd=psd)
        return blocks

    def psd_hessian_blocks(self, samples: SurfaceSamples, u_jets: torch.Tensor, *,
                           steps: torch.Tensor) -> torch.Tensor:
        """Positive semi-definite per-point blocks (projected Newton's "strain" treatment,
        as `Objective`'s: `hessian_blocks`' psd)."""
        return self.hessian_blocks(samples, u_jets, steps=steps, psd=True)

    def coupled_blocks(self, samples: SurfaceSamples, u_jets: torch.Tensor):
        """Hessian entries between pairs of points of all the terms (`Couplings` or None)."""
        return self.objective.with_terms(*self.terms).coupled_blocks(samples, u_jets,
                                                                     self.load_factor)

    def second_order_gradient(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                              step_jets: torch.Tensor) -> torch.Tensor | None:
        """The residual of Newton's second-order correction (`Objective.second_order_gradient`:
        the shell's; zero at the check points, of shell weight 0; the contact terms have none).
        The corrected point passes the line search's `feasible` like any other."""
        return self.objective.second_order_gradient(samples, u_jets, step_jets)


class NewtonContact:
    """The contact of one spline solve: the check points (kept over load steps and grid
    levels and time steps) and the terms it adds to the objective; its load-step solve is
    `ContactMinimiser`.

    config: the model's `ContactConfig`; model: the `ShellModel` (checked: no obstacle at the
    reference surface or a pin); dtype: of the solve; surface: the reference surface the check
    grid covers, in the chart of the rounds' grid (None: the model's; several patches: their
    `MultiPatchGrid.surface`, each patch checked by the caller)."""

    def __init__(self, config: ContactConfig, model, dtype: torch.dtype, *, surface=None):
        self.config = config
        self.hook = ContactHook.of_model(model, dtype, both_ends=False, surface=surface)
        self.friction = None
        if config.has_friction:
            self.friction = FrictionTerm(self.points.term, config.friction,
                                         FRICTION_SMOOTHING * config.activation)
        self.rounds = 0  # Newton rounds over all load steps and levels
        self.self_contact = None if config.self_contact is None else \
            SelfContactTerm(config.self_contact)
        # the chart whose free edges carry self-contact points: one grid's unmasked rectangle
        domain = model.surface.domain
        self._edge_surface = model.surface if (
            self.self_contact is not None and config.self_contact.edges and surface is None
            and domain.inside is None) else None
        self._round = None  # the load step's round in progress (`to_dict`)

    def to_dict(self) -> dict:
        """The contact's state as plain values (module docstring): the check points (mask
        over the dense grid), κ [N/m³], the rounds so far and the round in progress (None
        between load steps: index, start coefficients (n, 3), lag changed, the step's
        iterations of its finished rounds)."""
        within = None
        if self._round is not None:
            index, start, stiffness, lag_changed, history = self._round
            within = {"index": index, "start": start, "stiffness": stiffness,
                      "lag_changed": lag_changed, "history": [asdict(h) for h in history]}
        return {"active": self.points.active.clone(), "stiffness": self.points.term.stiffness,
                "rounds": self.rounds, "round": within}

    def restore(self, values: dict) -> None:
        """Take the state `to_dict` gave (the round in progress: for
        `ContactMinimiser(..., resume=)`)."""
        points = self.points
        active = values["active"]
        if active.shape != points.active.shape:
            raise ValueError(f"the checkpoint's contact has {len(active)} check-grid points, "
                             f"this run's {len(points.active)}")
        points.active, points._samples = active.clone(), None
        points.term.stiffness = float(values["stiffness"])
        self.rounds = int(values["rounds"])
        within = values["round"]
        self._round = None if within is None else (
            int(within["index"]), within["start"], float(within["stiffness"]),
            bool(within["lag_changed"]),
            [NewtonIteration(**h) for h in within["history"]])

    @property
    def points(self):
        """The hook's `ContactPoints` (the check grid and the check points so far)."""
        return self.hook.points

    def minimiser(self, config=None, **settings) -> ContactMinimiser:
        """A load step's `ContactMinimiser` on this contact (settings: its keywords)."""
        return ContactMinimiser(self, config, **settings)

    def edge_samples(self, quadrature: SurfaceSamples) -> SurfaceSamples | None:
        """The self-contact edge points of the grid whose Gauss points are `quadrature`, as
        samples of weight 0 (`taichi_ndf.contact.self_pairs.edge_points`), set on the
        self-contact term; None (and none set) without self-contact edges."""
        if self._edge_surface is None:
            return None
        area = quadrature.weight > 0
        domain = self._edge_surface.domain
        edges = edge_points(quadrature.xi[area], quadrature.weight[area], domain.bounds,
                            domain.periodic)
        self.self_contact.edges = edges
        zero = edges.weight.new_zeros(len(edges.xi))
        return SurfaceSamples(edges.xi, self._edge_surface.jets(edges.xi).to(zero), zero,
                              edges.weight.new_zeros(len(edges.xi), 3), zero)

    @property
    def terms(self) -> tuple:
        """The energy terms contact adds to the objective (`ContactPotential`)."""
        return (self.points.term,) + tuple(
            t for t in (self.friction, self.self_contact) if t is not None)


class ContactMinimiser:
    """The contact rounds of one load step behind the minimiser interface (`Minimiser`; module
    docstring): each round is `inner`'s Newton (`NewtonMinimiser`) on the round's points with
    the barrier, bounded by the hook's `feasible`; between rounds the check points, κ and
    friction's lag are updated. A driver runs it through `run_phases` as any minimiser.

    contact: the run's `NewtonContact` (its state carries over load steps, levels and time
    steps); config: Newton's settings; load_factor: t of the step; start_load_factor: the load
    factor of the starting coefficients (friction's start-of-step positions);
    terms_at(linearisation) -> tuple: further terms evaluated, like the contact terms, at every
    sample of a round's linearisation (made per round, in its sample order: a time step's
    `InertiaTerm`, its target at those samples, `taichi_ndf.solve.dynamics`; a garment's seams,
    their rows among the round's samples); base_at(linearisation) -> Objective: Π without
    the contact terms built per round on the round's linearisation (a garment's shell term
    over each panel's rows among the round's samples, `PanelEnergy`), in place of the
    objective's fixed one; report: Newton's progress reports; resume:
    Newton's iterate inside the round `NewtonContact.restore` gave (its check points, κ,
    round): the step goes on from there bit for bit; inner(config, **settings): the Minimiser
    of a round."""

    def __init__(self, contact: NewtonContact, config=None, *, load_factor: float,
                 start_load_factor: float, terms_at=None, base_at=None, report: bool = True,
                 resume: NewtonIterate | None = None, inner=NewtonMinimiser):
        self.contact, self.config, self.inner = contact, config, inner
        self.load_factor, self.start_load_factor = load_factor, start_load_factor
        self.terms_at, self.base_at = terms_at, base_at
        self.report, self.resume = report, resume

    def minimise(self, objective: tuple, parameters: torch.Tensor, hooks: Hooks | None = None
                 ) -> MinimiseResult:
        """objective = (grid, quadrature, Π): the linearisation builder (`ContactGrid`: one
        grid's `GridLinearisation` or several patches' `MultiPatchGrid`; each round assembles
        it anew on the round's points), its Gauss-point samples (in its chart) and Π without
        the contact terms (`ContactPotential` adds them; None where `base_at` builds it per
        round); parameters: the starting coefficients (n, 3).
        hooks.on_iteration, hooks.on_iterate: each round's Newton's (on_iterate: after each
        Newton step a round goes on from; `NewtonContact.to_dict` then holds the round)."""
        grid, quadrature, base = objective
        contact, t, resume = self.contact, self.load_factor, self.resume
        points = contact.points
        dtype = parameters.dtype
        grid_xi = points.grid_xi.to(dtype)
        area = quadrature.weight > 0
        edges = contact.edge_samples(quadrature)  # self-contact's edge points, or None
        selfs = [quadrature.xi[area]] + ([] if edges is None else [edges.xi])
        checked_xi = torch.cat(selfs + [grid_xi])
        checked_r = torch.cat([quadrature.r_jets[area, jets.VALUE]] + (
            [] if edges is None else [edges.r_jets[:, jets.VALUE]]) + [points.grid_r.to(dtype)])
        if edges is not None:  # in every round's samples, after the Gauss points
            quadrature = quadrature.joined(edges)
        checked = PointMap(grid, checked_xi, t)
        on_grid = slice(sum(len(x) for x in selfs), None)
        start = parameters
        # after each Newton iterate: the grid's points within ĝ (+ the look-ahead) added
        refresh = contact.hook.look_ahead(lambda c: checked(c)[on_grid], t)
        # the Gauss (and edge) points come first among the checked points: self-contact's
        selves = slice(on_grid.start)
        feasible = contact.hook.feasible(lambda c: checked_r + checked(c), t, self_rest=(
            None if contact.self_contact is None else
            contact.self_contact.rest(checked_xi[selves], checked_r[selves])))

        history, c, solution, lagged, first = [], parameters, None, None, 0
        if resume is None:
            contact._round = None
            refresh(start)
        else:  # the look-ahead's last positions: the iterate's (refreshed there before)
            first, c, stiffness, resumed_lag, history = contact._round
            kept = points.active.clone(), points.term.stiffness
            refresh(resume.parameters)
            points.active, points._samples, points.term.stiffness = kept[0], None, kept[1]
        for _round in range(first, MAX_ROUNDS):
            if resume is None:
                contact.rounds += 1
            count = points.count
            linearisation = grid.linearisation(t, points.augment(quadrature))
            extra = () if self.terms_at is None else tuple(self.terms_at(linearisation))
            if self.base_at is not None:
                base = self.base_at(linearisation)
            potential = ContactPotential(base, contact.terms + extra, t)
            lag_changed = False
            if resume is None:
                stiffness = points.term.stiffness  # κ at the round's start
            if contact.friction is not None:  # lagged at the round's start (and its κ)
                held, points.term.stiffness = points.term.stiffness, stiffness
                s = linearisation.samples
                x0 = s.r_jets[:, jets.VALUE] + displacement_at(
                    grid.operator, s.xi, start, self.start_load_factor)[:, jets.VALUE]
                capacity = contact.friction.lag(s, linearisation.displacement(c), t, x0,
                                                self.start_load_factor)
                if lagged is None or len(lagged) != len(capacity):
                    lag_changed = bool((capacity > 0).any())
                else:
                    change = float((capacity - lagged).abs().max())
                    lag_changed = change > LAG_TOLERANCE * float(capacity.abs().max())
                lagged = capacity
                points.term.stiffness = held
            if resume is not None:
                lag_changed = resumed_lag
            contact._round = (_round, c, stiffness, lag_changed, list(history))
            solution = self.inner(self.config, load_factor=t, feasible=feasible,
                                  on_step=refresh, report=self.report, resume=resume
                                  ).minimise((linearisation, potential), c, hooks or Hooks())
            resume = None
            history += solution.history
            c = solution.parameters
            refresh(c)
            added = points.count - count
            log.debug("contact round at λ=%.3g: %d Newton steps, %d check points added "
                      "(%d in all), κ %.4g", t, len(solution.history), added, points.count,
                      points.term.stiffness)
            if not added and not lag_changed:
                break
        else:
            log.warning("contact: %d rounds at load factor %g without settling the check "
                        "points", MAX_ROUNDS, t)
        contact._round = None
        return MinimiseResult(sum(h.step_length > 0 for h in history),
                              history[0].energy if history else solution.energy,
                              solution.energy, solution.converged and not added, c, history)
