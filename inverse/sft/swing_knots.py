"""The swing's spline grid (`inverse.sft.swing`): n1 × n2 spans of degree 3 or 4 on the flat
sheet [0, W] × [0, H] (ξ² = 0 the held edge), with uniform knots or knots graded towards the
held edge.

Why the held edge. A sheet held at two points of its top edge sags between them and buckles
out of its plane in a band along that edge, about a bending length c deep: there its bending
energy lives, and there a coarse grid bends too little — the model is then stiffer than the
sheet, and B fitted with it reads low (benchmarks/RESULTS.md, wip-sftmat10/11: the upper band's
bending energy 7–16 % short on 32², in step with B's bias). "graded" puts the same unknowns
where that band is: the ξ² knots graded towards ξ² = 0 by the law of `taichi_ndf.field.grading`
as `problem.spline_grid.graded_towards` applies it to singular features (core one span of the
grid, the graded part half of the spans); ξ¹ stays uniform (the band runs the whole edge).
Measured on the synthetic swing's rest state (RESULTS.md, wip-sftmat12): B's static bias
against a degree-4 64² reference on 32² spans, degree 4, −9.3 % uniform, −1.2 % graded.
"""

from __future__ import annotations

from taichi_ndf.field.spline import SplineConfig
from taichi_ndf.problem.spline_grid import graded_towards

KNOTS = ("uniform", "graded")  # SwingConfig.knots


def check_knots(knots: str) -> None:
    """ValueError unless `knots` is one of KNOTS."""
    if knots not in KNOTS:
        raise ValueError(f"knots must be one of {KNOTS}, got {knots!r}")


def swing_spline(size: tuple[float, float], spans: tuple[int, int], degree: int,
                 knots: str = "uniform") -> SplineConfig:
    """The spline field of the flat sheet (W, H) [m] on spans (n1, n2) of `degree`, its knots
    uniform or graded towards the held edge ξ² = 0 (module docstring)."""
    check_knots(knots)
    width, height = (float(s) for s in size)
    config = SplineConfig(spans=tuple(int(s) for s in spans), degree=degree,
                          domain=((0.0, width), (0.0, height)))
    return config if knots == "uniform" else graded_towards(config, ((), (0.0,)))
