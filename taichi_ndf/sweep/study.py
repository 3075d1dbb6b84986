"""Study files (TOML): the job every run does and the parameters that vary between runs.

    name = "napkin_materials"          # optional; default: the file's stem
    job = "scene"                      # scene | fit_material | sft | calibration
    base = "../scenes/napkin.toml"     # the scene file (job = "scene"), relative to this file
    [options]                          # fixed options of the job's tool, for every run
    quick = true
    precision = "f64"
    [axes]                             # a full grid: every combination, the first axis slowest
    material = ["cloth", "silk"]
    "loads.gravity" = [[0, 0, -9.81], [0, 0, -4.9]]

or, instead of [axes], a list of points, each a table of the same keys:

    [[points]]
    material = "silk"
    "loads.gravity" = [0, 0, -4.9]

or several grids, their points one after the other (each [[grids]] table like [axes], all
with the same keys):

    [[grids]]
    noise = [0.0]
    seed = [0]
    [[grids]]
    noise = [0.005, 0.02]
    seed = [1, 2, 3]

docs/sweeps.md documents every key. Errors raise `StudyError` naming the key.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from pathlib import Path

from taichi_ndf.scene.schema import SceneError, Table, read_toml
from taichi_ndf.sweep.jobs import JOBS, Job
from taichi_ndf.sweep.points import Point, points_of


class StudyError(ValueError):
    """A study file is invalid; the message names the offending key."""


@dataclass(frozen=True)
class Study:
    """A validated study: its name, the job, the base file (None for jobs without one), the
    fixed options, the axis names (columns of the results table, in order) and the points."""

    name: str
    job: Job
    base: Path | None
    options: dict
    axes: tuple[str, ...]
    points: tuple[Point, ...]
    path: Path

    def __post_init__(self):
        if not self.points:
            raise StudyError("axes: the study has no points")
        names = [p.name for p in self.points]
        repeated = sorted({n for n in names if names.count(n) > 1})
        if repeated:
            raise StudyError(f"points: {len(repeated)} point(s) repeat another ({repeated[0]})")

    def describe(self) -> dict:
        """Plain data naming everything that decides the runs' results (study.json)."""
        return {"name": self.name, "job": self.job.kind,
                "base": None if self.base is None else str(self.base),
                "options": self.options, "axes": list(self.axes),
                "points": [p.parameters for p in self.points]}


def flatten(table: dict, prefix: str = "") -> dict:
    """Nested TOML tables as dotted keys: {"loads": {"gravity": v}} -> {"loads.gravity": v}."""
    out = {}
    for key, value in table.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(flatten(value, f"{name}."))
        else:
            out[name] = value
    return out


def load_study(path: str | Path) -> Study:
    """Read and validate a study file (module docstring); relative paths are relative to it."""
    path = Path(path)
    try:
        return _parse(read_toml(path, "study file"), path)
    except SceneError as err:
        raise StudyError(str(err)) from None


def _parse(document: dict, path: Path) -> Study:
    top = Table(document, "")
    name = top.string("name", path.stem)
    job = JOBS[top.string("job", choices=tuple(JOBS))]
    base = top.string("base", None)
    if job.base_option is None and base is not None:
        raise StudyError(f"base: job {job.kind!r} takes no base file (give its inputs in "
                         "[options])")
    if job.base_option is not None:
        if base is None:
            raise StudyError(f"base: required key is missing (the {job.base_option} of job "
                             f"{job.kind!r})")
        base = (path.parent / base).resolve()
        if not base.is_file():
            raise StudyError(f"base: file not found: {base}")
    options = flatten(top.table("options", optional=True).data)
    for key, value in options.items():
        job.check_option(key, "options")
        job.check_value(key, value, "options")
    options = job.resolve_paths(options, path.parent)
    given = [k for k in ("axes", "grids", "points") if top.has(k)]
    if len(given) != 1:
        raise StudyError(f"{(given or ['axes'])[-1]}: give one of [axes] (a full grid), "
                         f"[[grids]] (several) or [[points]] (a list), not "
                         f"{' and '.join(given) or 'none'}")
    if given[0] == "points":
        rows = [flatten(t.data) for t in top.tables("points")]
        axes = tuple(dict.fromkeys(k for row in rows for k in row))
    else:
        grids = ([top.table("axes")] if given[0] == "axes" else top.tables("grids"))
        rows = [row for grid in grids for row in _grid(flatten(grid.data), grid.path)]
        axes = tuple(flatten(grids[0].data)) if grids else ()
    for i, row in enumerate(rows):
        missing = [k for k in axes if k not in row] or [k for k in row if k not in axes]
        if missing:
            where = f"points[{i}]" if given[0] == "points" else given[0]
            raise StudyError(f"{where}: key {missing[0]!r} is missing (every point names the "
                             "same keys)")
    for key in axes:
        job.check_option(key, "axes")
        if key in options:
            raise StudyError(f"axes.{key}: also set in [options]; a key is fixed or varied, "
                             "not both")
    for i, row in enumerate(rows):
        for key, value in row.items():
            job.check_value(key, value, given[0] if given[0] != "points" else f"points[{i}]")
    rows = [job.resolve_paths(row, path.parent) for row in rows]
    top.close()
    study = Study(name=name, job=job, base=base, options=options, axes=axes,
                  points=points_of(rows), path=path)
    if job.scene_keys:
        _check_scenes(study)
    return study


def _grid(table: dict, where: str) -> list[dict]:
    """Every combination of a grid table's value lists, the first key slowest."""
    for key, values in table.items():
        if not isinstance(values, list) or not values:
            raise StudyError(f"{where}.{key}: expected a non-empty list of values, got "
                             f"{values!r}")
    return [dict(zip(table, combo, strict=True)) for combo in itertools.product(*table.values())]


def _check_scenes(study: Study) -> None:
    """Parse the base scene with every point's keys (the checks of ndf-sim, before any run)."""
    from taichi_ndf.scene.reader import load_scene

    for point in study.points:
        keys = {**study.options, **point.parameters}
        scene_keys = {k: v for k, v in keys.items() if k not in study.job.options}
        try:
            load_scene(study.base, material=keys.get("material"), field=keys.get("field"),
                       overrides=scene_keys)
        except SceneError as err:
            raise StudyError(f"point {point.name}: {err}") from None
