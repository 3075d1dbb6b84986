"""The step control of a dynamic run: which time step comes next, as a policy the one
continuation loop calls (`taichi_ndf.minimise.continuation.solve_over`, `next_value`).

Steps run between output frames (`DynamicsConfig.frame_times`): of the fixed dt (exactly
frame_every of them per frame; the clock set to k dt after step k, no drift), or with
`DynamicsConfig.adaptive` of the size its `AdaptiveStep` rule gives after each step (shortened
to land on the next frame, never below the halving's floor dt/2^halvings). A step that Newton
does not converge is halved inside the step (`TimeStepper.advance`), not here.
"""

from __future__ import annotations

from dataclasses import replace

from taichi_ndf.problem.dynamics import DynamicsConfig
from taichi_ndf.solve.dynamics_trajectory import Motion


class TimeSteps:
    """The clock of a run from `state` (a resumed run's: its step index `step`, its step size
    h [s] (None: dt) and its count of easy steps); `state`: the last step's end from then on
    (`after`)."""

    def __init__(self, config: DynamicsConfig, state: Motion, *, step: int = 0,
                 size: float | None = None, easy: int = 0):
        self.config, self.rule, self.state = config, config.adaptive, state
        self.tol = 1e-9 * config.dt
        self.targets = [t for t in config.frame_times() if t > state.time + self.tol]
        self.step, self.h, self.easy = step, size or config.dt, easy
        self.size = self.frame = None  # the step in progress's length and frame [s]

    def next(self) -> float | None:
        """The end time [s] of the step from `state` (its length: `size`, its output frame:
        `frame`); None: the run is over."""
        time = self.state.time
        self.frame = next((t for t in self.targets if t > time + self.tol), None)
        if self.frame is None:
            return None
        self.size = self.h if self.rule is None else min(self.h, self.frame - time)
        return time + self.size

    def after(self, state: Motion, iterations: int, substeps: int) -> Motion:
        """The step just taken (its end `state`) counted and kept as `state`, with its clock
        set (k dt for fixed steps, the frame's time where an adaptive step landed on it); the
        next size chosen."""
        self.step += 1
        config = self.config
        if self.rule is None:
            self.state = replace(state, time=self.step * config.dt)  # no drift of the clock
            return self.state
        if abs(state.time - self.frame) <= self.tol:
            state = replace(state, time=self.frame)
        self.h, self.easy = self.rule.after(self.h, self.easy, iterations, substeps)
        self.h = max(self.h, config.dt / 2**config.halvings)
        self.state = state
        return state

    def at_frame(self) -> bool:
        """Whether the last step reached its output frame."""
        return not self.state.time < self.frame - self.tol
