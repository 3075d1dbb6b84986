"""Scene keys of issue 17: line loads, the annulus geometry, symmetry planes; errors name the
key."""

import copy
from pathlib import Path

import pytest

from taichi_ndf.scene import parse_scene
from taichi_ndf.scene_schema import SceneError

BASE = {
    "name": "t",
    "geometry": {"type": "plane", "bounds": [[0.0, 2.0], [0.0, 1.0]]},
    "material": {"preset": "cloth"},
    "field": {"output_scale": 0.1},
}


def parse(**sections):
    document = copy.deepcopy(BASE)
    document.update(sections)
    return parse_scene(document, base_dir=Path("."))


def test_line_loads_along_an_edge_and_a_path():
    scene = parse(loads={"line": [{"edge": "xi1_max", "force": [0, 0, -2.0]},
                                  {"path": [[0, 0], [1, 1]], "force": [1, 0, 0], "nodes": 3}]})
    first, second = scene.model.loads.line_loads
    assert first.path == ((2.0, 0.0), (2.0, 1.0)) and first.nodes == 8
    assert second.path == ((0.0, 0.0), (1.0, 1.0)) and second.nodes == 3


@pytest.mark.parametrize("line, key", [
    ({"force": [0, 0, 1]}, "loads.line[0]: give exactly one of 'edge' or 'path'"),
    ({"edge": "xi1_max", "path": [[0, 0], [1, 0]], "force": [0, 0, 1]}, "exactly one"),
    ({"edge": "left", "force": [0, 0, 1]}, "loads.line[0].edge"),
    ({"path": [[0, 0]], "force": [0, 0, 1]}, "loads.line[0].path"),
    ({"path": [[0, 0], [3, 0]], "force": [0, 0, 1]}, "line load path point"),
    ({"edge": "xi1_max", "force": [0, 1]}, "loads.line[0].force"),
    ({"edge": "xi1_max", "force": [0, 0, 1], "nodes": 0}, "loads.line[0].nodes"),
    ({"edge": "xi1_max", "force": [0, 0, 1], "follower": True}, "'follower'"),
])
def test_line_load_errors_name_the_key(line, key):
    with pytest.raises(SceneError, match=key.replace("[", r"\[").replace("]", r"\]")):
        parse(loads={"line": [line]})
