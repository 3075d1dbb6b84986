"""A probe point's displacement extrapolated over dyadically refined grids, one bar per
component, whose order is the point's (`richardson_point`; the scalar rule is
`extrapolation.richardson`). A component's order depends on the axes, the point's does not,
so a component's observed order is trusted only where the point's is too, observed on the
lengths of the vector changes; measurements in `richardson_point`'s docstring."""

from __future__ import annotations

import dataclasses
import logging

import numpy as np

from taichi_ndf.minimise.extrapolation import (
    BOUND_WORDS,
    SAFETY_UNRELIABLE,
    Extrapolation,
    OrderEstimate,
    extrapolate_changes,
    richardson,
    unconverged_reason,
)

log = logging.getLogger(__name__)


def richardson_point(values: list[list[float]], order: float | None = None,
                     converged: list[bool] | None = None,
                     solve_errors: list[list[float]] | None = None) -> list[Extrapolation]:
    """`richardson` for a point's displacement u (per grid a vector, (K, 3) in m), one
    Extrapolation per component: a component's observed order is trusted only where the
    point's is too, observed on the lengths of the vector changes |u_{i+1} − u_i| (as for a
    field; a level used that did not converge makes it unreliable, as for a component). A
    component's order depends on the axes, the point's does not (measured: the flag's
    fly_bottom moves 0.131 m then 0.102 m, order 0.37, while its z component alone falls at
    order 3.54, and that ± 1.1 mm bar missed the 120 × 80 value by 16 mm; and the other way
    round, the napkin's corner on 2²/4²/8² has norms falling at order 1.01 while x and y do not
    fall monotonically: benchmarks/RESULTS.md). So:

    - the point's order reliable: each component's own `richardson`, except that a component
      whose own order is unreliable (its value the finest, its bar 3 × the range or the
      floor) takes the smaller of its own bar and the point's (bound "point"). The point's
      bar, 1.25 |d₂|/(2ᵖ − 1) on the norms, bounds the changes of the vector still to come
      past the finest grid, |u∞ − u_finest| (the same assumption as any observed bar: the
      changes go on falling at the observed order), and a component's distance is at most
      the vector's: |u_c∞ − u_c,finest| ≤ |u∞ − u_finest|. It bounds the finest value only,
      not a component's extrapolated one, so an observed component keeps its own bar.
      Measured (benchmarks/RESULTS.md, issue 33): the pinched hemisphere's points converge
      at order 3.19 relative to the gauge (u_r and Π at 3.25), while a near-zero z
      component's changes fall at order 4.06, just above the cap: 3 × its range, 2.7e-3 of
      |u|, where the point's bar is 4.3e-5;
    - the point's order unreliable: where a component's own is reliable, the component's
      finest value with 3 × its range, the point's reason (with the point's bound "floor":
      the point's bar, the changes of the vector still to come bound each component's, never
      narrower than the component's own); the component's own `richardson` otherwise.
    With two grids each component's own `richardson`. solve_errors (K, 3): each component's
    solve error per grid (None: not measured, NaN: not for that component): its own bar at
    the a-priori order past the floor (`richardson(..., smooth=True, solve_errors=)`)."""
    u = np.asarray(values, dtype=float)
    errors = [None] * u.shape[1] if solve_errors is None else [  # per component, if all finite
        e.tolist() if np.isfinite(e).all() else None for e in np.abs(np.asarray(solve_errors)).T]
    own = [richardson(u[:, c].tolist(), order, converged, smooth=e is not None, solve_errors=e)
           for c, e in enumerate(errors)]
    if len(u) < 3:
        return own
    last = u[-3:]
    norms = np.linalg.norm(np.diff(last, axis=0), axis=1).tolist()
    point = extrapolate_changes(norms, order, scale=float(np.linalg.norm(last, axis=1).max()),
                                unconverged=unconverged_reason(converged, len(u)))
    if point.basis == "observed":
        return [_within_point(bar, point, last[:, c].tolist()) for c, bar in enumerate(own)]
    out = []
    for c, bar in enumerate(own):
        if bar.basis != "observed":
            out.append(bar)
            continue
        reason, v = f"the point's {point.reason}", last[:, c]
        if point.bound == "floor":
            out.append(Extrapolation(float(v[2]), max(point.error, bar.error), point.order,
                                     "unreliable", len(u), order, None, reason, "floor"))
            continue
        warning = (f"refinement order unreliable ({reason}): the finest value with 3 × the "
                   "range of the last three grids as its error bar; refine further")
        log.warning("%s", warning)
        out.append(Extrapolation(float(v[2]), SAFETY_UNRELIABLE * float(v.max() - v.min()),
                                 point.order, "unreliable", len(u), order, warning, reason))
    return out


def _within_point(bar: Extrapolation, point: OrderEstimate,
                  last: list[float]) -> Extrapolation:
    """A component's bar where its point's order is reliable (`richardson_point`; last: the
    component's last three values): an unreliable component (value: the finest) whose
    changes fall (same sign, the last smaller) and whose own bar is wider than the point's
    takes the point's, with the reason said; any other unchanged. A component whose changes
    do not fall keeps its own: the vector's changes then turn, and the norms' order is no
    measure of them (the napkin's corner on 2²/4²/8², `richardson_point`: norms at order 1.01,
    each component reversing, the 32² value 0.12 m from the 8² one, 3 × the point's bar)."""
    d1, d2 = last[1] - last[0], last[2] - last[1]
    falling = d1 * d2 > 0.0 and abs(d2) < abs(d1)
    if bar.basis != "unreliable" or not falling or bar.error <= point.error:
        return bar
    reason = (f"{bar.reason}; within the point's bar (observed order {point.order:.2f} of "
              "|Δu|)")
    log.info("probe component: %s, bar %.2g instead of %s %.2g", reason, point.error,
             BOUND_WORDS[bar.bound], bar.error)
    return dataclasses.replace(bar, error=point.error, reason=reason, warning=None,
                               bound="point")
