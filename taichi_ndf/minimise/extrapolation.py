"""Richardson extrapolation of a quantity over dyadically refined grids, with an error bar.

`richardson` extrapolates a quantity from its values on the last grids and bounds the error
of the result (one rule for every caller: `extrapolate_changes` works on the changes between
successive grids, signed for a scalar, a norm for a field of positions). It follows Roache's
grid convergence index (GCI; P. J. Roache, "Perspective: a method for uniform reporting of
grid refinement studies", J. Fluids Eng. 116 (1994) 405–413, and "Discussion: factors of
safety for Richardson extrapolation", J. Fluids Eng. 133 (2011) 115501): the extrapolation is
trusted only where the observed order is reasonable, with a safety factor Fs = 1.25; where it
is not, the bar falls back to a conservative one with Fs = 3. With three values v₀, v₁, v₂ on
grids h, h/2, h/4 (changes d₁ = v₁ − v₀, d₂ = v₂ − v₁):

- observed order p = log₂(d₁/d₂); the order is **reliable** where the changes fall
  monotonically (d₁/d₂ > 1), neither change is at the rounding level (|d| > `ROUNDING` ×
  max|v|) and `ORDER_MIN` ≤ p ≤ the expected order 2(p_deg − 1) (+ `ORDER_SLACK`, where one
  is given). Then
  v∞ = v₂ + d₂/(2ᵖ − 1) and the error is 1.25 |v∞ − v₂| (the interval reaches a quarter of
  the correction past v₂ on one side and 1.25 corrections past v∞ on the other); a warning
  is logged where p is below the expected order / `ORDER_FAR`.
- otherwise the order is **unreliable** (said so in the value's text and `order_basis`):
  v∞ = v₂ and the error is 3 Δ_M, Δ_M = max|vᵢ − vⱼ| the range of the three values (Eça and
  Hoekstra's data range, L. Eça and M. Hoekstra, J. Comput. Phys. 262 (2014) 104–130, with
  their Fs = 3 for data that do not converge monotonically). Not Roache's "p_th with Fs = 3"
  fallback, 3 |d₂|/(2^p_th − 1): where p is above the expected order the last change is
  small by coincidence (measured, benchmarks/RESULTS.md: cantilever_shear's tip at t = 0.1
  changes by 6.5e-6 then 6.4e-9, observed order 10, and the 64 × 16 value lies 4.8e-7 away,
  75× the last change), so no multiple of the last change bounds the error; the range does.
  For a field (norms of its differences) Δ_M is bounded by d₁ + d₂.

One case of an unreliable order has a tighter bound: the changes fall (same sign, |d₂| <
|d₁|), the order is unreliable only because it is above the expected one or d₂ is at the
rounding level, d₂ is within `NEAR_ROUNDING` (a decade) of the rounding level
(|d₂| ≤ 10 × `ROUNDING` × max|v|), and the order of d₁ over max(|d₂|, the rounding level) is
at most `ORDER_FAR` × the expected one (8). The sequence has then converged to the level where
the solves themselves stop (Newton's tolerance, a slowly converging part too small to show on
coarse grids), so what is left past v₂ is the changes still to come, of the size of d₂ or of
the rounding level, whichever is larger: summed as a geometric series falling at the slowest
order the rule ever trusts (`ORDER_MIN`), the error is max(|d₂|, `ROUNDING` max|v|) /
(2^0.5 − 1) = 2.41 × that (v∞ = v₂; `bound` "floor"). Measured (benchmarks/RESULTS.md, issue
33): cantilever_shear's tip, whose coarse grids fall at order 5.3–10 and whose finer ones at
order ≈ 0.8 from 1e-6 of the value, held at 2.6–6.9 × the distance to its 64 × 16 value
(the range bound: 40–344 ×). Where d₂ is larger, a fall faster than the expected order can be
a coincidence of the coarse grids (bowl in silk's centre on 2² / 4² / 8²: order 5.0, and the
32² value 28 × d₂ away), and where d₁ is more than 2⁸ × d₂ (or the rounding level) the
near-zero last change is a cancellation, not a convergence (a slow order-0.7 term cancelled
by an h⁴ term: tests/test_projected_newton.py): the range bound stays.

Measured for issue 33 (benchmarks/RESULTS.md, wip-adapt12; each case solved with Newton's
defaults and to λ²/2 ≤ 1e-15 |Π| without the discretisation stopping test), the slow tails
that set order 0.5 have two causes: the shear cantilever's tip (order 0.69) and its Π (1.88,
then 0.41) are the grid's (on 32 × 8 and 64 × 16 the same to 10 digits solved tight): its
point loads (the tip probe sits on one) are a singular feature; cantilever_moment's −U tail
(order 6.2, then 1.25) is the Newton solve's, 3.6e-5 on 32 × 4 and on 64 × 8 at the defaults,
while solved tight it falls at order 6.1, then 8.9. A displacement's solve error goes with
the energy norm of Newton's untaken step, √(λ²); Π's is λ²/2 ≤ `discretisation_fraction` ×
|Π − Π_coarse| (1e-4 of the change; `minimise.newton`), far below d₂ (cantilever_moment's Π:
5.2e-7 J apart both ways on 16 × 2, 1.3e-9 J on 64 × 8, where d₂ = 1.5e-4 J). So for **Π of
a model with no known singular feature** (`smooth`: no pin but gauges, point load, interior
line, line-load end, obstacle or extra term; `spline_grid.no_singular_feature`) whose changes
fell at least at the a-priori order (the caller's expected order 2(p − 1): Π's error is the
energy-norm error squared, whose rate is h^(p−1) for degree-p splines on a smooth
Kirchhoff–Love solution: J. Benzaken, J. A. Evans, S. McCormick and R. Tamstorf, "Weak
boundary condition enforcement for linear Kirchhoff–Love shells: formulation, error
analysis, and verification", arXiv:2007.01279, 2020), the changes to come
are summed at that order with Roache's factor of safety for an assumed order, Fs = 3: the
error is 3 max(|d₂|, `ROUNDING` max|v|) / (2^p − 1) (bound "a priori"; cantilever_moment's Π
falls at 5.70 then 3.48 solved tight, so 1.25 × the sum would miss its 128 × 16 value by 1 %).
A **probe component of such a model** takes it only with its solve errors e (`solve_errors`:
`minimise.refinement.GridLevels`' probe stop; none where a gauge motion moves it): the bar is
3 max(|d₂| + e₁ + e₂, `ROUNDING` max|v|)/(2^p − 1) + e₂ (the last two values'). Without them
a probe's solve error can exceed d₂ (cantilever_moment's −U at Newton's defaults, 3.6e-5 on
64 × 8 against d₂ = 8.1e-5: benchmarks/RESULTS.md, wip-adapt13). Models with a feature,
probes without solve errors and slower changes keep the order-0.5 sum.

Such a quantity (Π of a smooth model, or a probe of one with its solve errors e) whose changes
fall **faster than the a-priori order on both of the last two ratios** (bound "fast") has its
order observed from three grids, not assumed, so Roache's GCI for an observed order applies:
the error of the finest value is 1.25 max(|d₂| + e₂ + e₃, `ROUNDING` max|v|)/(2^p − 1) + e₃
(v∞ = v₃, the finest), p the smaller of the two orders, each taken within the solve errors:
log₂ of the smaller of (|d₀| − e₀ − e₁)/(|d₁| + e₁ + e₂) and (|d₁| − e₁ − e₂)/(|d₂| + e₂ + e₃)
(d₀, d₁, d₂ the last three changes of four values v₀ … v₃ with errors e₀ … e₃). It needs
four values that all converged, the three changes of one sign, each above the rounding level,
and both ratios at least 2^(a-priori order): one fast ratio alone may be a coincidence of the
coarse grids (the bowl in silk above). It replaces the "a priori" and "range" bars there
(always narrower than the a-priori one: 1.25/(2^p − 1) ≤ 3/(2^p_apriori − 1)). Measured
(benchmarks/RESULTS.md, wip-adapt15): cantilever_moment's −U solved to precision falls at
order 5.5 then 6.1 on 8×1 … 64×8; the stored studies' quarter plates' Π and w (order ≈ 4.06 on
both ratios) hold their 128² values at 1.21 × the distance where the a-priori bar was 3.05 ×,
the thick roof's Π at 1.09 × (the range bar: 7 100 ×).

A value whose grid's Newton solve did not converge (`converged`, where the caller knows it)
is not that grid's discrete answer, so its changes say nothing of the order: where one of the
values used (the last three, or two) did not converge, the order is unreliable whatever the
changes look like (measured: napkin in silk, 2 × 2 and 4 × 4 stopped at Π = 0 after one
refused step, benchmarks/RESULTS.md "Honest numbers (issue 35, 2026-12-06)").

With two values the order cannot be observed: it is assumed (the expected order, required),
the value is extrapolated with it and the error is widened to the whole change |v₂ − v₁|
between the two grids (Roache's two-grid GCI, 3 |d|/(2^p − 1), is 0.2 |d| at p = 4: narrower;
measured: the napkin's two-grid bar at the assumed order 4 was 15× smaller than the change;
benchmarks/RESULTS.md, "Refinement error bars"). The text says "order assumed".
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass

import numpy as np

log = logging.getLogger(__name__)


ORDER_FAR = 2.0  # a reliable observed order below expected / ORDER_FAR warns
ORDER_MIN = 0.5  # an observed order below this is unreliable (2ᵖ − 1 → 0: the correction blows up)
# An observed order up to expected + ORDER_SLACK is reliable (Xing and Stern's and Eça and
# Hoekstra's p < 2.05 for a second-order method), so an exact power law of the expected order
# is not refused for its rounding.
ORDER_SLACK = 0.05
# A change at most this fraction of max|v| is not resolved: float32's Π rounding floor is
# about 1e-6 |Π| (spline_solver.newton_config), and in float64 at the default Newton tolerance
# cantilever_shear's tip stops converging near 1e-7 relative (benchmarks/RESULTS.md).
ROUNDING = 1e-6
# A last change of at most NEAR_ROUNDING × ROUNDING × max|v|, falling faster than expected:
# converged to the solves' floor (module docstring), the bound "floor".
NEAR_ROUNDING = 10.0
SAFETY_OBSERVED = 1.25  # Roache's Fs for three grids with a reliable observed order
SAFETY_UNRELIABLE = 3.0  # Roache's Fs where the order cannot be trusted (times the range)
ORDER_BASES = ("observed", "assumed", "unreliable")
# an unreliable order's error bar (module docstring; "point": a probe component's, bounded by
# its point's, `richardson_point`; "a priori": Π, or a probe with its solve errors, of a
# smooth model past the floor; "fast": one falling faster than the a-priori order on the
# last two ratios)
BOUNDS = ("range", "floor", "point", "a priori", "fast")


@dataclass(frozen=True)
class Extrapolation:
    """A refinement-extrapolated value and its error bar (the interval value ± error should
    hold the converged value), the order it used, and how it was found: basis "observed"
    (three or more grids, a reliable observed order), "assumed" (two grids: `order` is the
    expected one) or "unreliable" (three or more grids whose order cannot be trusted: value
    = the finest value, error = 3 × the range of the last three values; `order` the observed
    one or None, `reason` why; module docstring). grids: how many values; warning: a
    one-line caution or None; bound: an unreliable order's error bar, "range" (3 × the range),
    "floor" (the changes still to come past a sequence converged to the rounding level),
    "point" (a probe component's: its point's bar, narrower than its own; `richardson_point`),
    "a priori" or "fast" (a smooth model's quantity: the changes to come at the a-priori
    order, or at the slower of two observed orders above it; module docstring)."""

    value: float
    error: float
    order: float | None
    basis: str = "observed"
    grids: int = 3
    expected: float | None = None
    warning: str | None = None
    reason: str | None = None
    bound: str = "range"

    @property
    def assumed(self) -> bool:
        return self.basis == "assumed"

    @property
    def unreliable(self) -> bool:
        return self.basis == "unreliable"

    def describe(self, unit: str = "") -> str:
        """'v ± e unit (how)', the way every output shows the value."""
        unit = f" {unit}" if unit else ""
        return f"{self.value:.6g} ± {self.error:.2g}{unit} ({self.how()})"

    def how(self) -> str:
        """How the value was found, in words (shown beside it everywhere)."""
        if self.basis == "assumed":
            return (f"order {self.order:g} assumed from {self.grids} grids, error = the change "
                    "between them")
        if self.basis == "unreliable":
            return (f"order unreliable from {self.grids} grids ({self.reason}): finest value, "
                    f"error = {BOUND_WORDS[self.bound]}")
        expected = "" if self.expected is None else f", expected {self.expected:g}"
        return f"observed order {self.order:.2f} from {self.grids} grids{expected}"

    def to_dict(self) -> dict:
        return {"extrapolated": self.value, "estimated_error": self.error, "order": self.order,
                "order_basis": self.basis, "order_reason": self.reason, "grids": self.grids,
                "expected_order": self.expected, "warning": self.warning,
                "error_bound": self.bound if self.basis == "unreliable" else None,
                "text": self.describe()}


BOUND_WORDS = {"range": "3 × the range of the last three",
               "floor": "the last change (at least the rounding level) summed at order 0.5",
               "point": "the point's bar, which bounds each component's distance",
               "a priori": "3 × the last change (at least the rounding level; a probe's with "
                           "its solve errors) summed at the a-priori order (no singular feature)",
               "fast": "1.25 × the last change (at least the rounding level; a probe's with its "
                       "solve errors) summed at the smaller of the last two observed orders, "
                       "both above the a-priori one (no singular feature)"}


@dataclass(frozen=True)
class OrderEstimate:
    """What the changes between successive grids say (`extrapolate_changes`): the order
    (observed, assumed, or the observed one that is not trusted; None where none can be
    computed), the correction v∞ − v_finest (0 where unreliable), the error bar, the basis,
    why an order is unreliable, a warning, and an unreliable order's bound (`BOUNDS`)."""

    order: float | None
    correction: float
    error: float
    basis: str
    reason: str | None = None
    warning: str | None = None
    bound: str = "range"


