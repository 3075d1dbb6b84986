"""Make docs/gallery.md and its pictures from converged runs of every shipped scene.

    python docs/make_gallery.py [--runs DIR] [--scenes a,b] [--runs-only] [--quick]

Each scene of scenes/*.toml is solved by `ndf-sim SCENE --field spline` (projected Newton to
its convergence test on the grid rule's grid, float64, the scene's load steps; a pseudo-time
scene at its trajectory frames) into DIR/<scene> (default /tmp/ndf-gallery-runs), one process
each (`benchmarks/spline_vs_siren.run_one`: Π, iterations, convergence, wall and CPU time, load);
a run directory that already holds a result.json and its record DIR/<scene>.json is reused.
From each run's own files (no field evaluation) it writes docs/gallery/<scene>.png (the
render: three-quarter and front view, coloured by displacement, obstacles, ground shadow),
<scene>_energy.png (Π history, refinement panel) and <scene>.mp4 (the trajectory, H.264, where
the run has more than one frame), and docs/gallery/overview.png (every scene, the README's
first image). The converged runs' spline rows (and their renders) also go into the
comparison of benchmarks/spline_vs_siren.py (marked f64 there). A run that did not converge
gets no pictures: the page lists it under "Not in this gallery" with its Newton record, as it
lists each `--leave-out SCENE=REASON` (a run looked at and found not to show the physical
state, e.g. a symmetric equilibrium that a perturbation leaves; such a scene is not run again
unless DIR holds its run). --note TEXT: a paragraph on
where the runs came from. --keep-others: a page for the scenes of --scenes (new scenes, or
those whose pictures changed) that keeps the current page's sections, overview tiles and
reasons for the other scenes. --spans SCENE=NxM: SCENE solved on N × M knot spans (`--set
field.spans=[N,M]`) instead of the grid rule's grid, where that grid is found too coarse by
refinement (the page's command line says so). --quick: the scenes' [training.quick]
settings, a smoke test of this script (the page then says so; nothing is stored).
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import cv2  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

from benchmarks import spline_vs_siren as comparison  # noqa: E402
from taichi_ndf.io.run_files import QUANTITIES, garment_panels, read_run  # noqa: E402
from taichi_ndf.render import save_png, write_video  # noqa: E402
from taichi_ndf.render.energy_plot import energy_figure  # noqa: E402
from taichi_ndf.render.figure import Obstacle, render_figure  # noqa: E402
from taichi_ndf.render.legend import Legend  # noqa: E402
from taichi_ndf.render.plot import plot_curves  # noqa: E402
from taichi_ndf.render.trajectory import FPS, real_time_fps, trajectory_frames  # noqa: E402

SCENES = ROOT / "scenes"
PICTURES = ROOT / "docs" / "gallery"
CAPTIONS = ROOT / "docs" / "gallery_captions.toml"  # what each picture shows, written by eye
TILE = (320, 256)  # width, height [pixels] of one scene in the overview
COLUMNS = 4  # of the overview
COLOUR = "displacement"  # of the scene pictures (render.png itself: bending strain)
VIDEO_SIZE = (640, 480)
CROP_PAD = 0.5  # obstacles drawn within the surface's box widened by this times its size
TILE_LABEL_ROWS = 30  # [pixels] at the top of a tile kept free of the shape, for its name
FOLD_AMPLITUDE = 0.03  # [m] of the radial fold perturbation at the open end (--folds)


def spans_options(spans: tuple[int, int] | None) -> tuple[str, ...]:
    """The ndf-sim arguments that solve on `spans` (--spans) instead of the grid rule's grid."""
    return () if spans is None else ("--set", f"field.spans=[{spans[0]},{spans[1]}]")


