"""The `[dynamics]` section of a scene file: a run in physical time instead of a quasistatic
solve over load steps (docs/scenes.md, docs/dynamics.md)."""

from __future__ import annotations

from taichi_ndf.problem.dynamics import (
    INTEGRATORS,
    AdaptiveStep,
    BoundaryMotion,
    DynamicsConfig,
)
from taichi_ndf.problem.spline_grid import SplinePlan
from taichi_ndf.problem.wind import AIR_DENSITY, FLAT_PLATE_DRAG, Wind
from taichi_ndf.scene.schema import SceneError, Table, checked


def parse_dynamics(top: Table, field, model) -> DynamicsConfig | None:
    """The scene's `DynamicsConfig` (None without a [dynamics] section): integrator, dt [s],
    duration [s], frame_rate [1/s], mass_damping α [1/s], stiffness_damping β_R [s],
    load_ramp [s], halvings, and the subtables [dynamics.wind] (`Wind`: velocity [m/s],
    gust_amplitude, gust_frequency [Hz], air_density [kg/m³], drag_coefficient) and
    [dynamics.motion] (`BoundaryMotion`: times [s] and factors, or amplitude and frequency
    [Hz]); adaptive = true with max_dt [s] (default 8 dt), easy_iterations, grow_after
    (`AdaptiveStep`). SceneError naming the key for a bad value, and for what the dynamic
    path does not support yet: a SIREN field (its pseudo-time is not physical time),
    stiffness damping or a boundary motion with obstacles."""
    if not top.has("dynamics"):
        return None
    t = top.table("dynamics")
    wind = _wind(t.table("wind")) if t.has("wind") else None
    motion = _motion(t.table("motion")) if t.has("motion") else None
    adaptive = _adaptive(t)
    config = checked(lambda: DynamicsConfig(
        dt=t.number("dt", positive=True), duration=t.number("duration", positive=True),
        integrator=t.string("integrator", "implicit_euler", choices=INTEGRATORS),
        frame_rate=t.number("frame_rate", None, positive=True),
        mass_damping=t.number("mass_damping", 0.0, nonnegative=True),
        stiffness_damping=t.number("stiffness_damping", 0.0, nonnegative=True),
        load_ramp=t.number("load_ramp", 0.0, nonnegative=True),
        halvings=t.integer("halvings", 4, minimum=0), wind=wind, motion=motion,
        adaptive=adaptive), "dynamics")
    t.close()
    if not isinstance(field, SplinePlan):
        raise SceneError("dynamics: needs a spline field ([field] type = \"spline\"); a SIREN "
                         "is solved quasistatically (its pseudo-time is not physical time)")
    if model.contact is not None and config.stiffness_damping:
        raise SceneError("dynamics: stiffness_damping with contact ([[obstacles]] or "
                         "[self_contact]) is not supported by the dynamic path yet (use "
                         "mass_damping)")
    if model.contact is not None and config.motion is not None:
        raise SceneError("dynamics.motion: a boundary motion with contact ([[obstacles]] or "
                         "[self_contact]) is not supported by the dynamic path yet")
    return config


def _wind(t: Table) -> Wind:
    wind = checked(lambda: Wind(
        velocity=t.vector("velocity", 3),
        gust_amplitude=t.number("gust_amplitude", 0.0, nonnegative=True),
        gust_frequency=t.number("gust_frequency", 0.0, nonnegative=True),
        air_density=t.number("air_density", AIR_DENSITY, positive=True),
        drag_coefficient=t.number("drag_coefficient", FLAT_PLATE_DRAG, positive=True)),
        "dynamics.wind")
    t.close()
    return wind


def _motion(t: Table) -> BoundaryMotion:
    if t.has("times") or t.has("factors"):
        if t.has("amplitude") or t.has("frequency"):
            raise SceneError(f"{t.path}: give times and factors, or amplitude and frequency, "
                             "not both")
        times, factors = t.numbers("times"), t.numbers("factors")
        if len(times) != len(factors):
            raise SceneError(f"{t.key('factors')}: one factor per time, got {len(factors)} for "
                             f"{len(times)} times")
        motion = checked(lambda: BoundaryMotion(keyframes=tuple(zip(times, factors,
                                                                    strict=True))),
                         "dynamics.motion")
    else:
        motion = checked(lambda: BoundaryMotion(amplitude=t.number("amplitude"),
                                                frequency=t.number("frequency", positive=True)),
                         "dynamics.motion")
    t.close()
    return motion



def _adaptive(t: Table) -> AdaptiveStep | None:
    keys = [k for k in ("max_dt", "easy_iterations", "grow_after") if t.has(k)]
    if not t.boolean("adaptive", False):
        if keys:
            raise SceneError(f"{t.key(keys[0])}: needs adaptive = true")
        return None
    dt = t.number("dt", positive=True)
    return checked(lambda: AdaptiveStep(
        max_dt=t.number("max_dt", 8 * dt, positive=True),
        easy_iterations=t.integer("easy_iterations", 4, minimum=1),
        grow_after=t.integer("grow_after", 3, minimum=1)), "dynamics")
