"""The [training] table of a scene (docs/scenes.md): Adam with its schedule, its
[training.quick] settings and the pseudo-time keys for a SIREN; projected Newton for a spline
field (`method = "newton"`)."""

from __future__ import annotations

from dataclasses import replace

from taichi_ndf.problem.optim import AdamConfig
from taichi_ndf.problem.training import LINEAR_SOLVERS, NEWTON_MAX_ITERATIONS, SolverConfig
from taichi_ndf.scene.schema import SceneError, Table
from taichi_ndf.scene.schema import checked as _check


def training(t: Table, spline: bool) -> tuple[SolverConfig, SolverConfig]:
    """The run's and the quick run's (`--quick`) solver configurations of [training] for a
    field that is a spline (`spline`) or a SIREN."""
    method = t.string("method", "newton" if spline else "adam", choices=("adam", "newton"))
    if method == "newton":
        if not spline:
            raise SceneError(f"{t.key('method')}: \"newton\" (projected Newton) needs [field] "
                             "type = \"spline\"; a SIREN field trains with \"adam\" (and its "
                             "last-layer Newton phases: newton_iterations)")
        return newton_training(t)
    adam = _adam(t)
    quick_table = t.table("quick", optional=True)
    solver = _solver(t, adam)
    # The pseudo-time keys shape the field (an extra input), so [training.quick] has none.
    pseudo_time = t.boolean("pseudo_time", False)
    start = t.number("pseudo_time_start", 0.0, nonnegative=True)
    if t.has("pseudo_time_start") and not pseudo_time:
        raise SceneError(f"{t.key('pseudo_time_start')}: needs pseudo_time = true")
    if start >= solver.load_steps[0]:
        raise SceneError(f"{t.key('pseudo_time_start')}: must be below the first load step "
                         f"{solver.load_steps[0]}, got {start}")
    if pseudo_time and solver.newton_iterations:
        raise SceneError(f"{t.key('pseudo_time')}: not available with newton_iterations > 0 "
                         f"(the last-layer Newton solver has no pseudo-time input)")
    solver = replace(solver, pseudo_time=pseudo_time, pseudo_time_start=start)
    quick_defaults = replace(solver, iterations=min(solver.iterations, 30),
                             samples=min(solver.samples, 512), monitor_every=10,
                             monitor_samples=min(solver.monitor_samples, 2048),
                             lbfgs_iterations=0, checkpoint_every=0)
    quick = _check(lambda: replace(_solver(quick_table, adam, quick_defaults),
                                   pseudo_time=pseudo_time, pseudo_time_start=start),
                   quick_table.path)
    quick_table.close()
    return solver, quick


def _adam(t: Table) -> dict:
    lr = t.number("learning_rate", 1e-3, positive=True)
    return {"lr": lr,
            "schedule": t.string("schedule", "exponential",
                                 choices=("constant", "exponential", "cosine")),
            "final_ratio": t.number("final_learning_rate_ratio", 0.1, positive=True),
            "grad_clip": t.number("grad_clip", None)}


def trains_the_field(config: SolverConfig) -> bool:
    """Whether `config` runs any optimisation at all (Adam, L-BFGS or Newton iterations)."""
    return config.iterations > 0 or config.lbfgs_iterations > 0 or config.newton_iterations > 0


def adam_config(lr: float, schedule: str, final_ratio: float, grad_clip: float | None,
                total_steps: int) -> AdamConfig:
    """Adam whose learning rate falls from `lr` to `final_ratio`·lr over `total_steps`
    (exponentially or along a cosine), or stays constant."""
    total_steps = max(int(total_steps), 1)
    return AdamConfig(lr=lr, schedule=schedule, decay_rate=min(final_ratio, 1.0),
                      decay_steps=total_steps, total_steps=total_steps,
                      min_lr=min(final_ratio, 1.0) * lr, grad_clip=grad_clip)


def _solver(t: Table, adam: dict, defaults: SolverConfig | None = None) -> SolverConfig:
    d = defaults or SolverConfig()
    steps = t.numbers("load_steps", d.load_steps)
    iterations = t.integer("iterations", d.iterations, minimum=0)
    config = SolverConfig(
        iterations=iterations,
        samples=t.integer("samples", d.samples, minimum=16),
        adam=adam_config(**adam, total_steps=iterations * len(steps)),
        load_steps=steps,
        monitor_every=t.integer("monitor_every", d.monitor_every, minimum=1),
        monitor_samples=t.integer("monitor_samples", d.monitor_samples, minimum=16),
        checkpoint_every=t.integer("checkpoint_every", d.checkpoint_every, minimum=0),
        lbfgs_iterations=t.integer("lbfgs_iterations", d.lbfgs_iterations, minimum=0),
        newton_iterations=t.integer("newton_iterations", d.newton_iterations, minimum=0),
        newton_every=t.integer("newton_every", d.newton_every, minimum=0),
        newton_samples=t.integer("newton_samples", d.newton_samples, minimum=16),
        seed=t.integer("seed", d.seed),
    )
    if not trains_the_field(config):
        raise SceneError(f"{t.key('iterations')}: must be >= 1 (or lbfgs_iterations or "
                         "newton_iterations > 0): nothing would train the field")
    return config


NEWTON_KEYS = ("method", "load_steps", "seed", "newton_max_iterations", "newton_tolerance",
               "linear_solver")


def newton_training(t: Table) -> tuple[SolverConfig, SolverConfig]:
    for key in sorted(t.data):
        if key not in NEWTON_KEYS:
            raise SceneError(f"{t.key(key)}: not used by method = \"newton\" (its keys: "
                             f"{', '.join(NEWTON_KEYS)})")
    solver = SolverConfig(
        method="newton", load_steps=t.numbers("load_steps", (1.0,)), seed=t.integer("seed", 0),
        newton_max_iterations=t.integer("newton_max_iterations", NEWTON_MAX_ITERATIONS,
                                        minimum=1),
        newton_tolerance=_tolerance(t),
        linear_solver=t.string("linear_solver", "auto", choices=LINEAR_SOLVERS))
    return solver, replace(solver, max_levels=1)


def _tolerance(t: Table) -> float | None:
    if not t.has("newton_tolerance"):
        return None
    value = t._get("newton_tolerance", None)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 < value < 1:
        raise SceneError(f"{t.key('newton_tolerance')}: expected a number in (0, 1) (λ²/2 "
                         f"relative to |Π|), got {value!r}")
    return float(value)
