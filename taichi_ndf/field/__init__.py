"""SIREN neural deformation field with exact jets (value, first and second derivatives)."""

from taichi_ndf.field.config import FieldConfig
from taichi_ndf.field.network import NeuralField

__all__ = ["FieldConfig", "NeuralField"]
