"""The memory a scene's sizes imply (spline grids and their levels, the contact check grid, a
SIREN's width and sample counts), refused before any work when the machine does not have it.

Each estimate is a count of the data a run keeps times the bytes measured per item
(`benchmarks/run_sizes.py`, one `ndf-sim` process per size, peak RSS growth between two sizes;
the table is in benchmarks/RESULTS.md, "Run sizes"), compared with the memory available now
(`io.memory.available_memory`). Time is not refused: on every size measured the memory binds
long before a run's time would (one Newton iteration on 147 456 Gauss points, 3.3 GB, takes
about 2 min on the 2-core test machine); the refusal states the seconds per Newton iteration
the measurement implies, so an absurd grid reads as absurd in both.
"""

from __future__ import annotations

from taichi_ndf.io.memory import available_memory

__all__ = ["check_run_size", "contact_memory", "siren_memory", "spline_gauss_points",
           "spline_memory"]

# Spline field, projected Newton: peak RSS growth per Gauss point of the finest grid, 1 299 ->
# 3 310 MiB from 48² to 96² cubic spans (36 864 -> 147 456 Gauss points, 4 × 4 per span, f64,
# banded Cholesky; Gauss points, local bases and Jacobians (N, 6, 48), the 18 × 18 Hessian
# blocks and their central differences, the assembly's scatter). f32 runs keep the Hessian
# work in f64 and are counted the same.
BYTES_PER_GAUSS_POINT = 19_000
# Wall time per Gauss point of one Newton iteration at 96² spans (272 s for the run's two
# iterations and its start, machine loaded ~16 on 2 cores): an indication only.
SECONDS_PER_GAUSS_POINT = 1e-3
# Contact check grid (check_resolution² points): peak RSS growth per grid point.
BYTES_PER_CHECK_POINT = 1_500
# SIREN: values kept per sample, neuron and sine layer for the backward (pre-activation and
# activation jets, cos: 13 values, plus scratch): 21 measured at 128 × 3 (131 MB over start-up
# with 4096 samples, f32, benchmarks/RESULTS.md "field step"), 16 at 512 × 5.
VALUES_PER_SAMPLE_NEURON = 21
# Per weight: the weight, its gradient and Adam's two moments.
VALUES_PER_WEIGHT = 4


def spline_gauss_points(plan) -> int:
    """Gauss points of the finest grid of `plan` (a `SplinePlan`), counted without building it:
    each level halves every span."""
    spans = [n * 2 ** (plan.levels - 1) for n in plan.config.spans]
    q = plan.quadrature_points or plan.config.degree + 1
    return spans[0] * spans[1] * q * q


def spline_memory(plan) -> int:
    """Estimated peak bytes of solving `plan`'s finest grid by projected Newton."""
    return spline_gauss_points(plan) * BYTES_PER_GAUSS_POINT


def contact_memory(resolution: int) -> int:
    """Estimated peak bytes of a contact check grid of `resolution`² points."""
    return resolution * resolution * BYTES_PER_CHECK_POINT


def siren_memory(field, samples: int, itemsize: int) -> int:
    """Estimated peak bytes of training the SIREN `field` (a `FieldConfig`) on batches of
    `samples` points with values of `itemsize` bytes."""
    weights = sum(rows * (columns + 1) for rows, columns in field.layer_sizes)
    kept = samples * field.width * field.hidden_layers * VALUES_PER_SAMPLE_NEURON
    return (kept + VALUES_PER_WEIGHT * weights) * itemsize


def _gib(n: float) -> str:
    return f"{n / 2**30:.3g} GiB"


def _refuse_beyond(need: int, what: str, advice: str) -> None:
    have = available_memory()
    if have is not None and need > have:
        raise ValueError(f"{what} needs about {_gib(need)} of memory, this machine has "
                         f"{_gib(have)} available; {advice}")


def check_run_size(scene, solver, *, itemsize: int = 4) -> None:
    """Raise ValueError (one line with the estimate) if a size of `scene` solved with `solver`
    (a `SolverConfig`) needs more memory than this machine has available. itemsize: bytes per
    value of the run's precision (4: f32, 8: f64)."""
    from taichi_ndf.spline_grid import SplinePlan

    field = scene.field
    if isinstance(field, SplinePlan):
        points = spline_gauss_points(field)
        spans = [n * 2 ** (field.levels - 1) for n in field.config.spans]
        levels = "" if field.levels == 1 else f" ({field.levels} levels)"
        seconds = points * SECONDS_PER_GAUSS_POINT
        _refuse_beyond(spline_memory(field),
                       f"spline field: the finest grid{levels} of {spans[0]} × {spans[1]} spans "
                       f"({points:.3g} Gauss points, ~{seconds:.2g} s per Newton iteration)",
                       "choose fewer spans, a longer span_length or fewer levels / --refine")
    else:
        samples = max(solver.samples, solver.monitor_samples,
                      solver.newton_samples if solver.newton_iterations else 0)
        _refuse_beyond(siren_memory(field, samples, itemsize),
                       f"SIREN field {field.width} wide × {field.hidden_layers} layers on "
                       f"{samples} samples", "choose a narrower field or fewer samples")
    contact = scene.model.contact
    if contact is not None:
        _refuse_beyond(contact_memory(contact.check_resolution),
                       f"contact.check_resolution = {contact.check_resolution} "
                       f"({contact.check_resolution ** 2:.3g} check points)",
                       "choose a smaller check_resolution")

