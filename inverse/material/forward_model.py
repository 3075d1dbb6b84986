"""The forward model of an implicit-function estimate for a field configuration, looked up
by its field type in the inverse registry (`inverse.material.field_types`, the one place in
`inverse` that tells field types apart, as `taichi_ndf.discretise` does for the forward
solves)."""

from __future__ import annotations

from typing import Any

from inverse.material.equilibrium import Equilibrium
from inverse.material.field_types import of_field_config
from inverse.material.unknowns import Unknown
from taichi_ndf.problem.model import ShellModel


def forward_model(spec: Any, model: ShellModel, unknowns: list[Unknown], config: Any, *,
                  seed: int = 0) -> Equilibrium:
    """The equilibrium of `model` with `unknowns` on the field `spec` (`FieldConfig`: fixed
    SIREN features; `SplineConfig`: a grid), with its forward model's settings `config`
    (`ImplicitConfig`, `SplineModelConfig`); seed: a SIREN's feature seed. TypeError on
    another specification."""
    return of_field_config(spec).equilibrium.of_field(spec, model, unknowns, config, seed=seed)
