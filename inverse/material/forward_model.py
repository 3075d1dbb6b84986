"""The forward model of an implicit-function estimate for a field specification: the one
place in `inverse.material` that tells field types apart (as `taichi_ndf.discretise` does for
the forward solves). A third field type is one `Equilibrium` subclass and one entry here."""

from __future__ import annotations

from typing import Any

from inverse.material.equilibrium import Equilibrium
from inverse.material.implicit import ImplicitEquilibrium
from inverse.material.spline_equilibrium import SplineEquilibrium
from inverse.material.unknowns import Unknown
from taichi_ndf.problem.model import ShellModel

# The field specification's type (`FieldConfig`: fixed SIREN features; `SplineConfig`: a
# grid) -> its equilibrium.
FORWARD_MODELS: dict[type, type[Equilibrium]] = {
    kind.field_type: kind for kind in (ImplicitEquilibrium, SplineEquilibrium)}


def forward_model(spec: Any, model: ShellModel, unknowns: list[Unknown], config: Any, *,
                  seed: int = 0) -> Equilibrium:
    """The equilibrium of `model` with `unknowns` on the field `spec`, with its forward
    model's settings `config` (`ImplicitConfig`, `SplineModelConfig`); seed: a SIREN's
    feature seed."""
    kind = FORWARD_MODELS.get(type(spec))
    if kind is None:
        raise TypeError(f"no forward model on a {type(spec).__name__} (known: "
                        f"{', '.join(t.__name__ for t in FORWARD_MODELS)})")
    return kind.of_field(spec, model, unknowns, config, seed=seed)
