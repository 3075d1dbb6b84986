"""The points of a study: one parameter set each, in study order, with its run name."""

from __future__ import annotations

from dataclasses import dataclass

from taichi_ndf.sweep.naming import run_name, short_keys


@dataclass(frozen=True)
class Point:
    """index: position in the study (row order of the results table); parameters: axis key ->
    value; name: the run directory's name (`naming.run_name`)."""

    index: int
    parameters: dict
    name: str


def points_of(rows: list[dict]) -> tuple[Point, ...]:
    """Points of parameter rows (every row with the same keys, in order)."""
    keys = short_keys(rows[0]) if rows else {}
    return tuple(Point(i, row, run_name(row, keys)) for i, row in enumerate(rows))