def run_scene(name: str, runs: Path, quick: bool, spans: tuple[int, int] | None = None) -> dict:
    """The record of scene `name`'s run (run_one's), running it unless it is stored; `spans`
    (N, M): on that grid (--spans), a stored run on another grid refused."""
    out, record_file = runs / name, runs / f"{name}.json"
    if (out / "result.json").is_file() and record_file.is_file():
        record = json.loads(record_file.read_text())
        if spans is not None and list(record.get("spans", [])) != list(spans):
            raise SystemExit(f"{out} holds a run on {record.get('spans')} spans, not "
                             f"{list(spans)} (--spans): use another --runs")
        return record
    if out.exists() and any(out.iterdir()):
        raise SystemExit(f"{out} holds an earlier run without its record; remove it")
    print(f"{name}: ndf-sim --field spline {' '.join(spans_options(spans))}"
          f"{' --quick' if quick else ''}", flush=True)
    record = comparison.run_one(name, "spline", out, "f64", quick, extra=spans_options(spans))
    if record["status"] == "ok" and "converged" not in record:
        record.update(run_convergence(json.loads((out / "result.json").read_text())))
    record_file.write_text(json.dumps(record, indent=1) + "\n")
    state = record["status"] if record["status"] != "ok" else (
        f"Π {record['energy']:.6g} J, {record['iterations']} iterations, "
        f"{'converged' if record['converged'] else 'NOT converged'}")
    print(f"{name}: {state}; {record['wall']:.0f} s wall, {record['cpu']:.0f} s CPU, "
          f"load {record['load']}", flush=True)
    return record


def run_convergence(result: dict) -> dict:
    """`converged` and `spans` of a run that has no `levels` in its result.json (which
    run_one reads): a garment's, every load step converged; a dynamic run's ([dynamics]),
    finished, since a time step that does not converge after its halvings stops the run
    (DynamicsError), with its grid's spans."""
    if "dynamics" in result:
        return {"converged": True, "spans": result["dynamics"].get("spans", []),
                "dynamic": True}
    steps = result.get("load_steps") or []
    return {"converged": bool(steps) and all(s.get("converged") for s in steps),
            "spans": []}


def add_folds(checkpoint: Path, folds: int, amplitude: float = FOLD_AMPLITUDE) -> None:
    """Add a `folds`-fold radial perturbation to a spline run's displacement coefficients in
    place: amplitude · cos(folds θ) (cos θ, sin θ, 0) [m] per coefficient, θ the periodic ξ₁,
    weighted (1 − j/(m₂ − 1))² along ξ₂ (largest at ξ₂ = 0, the skirt's hem; the boundary
    factor keeps a held edge held)."""
    payload = torch.load(checkpoint, map_location="cpu", weights_only=True)
    architecture = payload["architecture"]
    if payload["field_type"] != "spline" or not architecture["periodic"][0]:
        raise SystemExit(f"--folds: {checkpoint} is not a spline field periodic in ξ₁")
    coefficients = payload["parameters"]["coefficients"]
    m1 = architecture["spans"][0]  # periodic: one coefficient per span; index j1·m2 + j2
    m2 = coefficients.shape[0] // m1
    theta = 2 * math.pi * torch.arange(m1, dtype=coefficients.dtype) / m1
    weight = ((m2 - 1 - torch.arange(m2, dtype=coefficients.dtype)) / (m2 - 1)) ** 2
    radial = amplitude * torch.cos(folds * theta)[:, None] * weight[None, :]
    grid = coefficients.view(m1, m2, coefficients.shape[1])
    grid[..., 0] += radial * torch.cos(theta)[:, None]
    grid[..., 1] += radial * torch.sin(theta)[:, None]
    torch.save(payload, checkpoint)


def refold(name: str, folds: int, runs: Path, start: dict) -> dict:
    """The record of scene `name` re-solved (ndf-sim --resume) from its converged run plus a
    `folds`-fold perturbation (`add_folds`), in DIR/<name>_folds<K>; reused when stored."""
    label = f"{name}_folds{folds}"
    out, record_file = runs / label, runs / f"{label}.json"
    if (out / "result.json").is_file() and record_file.is_file():
        return json.loads(record_file.read_text())
    if start["status"] != "ok" or not start.get("converged"):
        raise SystemExit(f"--folds {name}: its own run did not converge; nothing to perturb")
    shutil.rmtree(out, ignore_errors=True)
    shutil.copytree(runs / name, out)
    add_folds(out / "checkpoint.pt", folds)
    print(f"{name}: re-solved from its run plus {folds} folds", flush=True)
    record = comparison.run_one(name, "spline", out, "f64", False, extra=("--resume",))
    record.update(run=label, start=(
        f"its symmetric solution, Π {start['energy']:.6g} J after {start['iterations']} "
        f"iterations and {start['cpu']:.0f} s CPU, plus a {folds}-fold radial perturbation of "
        f"{100 * FOLD_AMPLITUDE:.0f} cm at the hem"))
    record_file.write_text(json.dumps(record, indent=1) + "\n")
    return record


