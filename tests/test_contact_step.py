"""The one penetration test every minimiser asks (`ContactPoints.step_from` for the SIREN
path's Adam halvings and Newton phases, `ContactPoints.feasible` for projected Newton's line
search): the same answers as `step_allowed`, the start's gaps computed once per state."""

from __future__ import annotations

import torch

from taichi_ndf.contact import ContactPoints, ContactTerm, GroundPlane
from taichi_ndf.geometry import Plane


def _points():
    term = ContactTerm([GroundPlane(point=(0.0, 0.0, -0.1))], offset=0.0, activation=0.01,
                       stiffness=1.0)
    return ContactPoints(term, Plane(((0.0, 1.0), (0.0, 1.0))), 4)


def test_a_step_check_answers_as_step_allowed():
    points = _points()
    start = points.grid_r.clone()  # 0.1 m above the ground
    for both_ends in (False, True):
        check = points.step_from(start, 1.0, both_ends=both_ends)
        for drop in (0.05, 0.099, 0.15, -0.3):
            end = start - torch.tensor([0.0, 0.0, drop], dtype=start.dtype)
            expected = points.step_allowed(start, points.point_gaps(start, 1.0), end, 1.0,
                                           both_ends=both_ends)
            assert check.allows(end) == expected
    # one-sided: 0.099 m down is allowed, 0.15 m (through the ground) is not
    check = points.step_from(start, 1.0)
    assert check.allows(start - torch.tensor([0.0, 0.0, 0.099], dtype=start.dtype))
    assert not check.allows(start - torch.tensor([0.0, 0.0, 0.15], dtype=start.dtype))


def test_feasible_takes_parameter_states_and_evaluates_each_start_once():
    points = _points()
    calls = []

    def positions(state):
        calls.append(state)
        return points.grid_r - state * torch.tensor([0.0, 0.0, 1.0], dtype=points.grid_r.dtype)

    feasible = points.feasible(positions, 1.0)
    state = torch.tensor(0.0, dtype=torch.float64)
    assert feasible(state, torch.tensor(0.05, dtype=torch.float64))
    assert not feasible(state, torch.tensor(0.15, dtype=torch.float64))
    assert sum(c is state for c in calls) == 1  # the start evaluated once for both trials
    moved = torch.tensor(0.05, dtype=torch.float64)
    assert not feasible(moved, torch.tensor(0.11, dtype=torch.float64))  # 0.06 m > its gap
    assert feasible(moved, torch.tensor(0.09, dtype=torch.float64))
