"""The [field] table of a scene (a SIREN or a spline field) and the field-type switch of
`ndf-sim --field` (docs/scenes.md)."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from taichi_ndf.boundary.gauges import gauge_points
from taichi_ndf.field import FieldConfig, SplineConfig
from taichi_ndf.problem.field_types import DEFAULT, FIELD_TYPES
from taichi_ndf.problem.model import ShellModel
from taichi_ndf.problem.pseudo_time import DEFAULT_FRAMES
from taichi_ndf.problem.scaling import SCALE_ESTIMATES, characteristic_displacement
from taichi_ndf.problem.spline_grid import (
    GRADINGS,
    SplinePlan,
    auto_span_length,
    band_end_config,
    graded_config,
    spans_for,
)
from taichi_ndf.scene.schema import SceneError, Table


def field_config(t: Table, model: ShellModel) -> tuple[Any, str | None]:
    """The [field] table: the specification of its field type (`FIELD_TYPES`; a SIREN's
    `FieldConfig`, a spline field's `SplinePlan`) read by that type's entry in `READERS`, and
    the output-scale estimate a SIREN names (one of `scaling.SCALE_ESTIMATES`; None: a number
    given, or another field type). A key of another field type is refused by name."""
    kind = t.string("type", DEFAULT, choices=tuple(FIELD_TYPES))
    own = FIELD_TYPES[kind].keys
    for other in FIELD_TYPES.values():
        for key in other.keys:
            if key not in own and t.has(key):
                raise SceneError(f"{t.key(key)}: a {other.label} key, not used with "
                                 f"field.type = {kind!r}")
    return READERS[kind](t, model)


def _siren(t: Table, model: ShellModel) -> tuple[FieldConfig, str | None]:
    """A SIREN's configuration. An estimated output scale holds the dimensional estimate
    (`scaling.characteristic_displacement`, no solve); those that solve are made when a run
    starts (`taichi_ndf.solve.output_scale.field_for_run`)."""
    domain = model.surface.domain
    scale = t._get("output_scale", "auto")
    estimate = scale if scale in SCALE_ESTIMATES else None
    if estimate is not None:
        scale = characteristic_displacement(model)
    elif isinstance(scale, bool) or not isinstance(scale, (int, float)) or not scale > 0:
        raise SceneError(f"{t.key('output_scale')}: expected one of "
                         f"{', '.join(repr(e) for e in SCALE_ESTIMATES)} or a positive number "
                         f"[m], got {scale!r}")
    return FieldConfig(width=t.integer("width", 128, minimum=1),
                       hidden_layers=t.integer("hidden_layers", 3, minimum=1),
                       omega0=t.number("omega0", 30.0, positive=True),
                       domain=domain.bounds, periodic=domain.periodic,
                       output_scale=float(scale)), estimate


DEFAULT_GRADING = "uniform"  # [field] grading of a spline field (benchmarks/RESULTS.md)
DEFAULT_BAND_END_KNOTS = False  # [field] band_end_knots: opt-in (benchmarks/RESULTS.md, issue 33:
# the full order asymptotically, but the moved knot costs accuracy on coarse grids)


def _spline(t: Table, model: ShellModel) -> tuple[SplinePlan, None]:
    """A spline field's grids (the grid rule's spans where [field] gives none), their knots
    uniform or graded towards the model's singular features (`grading`,
    `spline_grid.graded_config`), with knot lines on the edges' band ends (`band_end_knots`,
    `spline_grid.band_end_config`)."""
    degree = t.integer("degree", 3)
    if degree not in (3, 4):
        raise SceneError(f"{t.key('degree')}: must be 3 (cubic) or 4 (quartic), got {degree}")
    surface = model.surface
    if t.has("spans") and t.has("span_length"):
        raise SceneError(f"{t.key('spans')}: give spans or span_length, not both")
    if t.has("spans"):
        spans = t._get("spans", None)
        if (not isinstance(spans, list) or len(spans) != 2 or any(
                isinstance(n, bool) or not isinstance(n, int) or n < 1 for n in spans)):
            raise SceneError(f"{t.key('spans')}: expected two integers >= 1, got {spans!r}")
        spans = tuple(spans)
    else:
        length = t._get("span_length", "auto")
        if length == "auto":
            length = auto_span_length(surface, model.material.thickness,
                                      model.boundary.narrowest_band)
        elif (isinstance(length, bool) or not isinstance(length, (int, float))
              or not (math.isfinite(length) and length > 0)):
            raise SceneError(f"{t.key('span_length')}: expected \"auto\" or a positive length "
                             f"[m], got {length!r}")
        spans = spans_for(surface, float(length), model.loads)
    domain = surface.domain
    # Even across the symmetry planes by its coefficients (not by folded coordinates, which
    # coarsen the grid at the planes: SplineConfig.even_ends).
    even = model.boundary.fold.edge_ends
    for d, side in enumerate(even):
        if side and spans[d] < degree:
            raise SceneError(f"{t.key('spans')}: a symmetry plane on an edge of ξ{d + 1} needs "
                             f"at least {degree} spans (the degree) along it, got {spans[d]}")
    config = SplineConfig(spans=spans, degree=degree, domain=domain.bounds,
                          periodic=domain.periodic, even_ends=even)
    if t.string("grading", DEFAULT_GRADING, choices=GRADINGS) == "features":
        config = graded_config(config, model.boundary, model.loads, domain,
                               gauges=gauge_points(model))
    if t.boolean("band_end_knots", DEFAULT_BAND_END_KNOTS):
        config = band_end_config(config, model.boundary)
    points = t.integer("quadrature_points", degree + 1, minimum=1)
    return SplinePlan(config, levels=t.integer("levels", 1, minimum=1),
                      quadrature_points=points), None


# [field] type -> the reader of its keys: (table, model) -> (specification, output-scale
# estimate or None). One entry per type of `FIELD_TYPES`.
READERS: dict[str, Callable[[Table, ShellModel], tuple[Any, str | None]]] = {
    "siren": _siren, "spline": _spline}


def with_field_type(document: dict, kind: str) -> dict:
    """The scene document solved with another field type (`ndf-sim --field`): unchanged if its
    [field] already has that type; otherwise [field] holds only the type (every other setting
    at its default: for a spline the grid rule, span_length = "auto", one level) and
    [training] keeps its load steps and seed, with the method of that field type (spline:
    projected Newton; SIREN: Adam with its defaults). A pseudo-time scene's spline solve
    takes its trajectory frames as load steps (`_path_as_load_steps`)."""
    if kind not in FIELD_TYPES:
        raise SceneError(f"field type must be one of {list(FIELD_TYPES)}, got {kind!r}")
    current = document.get("field", {})
    if isinstance(current, dict) and current.get("type", DEFAULT) == kind:
        return document
    training = document.get("training", {})
    training = training if isinstance(training, dict) else {}
    kept = {k: training[k] for k in ("load_steps", "seed") if k in training}
    if not FIELD_TYPES[kind].pseudo_time and training.get("pseudo_time") is True:
        return _path_as_load_steps(document, kept, kind)
    return {**document, "field": {"type": kind},
            "training": {**kept, "method": FIELD_TYPES[kind].method}}


def _path_as_load_steps(document: dict, kept: dict, kind: str) -> dict:
    """A pseudo-time scene solved with a field type `kind` without a pseudo-time input (a
    spline): its trajectory frames (t evenly spaced from pseudo_time_start to 1) become load
    steps (t = 0, the undeformed state, left out),
    so the run writes the same trajectory, one frame per load step solved."""
    output = document.get("output", {})
    output = output if isinstance(output, dict) else {}
    frames = output.get("frames", DEFAULT_FRAMES)
    start = document["training"].get("pseudo_time_start", 0.0)
    if isinstance(frames, bool) or not isinstance(frames, int) or frames < 2:
        raise SceneError(f"output.frames: expected an integer >= 2, got {frames!r}")
    if isinstance(start, bool) or not isinstance(start, (int, float)) or not 0 <= start < 1:
        raise SceneError(f"training.pseudo_time_start: expected a number in [0, 1), got "
                         f"{start!r}")
    steps = [start + (1.0 - start) * k / (frames - 1) for k in range(frames)]
    kept["load_steps"] = [t for t in steps if t > 0]
    rest = {k: v for k, v in output.items() if k != "frames"}
    return {**document, "field": {"type": kind}, "output": rest,
            "training": {**kept, "method": FIELD_TYPES[kind].method}}