def cropped(vertices: np.ndarray, shapes: np.ndarray, pad: float = CROP_PAD) -> np.ndarray:
    """An obstacle's vertices (N, 3) [m] clamped to the box around the surface's positions
    `shapes` (M, 3) [m] widened by `pad` times its largest side: a table plane (a 2 m square
    of two triangles by default) then frames a 0.3 m napkin instead of dwarfing it; a flat
    axis-aligned obstacle is cut exactly, a curved one sticking out of the box is flattened
    where it does, and one inside the box is unchanged."""
    low, high = shapes.min(axis=0), shapes.max(axis=0)
    margin = pad * float(np.ptp(shapes, axis=0).max())
    return np.clip(vertices, low - margin, high + margin)


def energy_picture(result: dict) -> np.ndarray:
    """A run's energy plot: Π over the Newton iterations (`energy_figure`), or for a dynamic
    run (no Newton history) its kinetic energy T, potential energy Π and T + Π [J] over
    time [s] (result.json's `dynamics`)."""
    dynamics = result.get("dynamics")
    if dynamics is None:
        return energy_figure(result["history"], result.get("refinement"))
    times = np.asarray(dynamics["times"], dtype=np.float64)
    return plot_curves({"$T$": (times, dynamics["kinetic"]), r"$\Pi$": (times,
                        dynamics["potential"]), r"$T + \Pi$": (times, dynamics["total"])},
                       title=f"Energies over time ({dynamics['integrator']}, "
                       f"h = {1000 * dynamics['dt']:g} ms)", xlabel="time [s]",
                       ylabel="energy [J]", width=820, height=500)


