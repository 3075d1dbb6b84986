"""The `[dynamics]` section of a scene file: a run in physical time instead of a quasistatic
solve over load steps (docs/scenes.md, docs/dynamics.md)."""

from __future__ import annotations

from taichi_ndf.problem.dynamics import INTEGRATORS, DynamicsConfig
from taichi_ndf.problem.spline_grid import SplinePlan
from taichi_ndf.scene.schema import SceneError, Table, checked


def parse_dynamics(top: Table, field, model) -> DynamicsConfig | None:
    """The scene's `DynamicsConfig` (None without a [dynamics] section): integrator, dt [s],
    duration [s], frame_rate [1/s], mass_damping α [1/s], stiffness_damping β_R [s],
    load_ramp [s], halvings. SceneError naming the key
    for a bad value, and for what the dynamic path does not support yet: a SIREN field (its
    pseudo-time is not physical time) and stiffness damping with obstacles."""
    if not top.has("dynamics"):
        return None
    t = top.table("dynamics")
    config = checked(lambda: DynamicsConfig(
        dt=t.number("dt", positive=True), duration=t.number("duration", positive=True),
        integrator=t.string("integrator", "implicit_euler", choices=INTEGRATORS),
        frame_rate=t.number("frame_rate", None, positive=True),
        mass_damping=t.number("mass_damping", 0.0, nonnegative=True),
        stiffness_damping=t.number("stiffness_damping", 0.0, nonnegative=True),
        load_ramp=t.number("load_ramp", 0.0, nonnegative=True),
        halvings=t.integer("halvings", 4, minimum=0)), "dynamics")
    t.close()
    if not isinstance(field, SplinePlan):
        raise SceneError("dynamics: needs a spline field ([field] type = \"spline\"); a SIREN "
                         "is solved quasistatically (its pseudo-time is not physical time)")
    if model.contact is not None and config.stiffness_damping:
        raise SceneError("dynamics: stiffness_damping with contact ([[obstacles]]) is not "
                         "supported by the dynamic path yet (use mass_damping)")
    return config
