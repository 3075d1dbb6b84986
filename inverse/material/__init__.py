"""Material and force estimation from observed equilibrium shapes (inverse.md §1)."""

from inverse.material.bilevel import BilevelConfig, BilevelResult, bilevel_estimate
from inverse.material.conditioned import ConditionedConfig, ConditionedEquilibrium
from inverse.material.identifiability import Identifiability
from inverse.material.implicit import ImplicitConfig
from inverse.material.implicit_fit import ImplicitResult, implicit_estimate
from inverse.material.observations import Observation, read_observation, template_xi
from inverse.material.residual import (
    Estimate,
    ResidualConfig,
    bending_length,
    equilibrium_system,
    residual_estimate,
)
from inverse.material.shape_fit import FittedShape, fit_shape
from inverse.material.unknowns import Unknown, apply, parse_unknowns

__all__ = ["Observation", "read_observation", "template_xi", "FittedShape", "fit_shape",
           "Unknown", "parse_unknowns", "apply", "ResidualConfig", "Estimate",
           "residual_estimate", "equilibrium_system", "bending_length", "Identifiability",
           "ConditionedConfig", "ConditionedEquilibrium", "BilevelConfig", "BilevelResult",
           "bilevel_estimate", "ImplicitConfig", "ImplicitResult", "implicit_estimate"]
