"""Fuzzing of the keys added for issue 35 (the property of tests/test_fuzz.py: a tool succeeds
or exits with code 2 and one line on stderr, no traceback, an earlier output directory left
unchanged), with what each key must mean once accepted:

- a part of a turn (`[geometry] angle_deg` of a cylinder, `azimuth_deg` of a hemisphere) with
  symmetry planes on its ξ¹ edges: accepted only for an angle in (0°, 360°], and an edge of ξ¹
  (a constraint or a line load on it) only where the angle is less than a whole turn;
- the pseudo-time keys (`[training] pseudo_time`, `pseudo_time_start`, `[output] frames`):
  accepted only on a SIREN field without obstacles, `frames` only with `pseudo_time = true`;
- the rigid-motion check (`warn_rigid_motions`, run by ndf-sim and ndf-validate before a
  solve) on scenes with drawn supports and loads: no exception, one log line per finding, a
  sheet with no support under gravity has no equilibrium, a clamped edge leaves no motion.
"""

from __future__ import annotations

import json
import logging
import math
import tempfile
from pathlib import Path

from hypothesis import event, example, given
from hypothesis import strategies as st
from test_fuzz import (
    ODD_VALUES,
    fuzz_settings,
    mutated,
    set_keys,
    sim_refuses_or_accepts,
    toml_text,
)

from taichi_ndf.boundary.rigid_motions import warn_rigid_motions
from taichi_ndf.scene.reader import parse_scene
from taichi_ndf.scene.schema import SceneError

ROOT = Path(__file__).resolve().parents[1]

SPLINE = {"type": "spline", "spans": [4, 4], "levels": 1}
NEWTON = {"method": "newton", "newton_max_iterations": 5}
# A quarter of a cylinder (θ from 0 to 90°) and a quarter of a hemisphere with a hole, each cut
# by two symmetry planes on its ξ¹ edges (the planes y = 0 at θ = 0 and x = 0 at θ = 90°).
PLANES = [{"type": "symmetry_plane", "edge": "xi1_min", "normal": "y"},
          {"type": "symmetry_plane", "edge": "xi1_max", "normal": "x"}]
TURN_CYLINDER = {
    "name": "turn_cylinder",
    "geometry": {"type": "cylinder", "radius": 0.1, "length": 0.4, "angle_deg": 90.0},
    "material": {"preset": "cloth"},
    "loads": {"gravity": [0.0, 0.0, -9.81],
              "line": [{"edge": "xi2_max", "force": [0.0, 0.0, -1.0]}]},
    "boundary": {"constraint": [{"type": "clamped_edge", "edge": "xi2_min"}, *PLANES]},
    "field": SPLINE, "training": NEWTON, "output": {"resolution": [8, 8]},
}
TURN_HEMISPHERE = {
    "name": "turn_hemisphere",
    "geometry": {"type": "hemisphere", "radius": 1.0, "hole_half_angle_deg": 18.0,
                 "azimuth_deg": 90.0},
    "material": {"type": "linear", "young_modulus": 1e6, "poisson_ratio": 0.3,
                 "thickness": 0.01, "areal_density": 1.0},
    "loads": {"point": [{"xi": [0.0, 0.0], "force": [1.0, 0.0, 0.0]},
                        {"xi": [1.5707963267948966, 0.0], "force": [0.0, -1.0, 0.0]}]},
    "boundary": {"constraint": [*PLANES, {"type": "pinned_point", "xi": [0.7853981633974483,
                                                                          0.5]}]},
    "field": SPLINE, "training": NEWTON, "output": {"resolution": [8, 8]},
}
TURN_VALUES = st.sampled_from([0, 45.0, 90.0, 180.0, 359.999, 360.0, 360.0001, 720.0, -90.0,
                               1e-300, "xi1_min", "xi1_max", "xi2_min", "x", "y", "z",
                               "symmetry_plane", "hinged_edge"])
TURN_TARGETS = [("geometry", "angle_deg"), ("geometry", "azimuth_deg"),
                ("geometry", "hole_half_angle_deg"),
                ("boundary", "constraint", 0, "edge"), ("boundary", "constraint", 1, "edge"),
                ("boundary", "constraint", 1, "normal"), ("boundary", "constraint", 0, "type"),
                ("loads", "line", 0, "edge")]


def drawn_keys(draw, document: dict, targets, values) -> dict:
    """`document` with 0-3 of `targets` set to drawn `values` (three in four) or odd ones, or
    deleted (tests/test_fuzz.py's `set_keys`), now and then mutated further."""
    document, _ = set_keys(draw, document, targets, st.one_of(values, values, values,
                                                              ODD_VALUES), counts=(0, 3))
    return draw(mutated(document)) if draw(st.integers(0, 4)) == 0 else document