def pictures(name: str, run_dir: Path) -> dict:
    """docs/gallery/<name>.png, <name>_energy.png and (several states) <name>.mp4 from the
    run's files; returns the overview tile and what was written."""
    run = read_run(run_dir)
    result = json.loads((run_dir / "result.json").read_text())
    shapes = np.concatenate([run.deformed, *(f.vertices for f in run.frames)])
    obstacles = tuple(Obstacle(cropped(o.vertices, shapes), o.faces) for o in run.obstacles)
    colour = COLOUR if COLOUR in run.available() else "bending_strain"
    image = render_figure(run.deformed, run.faces, scalars=run.quantity(colour),
                          scalar_label=QUANTITIES[colour], up=run.up, obstacles=obstacles,
                          views=("iso", "front"), width=None, height=480)
    save_png(PICTURES / f"{name}.png", image)
    save_png(PICTURES / f"{name}_energy.png", energy_picture(result))
    written = {"picture": f"{name}.png", "energy": f"{name}_energy.png", "video": None,
               "panels": None}
    panels = garment_panels(run_dir)
    if panels and "panel" in run.scalars:  # a garment: its panels named, as its render.png
        image = render_figure(run.deformed, run.faces, scalars=run.scalars["panel"],
                              scalar_label="panel", legend=Legend(tuple(panels)), up=run.up,
                              obstacles=obstacles, views=("iso", "front"), width=None,
                              height=480)
        save_png(PICTURES / f"{name}_panels.png", image)
        written["panels"] = f"{name}_panels.png"
    if len(run.frames) > 1 and run.reference is not None:
        pseudo = (result.get("trajectory") or {}).get("source") == "pseudo_time"
        # a dynamic run's frames are at times [s]: labelled "t = … s", played in real time
        dynamic = "dynamics" in result
        values = [f.load_factor for f in run.frames]
        fps = real_time_fps(values) if dynamic else FPS
        frames = trajectory_frames([f.vertices for f in run.frames], run.faces, values,
                                   reference=run.reference,
                                   obstacles=[obstacles] * len(run.frames), up=run.up,
                                   pseudo_time=pseudo, physical_time=dynamic, size=VIDEO_SIZE,
                                   fps=fps)
        write_video(PICTURES / f"{name}.mp4", frames, fps)
        written["video"] = f"{name}.mp4"
    # the shape alone, steel blue; a scene with obstacles from the front, where the
    # three-quarter view from above hides them under the sheet
    tile = render_figure(run.deformed, run.faces, up=run.up, obstacles=obstacles,
                         views=("front",) if obstacles else ("iso",),
                         width=TILE[0], height=TILE[1], label_rows=TILE_LABEL_ROWS)
    cv2.putText(tile, name, (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (40, 40, 40), 1,
                cv2.LINE_AA)
    return {**written, "tile": tile, "colour": colour}


def overview(tiles: list[np.ndarray]) -> np.ndarray:
    """The tiles, COLUMNS per row, blank tiles filling the last row."""
    blank = np.full_like(tiles[0], 235)
    tiles = tiles + [blank] * (-len(tiles) % COLUMNS)
    rows = [np.concatenate(tiles[i:i + COLUMNS], axis=1) for i in range(0, len(tiles), COLUMNS)]
    return np.concatenate(rows, axis=0)


def describe(record: dict) -> str:
    """Π, iterations, convergence, times and load of one run, for the page."""
    if record["status"] != "ok":
        return f"{record['status']}: {record.get('message', '')}"
    state = "converged" if record.get("converged") else "**NOT converged**"
    if record.get("dynamic") and record.get("converged"):
        state = "every time step converged"
    spans = " × ".join(str(s) for s in record.get("spans", []))
    commit = "commit not recorded" if record["commit"] == "unknown" else record["commit"]
    grid = f" ({spans} spans)" if spans else ""
    start = f"; re-solved (`--resume`) from {record['start']}" if record.get("start") else ""
    return (f"Π = {record['energy']:.6g} J; {record['iterations']} Newton iterations, {state}"
            f"{grid}{start}; {record['wall']:.0f} s wall, {record['cpu']:.0f} s CPU "
            f"at load {record['load'][0]:.1f}–{record['load'][1]:.1f} ({record['date']}, "
            f"{commit})")


def left_out_reasons(records: dict, leave_out: dict[str, str]) -> dict[str, str]:
    """Why each scene gets no pictures: its run failed or did not converge (with the last
    Newton step's λ²/2), or the reason given by --leave-out (a left-out scene that was not
    run has no record)."""
    reasons = {name: reason for name, reason in leave_out.items() if name not in records}
    for name, record in records.items():
        if name in leave_out:
            reasons[name] = leave_out[name]
        elif record["status"] != "ok":
            reasons[name] = f"the run {record['status']}: {record.get('message', '')}"
        elif not record.get("converged"):
            tail = record.get("newton_tail") or [[None, float("nan")]]
            reasons[name] = (f"not converged: {describe(record)}; the last Newton step's "
                             f"λ² = {tail[-1][1]:.2g} J")
    return reasons


def kept_sections(page: str, tiles: np.ndarray) -> tuple[dict, dict]:
    """What an earlier docs/gallery.md (`page`) with its overview image `tiles` shows: per
    scene its section (from its "### name" heading to the next) and its overview tile (the
    sections' order, COLUMNS per row), and per scene of its "Not in this gallery" list the
    reason given there."""
    sections, reasons = {}, {}
    for block in page.split("\n### ")[1:]:
        name, _, body = block.partition("\n")
        if name.strip() == "Not in this gallery":
            for line in body.splitlines():
                if line.startswith("- **") and "**: " in line:
                    scene, _, reason = line[4:].partition("**: ")
                    reasons[scene] = reason
            continue
        index = len(sections)
        row, column = divmod(index, COLUMNS)
        tile = tiles[row * TILE[1]:(row + 1) * TILE[1], column * TILE[0]:(column + 1) * TILE[0]]
        if tile.shape[:2] != (TILE[1], TILE[0]):
            raise SystemExit(f"--keep-others: the overview has no tile {index} for {name}")
        sections[name.strip()] = ("### " + block.rstrip() + "\n", tile)
    return sections, reasons


def write_gallery(records: dict, args) -> int:
    """The pictures, overview.png, docs/gallery.md and (converged runs) the comparison store's
    spline rows."""
    PICTURES.mkdir(exist_ok=True)
    rows, tiles = {}, {}
    left_out = left_out_reasons(records, args.leave_out)
    if args.keep_others:  # the earlier page's sections, tiles and reasons of scenes not run
        sections, reasons = kept_sections((ROOT / "docs" / "gallery.md").read_text(),
                                          cv2.imread(str(PICTURES / "overview.png")))
        for name in comparison.shipped_scenes():
            if name in records or name in left_out:
                continue
            if name in sections:
                rows[name], tiles[name] = sections[name]
            elif name in reasons:
                left_out[name] = reasons[name]
    captions = tomllib.loads(CAPTIONS.read_text()) if CAPTIONS.is_file() else {}
    for name, record in records.items():
        if name in left_out:
            continue
        document = tomllib.loads((SCENES / f"{name}.toml").read_text())
        heading = f"### {name}\n\n{document.get('description', '')}  \n" \
                  f"material `{document.get('material', {}).get('preset', 'custom')}`; " \
                  f"`ndf-sim scenes/{name}.toml --field spline" \
                  f"{''.join(' ' + o for o in spans_options(args.spans.get(name)))}" \
                  f"{' --quick' if args.quick else ''}`: {describe(record)}\n"
        made = pictures(name, args.runs / record.get("run", name))
        tiles[name] = made.pop("tile")
        caption = captions.get(name, "not described yet: look at the pictures and say what "
                               f"they show in {CAPTIONS.relative_to(ROOT)}")
        rows[name] = (heading + f"\n{caption}\n\n![{name}](gallery/{made['picture']})\n"
                    + (f"![{name}: panels](gallery/{made['panels']})\n"
                       if made["panels"] else "")
                    + f"![{name}: energy](gallery/{made['energy']})\n"
                    + (f"\n[trajectory video (H.264)](gallery/{made['video']})\n"
                       if made["video"] else ""))
        print(f"{name}: pictures written", flush=True)
    order = sorted(rows)  # the scenes' order, on the page and in the overview
    save_png(PICTURES / "overview.png", overview([tiles[name] for name in order]))
    training = ("`--quick` runs (the scenes' `[training.quick]` settings: smoke runs, NOT "
                "converged results)" if args.quick else "converged runs")
    page = ["# Gallery", "",
            f"The shipped scenes (`scenes/*.toml`; those without pictures are listed at the "
            f"end with the reason) from {training} of the spline field solved "
            "by projected Newton (`ndf-sim SCENE --field spline`: the grid rule's grid, one "
            "level, float64, the scene's load steps), pictures drawn from each run's own files "
            "by `python docs/make_gallery.py` (which runs the scenes too: "
            + ("the runs for this page's last update " if args.keep_others else "these runs ")
            + f"took {sum(r.get('cpu', 0) for r in records.values()) / 60:.0f} minutes of "
            "CPU; each scene's line gives its run's date). "
            "Per scene: the final state from the three-quarter and "
            f"the front view coloured by {QUANTITIES[COLOUR]} (bending strain where a run has "
            "no reference mesh) on its 1st–99th percentile (the colour bar states what it "
            "clips), obstacles in grey, ground shadow; the energy plot (Π over the Newton "
            "iterations with the load-step and grid-level boundaries, each solve's distance "
            "to its final Π); and where the run has several states (load steps, pseudo-time "
            "frames) the trajectory video. Times were measured on a 2-core VM shared with "
            "other sessions, so they are upper bounds; CPU time is the figure to read. The "
            "scenes in `scenes/inverse/` are start points of the material estimator "
            "(`ndf-fit-material`, docs/inverse_material.md), not shown here.", "",
            *([args.note, ""] if args.note else []),
            "![all scenes](gallery/overview.png)", ""] + [rows[name] for name in order]
    missing = [s for s in comparison.shipped_scenes()
               if s not in records and s not in left_out and s not in rows]
    if missing or left_out:
        page += ["### Not in this gallery", ""]
        page += [f"- **{name}**: {reason}" for name, reason in left_out.items()]
        if missing:
            page += ["- " + ", ".join(missing) + ": not run for this page (`--scenes` left "
                     "them out); `python docs/make_gallery.py` runs them."]
        page += [""]
    (ROOT / "docs" / "gallery.md").write_text("\n".join(page) + "\n")
    if not args.quick:
        for name, record in records.items():  # the comparison page's render of each row
            target = comparison.RENDERS / f"{name}_spline.png"
            if name in left_out:  # no picture of a state this page does not show
                target.unlink(missing_ok=True)
            else:
                comparison.render(args.runs / record.get("run", name), target)
        # read just before writing: benchmarks/spline_vs_siren.py may have stored meanwhile
        store = json.loads(comparison.STORE.read_text()) if comparison.STORE.is_file() else {}
        for name, record in records.items():
            store.setdefault(name, {})["spline"] = record
        comparison.STORE.write_text(json.dumps(store, indent=1, sort_keys=True) + "\n")
        print("comparison store updated: rebuild its table with "
              "`python benchmarks/spline_vs_siren.py --table-only`")
    print(f"wrote docs/gallery.md and the pictures of {len(records)} runs in {PICTURES}")
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--runs", type=Path, default=Path("/tmp/ndf-gallery-runs"))
    p.add_argument("--scenes", default=None,
                   help="comma-separated scene names (default: every scenes/*.toml)")
    p.add_argument("--runs-only", action="store_true", help="run the scenes, draw nothing")
    p.add_argument("--quick", action="store_true",
                   help="[training.quick] settings: a smoke test of this script")
    p.add_argument("--leave-out", action="append", default=[], metavar="SCENE=REASON",
                   help="draw no pictures of SCENE; the page gives REASON (repeatable)")
    p.add_argument("--keep-others", action="store_true",
                   help="keep the current page's sections (and overview tiles) of the scenes "
                   "not in --scenes, and its reasons for those it leaves out")
    p.add_argument("--note", default="", help="a paragraph on where the runs came from")
    p.add_argument("--spans", action="append", default=[], metavar="SCENE=NxM",
                   help="solve SCENE on N x M knot spans instead of the grid rule's grid (a "
                   "scene the rule's grid leaves grid-limited; repeatable)")
    p.add_argument("--folds", action="append", default=[], metavar="SCENE=K",
                   help="show SCENE re-solved from its run plus a K-fold radial perturbation "
                   "(a scene whose symmetric start stays on a symmetric equilibrium)")
    args = p.parse_args(argv)
    names = comparison.shipped_scenes() if args.scenes is None else args.scenes.split(",")
    leave_out = {}
    for item in args.leave_out:
        name, _, reason = item.partition("=")
        if not reason.strip() or name not in names:
            p.error(f"--leave-out {item!r}: expected SCENE=REASON with SCENE among the scenes")
        leave_out[name] = reason.strip()
    args.leave_out = leave_out
    folds = {}
    for item in args.folds:
        name, _, count = item.partition("=")
        if name not in names or not count.isdigit() or int(count) < 1:
            p.error(f"--folds {item!r}: expected SCENE=K with SCENE among the scenes, K >= 1")
        folds[name] = int(count)
    spans = {}
    for item in args.spans:
        name, _, grid = item.partition("=")
        sizes = grid.lower().split("x")
        if name not in names or len(sizes) != 2 or not all(v.isdigit() and int(v) >= 1
                                                            for v in sizes):
            p.error(f"--spans {item!r}: expected SCENE=NxM with SCENE among the scenes, N, M >= 1")
        spans[name] = (int(sizes[0]), int(sizes[1]))
    args.spans = spans
    for name in names:
        if not (SCENES / f"{name}.toml").is_file():
            p.error(f"--scenes: no scene {name!r} in {SCENES}")
    args.runs.mkdir(parents=True, exist_ok=True)
    # a left-out scene is run only where its run is stored (its reason needs no new run)
    records = {name: run_scene(name, args.runs, args.quick, spans.get(name)) for name in names
               if name not in leave_out or (args.runs / f"{name}.json").is_file()}
    for name, count in folds.items():
        records[name] = refold(name, count, args.runs, records[name])
    if args.runs_only:
        return 0
    return write_gallery(records, args)


if __name__ == "__main__":
    sys.exit(main())
