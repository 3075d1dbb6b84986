"""Kirchhoff–Love thin-shell mechanics: kinematics, materials, energy."""

from taichi_ndf.shell.energy import (
    EnergyResult,
    PotentialEnergy,
    ShellEnergy,
    function_jets,
    potential_energy,
)
from taichi_ndf.shell.kinematics import strains
from taichi_ndf.shell.materials import (
    PRESETS,
    ClydeFabric,
    LinearIsotropic,
    Material,
    OrthotropicStVK,
    preset,
)

__all__ = [
    "strains",
    "Material",
    "LinearIsotropic",
    "OrthotropicStVK",
    "ClydeFabric",
    "preset",
    "PRESETS",
    "ShellEnergy",
    "EnergyResult",
    "potential_energy",
    "PotentialEnergy",
    "function_jets",
]