def _unreliable_reason(d1: float, d2: float, scale: float,
                       expected: float | None) -> tuple[float | None, str | None]:
    """The observed order of changes d₁, d₂ (None where the changes do not fall) and why it
    is not to be trusted (None: it is)."""
    ratio = d1 / d2 if d2 != 0.0 else math.inf
    observed = math.log2(ratio) if math.isfinite(ratio) and ratio > 1.0 else None
    if min(abs(d1), abs(d2)) <= ROUNDING * scale:
        return observed, f"a change at the rounding level, ≤ {ROUNDING:g} of the value"
    if observed is None:
        return None, "changes not falling monotonically"
    if observed < ORDER_MIN:
        return observed, f"observed order {observed:.2f} below {ORDER_MIN:g}"
    if expected is not None and observed > expected + ORDER_SLACK:
        return observed, f"observed order {observed:.2f} above the expected {expected:g}"
    return observed, None


def _fast_order(changes: list[float], errors: list[float], order: float,
                floor: float) -> float | None:
    """The order that the last three changes d₀, d₁, d₂ (values with solve errors `errors`,
    one per value) show for certain, where both of their ratios show at least the a-priori
    `order` (None otherwise: fewer than three changes, a change at the rounding level `floor`,
    changes not falling with one sign). Each value lies within its e of its grid's answer,
    so a change d_k between values k and k + 1 is that grid pair's within e_k + e_{k+1}; the
    ratio taken is the smaller of (|d₀| − e₀ − e₁)/(|d₁| + e₁ + e₂) and (|d₁| − e₁ − e₂)/(|d₂|
    + e₂ + e₃), the slowest the grids' own changes can fall (module docstring)."""
    if len(changes) < 3:
        return None
    d = changes[-3:]
    e = list(errors[-4:]) if len(errors) >= 4 else [0.0] * 4
    if not (d[0] * d[1] > 0.0 and d[1] * d[2] > 0.0 and min(map(abs, d)) > floor):
        return None
    ratios = [(abs(d[k]) - e[k] - e[k + 1]) / (abs(d[k + 1]) + e[k + 1] + e[k + 2])
              for k in (0, 1)]
    if min(ratios) <= 1.0:
        return None
    fast = math.log2(min(ratios))
    return fast if fast >= order else None


