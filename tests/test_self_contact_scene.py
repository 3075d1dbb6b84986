"""The `[self_contact]` table (issue 30; docs/scenes.md "Self-contact"): read into the
contact's `SelfContactConfig` with its defaults, refused in one line where it cannot work."""

from __future__ import annotations

import copy
import tomllib
from pathlib import Path

import pytest
from sim_process import sim_refusal

from taichi_ndf.contact.self_pairs import default_stiffness, hole_radius
from taichi_ndf.problem.scaling import load_per_area
from taichi_ndf.scene.reader import parse_scene
from taichi_ndf.scene.schema import SceneError

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "napkin_fold.toml"


def _document(**self_contact) -> dict:
    document = tomllib.loads(SCENE.read_text())
    document["self_contact"] = {"distance": 0.004, **self_contact}
    return document


def _parse(document):
    return parse_scene(copy.deepcopy(document), base_dir=ROOT / "scenes")


def test_the_scene_reads_its_settings_with_the_stated_defaults():
    """napkin_fold: 32 × 8 spans of 1.875 cm, 4 Gauss points: hole radius ½ × 0.34 × 1.875
    × √2 cm = 4.5 mm, offset 1.25 × that; κ from the sheet's weight; exclusion 2 (o + ĝ)."""
    scene = _parse(_document())
    config = scene.model.contact.self_contact
    hole = hole_radius((0.6 / 32, 0.15 / 8), 4)
    assert hole == pytest.approx(0.0045, abs=1e-4)
    assert config.activation == 0.004
    assert config.offset == pytest.approx(1.25 * hole)
    assert config.stiffness == pytest.approx(
        default_stiffness(load_per_area(scene.model), 0.004, config.offset))
    assert config.exclusion == pytest.approx(2 * (config.offset + 0.004))
    given = _parse(_document(offset=0.006, stiffness=1e7, exclusion=0.05))
    assert (given.model.contact.self_contact.offset, given.model.contact.self_contact.stiffness,
            given.model.contact.self_contact.exclusion) == (0.006, 1e7, 0.05)
    without = tomllib.loads(SCENE.read_text())
    del without["self_contact"]
    assert _parse(without).model.contact.self_contact is None


def test_self_contact_stands_alone_without_obstacles():
    """Without [[obstacles]] the scene's contact is self-contact alone (`ContactConfig.
    self_only`): no obstacle, the obstacle barrier at stiffness 0, the 2² check grid, and the
    same self-contact settings as with the table."""
    document = _document()
    document.pop("obstacles")
    contact = _parse(document).model.contact
    with_table = _parse(_document()).model.contact
    assert contact.obstacles == () and contact.stiffness == 0.0
    assert contact.check_resolution == 2
    assert contact.self_contact == with_table.self_contact
    assert contact.activation == with_table.self_contact.activation
    plain = _document()
    plain.pop("obstacles")
    plain.pop("self_contact")
    assert _parse(plain).model.contact is None


@pytest.mark.parametrize("change, message", [
    (lambda d: d.update(field={"width": 16}), "self_contact: needs a spline field"),
    (lambda d: d["self_contact"].update(offset=0.001), "self_contact.offset: 0.001 m is below"),
    (lambda d: d["self_contact"].update(exclusion=0.005), "self_contact: self-contact exclusion"),
    (lambda d: d["self_contact"].pop("distance"), "self_contact.distance: required key"),
    (lambda d: d["self_contact"].update(distance=-1.0), "self_contact.distance"),
    (lambda d: d["self_contact"].update(radius=1.0), "radius"),
])
def test_bad_settings_are_refused_naming_the_key(change, message):
    document = _document()
    change(document)
    with pytest.raises(SceneError) as error:
        _parse(document)
    assert message in str(error.value)
    assert "\n" not in str(error.value)


def test_a_garment_file_reads_self_contact_from_its_coarsest_panel_grid():
    """A garment file's [self_contact] (issue 30): the offset's default from its panels'
    coarsest grid (tests/test_garment_self_contact.py runs it)."""
    document = tomllib.loads((ROOT / "scenes" / "skirt_body.toml").read_text())
    document["self_contact"] = {"distance": 0.004}
    scene = _parse(document)
    config = scene.model.contact.self_contact
    assert config.activation == 0.004
    assert [o.name for o in scene.model.contact.obstacles] == ["body"]
    document["field"]["spans"] = [2 * s for s in document["field"]["spans"]]
    assert _parse(document).model.contact.self_contact.offset < config.offset


def test_ndf_sim_refuses_a_bad_table_with_exit_code_2_and_one_line(tmp_path):
    text = SCENE.read_text().replace("distance = 0.004", "distance = 0.004\noffset = 0.001")
    scene = tmp_path / "bad.toml"
    scene.write_text(text)
    assert "self_contact.offset" in sim_refusal(scene, tmp_path / "out")


def test_the_swinging_pendulum_copy_has_self_contact_and_no_obstacle():
    """scenes/cloth_pendulum_self.toml: cloth_pendulum with [self_contact] alone (no floor:
    self-contact needs no obstacle); the same dynamics as cloth_pendulum. Its runs with and
    without the former floor, and the triangle test of every output frame:
    benchmarks/RESULTS.md ("Self-contact without obstacles")."""
    document = tomllib.loads((ROOT / "scenes" / "cloth_pendulum_self.toml").read_text())
    plain = tomllib.loads((ROOT / "scenes" / "cloth_pendulum.toml").read_text())
    assert document["dynamics"] == plain["dynamics"]
    assert document["boundary"] == plain["boundary"]
    assert "obstacles" not in document
    contact = _parse(document).model.contact
    assert contact.self_contact is not None and contact.self_contact.activation == 0.005
    assert contact.obstacles == ()


def test_ndf_sim_runs_the_pendulum_with_self_contact_alone(tmp_path):
    """Two time steps of scenes/cloth_pendulum_self.toml (no obstacle) under `ndf-sim`: it
    finishes, and result.json (strict JSON: no inf from the check grid's gap with no obstacle
    to measure) has no obstacle distances."""
    import json
    import os
    import subprocess
    import sys

    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    process = subprocess.run(
        [sys.executable, "-m", "taichi_ndf.cli.sim", str(ROOT / "scenes" /
                                                          "cloth_pendulum_self.toml"),
         "--out", str(tmp_path / "out"), "--no-pictures", "--set", "dynamics.duration=0.02",
         "--set", "output.resolution=[8, 8]"],
        capture_output=True, text=True, env=env, timeout=600)
    assert process.returncode == 0, process.stderr[-2000:]
    result = json.loads((tmp_path / "out" / "result.json").read_text(),
                        parse_constant=lambda name: pytest.fail(f"result.json has {name}"))
    assert result["contact"]["min_signed_distance"] is None
    assert result["contact"]["min_signed_distance_per_obstacle"] == {}
    assert result["dynamics"]["steps"] == 2
