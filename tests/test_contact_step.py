"""The one contact hook every minimiser calls (`ContactHook`): its step test answers as
`step_allowed` with the start's gaps computed once per state, its line-search `feasible`
takes parameter states, its acceptance policy halves a refused step up to `halvings` times
and then undoes it, its feasible start restarts a state that touches an obstacle, and its
look-ahead refresh adds the grid points that could come close by the next steps."""

from __future__ import annotations

import pytest
import torch

from taichi_ndf.contact import ContactHook, ContactPoints, ContactTerm, GroundPlane
from taichi_ndf.geometry import Plane

UP = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)


def _hook(*, both_ends: bool = False, halvings: int = 10) -> ContactHook:
    term = ContactTerm([GroundPlane(point=(0.0, 0.0, -0.1))], offset=0.0, activation=0.01,
                       stiffness=1.0)
    return ContactHook(ContactPoints(term, Plane(((0.0, 1.0), (0.0, 1.0))), 4),
                       both_ends=both_ends, halvings=halvings)


def test_a_step_check_answers_as_step_allowed():
    for both_ends in (False, True):
        hook = _hook(both_ends=both_ends)
        points = hook.points
        start = points.grid_r.clone()  # 0.1 m above the ground
        check = hook.check(start, 1.0)
        for drop in (0.05, 0.099, 0.15, -0.3):
            end = start - drop * UP
            expected = points.step_allowed(start, points.point_gaps(start, 1.0), end, 1.0,
                                           both_ends=both_ends)
            assert check.allows(end) == expected
        # 0.099 m down is allowed, 0.15 m (through the ground) is not
        assert check.allows(start - 0.099 * UP)
        assert not check.allows(start - 0.15 * UP)


def test_feasible_takes_parameter_states_and_evaluates_each_start_once():
    hook = _hook()
    calls = []

    def positions(state):
        calls.append(state)
        return hook.points.grid_r - state * UP

    feasible = hook.feasible(positions, 1.0)
    state = torch.tensor(0.0, dtype=torch.float64)
    assert feasible(state, torch.tensor(0.05, dtype=torch.float64))
    assert not feasible(state, torch.tensor(0.15, dtype=torch.float64))
    assert sum(c is state for c in calls) == 1  # the start evaluated once for both trials
    moved = torch.tensor(0.05, dtype=torch.float64)
    assert not feasible(moved, torch.tensor(0.11, dtype=torch.float64))  # 0.06 m > its gap
    assert feasible(moved, torch.tensor(0.09, dtype=torch.float64))


def _taken(hook: ContactHook, drop: float):
    """A step of the whole grid from 0 to `drop` m down, already taken: the state, the
    check, and `move` / `positions` over a one-number parameter state."""
    state = {"P": torch.tensor([drop], dtype=torch.float64)}
    grid = hook.points.grid_r

    def move(p):
        state["P"] = p

    def positions():
        return grid - state["P"][0] * UP
    check = hook.check(grid.clone(), 1.0)
    return state, check, move, positions


def test_accept_keeps_an_allowed_step_and_flags_the_points_that_came_close():
    hook = _hook()
    state, check, move, positions = _taken(hook, 0.095)  # ends 5 mm above: within ĝ
    before = torch.zeros(1, dtype=torch.float64)
    assert hook.accept(check, before, state["P"].clone(), move, positions)
    assert float(state["P"][0]) == 0.095
    assert hook.points.count == len(hook.points.grid_xi)


def test_accept_halves_a_refused_step_until_allowed():
    hook = _hook()
    state, check, move, positions = _taken(hook, 0.3)  # 0.3 and 0.15 refused, 0.075 not
    before = torch.zeros(1, dtype=torch.float64)
    assert hook.accept(check, before, state["P"].clone(), move, positions)
    assert float(state["P"][0]) == pytest.approx(0.075)  # 0.3 → 0.15 → 0.075
    assert hook.points.count == 0  # 2.5 cm above: none within ĝ = 1 cm


def test_accept_undoes_a_step_refused_after_all_halvings():
    hook = _hook(halvings=2)
    state, check, move, positions = _taken(hook, 0.5)  # 0.5, 0.25, 0.125: all refused
    before = torch.zeros(1, dtype=torch.float64)
    assert not hook.accept(check, before, state["P"].clone(), move, positions)
    assert state["P"] is before
    with pytest.raises(ValueError, match="halvings"):
        _hook(halvings=-1)


def test_feasible_start_restarts_a_state_that_touches_an_obstacle():
    hook = _hook()
    below = {"u": -0.2 * UP}  # the starting field puts the sheet 10 cm under the ground

    def displacement(xi):
        return below["u"].expand(len(xi), 3)

    def restart():
        below["u"] = torch.zeros(3, dtype=torch.float64)
    assert hook.feasible_start(displacement, 1.0, restart) == pytest.approx(0.1)
    assert not below["u"].any()
    untouched = _hook()
    assert untouched.feasible_start(lambda xi: torch.zeros(len(xi), 3, dtype=torch.float64),
                                    1.0, lambda: pytest.fail("restarted")) == pytest.approx(0.1)


def test_look_ahead_adds_the_points_that_could_come_close_by_the_next_steps():
    hook = _hook()
    refresh = hook.look_ahead(lambda drop: (-drop * UP).expand(len(hook.points.grid_xi), 3),
                              1.0)
    assert not refresh(torch.tensor(0.0, dtype=torch.float64))  # gap 10 cm
    # moved 2 cm to a gap of 8 cm: within ĝ + 4 × 2 cm = 9 cm → added
    assert refresh(torch.tensor(0.02, dtype=torch.float64))
    assert hook.points.count == len(hook.points.grid_xi)


def test_the_end_gaps_are_evaluated_only_for_the_points_that_need_them():
    """`step_allowed(..., both_ends=True)` without the caller's end gaps evaluates them only
    for the points that moved by their start gap or more, and answers as the rule written out
    in full."""
    hook = _hook()
    points = hook.points
    evaluated = []
    gaps = points.point_gaps

    def counting(x, load_factor):
        evaluated.append(len(x))
        return gaps(x, load_factor)
    points.point_gaps = counting
    start = points.grid_r.clone()  # 0.1 m above the ground
    start_gap = gaps(start, 1.0)
    assert points.step_allowed(start, start_gap, start - 0.05 * UP, 1.0, both_ends=True)
    assert evaluated == []  # every point moved by less than its start gap
    end = start.clone()
    end[3] += 0.3 * UP  # one point 0.3 m away from the ground: allowed by its end gap
    assert points.step_allowed(start, start_gap, end, 1.0, both_ends=True)
    assert evaluated == [1]
    generator, answers = torch.Generator().manual_seed(0), []
    for _ in range(50):
        end = start + 0.05 * torch.randn(start.shape, generator=generator, dtype=start.dtype)
        moved = (end - start).norm(dim=1)
        full = bool((moved < start_gap + gaps(end, 1.0).clamp(min=0.0)).all())
        answers.append(points.step_allowed(start, start_gap, end, 1.0, both_ends=True))
        assert answers[-1] == full
    assert 0 < sum(answers) < len(answers)  # both answers occur (20 of 50 allowed)
