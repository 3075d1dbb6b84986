"""The memory a scene's sizes imply (spline grids and their levels, the contact check grid, a
SIREN's width and sample counts), refused before any work where the machine cannot hold it.

Each estimate is a count of the points a solve keeps data for times the bytes measured per
point (`benchmarks/run_sizes.py`: one `ndf-sim` process per size, peak RSS growth between two
sizes; the table is in benchmarks/RESULTS.md, "Run sizes"). A contact check point can join
every sample set of the solve (`contact.check_points`: the points that come close carry the
barrier), so each of the check_resolution² points is counted as one more Gauss point or
sample. The ceiling is the machine's physical memory (`io.memory.physical_memory`): more is
refused (ValueError, one line with the estimate); more than is available now (other processes
hold the rest) is a logged warning, since that changes from one moment to the next.
Time is not refused: on every size measured the memory binds first (one Newton iteration on
147 456 Gauss points, 3.3 GB, took about 2 min on the loaded 2-core test machine); the
refusal states the seconds per Newton iteration the measurement implies.
Which estimate applies is the field type's: its discretisation's `check_size` at run start
(`taichi_ndf.discretise`), the scene reader's when a scene is read.
"""

from __future__ import annotations

import logging

from taichi_ndf.io.memory import available_memory, physical_memory

__all__ = ["check_siren_size", "check_spline_size", "contact_check_points", "siren_memory",
           "siren_samples", "spline_gauss_points", "spline_memory"]

log = logging.getLogger(__name__)

# Spline field, projected Newton: peak RSS growth per Gauss point of the finest grid, 1 299 ->
# 3 310 MiB from 48² to 96² cubic spans (36 864 -> 147 456 Gauss points, 4 × 4 per span, f64,
# banded Cholesky; per point: local basis and Jacobian jets (N, 6, 48), the 18 × 18 Hessian
# block and its central differences, the assembly's products). f32 runs keep the Hessian
# work in f64 and are counted the same. Contact check points close to the obstacle cost about
# as much: 17-25 kB each from 128² to 256² check points, and a 1024² grid on 8 × 8 spans held
# 18.8 GB when stopped (1.05e6 points × 19 kB = 19.9 GB).
BYTES_PER_GAUSS_POINT = 19_000
# Wall time per Gauss point of one Newton iteration at 96² spans (272 s for the run's two
# iterations and its start, machine loaded ~16 on 2 cores): an indication only.
SECONDS_PER_GAUSS_POINT = 1e-3
# SIREN: values kept per sample, neuron and sine layer for the backward (pre-activation and
# activation jets, cos: 13 values, plus scratch): 21 measured at 128 × 3 (131 MB over start-up
# with 4096 samples, f32, benchmarks/RESULTS.md "field step"), 16 at 512 × 5.
VALUES_PER_SAMPLE_NEURON = 21
# Per weight: the weight, its gradient and Adam's two moments.
VALUES_PER_WEIGHT = 4


# Levels beyond which the finest grid is counted as this many levels (its memory is then past
# any machine's by far; the count stays an exact integer and its message a float).
MAX_COUNTED_LEVELS = 100


def _finest_spans(plan) -> list[int]:
    """Spans per direction of the finest grid (each level halves every span)."""
    return [n * 2 ** (min(plan.levels, MAX_COUNTED_LEVELS) - 1) for n in plan.config.spans]


def spline_gauss_points(plan) -> int:
    """Gauss points of the finest grid of `plan` (a `SplinePlan`), counted without building it
    (more than MAX_COUNTED_LEVELS levels count as that many)."""
    spans = _finest_spans(plan)
    q = plan.quadrature_points or plan.config.degree + 1
    return spans[0] * spans[1] * q * q


def spline_memory(plan, extra_points: int = 0) -> int:
    """Estimated peak bytes of solving `plan`'s finest grid by projected Newton, with
    `extra_points` more points in the assembly (contact check points)."""
    return (spline_gauss_points(plan) + extra_points) * BYTES_PER_GAUSS_POINT


def siren_memory(field, samples: int, itemsize: int) -> int:
    """Estimated peak bytes of training the SIREN `field` (a `FieldConfig`) on batches of
    `samples` points with values of `itemsize` bytes."""
    weights = sum(rows * (columns + 1) for rows, columns in field.layer_sizes)
    kept = samples * field.width * field.hidden_layers * VALUES_PER_SAMPLE_NEURON
    return (kept + VALUES_PER_WEIGHT * weights) * itemsize


def _gib(n: float) -> str:
    return f"{n / 2**30:.3g} GiB"


def _check(need: int, what: str, advice: str) -> None:
    total = physical_memory()
    if total is not None and need > total:
        raise ValueError(f"{what} needs about {_gib(need)} of memory, more than this machine's "
                         f"{_gib(total)}; {advice}")
    have = available_memory()
    if have is not None and need > have:
        log.warning("%s needs about %s of memory, more than the %s available now (other "
                    "processes hold the rest): the run may swap or run out", what, _gib(need),
                    _gib(have))


def check_spline_size(plan, *, check_points: int = 0, grid: str = "",
                      advice: str = "choose fewer spans, a longer span_length, fewer levels / "
                                    "--refine or a smaller check_resolution") -> None:
    """Raise ValueError (one line with the estimate) if solving `plan`'s finest grid (a
    `SplinePlan`, with `check_points` contact check points, described by `grid`) needs more
    memory than this machine has; warn if more than is available now."""
    points = spline_gauss_points(plan)
    spans = [f"{n:.3g}" if n > 10**6 else str(n) for n in _finest_spans(plan)]
    levels = "" if plan.levels == 1 else f" ({plan.levels} levels)"
    seconds = float(points + check_points) * SECONDS_PER_GAUSS_POINT
    _check(spline_memory(plan, check_points),
           f"spline field: the finest grid{levels} of {spans[0]} × {spans[1]} spans "
           f"({float(points):.3g} Gauss points){grid}, ~{seconds:.2g} s per Newton iteration,",
           advice)


def check_siren_size(field, samples: int, itemsize: int, *, check_points: int = 0,
                     grid: str = "", advice: str = "choose a narrower field, fewer samples or "
                                                   "a smaller check_resolution") -> None:
    """Raise ValueError (one line with the estimate) if training the SIREN `field` (a
    `FieldConfig`) on `samples` points (+ `check_points`) of `itemsize` bytes needs more memory
    than this machine has; warn if more than is available now."""
    _check(siren_memory(field, samples + check_points, itemsize),
           f"SIREN field {field.width} wide × {field.hidden_layers} layers on {samples} "
           f"samples{grid}", advice)


def contact_check_points(contact) -> dict:
    """The contact check grid's part of an estimate: `check_points` (check_resolution² points,
    0 without obstacles) and `grid`, its words in the message; keyword arguments of
    `check_spline_size` and `check_siren_size`. contact: the model's `ContactConfig` or None."""
    if contact is None:
        return {"check_points": 0, "grid": ""}
    return {"check_points": contact.check_resolution ** 2,
            "grid": f" and a contact check grid of {contact.check_resolution}² points "
                    "(contact.check_resolution)"}


def siren_samples(solver) -> int:
    """The most samples one evaluation of a SIREN run with `solver` (a `SolverConfig`) holds."""
    return max(solver.samples, solver.monitor_samples,
               solver.newton_samples if solver.newton_iterations else 0)
