"""The stopping test of `--tolerance` (issue 33): whether every estimated error of a
refinement document (`SplineRun.refinement`: Π and every probe component over the last three
grids) is within a relative tolerance, and the probes read relative to the model's gauge
motions before the test.

A probe component that a gauge motion moves (`boundary.gauge_motions`: a free rigid motion
nothing fixes, e.g. the Scordelis–Lo roof's and the pinched cylinder's axial translation, the
pinched hemisphere's swing about its pin) changes between grids by wherever each solve left
the shell, not by a grid error, and it spoils the bar of its point's other components
(`richardson_point` reads the point's vector changes). So where the model has gauge motions
the test reads the probes relative to their best-fit gauge motion (`ProbeGauge.relative`),
re-extrapolated over the levels (`gauge_relative`); Π, the components no gauge motion moves
and the first-order rigid invariants of the probes (distances) are unchanged by that. The
document's own probe entries (result.json) keep the raw readings and their bars; the
relative ones are reported beside them (measured on both alternatives, benchmarks/RESULTS.md:
"the tolerance and free rigid motions").
"""

from __future__ import annotations

import math

from taichi_ndf.boundary.gauge_motions import ProbeGauge
from taichi_ndf.minimise.point_extrapolation import richardson_point


def unconverged_window(converged: list[bool] | None) -> str | None:
    """Why the estimate over the last three levels is no discretisation error: the levels
    among them whose Newton solve did not converge, in words (None: all converged, or
    unknown)."""
    if converged is None:
        return None
    first = max(len(converged) - 3, 0)
    failed = [i for i in range(first, len(converged)) if not converged[i]]
    if not failed:
        return None
    return (f"grid level{'s' if len(failed) > 1 else ''} {', '.join(map(str, failed))} of "
            f"{len(converged)} not converged (Newton stopped before its tolerance): the "
            "estimate is not a discretisation error")


def tolerance_met(document: dict, tolerance: float,
                  converged: list[bool] | None = None) -> tuple[bool, str]:
    """Whether every estimated error in a refinement document is within the tolerance
    (module docstring), and the largest relative one in words. converged: per grid level,
    whether its Newton solve converged (None: all did); where one of the last three did not,
    the tolerance is not met whatever the bars (`richardson` marks such an estimate
    unreliable; its bar can be small, e.g. 0 where Newton stopped at the same Π on every
    grid), and the words say which level."""
    if len(document["spans"]) < 3:
        return False, "fewer than three grids"
    unconverged = unconverged_window(converged)
    if unconverged is not None:
        return False, unconverged
    worst, what = 0.0, ""
    energy = document["energy"]
    ratio = energy["estimated_error"] / max(abs(energy["extrapolated"]), 1e-300)
    worst, what = ratio, "Π"
    for name, parts in document["probes"].items():
        scale = math.sqrt(sum(c["extrapolated"] ** 2 for c in parts))
        for axis, c in enumerate(parts):
            if c["estimated_error"] == 0.0:
                continue
            ratio = c["estimated_error"] / max(scale, 1e-300)
            if ratio > worst:
                worst, what = ratio, f"probe {name}:{axis}"
    return worst <= tolerance, f"largest estimated relative error {worst:.3g} ({what})"


def gauge_relative(document: dict, gauge: ProbeGauge, order: float,
                   converged: list[bool] | None = None) -> dict:
    """`document` with its probes read relative to their best-fit gauge motion on every
    level and extrapolated again (`richardson_point`, order: the expected order; converged:
    per level, as `SplineRun.refinement`); Π and the spans as they were."""
    names = list(document["probes"])
    levels = [{name: [c["values"][i] for c in document["probes"][name]] for name in names}
              for i in range(len(document["spans"]))]
    relative = [gauge.relative(level) for level in levels]

    def point(name):
        values = [level[name] for level in relative]
        return [{"values": [v[c] for v in values], **e.to_dict()} for c, e in enumerate(
            richardson_point(values, order=order, converged=converged))]

    return {**document, "probes": {name: point(name) for name in names}}
