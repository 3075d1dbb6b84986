"""The `[start]` table of a scene file: where the solve starts (docs/scenes.md, "Start").

Read into a `StartShape` (`taichi_ndf.problem.start_shape`); a fold or a wrap needs a flat
sheet (`[geometry] type = "plane"`, whose chart is isometric) and every start a spline field
(its coefficients are fitted to the start: `taichi_ndf.discretise.start.fitted_start`).
Errors are one line naming the key.
"""

from __future__ import annotations

from taichi_ndf.geometry import Plane
from taichi_ndf.problem.field_types import of_spec
from taichi_ndf.problem.start_shape import KINDS, StartShape
from taichi_ndf.scene.schema import SceneError, Table, checked

AXES = {"xi1": 0, "xi2": 1}


def parse_start(top: Table, surface, field) -> StartShape | None:
    """The `[start]` table's start shape (None: no table, the rest shape)."""
    if not top.has("start"):
        return None
    t = top.table("start")
    kind = t.string("type", choices=KINDS)
    axis = AXES[t.string("axis", "xi1", choices=tuple(AXES))]
    bent = kind != "rigid"
    shape = checked(lambda: StartShape(
        kind, axis=axis, at=t.number("at") if bent else 0.0,
        radius=t.number("radius", positive=True) if bent else 0.0,
        rotation_axis=t.vector("rotation_axis", 3, (0.0, 0.0, 1.0)),
        angle=t.number("angle", 0.0), about=t.vector("about", 3, (0.0, 0.0, 0.0)),
        translation=t.vector("translation", 3, (0.0, 0.0, 0.0))), "start")
    t.close()
    if bent and not isinstance(surface, Plane):
        raise SceneError(f"start.type: a {kind} needs [geometry] type = \"plane\" (an isometric "
                         f"chart), not a {type(surface).__name__}")
    lo, hi = surface.domain.bounds[axis]
    if bent and not lo <= shape.at <= hi:
        raise SceneError(f"start.at: {shape.at} is outside the domain's "
                         f"{'ξ¹' if axis == 0 else 'ξ²'} range [{lo}, {hi}]")
    if of_spec(field).method != "newton":
        raise SceneError("start: needs [field] type = \"spline\" (the start is fitted by the "
                         "spline's coefficients)")
    return shape