def extrapolate_changes(changes: list[float], order: float | None = None,
                        scale: float = 0.0, unconverged: str | None = None,
                        smooth: bool = False,
                        solve_errors: list[float] | None = None) -> OrderEstimate:
    """The order, correction and error bar of the finest value from the changes between
    successive grids refined by 2 each (signed differences of a scalar, or norms of a field's
    differences; the last two are used; module docstring). order: the expected order, assumed
    with one change and the upper limit of a reliable observed one with two or more. scale:
    the size of the values (max |v|) that the rounding level is relative to (0: no rounding
    check). unconverged: with two or more changes, why the order is unreliable because a
    value used did not converge (None: every one did). smooth: the values are Π of a model
    with no known singular feature, or a probe of one with solve_errors, one per value behind
    the changes (None: zero; the floor's changes to come at the a-priori `order`, and with
    three changes falling faster than it on both ratios at the slower observed order, bound
    "fast"; module docstring). Three changes are given only where all four values converged."""
    if not changes:
        raise ValueError("richardson needs at least two values, got 1")
    last = changes[-1]
    if len(changes) == 1:
        if order is None:
            raise ValueError("two values need an assumed order")
        return OrderEstimate(order, last / (2.0**order - 1.0), abs(last), "assumed")
    d1, d2 = changes[-2:]
    errors = [0.0] * (len(changes) + 1) if solve_errors is None else list(solve_errors)
    observed, reason = _unreliable_reason(d1, d2, scale, order)
    if unconverged is not None:
        reason = unconverged
    if reason is not None:
        floor = ROUNDING * scale
        fast = (None if not smooth or unconverged is not None or order is None
                or observed is None or observed <= order + ORDER_SLACK
                else _fast_order(changes, errors, order, floor))
        if fast is not None:
            # Roache's GCI of an order observed from three grids (Fs 1.25) on the finest value
            # at the slower of the last two orders; the last change within its solve errors
            return OrderEstimate(observed, 0.0, SAFETY_OBSERVED * max(
                                 abs(d2) + errors[-2] + errors[-1], floor) / (2.0**fast - 1.0)
                                 + errors[-1], "unreliable",
                                 f"{reason}; no singular feature: observed order ≥ {fast:.2f} "
                                 f"on the last two ratios, above the a-priori {order:g}",
                                 None, "fast")
        if (unconverged is None and order is not None and d1 * d2 >= 0.0
                and abs(d2) < abs(d1) and abs(d2) <= NEAR_ROUNDING * floor
                and abs(d1) <= 2.0 ** (ORDER_FAR * order) * max(abs(d2), floor)):
            reason = (f"{reason}; changes falling to within {NEAR_ROUNDING:g} × the rounding "
                      "level")
            if smooth and observed is not None and observed >= order:
                # each value within its e of its grid's: d₂ within |d₂| + e₁ + e₂, v₂ e₂ off
                return OrderEstimate(observed, 0.0, SAFETY_UNRELIABLE * max(
                                     abs(d2) + errors[-2] + errors[-1], floor)
                                     / (2.0**order - 1.0) + errors[-1], "unreliable",
                                     f"{reason}; no singular feature: order {order:g} a priori",
                                     None, "a priori")
            return OrderEstimate(observed, 0.0, max(abs(d2), floor) / (2.0**ORDER_MIN - 1.0),
                                 "unreliable", reason, None, "floor")
        spread = max(abs(d1), abs(d2), abs(d1 + d2))  # the range of the three values
        warning = (f"refinement order unreliable ({reason}): the finest value with 3 × the "
                   "range of the last three grids as its error bar; refine further for an "
                   "extrapolation")
        return OrderEstimate(observed, 0.0, SAFETY_UNRELIABLE * spread, "unreliable",
                             reason, warning)
    correction = d2 / (2.0**observed - 1.0)
    warning = None
    if order is not None and observed < order / ORDER_FAR:
        warning = (f"observed refinement order {observed:.2f} is far below the expected "
                   f"{order:g}: the grids are not in the asymptotic range (a singularity or "
                   "an unresolved layer?); the error bar rests on the observed order")
    return OrderEstimate(observed, correction, SAFETY_OBSERVED * abs(correction), "observed",
                         None, warning)


