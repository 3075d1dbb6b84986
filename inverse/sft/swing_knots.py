"""The swing's spline grid (`inverse.sft.swing`): n1 × n2 spans of degree 3 or 4 on the flat
sheet, with uniform knots or knots graded towards the held points.

Why the held points. A sheet held at two points of its top edge sags between them and buckles
out of its plane in a band along that edge; at each held point the field must resolve an ever
sharper layer (a point's held slope is not a bounded condition on the bending energy,
`boundary.constraints.Handle`) and the membrane's point singularity. On a uniform grid the
model bends too little there and is stiffer than the sheet, so B fitted with it reads low
(benchmarks/RESULTS.md, wip-sftmat10/11: the upper band's bending energy 7–16 % short on 32²,
in step with B's bias). "graded" puts the same unknowns towards the model's singular features
— the handles' points, both coordinates — by the project's rule for them
(`problem.spline_grid.graded_config`: the law of `taichi_ndf.field.grading`, core one span,
half the spans graded), nothing tuned to the swing. Measured on the synthetic swing's rest
state (RESULTS.md, wip-sftmat12): B's static bias against a degree-4 64² uniform reference on
32² spans, degree 3, −20.7 % uniform, −0.3 % graded (degree 4: −9.3 %, +0.5 %), the same
unknowns at 1.5–2.2 × the CPU per solve. What the grading leaves is slow: the graded grids'
B still rises by ≈ 0.5–0.9 % per grid step from 32² to 48² (an observed order ≈ 1, the held
point's layer), so a point hold's B is defined by its grid only to about that. A held patch
(`SwingConfig.grip`, its rim integrated exactly: `taichi_ndf.discretise.held_patches`) is the
bounded condition: graded, its rest converges in the grid (2 cm grip: B's steps −9.0, −3.4,
−0.5 % from 16² to 40², dP/dB by central differences; `inverse.sft.hanging.hanging_model`,
RESULTS.md wip-sftmat13).
"""

from __future__ import annotations

from taichi_ndf.field.spline import SplineConfig
from taichi_ndf.problem.model import ShellModel
from taichi_ndf.problem.spline_grid import graded_config

KNOTS = ("uniform", "graded")  # SwingConfig.knots


def check_knots(knots: str) -> None:
    """ValueError unless `knots` is one of KNOTS."""
    if knots not in KNOTS:
        raise ValueError(f"knots must be one of {KNOTS}, got {knots!r}")


def swing_spline(model: ShellModel, spans: tuple[int, int], degree: int,
                 knots: str = "uniform") -> SplineConfig:
    """The spline field of the model's flat sheet (its surface's domain [m]) on spans
    (n1, n2) of `degree`, its knots uniform or graded towards the model's held points
    (module docstring)."""
    check_knots(knots)
    domain = model.surface.domain
    config = SplineConfig(spans=tuple(int(s) for s in spans), degree=degree,
                          domain=tuple(tuple(float(b) for b in bounds) for bounds in domain.bounds))
    if knots == "uniform":
        return config
    return graded_config(config, model.boundary, model.loads, domain)
