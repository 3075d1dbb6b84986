"""The inverse package's one registry of field types (`inverse.material.field_types`): every
forward field type has its inverse classes, and the material fits' forward model and the SfT
frame fit are looked up there from the field configuration or the SfT settings."""

from __future__ import annotations

import pytest

from inverse.material.field_types import (
    INVERSE_FIELD_TYPES,
    of_field_config,
    of_frame_settings,
)
from inverse.material.forward_model import forward_model
from inverse.material.implicit import ImplicitEquilibrium
from inverse.material.spline_equilibrium import SplineEquilibrium
from inverse.sft.settings import ReconstructionConfig, SplinePriorConfig
from inverse.sft.siren_prior import SirenFrameField
from inverse.sft.spline_prior import SplineFrameField
from taichi_ndf.field import FieldConfig, SplineConfig
from taichi_ndf.problem.field_types import FIELD_TYPES
from taichi_ndf.problem.spline_grid import SplinePlan


def test_every_forward_field_type_has_its_inverse_classes():
    assert set(INVERSE_FIELD_TYPES) == set(FIELD_TYPES)
    for name, kind in INVERSE_FIELD_TYPES.items():
        assert kind.field_type is FIELD_TYPES[name]


def test_the_classes_are_looked_up_from_the_configuration_or_the_settings():
    siren = of_field_config(FieldConfig(width=8))
    spline = of_field_config(SplineConfig(spans=(2, 2)))
    assert (siren.equilibrium, spline.equilibrium) == (ImplicitEquilibrium, SplineEquilibrium)
    assert of_frame_settings(SplinePriorConfig()).frame_field is SplineFrameField
    assert of_frame_settings(ReconstructionConfig()).frame_field is SirenFrameField
    assert siren.initial_guesses and not spline.initial_guesses


def test_other_specifications_are_refused_by_name():
    """A spline plan is the forward solve's specification, not a forward model's grid."""
    plan = SplinePlan(SplineConfig(spans=(2, 2)))
    with pytest.raises(TypeError, match="no forward model on a SplinePlan .*SplineConfig"):
        forward_model(plan, None, [], None)
    with pytest.raises(TypeError, match="no SfT field for settings of type dict"):
        of_frame_settings({})
