"""The one continuation loop (taichi_ndf.minimise.continuation): its steps' values, starts,
callbacks and the progress stage it reports to when named."""

import pytest

from taichi_ndf import progress
from taichi_ndf.minimise.continuation import Stages, Step, solve_over


class Calls:
    def __init__(self):
        self.seen = []

    def on_start(self, solver):
        self.seen.append("start")

    def on_load_step(self, solver, value):
        self.seen.append(value)

    def on_level(self, solver):
        self.seen.append("level")

    def on_end(self, solver):
        self.seen.append("end")


def test_steps_carry_their_value_start_from_the_previous_and_the_coarser_result():
    starts = []

    def start(step, previous, coarser):
        starts.append((step.level, step.index, previous, coarser))
        return previous

    calls = Calls()
    results = solve_over(Stages(lambda step, begin: (step.level, step.value),
                                start=start), [0.5, 1.0], levels=2, callbacks=[calls])
    assert results == [[(0, 0.5), (0, 1.0)], [(1, 0.5), (1, 1.0)]]
    assert starts == [(0, 0, None, None), (0, 1, (0, 0.5), None),
                      (1, 0, None, (0, 0.5)), (1, 1, (1, 0.5), (0, 1.0))]
    assert calls.seen == ["start", 0.5, 1.0, "level", 0.5, 1.0, "level", "end"]
    assert Step(0, 1, 0.25).load_factor == 0.25  # the forward paths' name for the value


def test_a_level_resumed_with_its_done_steps_and_the_coarser_results_goes_on_there():
    """`done` (the first level's finished steps) are not solved again but are the previous
    result and part of the level's results; `coarser` is the level below's."""
    starts, solved = [], []

    def start(step, previous, coarser):
        starts.append((step.level, step.index, previous, coarser))

    def solve(step, begin):
        solved.append((step.level, step.index))
        return (step.level, step.value)

    calls = Calls()
    results = solve_over(Stages(solve, start=start), [0.25, 0.5, 1.0], levels=3, first_level=1,
                         callbacks=[calls], done=[(1, 0.25)],
                         coarser=[(0, 0.25), (0, 0.5), (0, 1.0)])
    assert solved == [(1, 1), (1, 2), (2, 0), (2, 1), (2, 2)]
    assert starts[:2] == [(1, 1, (1, 0.25), (0, 0.5)), (1, 2, (1, 0.5), (0, 1.0))]
    assert starts[2] == (2, 0, None, (1, 0.25))
    assert results[0] == [(1, 0.25), (1, 0.5), (1, 1.0)]
    assert calls.seen == ["start", 0.5, 1.0, "level", 0.25, 0.5, 1.0, "level", "end"]


def test_a_named_stage_reports_each_finished_step_and_none_without_it():
    reports = []
    with progress.listening(reports.append):
        solve_over(Stages(lambda step, begin: step.value), [3, 4, 5], first_step=1)
        assert reports == []
        kept = []
        solve_over(Stages(lambda step, begin: step.value,
                          after_step=lambda step, result: kept.append(len(reports))),
                   range(1, 4), stage="frames")
    assert [(r.stage, r.step, r.total, r.done) for r in reports] == [
        ("frames", 0, 3, False), ("frames", 1, 3, False), ("frames", 2, 3, False),
        ("frames", 3, 3, False), ("frames", 3, 3, True)]
    assert kept == [1, 2, 3]  # a step is reported after its bookkeeping


def test_bad_first_step_or_level_is_refused():
    with pytest.raises(ValueError, match="first_step"):
        solve_over(Stages(lambda step, begin: None), [1.0], first_step=2)
    with pytest.raises(ValueError, match="first_step"):  # a level has steps to solve
        solve_over(Stages(lambda step, begin: None), [1.0], levels=1, first_step=1)
    with pytest.raises(ValueError, match="first_level"):
        solve_over(Stages(lambda step, begin: None), [1.0], levels=2, first_level=2)


def test_steps_found_as_the_loop_goes_take_their_value_from_the_last_result():
    """`next_value`: a dynamic run's time steps, each step's end time from the last result
    (here: doubling sizes up to t = 1), the callbacks after each, no count in advance."""
    asked = []

    def next_value(index, last):
        asked.append((index, last))
        time = 0.0 if last is None else last[1]
        size = 0.125 if last is None else 2 * last[2]
        return None if time >= 1.0 else min(1.0, time + size)

    def solve(step, start):  # (index, end time, size)
        last = asked[-1][1]
        return step.index, step.value, step.value - (0.0 if last is None else last[1])

    calls = Calls()
    results = solve_over(Stages(solve), (), first_step=3, callbacks=[calls],
                         next_value=next_value)
    assert [r[:2] for r in results[0]] == [(3, 0.125), (4, 0.375), (5, 0.875), (6, 1.0)]
    assert calls.seen == ["start", 0.125, 0.375, 0.875, 1.0, "end"]
    assert [i for i, _ in asked] == [3, 4, 5, 6, 7]
    with pytest.raises(ValueError, match="cannot be counted"):
        solve_over(Stages(solve), (), next_value=next_value, stage="steps")


def test_a_finished_run_resumed_solves_nothing_but_starts_and_ends():
    """first_step = len(steps) without levels (a garment's finished run resumed): no step is
    solved, on_start and on_end are called."""
    calls = Calls()
    results = solve_over(Stages(lambda step, begin: pytest.fail("solved")), [0.5, 1.0],
                         first_step=2, callbacks=[calls])
    assert results == [[]] and calls.seen == ["start", "end"]


def test_ctrl_c_inside_the_loop_calls_interrupted_and_propagates_without_ending():
    """`Stages.interrupted`: called on a KeyboardInterrupt in a step or its callbacks, after
    the steps finished before it; on_end and before_end are not called."""
    seen = []

    class Stop(Calls):
        def on_load_step(self, solver, value):
            super().on_load_step(solver, value)
            if value == 0.5:
                raise KeyboardInterrupt

    calls = Stop()
    with pytest.raises(KeyboardInterrupt):
        solve_over(Stages(lambda step, begin: step.value,
                          after_step=lambda step, result: seen.append(result),
                          before_end=lambda: seen.append("before_end"),
                          interrupted=lambda: seen.append("interrupted")),
                   [0.25, 0.5, 1.0], callbacks=[calls])
    assert seen == [0.25, 0.5, "interrupted"]
    assert calls.seen == ["start", 0.25, 0.5]


def test_levels_chosen_as_the_loop_goes_stop_where_next_level_says():
    """`next_level(level)`: asked before each level from `first_level` on (here: on while the
    last level's result is below 3); on_level and after_level after each level solved."""
    asked, after = [], []
    results: list = []

    def next_level(level):
        asked.append(level)
        return not results or results[-1] < 3

    def solve(step, begin):
        results.append(step.level + step.value)
        return results[-1]

    calls = Calls()
    levels = solve_over(Stages(solve, after_level=lambda level, r: after.append((level, r))),
                        [0.5, 1.0], first_level=1, next_level=next_level, callbacks=[calls])
    assert asked == [1, 2, 3] and levels == [[1.5, 2.0], [2.5, 3.0]]
    assert after == [(1, [1.5, 2.0]), (2, [2.5, 3.0])]
    assert calls.seen == ["start", 0.5, 1.0, "level", 0.5, 1.0, "level", "end"]
    with pytest.raises(ValueError, match="not counted"):
        solve_over(Stages(solve), [1.0], levels=2, next_level=next_level)
