"""Displacement fields with exact jets (value, first and second derivatives): the SIREN neural
field and the tensor-product B-spline field."""

from taichi_ndf.field.config import FieldConfig
from taichi_ndf.field.network import NeuralField
from taichi_ndf.field.spline import SplineConfig, SplineField

__all__ = ["FieldConfig", "NeuralField", "SplineConfig", "SplineField"]
