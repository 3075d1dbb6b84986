"""Argument checks shared by the configuration dataclasses."""

from __future__ import annotations

import math


def finite_vector(name: str, value, size: int, unit: str = "") -> tuple[float, ...]:
    """`value` as a tuple of `size` finite floats, or a ValueError naming `name` (and the unit,
    when given)."""
    unit = f" [{unit}]" if unit else ""
    try:
        out = tuple(float(v) for v in value)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{name} must be {size} numbers{unit}, got {value!r}") from err
    if len(out) != size or not all(math.isfinite(v) for v in out):
        raise ValueError(f"{name} must be {size} finite numbers{unit}, got {value!r}")
    return out
