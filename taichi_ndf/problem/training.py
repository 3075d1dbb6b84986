"""The training specification of a quasistatic solve: a plain frozen configuration.

Scene files produce it (`taichi_ndf.scene.reader`) without importing the solver; the solver
(`taichi_ndf.solve.solver`) consumes it.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from taichi_ndf import checks
from taichi_ndf.problem.optim import AdamConfig

METHODS = ("adam", "newton")
LINEAR_SOLVERS = ("auto", "direct", "multigrid")  # projected Newton's (`linear_solve`)


# Most projected-Newton iterations per load step and level by default: a guard against a solve
# that never converges, not a tolerance. A draped cloth spends most of its solve in Newton's
# damped phase (float64 flag on 15 × 10 spans: 106 iterations, the last 5 quadratic; float32:
# 100), so the former 100 ended it unconverged. In the measured `polyester` fabric (2026-12-03)
# the same flag needs 405 iterations (float64, Π −0.965153 J, λ² 9e-15, 37 s CPU), beyond the
# former 300; 600 leaves room for finer grids.
NEWTON_MAX_ITERATIONS = 600


@dataclass(frozen=True)
class SolverConfig:
    """How Π is minimised.

    iterations: Adam iterations per load step.
    samples: area samples per iteration (stratified, jittered, resampled every iteration).
    load_steps: load factors solved in turn (continuation); loads and prescribed displacements
        are scaled by the factor. The last must be 1.
    monitor_every: iterations between evaluations of Π on a fixed monitor sample set.
    checkpoint_every: iterations between checkpoints (0: only at the end).
    lbfgs_iterations: L-BFGS polish iterations on a fixed sample set after each load step.
    newton_iterations: most last-layer Newton steps per Newton phase (0: no Newton phases).
    newton_every: Adam iterations between Newton phases inside a load step (0: Newton only at
        the start and the end of each load step).
    newton_samples: area samples of the fixed Newton sample set (point-load samples added).
    pseudo_time: train a field whose one conditioning input is the load factor t over all t in
        [pseudo_time_start, λ] at once (module docstring); λ is the current load step.
    pseudo_time_start: the smallest t trained, in [0, first load step).
    method: "adam" (the Adam / Newton / L-BFGS phases above, SIREN or spline field) or
        "newton" (projected Newton over a spline field's coefficients on fixed Gauss points,
        load continuation over `load_steps`, coarse to fine over the field's levels; the
        Adam keys do not apply).
    newton_max_iterations: most projected-Newton iterations per load step and level
        (NEWTON_MAX_ITERATIONS by default).
    newton_tolerance: stop a level's Newton iterations when λ²/2 ≤ this × |Π| (λ² the Newton
        decrement; λ²/2 estimates Π − Π*); None: the precision's rounding floor (1e-12 in
        float64, 1e-7 in float32). E.g. 1e-4 for a solve whose Π must be good to 1 %.
    max_levels: most grid levels a Newton run solves (0: all of the field's; 1 for --quick).
    linear_solver: how Newton solves its linear systems: "auto" (the direct solve below
        `LinearSolverConfig.band_threshold` unknowns, or `threshold` where K's band is too
        wide, multigrid-preconditioned CG above),
        "direct" or "multigrid" (`taichi_ndf.minimise.linear_solve`).
    """

    iterations: int = 1500
    samples: int = 4096
    adam: AdamConfig = field(default_factory=AdamConfig)
    load_steps: tuple[float, ...] = (1.0,)
    monitor_every: int = 50
    monitor_samples: int = 16384
    checkpoint_every: int = 500
    lbfgs_iterations: int = 0
    newton_iterations: int = 0
    newton_every: int = 0
    newton_samples: int = 16384
    seed: int = 0
    progress: bool = True
    pseudo_time: bool = False
    pseudo_time_start: float = 0.0
    method: str = "adam"
    newton_max_iterations: int = NEWTON_MAX_ITERATIONS
    newton_tolerance: float | None = None
    max_levels: int = 0
    linear_solver: str = "auto"

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {list(METHODS)}, got {self.method!r}")
        if self.newton_max_iterations < 1 or self.max_levels < 0:
            raise ValueError(f"newton_max_iterations must be >= 1 and max_levels >= 0, got "
                             f"{self.newton_max_iterations}, {self.max_levels}")
        tol = self.newton_tolerance
        if tol is not None and not (isinstance(tol, (int, float)) and 0 < tol < 1):
            raise ValueError(f"newton_tolerance must be in (0, 1), got {tol!r}")
        if self.linear_solver not in LINEAR_SOLVERS:
            raise ValueError(f"linear_solver must be one of {list(LINEAR_SOLVERS)}, got "
                             f"{self.linear_solver!r}")
        if self.method == "newton" and self.pseudo_time:
            raise ValueError("pseudo_time needs method 'adam' (a SIREN field)")
        if self.iterations < 0:
            raise ValueError(f"iterations must be >= 0, got {self.iterations}")
        if self.samples < 16:
            raise ValueError(f"samples must be >= 16, got {self.samples}")
        checks.load_steps(self.load_steps)
        if self.monitor_every < 1:
            raise ValueError(f"monitor_every must be >= 1, got {self.monitor_every}")
        if self.checkpoint_every < 0 or self.lbfgs_iterations < 0:
            raise ValueError("checkpoint_every and lbfgs_iterations must be >= 0")
        if self.newton_iterations < 0 or self.newton_every < 0:
            raise ValueError(f"newton_iterations and newton_every must be >= 0, got "
                             f"{self.newton_iterations}, {self.newton_every}")
        if self.newton_samples < 16:
            raise ValueError(f"newton_samples must be >= 16, got {self.newton_samples}")
        if not 0.0 <= self.pseudo_time_start < self.load_steps[0]:
            raise ValueError(f"pseudo_time_start must be in [0, {self.load_steps[0]}) (the "
                             f"first load step), got {self.pseudo_time_start}")
        if self.pseudo_time and self.newton_iterations:
            raise ValueError("newton_iterations must be 0 with pseudo_time: the last-layer "
                             "Newton solver does not take a pseudo-time input")

    def with_iterations(self, iterations: int) -> SolverConfig:
        """The same run with another iteration count; the learning-rate schedule is stretched
        to the new length."""
        total = max(iterations * len(self.load_steps), 1)
        adam = replace(self.adam, decay_steps=total, total_steps=total)
        return replace(self, iterations=iterations, adam=adam)
