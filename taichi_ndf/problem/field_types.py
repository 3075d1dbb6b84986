"""The field types a run can solve with, in one registry (`FIELD_TYPES`) that every layer
reads: the scene reader (the [field] type, its keys, the default method, what it refuses, the
size check when a scene is read), the checkpoint (its type tag, field class and architecture:
`CHECKPOINT_TYPES`, which adds a garment's panels), the displacement operator (what a field
type's configuration may ask of the composition: even ends, a pseudo-time factor), the
inverse fits (whether it takes conditioning inputs) and the discretisations
(`taichi_ndf.discretise`, one class per field type, which take their `FieldType` from here).
A third field type is its field module, one `FieldType` here, its [field] reader
(`taichi_ndf.scene.field.READERS`) and its discretisation class.

Outside the discretisations and the scene reader nothing tells field types apart by class or
by name: it asks the entry (`of_field(field)`, `of_spec(spec)`) for a value or a capability
(tests/test_field_type_branches.py).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from taichi_ndf.field import FieldConfig, NeuralField, SplineConfig, SplineField
from taichi_ndf.field.panels import PanelFields, PanelsConfig
from taichi_ndf.problem.run_size import check_siren_size, check_spline_size, siren_samples
from taichi_ndf.problem.spline_grid import SplinePlan
from taichi_ndf.problem.training import SolverConfig

# check_size(spec, solver, itemsize, check_points, grid): ValueError (one line with the
# estimate) where solving `spec` with `solver` needs more memory than the machine has.
SizeCheck = Callable[..., None]


@dataclass(frozen=True)
class FieldType:
    """One field type.

    name: its name in scenes ([field] type), on `ndf-sim --field` and as the checkpoint's
    type tag; label: its name in messages. field: the field class a checkpoint loads into;
    config: its architecture class (`to_dict` / `from_dict`, a checkpoint's "architecture").
    spec: the field specification a scene gives (the `Scene.field` of this type; None: not
    a type a scene names). method: its [training] method by default ("adam" or "newton").
    keys: its [field] keys (a key of another type is refused by name). pseudo_time: whether
    it takes a pseudo-time input (its configuration's `pseudo_time` then says whether a
    field does: the operator scales its raw output by t). conditioned: whether it takes
    inputs beside ξ at all (`config.conditioning`: pseudo-time, material parameters).
    even_ends: whether its configuration may make it even across ends of the domain
    (`config.even_ends`: the operator then composes it without folded coordinates).
    check_size: the memory check (`taichi_ndf.problem.run_size`; None: none a scene asks).
    """

    name: str
    label: str
    field: type
    config: type
    spec: type | None
    method: str
    keys: tuple[str, ...]
    pseudo_time: bool
    conditioned: bool
    even_ends: bool
    check_size: SizeCheck | None


def _siren_size(spec: FieldConfig, solver: SolverConfig, itemsize: int, **contact) -> None:
    check_siren_size(spec, siren_samples(solver), itemsize, **contact)


def _spline_size(spec: SplinePlan, solver: SolverConfig, itemsize: int, **contact) -> None:
    """The finest grid's Gauss points (f32 runs keep the Hessian work in f64: itemsize
    unused)."""
    check_spline_size(spec, **contact)


SIREN = FieldType(name="siren", label="SIREN", field=NeuralField, config=FieldConfig,
                  spec=FieldConfig, method="adam",
                  keys=("width", "hidden_layers", "omega0", "output_scale"),
                  pseudo_time=True, conditioned=True, even_ends=False, check_size=_siren_size)
SPLINE = FieldType(name="spline", label="spline", field=SplineField, config=SplineConfig,
                   spec=SplinePlan, method="newton",
                   keys=("degree", "spans", "span_length", "levels", "quadrature_points",
                         "grading"),
                   pseudo_time=False, conditioned=False, even_ends=True,
                   check_size=_spline_size)
# A garment's fields, one spline field per panel (`PanelFields`), as a checkpoint stores
# them: not a type a scene names (a garment scene's panels are read by the scene reader and
# solved by `discretise.MultiPatchDiscretisation`), so not in FIELD_TYPES.
PANELS = FieldType(name="panels", label="garment panels", field=PanelFields,
                   config=PanelsConfig, spec=None, method="newton", keys=(),
                   pseudo_time=False, conditioned=False, even_ends=False, check_size=None)

# Field types by name: the types a scene's [field] names.
FIELD_TYPES: dict[str, FieldType] = {kind.name: kind for kind in (SIREN, SPLINE)}
DEFAULT = SIREN.name  # a scene's field type where [field] gives none
# The types a checkpoint is tagged with, by name (its "field_type"): FIELD_TYPES and PANELS.
CHECKPOINT_TYPES: dict[str, FieldType] = {**FIELD_TYPES, PANELS.name: PANELS}


def of_spec(spec: Any) -> FieldType:
    """The field type of a field specification (a `FieldConfig`, a `SplinePlan`, ...)."""
    for kind in FIELD_TYPES.values():
        if type(spec) is kind.spec:
            return kind
    raise TypeError(f"no field type of a {type(spec).__name__} (known: "
                    f"{', '.join(kind.spec.__name__ for kind in FIELD_TYPES.values())})")


def of_field(field: Any) -> FieldType:
    """The field type of a field (a `NeuralField`, a `SplineField`, a garment's
    `PanelFields`); TypeError naming the known ones otherwise."""
    for kind in CHECKPOINT_TYPES.values():
        if isinstance(field, kind.field):
            return kind
    raise TypeError(f"no field type of a {type(field).__name__} (known: "
                    f"{', '.join(kind.field.__name__ for kind in CHECKPOINT_TYPES.values())})")
