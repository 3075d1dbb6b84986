"""Discretisations of the displacement field (`Discretisation`): one object per field type
that the tools solve, size, resume and report through. `discretisation` picks the class by
the field type of the specification (`problem.field_types.FIELD_TYPES`, which each class
names as its `field_type`): a third field type (adaptive grids, several patches) is one class
here and one entry in DISCRETISATIONS."""

from __future__ import annotations

from typing import Any

import torch

from taichi_ndf.discretise.multipatch import MultiPatchDiscretisation, MultiPatchPlan
from taichi_ndf.discretise.protocol import Discretisation, ResultPart, Solution, SolveRefused
from taichi_ndf.discretise.siren import SirenDiscretisation
from taichi_ndf.discretise.spline import SplineDiscretisation
from taichi_ndf.objective import Objective
from taichi_ndf.problem.model import ShellModel

__all__ = ["DISCRETISATIONS", "Discretisation", "MultiPatchDiscretisation", "ResultPart",
           "SirenDiscretisation", "Solution",
           "SolveRefused", "SplineDiscretisation", "discretisation", "of_scene"]

# The field specification's class -> its discretisation (one per field type).
DISCRETISATIONS: dict[type, type] = {kind.field_type.spec: kind for kind in (
    SirenDiscretisation, SplineDiscretisation)}


def discretisation(spec: Any, model: ShellModel, *, objective: Objective | None = None,
                   estimate: str | None = None, start_shape: Any = None,
                   dtype: torch.dtype | None = None) -> Discretisation:
    """The discretisation of the field specification `spec` (a `FieldConfig` or a
    `SplinePlan`) on `model`. objective: what is minimised (None: Π of the model); estimate:
    a SIREN's output-scale estimate made at run start (`Scene.output_scale_estimate`);
    start_shape: a spline field's start shape (`problem.start_shape.StartShape`; None: rest);
    dtype: its fields' (None: the runtime's; a garment's panels are float64 only)."""
    if isinstance(spec, MultiPatchPlan):  # a garment's panels: several fields, no field type
        if dtype not in (None, MultiPatchDiscretisation.dtype):
            raise ValueError(f"a multi-patch field is {MultiPatchDiscretisation.dtype}, "
                             f"not {dtype}")
        return MultiPatchDiscretisation(spec, model, objective=objective)
    kind = DISCRETISATIONS.get(type(spec))
    if kind is None:
        raise TypeError(f"no discretisation of a {type(spec).__name__} (known: "
                        f"{', '.join(t.__name__ for t in DISCRETISATIONS)})")
    if start_shape is None:
        return kind(spec, model, objective=objective, estimate=estimate, dtype=dtype)
    if kind is not SplineDiscretisation:
        raise ValueError(f"a start shape needs a spline field, not a {kind.name} field")
    return kind(spec, model, objective=objective, estimate=estimate, start_shape=start_shape,
                dtype=dtype)


def of_scene(scene) -> Discretisation:
    """The discretisation of a `Scene`'s field on its model."""
    return discretisation(scene.field, scene.model, estimate=scene.output_scale_estimate,
                          start_shape=scene.start)