def unconverged_reason(converged: list[bool] | None, count: int) -> str | None:
    """Which of the last three of `count` levels did not converge, in words (None: all
    did, or unknown)."""
    if converged is None:
        return None
    first = count - min(count, 3)
    failed = [first + i for i, ok in enumerate(converged[first:]) if not ok]
    if not failed:
        return None
    return (f"grid level{'s' if len(failed) > 1 else ''} {', '.join(map(str, failed))} of "
            f"{count} not converged")


def richardson(values: list[float], order: float | None = None,
               converged: list[bool] | None = None, smooth: bool = False,
               solve_errors: list[float] | None = None) -> Extrapolation:
    """Richardson extrapolation of values on grids refined by 2 each, with a GCI-style error
    bar (module docstring). order: the expected convergence order, assumed with two values
    (required then) and the upper limit of a reliable observed order of the last three with
    three or more. converged: per value, whether its grid's solve converged (None: all did);
    three or more values of which one used did not: the order is unreliable. With two such
    values the bar stays the change, and the warning says it. smooth: the values are Π of a
    model with no known singular feature, or a probe of one with solve_errors, per value
    (`GridLevels`' probe stop; module docstring)."""
    if len(values) < 2:
        raise ValueError(f"richardson needs at least two values, got {len(values)}")
    if converged is not None and len(converged) != len(values):
        raise ValueError(f"{len(converged)} convergence flags for {len(values)} values")
    if solve_errors is not None and len(solve_errors) != len(values):
        raise ValueError(f"{len(solve_errors)} solve errors for {len(values)} values")
    last = values[-3:]
    # a fourth value (the "fast" bound's third change) only where it converged too
    used = values[-4:] if converged is None or all(converged[-4:]) else last
    changes = np.diff(used).tolist()
    unconverged = unconverged_reason(converged, len(values))
    errors = (None if solve_errors is None
              else [abs(float(e)) for e in solve_errors[len(values) - len(used):]])
    estimate = extrapolate_changes(changes, order, scale=max(abs(v) for v in last),
                                   unconverged=unconverged, smooth=smooth, solve_errors=errors)
    if estimate.basis == "assumed" and unconverged is not None:
        estimate = dataclasses.replace(
            estimate, reason=unconverged,
            warning=f"{unconverged}: the two-grid change is not a discretisation error")
    if estimate.warning is not None:
        log.warning("%s", estimate.warning)
    return Extrapolation(values[-1] + estimate.correction, estimate.error, estimate.order,
                         estimate.basis, len(values), order, estimate.warning, estimate.reason,
                         estimate.bound)
