"""Make docs/gallery.md and its pictures: one render of every shipped scene (scenes/*.toml).

    python docs/make_gallery.py [--runs DIR] [--full]

Each scene runs with `ndf-sim --quick` (its [training.quick] settings; --full: the whole
training) into DIR/<scene> (default /tmp/ndf-gallery-runs); a run directory that already holds a
result.json is reused. Pictures: docs/gallery/<scene>.png (three-quarter view coloured by
displacement, ground shadow, colour bar) and docs/gallery/overview.png (all of them, for the
README).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tomllib
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from taichi_ndf.io.run_files import QUANTITIES, read_run  # noqa: E402
from taichi_ndf.render import save_png  # noqa: E402
from taichi_ndf.render.figure import Obstacle, render_figure  # noqa: E402

PICTURE = (480, 360)  # width, height [pixels] of one scene's picture
COLUMNS = 4  # of the overview
COLOUR = "displacement"


def run_scene(scene: Path, out: Path, full: bool) -> None:
    if (out / "result.json").is_file():
        return
    command = [sys.executable, "-m", "taichi_ndf.cli.sim", str(scene), "--out", str(out),
               "--overwrite"] + ([] if full else ["--quick"])
    print(" ".join(command[1:]), flush=True)
    subprocess.run(command, check=True, cwd=ROOT)


def picture(run_dir: Path) -> np.ndarray:
    run = read_run(run_dir)
    colour = COLOUR if COLOUR in run.available() else "bending_strain"
    return render_figure(run.deformed, run.faces, scalars=run.quantity(colour),
                         scalar_label=QUANTITIES[colour], up=run.up,
                         obstacles=tuple(Obstacle(o.vertices, o.faces) for o in run.obstacles),
                         width=PICTURE[0], height=PICTURE[1])


def overview(images: list[np.ndarray], names: list[str]) -> np.ndarray:
    """Thumbnails at half size with their scene names, COLUMNS per row."""
    w, h = PICTURE[0] // 2, PICTURE[1] // 2
    tiles = []
    for image, name in zip(images, names, strict=True):
        tile = cv2.resize(image, (w, h), interpolation=cv2.INTER_AREA)
        cv2.putText(tile, name, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (40, 40, 40), 1,
                    cv2.LINE_AA)
        tiles.append(tile)
    blank = np.full_like(tiles[0], 235)
    tiles += [blank] * (-len(tiles) % COLUMNS)
    rows = [np.concatenate(tiles[i:i + COLUMNS], axis=1) for i in range(0, len(tiles), COLUMNS)]
    return np.concatenate(rows, axis=0)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--runs", type=Path, default=Path("/tmp/ndf-gallery-runs"))
    p.add_argument("--full", action="store_true", help="full training instead of --quick")
    args = p.parse_args(argv)
    pictures_dir = ROOT / "docs" / "gallery"
    pictures_dir.mkdir(exist_ok=True)
    rows, images, names = [], [], []
    for scene in sorted((ROOT / "scenes").glob("*.toml")):
        name = scene.stem
        run_scene(scene, args.runs / name, args.full)
        image = picture(args.runs / name)
        save_png(pictures_dir / f"{name}.png", image)
        images.append(image)
        names.append(name)
        result = json.loads((args.runs / name / "result.json").read_text())
        description = tomllib.loads(scene.read_text()).get("description", "")
        rows.append(f"### {name}\n\n{description}  \n`ndf-sim scenes/{name}.toml"
                    f"{'' if args.full else ' --quick'}`: {result['iterations']} iterations, "
                    f"{result['wall_time']:.0f} s\n\n![{name}](gallery/{name}.png)\n")
    save_png(pictures_dir / "overview.png", overview(images, names))
    training = ("full training" if args.full else "`--quick` runs (the scenes' "
                "`[training.quick]` settings: short smoke runs, not converged results)")
    page = ["# Gallery", "",
            f"Every shipped scene (`scenes/*.toml`), from {training}, rendered by `ndf-render`'s "
            f"renderer: three-quarter view, coloured by {QUANTITIES[COLOUR]} (bending strain "
            "where a run has no reference mesh), ground shadow. Made by `python "
            "docs/make_gallery.py`; the wall times are of that run on a shared 2-core CPU. "
            "The scenes in `scenes/inverse/` are start points of the material estimator "
            "(`ndf-fit-material`, docs/inverse_material.md), not shown here.", "",
            "![all scenes](gallery/overview.png)", ""] + rows
    (ROOT / "docs" / "gallery.md").write_text("\n".join(page))
    print(f"wrote docs/gallery.md and {len(images) + 1} pictures in {pictures_dir}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
