"""Contact as one hook that every minimiser calls (docs/contact.md, docs/architecture.md).

A `ContactHook` is made once per run from the model's contact (`ContactHook.of_model`) and
holds its `ContactPoints` (the dense check grid and the check points so far). The drivers ask
it, and nothing else, about contact:
- `feasible_start(displacement, t, restart)`: the grid evaluated at the starting state; where
  it touches an obstacle, `restart()` (a SIREN: its output layer set to zero) and again;
- `check(start, t)`: the test of steps from one state of the checked points (a `StepCheck`,
  the start's gaps computed once), with the run's rule (`both_ends`);
- `feasible(positions, t)`: the same test between two parameter states, the `feasible(P,
  P_trial)` of a Newton line search (`taichi_ndf.minimise.newton.minimise`); with
  self-contact (`self_contact`) the trial must also pass the self-contact step test
  (`taichi_ndf.contact.self_step`) on the self-contact points among the checked ones;
- `accept(check, before, after, move, positions)`: the acceptance policy of a step that has
  been taken: kept where the test allows it, else halved towards `before` up to `halvings`
  times, else undone (Adam's step; any step whose end can be set);
- `refresh(displacement, t)` after an accepted state and `look_ahead(grid_displacement, t)`
  after each Newton iterate: the grid points that came close become check points.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import torch

from taichi_ndf.contact.check_points import ContactPoints
from taichi_ndf.contact.self_step import self_step_allowed

log = logging.getLogger(__name__)

# Most halvings of a step that makes a checked point penetrate before it is undone.
HALVINGS = 10
# Newton's refresh also adds the grid points within ĝ + LOOK_AHEAD × their last move [m].
LOOK_AHEAD = 4.0


@dataclass(frozen=True)
class StepCheck:
    """The penetration test of steps from one state of the checked points
    (`ContactHook.check`): start (M, 3) [m] and their gaps start_gap (M,) [m]."""

    points: ContactPoints
    start: torch.Tensor
    start_gap: torch.Tensor
    load_factor: float
    both_ends: bool

    def allows(self, end: torch.Tensor, *, end_gap: torch.Tensor | None = None) -> bool:
        """Whether the step to `end` (M, 3) [m] is allowed (`ContactPoints.step_allowed`;
        end_gap: the gaps at `end` where the caller has them)."""
        return self.points.step_allowed(self.start, self.start_gap, end, self.load_factor,
                                        both_ends=self.both_ends, end_gap=end_gap)


class ContactHook:
    """The contact of one run, as every minimiser asks it (module docstring).

    points: the `ContactPoints`; both_ends: the step test's rule (`step_allowed`);
    halvings: most halvings of a refused step (`accept`); self_contact: the
    `SelfContactConfig` of the sheet's self-contact, or None."""

    def __init__(self, points: ContactPoints, *, both_ends: bool, halvings: int = HALVINGS,
                 self_contact=None):
        if halvings < 0:
            raise ValueError(f"halvings must be >= 0, got {halvings}")
        self.points = points
        self.both_ends = both_ends
        self.halvings = halvings
        self.self_contact = self_contact

    @classmethod
    def of_model(cls, model, dtype: torch.dtype, *, both_ends: bool, surface=None
                 ) -> ContactHook:
        """The hook of `model`'s contact (a `ContactConfig`, checked against the model: no
        obstacle at the reference surface or a pin), its grid in `dtype` over `surface` (None:
        the model's; several patches' joint surface, `minimise.multipatch.JointSurface`, which
        lays the grid over each patch: its `check_grid`; each patch is then checked by the
        caller, a flat-cut panel where it starts rather than at its reference surface)."""
        config = model.contact
        if surface is None:
            config.check(model)
        resolution = config.check_resolution
        grid = None if surface is None else surface.check_grid(resolution, dtype)
        return cls(ContactPoints(config.term(), surface or model.surface, resolution,
                                 dtype=dtype, grid=grid), both_ends=both_ends,
                   self_contact=config.self_contact)

    @property
    def term(self):
        """The barrier term (`ContactTerm`) the objective adds."""
        return self.points.term

    def check(self, start: torch.Tensor, load_factor: float) -> StepCheck:
        """The test of steps from the checked points' positions `start` (M, 3) [m]."""
        return StepCheck(self.points, start, self.points.point_gaps(start, load_factor),
                         load_factor, self.both_ends)

    def feasible(self, positions: Callable[[torch.Tensor], torch.Tensor], load_factor: float,
                 *, self_rest: torch.Tensor | None = None
                 ) -> Callable[[torch.Tensor, torch.Tensor], bool]:
        """`feasible(P, P_trial) -> bool`, a line search's test of a step between two
        parameter states: `positions(P) -> x (M, 3)` [m] of the checked points; the start is
        evaluated once per state P. With self-contact, self_rest (S, 3) [m]: the rest
        positions of the first S checked points, the self-contact points, whose step must
        also pass `self_step_allowed` (refused without them: a hook with self-contact has no
        test of its steps otherwise)."""
        if self.self_contact is not None and self_rest is None:
            raise ValueError("the contact hook has self-contact: feasible needs self_rest")
        cache: dict = {}

        def feasible(state: torch.Tensor, trial: torch.Tensor) -> bool:
            if cache.get("state") is not state:
                start = positions(state)
                cache.update(state=state, start=start,
                             check=self.check(start, load_factor))
            end = positions(trial)
            if not cache["check"].allows(end):
                return False
            if self.self_contact is None:
                return True
            count = len(self_rest)
            return self_step_allowed(self.self_contact, self_rest, cache["start"][:count],
                                     end[:count])
        return feasible

    def accept(self, check: StepCheck, before: torch.Tensor, after: torch.Tensor,
               move: Callable[[torch.Tensor], None],
               positions: Callable[[], torch.Tensor]) -> bool:
        """The policy of a step already taken from the parameters `before` to `after` (the
        current state): kept if `check` allows it, else halved towards `before` (`move(P)`
        sets the parameters) up to `halvings` times, else undone (back at `before`);
        `positions()` are the checked points at the current state. The grid points of the
        accepted state that came close become check points. Returns whether a step was
        kept."""
        for halving in range(self.halvings + 1):
            end = positions()
            end_gap = self.points.point_gaps(end, check.load_factor)
            if check.allows(end, end_gap=end_gap):
                self.points.flag(end_gap)
                return True
            if halving < self.halvings:
                after = 0.5 * (before + after)
                move(after)
        move(before)
        return False

    def refresh(self, displacement, load_factor: float) -> float:
        """The grid evaluated at a state (`displacement(xi) -> u (N, 3)` [m]); its points
        within the activation distance become check points. Returns the smallest gap [m]."""
        return self.points.refresh(displacement, load_factor)

    def feasible_start(self, displacement, load_factor: float,
                       restart: Callable[[], None]) -> float:
        """`refresh` at the starting state; where the grid touches an obstacle (smallest gap
        ≤ 0), `restart()` moves to a state without penetration (a SIREN: the output layer set
        to zero, u = the prescribed motions) and the grid is evaluated again: the step test
        needs a state outside to start from. Returns the smallest gap [m]."""
        gap = self.refresh(displacement, load_factor)
        if gap > 0:
            return gap
        restart()
        gap = self.refresh(displacement, load_factor)
        log.info("contact: the initial field touched an obstacle; restarted from a state "
                 "without it (smallest gap now %.3g m)", gap)
        return gap

    def look_ahead(self, grid_displacement: Callable[[torch.Tensor], torch.Tensor],
                   load_factor: float) -> Callable[[torch.Tensor], bool]:
        """`refresh(P) -> bool` after each Newton iterate P (`minimise`'s `on_step`):
        `grid_displacement(P) -> u (G, 3)` [m] on the whole grid; adds the points within ĝ
        plus LOOK_AHEAD × how far they moved since the last call (they could come that close
        by the next steps, so fewer rounds are needed while a sheet wraps an obstacle).
        True when points were added."""
        points, last = self.points, {}

        def refresh(state: torch.Tensor) -> bool:
            before = points.count
            u = grid_displacement(state)
            moved = 0.0 if "u" not in last else (u - last["u"]).norm(dim=1)
            last["u"] = u
            points.flag(points.point_gaps(points.grid_r.to(u.dtype) + u, load_factor),
                        LOOK_AHEAD * moved)
            return points.count > before
        return refresh
