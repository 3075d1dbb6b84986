"""benchmarks/spline_vs_siren.py: the table and the render gallery rebuilt from stored results
(no simulation runs here), and its filters refusing unknown names."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from tests.scripts import load_script

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "spline_vs_siren.py"


def _module():
    return load_script("benchmarks/spline_vs_siren.py")


def _record(**values):
    return {"wall": 10.0, "peak_mib": 900.0, "load": [1.0, 2.0], "date": "2026-12-01 20:00 UTC",
            "commit": "abc1234", "precision": "f32", "quick": False, **values}


STORE = {
    "napkin": {"siren": _record(status="ok", energy=-1.0, solve=8.0, iterations=800),
               "spline": _record(status="ok", energy=-1.02, solve=2.0, iterations=12,
                                 converged=True, spans=[8, 8])},
    "napkin_sphere": {"siren": _record(status="ok", energy=-0.5, solve=8.0, iterations=400,
                                       output_scale=0.4517, backoffs=2),
                      "spline": _record(status="refused", exit_code=2, message=(
                          "ndf-sim: error: [[obstacles]]: contact is solved on the SIREN "
                          "path only"))},
    "flag": {"spline": _record(status="ok", energy=-1.4, solve=70.0, iterations=100,
                               converged=False, spans=[15, 10])},
}


def _current(store: dict, module) -> dict:
    """The store with every record run with its scene's present material."""
    return {scene: {field: {"material": module.scene_material(scene), **r}
                    for field, r in rows.items()} for scene, rows in store.items()}


def _rows(table: str) -> dict:
    return {tuple(c.strip() for c in line.split("|")[1:3]): line
            for line in table.splitlines() if line.startswith("| ")}


def test_a_run_with_another_material_is_marked_stale_and_has_no_gap():
    module = _module()
    store = _current(STORE, module)
    store["napkin"]["siren"] = {**store["napkin"]["siren"], "material": '{"preset":"cloth"}'}
    rows = {k[0]: line for k, line in _rows(module.table(store)).items()
            if k[0] == "napkin"}
    siren = next(line for line in _rows(module.table(store)).values()
                 if line.startswith("| napkin | SIREN"))
    assert "not rerun since the scene's material became" in siren and "cloth" in siren
    assert "| -1 |" not in siren  # its Π (-1 J) is not shown
    assert "(materials differ)" in rows["napkin"] and "-2.00 %" not in rows["napkin"]


def test_table_gives_the_gap_and_names_refused_and_missing_runs():
    module = _module()
    rows = _rows(module.table(_current(STORE, module)))
    assert "-2.00 %" in rows["napkin", "spline + Newton"]  # (−1.02 − −1) / 1
    assert "12 (converged, 8 × 8 spans)" in rows["napkin", "spline + Newton"]
    assert "800 (fixed; dimensional output scale)" in rows["napkin", "SIREN + Adam"]
    assert "400 (fixed; output scale 0.452 m, 2 backoffs)" in rows["napkin_sphere",
                                                                  "SIREN + Adam"]
    assert "refused (contact on Newton path: pending)" in rows["napkin_sphere",
                                                              "spline + Newton"]
    assert "not run" in rows["flag", "SIREN + Adam"]
    assert "NOT converged" in rows["flag", "spline + Newton"]
    assert "%" not in rows["flag", "spline + Newton"].split("|")[4]  # no gap without both
    assert "not run" in rows["skirt", "spline + Newton"]  # every shipped scene has its rows


def test_sections_are_replaced_between_the_markers(tmp_path, monkeypatch):
    module = _module()
    page = tmp_path / "page.md"
    page.write_text("# Title\n\nprose\n")
    module.replace_section(page, "first", "## Section")
    module.replace_section(page, "second", "## Section")
    text = page.read_text()
    assert text.count(module.BEGIN) == 1 and "first" not in text and "second" in text
    assert text.startswith("# Title\n\nprose\n\n## Section\n")
    monkeypatch.setattr(module, "GALLERY", tmp_path / "page.md")
    monkeypatch.setattr(module, "RENDERS", tmp_path / "images")
    (tmp_path / "images").mkdir()
    (tmp_path / "images" / "napkin_siren.png").write_bytes(b"png")
    store = _current(STORE, module)
    gallery = module.renders(store)
    assert "(images/napkin_siren.png)" in gallery
    assert "| napkin_sphere | no render | refused |" in gallery  # a row without its image
    store["napkin"]["siren"]["material"] = '{"preset":"cloth"}'
    assert "| napkin | not rerun on the scene's material |" in module.renders(store)
    assert "| flag | not run |" in gallery


def test_unknown_scene_or_field_is_exit_code_2():
    for args in (["--scenes", "no_such_scene"], ["--fields", "mlp"]):
        done = subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True,
                              text=True, timeout=60)
        assert done.returncode == 2 and args[1] in done.stderr.strip().splitlines()[-1]