def accepted(document: dict, existing: bool) -> bool:
    """Whether ndf-sim accepts `document` (tests/test_fuzz.py's `sim_refuses_or_accepts`:
    else a one-line refusal that leaves an earlier output directory unchanged)."""
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        scene = folder / "scene.toml"
        scene.write_text(toml_text(document))
        return sim_refuses_or_accepts(scene, folder, existing) == 0


TURN_ANGLES = st.sampled_from([45.0, 90.0, 180.0, 270.0, 359.999, 360.0, 360.0001, 720.0,
                               -90.0, 0, 1e-300, None])


@st.composite
def turn_scene(draw):
    """TURN_CYLINDER or TURN_HEMISPHERE turned by a drawn angle (None: the key left out, a
    whole turn), the plane on ξ¹_max named to fit it (x at odd multiples of 90°, else y),
    the planes now and then left out, then keys set as `set_keys` does."""
    document = json.loads(json.dumps(draw(st.sampled_from([TURN_CYLINDER, TURN_HEMISPHERE]))))
    geometry = document["geometry"]
    key = "angle_deg" if geometry["type"] == "cylinder" else "azimuth_deg"
    angle = draw(TURN_ANGLES)
    if angle is None:
        del geometry[key]
    else:
        geometry[key] = angle
    constraints = document["boundary"]["constraint"]
    if draw(st.integers(0, 2)) == 0:
        constraints[:] = [c for c in constraints if c["type"] != "symmetry_plane"]
    for c in constraints:
        if c.get("edge") == "xi1_max":
            c["normal"] = "x" if round((360.0 if angle is None else angle) / 90) % 2 else "y"
    return drawn_keys(draw, document, TURN_TARGETS, TURN_VALUES)


def turn_degrees(document: dict) -> float | None:
    """The stated part of a turn [deg] (360 where the key is absent), None if not a number."""
    geometry = document.get("geometry", {})
    key = "angle_deg" if geometry.get("type") == "cylinder" else "azimuth_deg"
    value = geometry.get(key, 360.0)
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return float(value)


def on_a_xi1_edge(document: dict) -> bool:
    """Whether a constraint or a line load of `document` names an edge of ξ¹."""
    def items(section, key):
        value = document.get(section, {})
        value = value.get(key, []) if isinstance(value, dict) else []
        return [v for v in value if isinstance(v, dict)] if isinstance(value, list) else []

    return any(str(item.get("edge", "")).startswith("xi1_")
               for item in items("boundary", "constraint") + items("loads", "line"))


def whole_turn(document: dict, degrees: float | None) -> dict:
    """`document` turned by `degrees` (None: the key left out), the ξ¹_max plane named y."""
    document = json.loads(json.dumps(document))
    key = "angle_deg" if document["geometry"]["type"] == "cylinder" else "azimuth_deg"
    document["geometry"].pop(key)
    if degrees is not None:
        document["geometry"][key] = degrees
    for c in document["boundary"]["constraint"]:
        if c.get("edge") == "xi1_max":
            c["normal"] = "y"
    return document


@fuzz_settings(80)
@given(document=turn_scene(), existing=st.booleans())
@example(document=whole_turn(TURN_CYLINDER, None), existing=False)  # planes on a closed shell
@example(document=whole_turn(TURN_HEMISPHERE, 360.0), existing=False)
@example(document={**whole_turn(TURN_CYLINDER, 720.0), "boundary": {"constraint": [
    TURN_CYLINDER["boundary"]["constraint"][0]]}}, existing=False)  # two turns, no planes
def test_part_of_a_turn_keys_are_refused_in_one_line(document, existing):
    if not accepted(document, existing):
        return
    degrees = turn_degrees(document)
    event(f"accepted, {degrees}°")
    assert degrees is not None and 0.0 < degrees <= 360.0 * (1 + 1e-12), degrees
    whole = degrees >= 360.0 * (1 - 1e-12)
    assert not (whole and on_a_xi1_edge(document)), "an edge of a periodic ξ¹ was accepted"


MEMBRANE = json.loads(json.dumps(__import__("tomllib").loads(
    (ROOT / "scenes" / "membrane_stretch.toml").read_text())))
PSEUDO = {**MEMBRANE, "training": {**MEMBRANE["training"], "pseudo_time": True,
                                   "pseudo_time_start": 0.0, "load_steps": [0.5, 1.0]},
          "output": {**MEMBRANE.get("output", {}), "frames": 5}}
# The same path asked of a spline field (refused: it has no pseudo-time input).
PSEUDO_SPLINE = {**PSEUDO, "field": SPLINE,
                 "training": {**NEWTON, "pseudo_time": True, "load_steps": [0.5, 1.0]}}
PSEUDO_VALUES = st.sampled_from([True, False, 0.0, 0.5, 1.0, -0.5, 2.0, 2, 1, 10**6,
                                 [0.5, 1.0], [1.0, 0.5], "spline", "siren"])
