"""docs/make_gallery.py draws a scene's pictures, energy plot and video from its run files."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import cv2
import numpy as np
from test_render_figure import fake_run

from taichi_ndf.render.video import video_info

ROOT = Path(__file__).resolve().parents[1]


def gallery():
    spec = importlib.util.spec_from_file_location("make_gallery", ROOT / "docs" / "make_gallery.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_pictures_energy_plot_video_and_overview_of_a_run(tmp_path, monkeypatch):
    module = gallery()
    monkeypatch.setattr(module, "PICTURES", tmp_path / "pictures")
    (tmp_path / "pictures").mkdir()
    run = fake_run(tmp_path / "run", frames=3, obstacle=True)
    made = module.pictures("sheet", run)
    assert made["video"] == "sheet.mp4" and made["colour"] == "displacement"
    picture = cv2.imread(str(tmp_path / "pictures" / "sheet.png"))
    energy = cv2.imread(str(tmp_path / "pictures" / "sheet_energy.png"))
    assert picture.shape[0] == 480 and picture.std() > 0 and energy.std() > 0
    info = video_info(tmp_path / "pictures" / "sheet.mp4")
    assert info["codec"].startswith("h264") and info["size"] == module.VIDEO_SIZE
    tile = made["tile"]
    assert tile.shape == (module.TILE[1], module.TILE[0], 3)
    # four tiles, one row; five: two rows with the rest blank
    assert module.overview([tile] * 4).shape == (module.TILE[1], 4 * module.TILE[0], 3)
    two_rows = module.overview([tile] * 5)
    assert two_rows.shape[0] == 2 * module.TILE[1]
    assert np.all(two_rows[module.TILE[1]:, module.TILE[0]:] == 235)
