"""Kirchhoff–Love thin-shell mechanics: kinematics, materials, energy.

The names below are imported from their modules on first use, so that importing one light
module of the package (`taichi_ndf.shell.fabrics`, the measured presets) does not import Taichi.
"""

import importlib

_MODULE_OF = {
    "EnergyResult": "energy", "PotentialEnergy": "energy", "ShellEnergy": "energy",
    "function_jets": "energy", "potential_energy": "energy",
    "strains": "kinematics",
    "PRESETS": "materials", "ClydeFabric": "materials", "LinearIsotropic": "materials",
    "Material": "materials", "OrthotropicStVK": "materials", "preset": "materials",
}

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


def __getattr__(name: str):
    if name in _MODULE_OF:
        return getattr(importlib.import_module(f"taichi_ndf.shell.{_MODULE_OF[name]}"), name)
    raise AttributeError(f"module 'taichi_ndf.shell' has no attribute {name!r}")