PSEUDO_TARGETS = [("training", "pseudo_time"), ("training", "pseudo_time_start"),
                  ("training", "load_steps"), ("output", "frames"), ("field", "type")]
OBSTACLE = [{"type": "sphere", "centre": [0.5, 0.5, -0.3], "radius": 0.2}]


@st.composite
def pseudo_time_scene(draw):
    document = drawn_keys(draw, draw(st.sampled_from([PSEUDO, PSEUDO_SPLINE])),
                          PSEUDO_TARGETS, PSEUDO_VALUES)
    if draw(st.integers(0, 4)) == 0:
        document["obstacles"] = OBSTACLE
    return document


@fuzz_settings(60)
@given(document=pseudo_time_scene(), existing=st.booleans())
@example(document={**PSEUDO, "training": {**PSEUDO["training"], "pseudo_time": False}},
         existing=False)  # frames without the pseudo-time path
@example(document={**PSEUDO, "obstacles": OBSTACLE}, existing=False)
def test_pseudo_time_keys_are_refused_in_one_line(document, existing):
    if not accepted(document, existing):
        return
    training = document.get("training", {})
    field = document.get("field", {})
    pseudo = training.get("pseudo_time", False) is True
    event(f"accepted, pseudo_time {pseudo}")
    if pseudo:
        assert field.get("type", "siren") != "spline", "a spline field with pseudo_time"
        assert "obstacles" not in document, "pseudo_time with obstacles"
    if isinstance(document.get("output"), dict) and "frames" in document["output"]:
        assert pseudo, "[output] frames without pseudo_time"


CONSTRAINTS = st.sampled_from([
    {"type": "clamped_edge", "edge": "xi1_min"},
    {"type": "hinged_edge", "edge": "xi2_max"},
    {"type": "hinged_edge", "edge": "xi1_max", "components": "z"},
    {"type": "pinned_point", "xi": [0.0, 0.0]},
    {"type": "pinned_point", "xi": [0.5, 0.25], "rotation": "free"},
    {"type": "pinned_point", "xi": [1.0, 0.5], "components": "xy"},
    {"type": "symmetry_plane", "edge": "xi2_min", "normal": "y"},
    {"type": "interior_line", "start": [0.0, 0.25], "end": [1.0, 0.25], "extend": True,
     "hinged": True},
])
GRAVITIES = st.sampled_from([[0.0, 0.0, -9.81], [0.0, -9.81, 0.0], [3.0, 0.0, -9.0],
                             [0.0, 0.0, 0.0]])
POINT_LOADS = st.sampled_from([[], [{"xi": [1.0, 0.5], "force": [0.0, 0.0, -1.0]}],
                               [{"xi": [1.0, 0.0], "force": [1.0, 0.0, 0.0]},
                                {"xi": [0.0, 0.5], "force": [-1.0, 0.0, 0.0]}]])


@st.composite
def supported_sheet(draw):
    """A 1 × 0.5 m sheet with 0-3 drawn supports, a drawn gravity and point loads, on a
    spline field (Newton) or a SIREN (Adam), now and then over a sphere."""
    spline = draw(st.booleans())
    document = {
        "name": "supports",
        "geometry": {"type": "plane", "bounds": [[0.0, 1.0], [0.0, 0.5]]},
        "material": {"preset": "cloth"},
        "loads": {"gravity": draw(GRAVITIES), "point": draw(POINT_LOADS)},
        "boundary": {"constraint": draw(st.lists(CONSTRAINTS, max_size=3, unique_by=str))},
        "field": SPLINE if spline else {"width": 16, "hidden_layers": 1},
        "training": NEWTON if spline else {"iterations": 2},
    }
    loaded = any(document["loads"]["gravity"]) or document["loads"]["point"]
    if loaded and draw(st.integers(0, 3)) == 0:
        document["obstacles"] = [{"type": "sphere", "centre": [0.5, 0.25, -0.3],
                                  "radius": 0.25}]
    return document


@fuzz_settings(60)
@given(document=supported_sheet())
def test_the_rigid_motion_check_is_one_line_per_finding_on_drawn_supports(document, caplog):
    try:
        scene = parse_scene(document, base_dir=ROOT)
    except SceneError as refused:
        event(f"refused: {str(refused)[:60]}")
        return
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="taichi_ndf.boundary.rigid_motions"):
        lines = warn_rigid_motions(scene.model, newton=document["training"] is NEWTON)
    assert [r.getMessage() for r in caplog.records] == lines
    assert all(line and "\n" not in line for line in lines), lines
    event(f"{len(lines)} findings")
    constraints = document["boundary"]["constraint"]
    gravity = math.hypot(*document["loads"]["gravity"])
    if not constraints and gravity > 0 and "obstacles" not in document:
        assert any("no equilibrium" in line for line in lines), lines
    if any(c["type"] == "clamped_edge" for c in constraints):
        assert lines == [], lines
