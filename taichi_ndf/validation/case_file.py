"""Validation case files (TOML): a scene plus the quantities read from its solution and their
published references (docs/validation.md describes every key). The built-in cases are such
files (`validation/cases/`); `ndf-validate CASE.toml` runs any other.

Unknown keys and wrong types raise `SceneError` naming the key (`quantity[0].tolerance`).
"""

from __future__ import annotations

from pathlib import Path

from taichi_ndf.scene.schema import SceneError, Table, checked, read_toml
from taichi_ndf.validation.catalogue import (
    CASES_DIR,
    SCENES_DIR,
    Case,
    Quantity,
    component_read,
    distance_change_read,
    mean_read,
    roll_up_moment,
    rotation_read,
)

COMPONENTS = ("x", "y", "z")
END_MOMENTS = {"roll_up": roll_up_moment}


def builtin_cases() -> dict[str, Case]:
    """The built-in cases, `validation/cases/*.toml`, by name (scenes named relative to
    `validation/scenes/`)."""
    cases = [load_case(p, scenes_dir=SCENES_DIR) for p in sorted(CASES_DIR.glob("*.toml"))]
    return {case.name: case for case in cases}


def load_case(path: str | Path, *, scenes_dir: Path | None = None) -> Case:
    """Read a case file. Its `scene` is relative to the file; when `scenes_dir` is given and
    the scene lies in it, the case names the scene relative to that folder (so a runner's
    `scenes_dir` may replace it, as `ndf-validate --scenes` does for the built-in cases)."""
    path = Path(path)
    document = read_toml(path, "case file")
    try:
        return parse_case(document, base_dir=path.parent, scenes_dir=scenes_dir)
    except SceneError as err:
        raise SceneError(f"{path.name}: {err}") from err


def parse_case(document: dict, *, base_dir: Path, scenes_dir: Path | None = None) -> Case:
    top = Table(document, "")
    name = top.string("name")
    scene = (base_dir / top.string("scene")).resolve()
    if not scene.is_file():
        raise SceneError(f"scene: scene file not found: {scene}")
    if scenes_dir is not None and scene.is_relative_to(Path(scenes_dir).resolve()):
        scene = scene.relative_to(Path(scenes_dir).resolve())
    moment = top.string("end_moment", None, choices=tuple(END_MOMENTS))
    quantities = tuple(_quantity(q) for q in top.tables("quantity"))
    options = {"load_scale": top.number("load_scale", 1.0, positive=True),
               "linear": top.boolean("linear", False),
               "membrane_scale": top.number("membrane_scale", 1.0, positive=True),
               "end_moment": END_MOMENTS[moment] if moment else None}
    top.close()
    try:
        return Case(name, str(scene), quantities, **options)
    except ValueError as err:
        raise SceneError(str(err)) from err


def _quantity(t: Table) -> Quantity:
    reads = t.tables("read")
    if not reads:
        raise SceneError(f"{t.key('read')}: needs at least one read "
                         "({ probe = ..., component = ... } or { distance = [a, b] })")
    functions, probes = [], []
    for r in reads:
        sign = r.number("sign", 1.0)
        if sign not in (1.0, -1.0):
            raise SceneError(f"{r.key('sign')}: must be 1 or -1, got {sign}")
        kinds = [k for k in ("probe", "distance", "rotation") if r.has(k)]
        if len(kinds) != 1:
            raise SceneError(f"{r.path}: give exactly one of 'probe' (with 'component'), "
                             "'distance' (two probes) or 'rotation' (two probes, with 'axis')")
        if r.has("probe"):
            probe = r.string("probe")
            axis = COMPONENTS.index(r.string("component", choices=COMPONENTS))
            functions.append(component_read(probe, axis, sign))
            probes.append(probe)
        elif r.has("distance"):
            pair = _probe_pair(r, "distance")
            functions.append(distance_change_read(pair[0], pair[1], sign))
            probes.extend(pair)
        else:
            pair = _probe_pair(r, "rotation")
            axis = r._get("axis", None)
            if not (isinstance(axis, list) and len(axis) == 3 and all(
                    isinstance(a, (int, float)) and not isinstance(a, bool) for a in axis)):
                raise SceneError(f"{r.key('axis')}: expected three numbers (the rotation "
                                 f"axis), got {axis!r}")
            functions.append(checked(
                lambda p=pair, a=axis, s=sign: rotation_read(p[0], p[1], a, s), r.key("axis")))
            probes.extend(pair)
        r.close()
    quantity = checked(lambda: Quantity(
        t.string("name"), t.string("description", ""), t.number("reference"),
        t.number("tolerance", positive=True), mean_read(*functions),
        t.number("level", 1.0, positive=True), source=t.string("source", ""),
        probes=tuple(dict.fromkeys(probes))), t.path)
    t.close()
    return quantity


def _probe_pair(r: Table, key: str) -> list[str]:
    pair = r._get(key, None)
    if not (isinstance(pair, list) and len(pair) == 2 and all(isinstance(p, str) for p in pair)
            and pair[0] != pair[1]):
        raise SceneError(f"{r.key(key)}: expected two different probe names, got {pair!r}")
    return pair
