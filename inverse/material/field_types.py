"""The inverse package's part of each field type, in one registry (`INVERSE_FIELD_TYPES`)
keyed on the forward registry's field types (`taichi_ndf.problem.field_types.FIELD_TYPES`):
the material fits' forward model (an `Equilibrium` subclass) and the shape-from-template
per-frame fit with the settings class that names it.

The one place in `inverse` that tells field types apart, as `taichi_ndf.discretise` is for
the forward solves: `inverse.material.forward_model` and `inverse.sft.frame_fits` look their
class up here, and `ndf-sft` (`inverse.cli.sft_run`) its `--field`'s settings class and
capabilities (initial guesses, the photometric term, float64 only). A third field type is
one `InverseFieldType` entry (its equilibrium and its frame fit) beside its forward
`FieldType`. It lives in `inverse.material` although it names
the SfT fits too: `inverse.material` imports `forward_model` when the package is imported,
so a registry outside the package that imports the equilibria would close an import cycle.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from inverse.material.equilibrium import Equilibrium
from inverse.material.implicit import ImplicitEquilibrium
from inverse.material.spline_equilibrium import SplineEquilibrium
from inverse.sft.settings import ReconstructionConfig, SplinePriorConfig
from inverse.sft.siren_prior import SirenFrameField
from inverse.sft.spline_prior import SplineFrameField
from taichi_ndf.problem.field_types import SIREN, SPLINE, FieldType


@dataclass(frozen=True)
class InverseFieldType:
    """One field type's inverse classes.

    field_type: its forward entry (`FieldType`: name, field and configuration classes).
    equilibrium: the material fits' forward model on this field, built from the field's
    configuration (`field_type.config`) by `Equilibrium.of_field`. frame_settings: the SfT
    settings class that names this field; frame_field: its part of the one per-frame fit
    (`inverse.sft.sequential.FrameField`, which `inverse.sft.reconstruct.FrameReconstructor`
    builds); initial_guesses: whether the frame fit takes per-frame initial guesses
    (`initial=`, the field's `fit_to`);
    photometric: whether it takes the photometric term (`inverse.sft.photometric`);
    float64_only: whether the frame fit needs the runtime in float64 (`ndf-sft --precision
    f64`: the spline prior's Hessian blocks are central differences).
    """

    field_type: FieldType
    equilibrium: type[Equilibrium]
    frame_settings: type
    frame_field: type
    initial_guesses: bool
    photometric: bool
    float64_only: bool


# Field types by name (the forward registry's names).
INVERSE_FIELD_TYPES: dict[str, InverseFieldType] = {kind.field_type.name: kind for kind in (
    InverseFieldType(SIREN, ImplicitEquilibrium, ReconstructionConfig, SirenFrameField,
                     initial_guesses=True, photometric=False, float64_only=False),
    InverseFieldType(SPLINE, SplineEquilibrium, SplinePriorConfig, SplineFrameField,
                     initial_guesses=False, photometric=True, float64_only=True))}


def of_field_config(spec: Any) -> InverseFieldType:
    """The field type of a field configuration (`FieldConfig`: fixed SIREN features;
    `SplineConfig`: a grid); TypeError naming the known ones otherwise."""
    for kind in INVERSE_FIELD_TYPES.values():
        if type(spec) is kind.field_type.config:
            return kind
    known = ", ".join(k.field_type.config.__name__ for k in INVERSE_FIELD_TYPES.values())
    raise TypeError(f"no forward model on a {type(spec).__name__} (known: {known})")


def of_frame_settings(config: Any) -> InverseFieldType:
    """The field type that SfT settings name (`SplinePriorConfig`, `ReconstructionConfig`);
    TypeError naming the known ones otherwise."""
    for kind in INVERSE_FIELD_TYPES.values():
        if type(config) is kind.frame_settings:
            return kind
    known = ", ".join(k.frame_settings.__name__ for k in INVERSE_FIELD_TYPES.values())
    raise TypeError(f"no SfT field for settings of type {type(config).__name__} (known: "
                    f"{known})")
