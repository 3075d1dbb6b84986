"""Argument checks shared by the configuration dataclasses."""

from __future__ import annotations

import itertools
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


def load_steps(value) -> None:
    """Load factors solved in turn: in (0, 1], strictly increasing, the last 1; a ValueError
    naming `load_steps` otherwise."""
    if not value or any(not 0 < s <= 1 for s in value):
        raise ValueError(f"load_steps must be load factors in (0, 1], got {value}")
    if abs(value[-1] - 1.0) > 1e-12:
        raise ValueError(f"load_steps must end at 1.0, got {value}")
    if any(b <= a for a, b in itertools.pairwise(value)):
        raise ValueError(f"load_steps must increase strictly, got {value}")
