"""`ndf-sim SCENE.toml --out DIR`: run a scene to equilibrium and write what it produced."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from collections.abc import Callable
from pathlib import Path

from taichi_ndf.cli.common import (
    ArgumentParser,
    add_runtime_options,
    description,
    machine_description,
    start,
)
from taichi_ndf.cli.progress import shown


def build_parser() -> argparse.ArgumentParser:
    p = ArgumentParser(prog="ndf-sim", description=description(__doc__))
    p.add_argument("scene", type=Path, help="scene file (TOML); see docs/scenes.md")
    p.add_argument("--out", type=Path, required=True, help="output directory (must be new or "
                   "empty unless --overwrite or --resume); written as DIR.incomplete and moved "
                   "into place when the run completes")
    p.add_argument("--iterations", "--iters", dest="iterations", type=int,
                   help="Adam iterations per load step (overrides the scene; --iters: the same)")
    p.add_argument("--samples", type=int, help="samples per iteration (overrides scene)")
    p.add_argument("--material", help="replace the scene's material by a preset (cloth, "
                   "denim, cotton_polyester, ...: docs/scenes.md, \"Material presets\")")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="set a scene key before the scene is validated, VALUE in TOML "
                   "(repeatable): --set material.stiffness_scale=0.5 --set "
                   "'loads.gravity=[0, 0, -5]' (docs/scenes.md)")
    p.add_argument("--field", choices=("siren", "spline"),
                   help="solve with this field type: spline = a B-spline field solved by "
                   "projected Newton on the grid rule's grid (docs/scenes.md); keeps the "
                   "scene's load steps and seed, other field and training settings default")
    p.add_argument("--refine", type=int, metavar="K", nargs="?", const=3,
                   help="spline field: solve on K successively refined grids (default 3; "
                   "replaces [field] levels) and report Π and every probe per level with the "
                   "Richardson-extrapolated value and its error bar: from the observed order "
                   "with K >= 3 (where that order is unreliable, said so: the finest value "
                   "with 3 x the range of the last three); with K = 2 the order is assumed "
                   "and the bar is the change between the two grids")
    p.add_argument("--tolerance", type=float, metavar="REL",
                   help="spline field: refine (spans doubled per grid) until the estimated "
                   "relative error of Π and of every probe is at most REL, or the budget "
                   "--max-unknowns is spent; the estimate is printed and in result.json "
                   "(docs/scenes.md)")
    p.add_argument("--indicator", choices=("features", "none", "density", "energy_norm"),
                   default="features",
                   help="--tolerance: how each grid's knots are placed: features (default): "
                   "graded towards the scene's pins, point loads and interior lines by the "
                   "grid's own spans, dyadic refinement where it has none; none: dyadic "
                   "refinement, the grid's grading kept; density, energy_norm: equidistribute "
                   "this error indicator (density: the change of the strain energy density)")
    p.add_argument("--max-unknowns", type=int, default=200_000, metavar="N",
                   help="--tolerance: the most unknowns of a grid (default 200000)")
    p.add_argument("--quick", action="store_true",
                   help="a short run with the scene's [training.quick] settings (smoke test)")
    p.add_argument("--resume", action="store_true",
                   help="continue an interrupted run from DIR.incomplete/checkpoint.pt (or a "
                   "finished one from DIR/checkpoint.pt, e.g. with more --iterations)")
    p.add_argument("--overwrite", action="store_true",
                   help="allow writing into a non-empty output directory")
    p.add_argument("--no-pictures", dest="pictures", action="store_false",
                   help="leave out render.png, energy.png and trajectory.mp4 (seconds of CPU "
                   "after the result is printed; the meshes, probes, checkpoint and "
                   "result.json are written all the same)")
    add_runtime_options(p, seed=None, seed_help="random seed (default: the scene's "
                        "[training] seed, 0 if none)")
    return p


def refined_scene(scene, levels: int):
    """The scene with its field solved on `levels` grids (--refine; ValueError where the
    field has no grids)."""
    from taichi_ndf.discretise import of_scene

    return dataclasses.replace(scene, field=of_scene(scene).refined(levels).spec)


def main(argv: list[str] | None = None, *,
         on_result: Callable[[dict], None] | None = None) -> int:
    """Run the tool; `on_result` (e.g. a demo's own result line) is called with the result
    right after the summary is printed: once the solve is done, before the outputs are
    written (`simulate`)."""
    args = build_parser().parse_args(argv)
    # Imported after parsing: --help and a bad option answer without loading torch or Taichi.
    from taichi_ndf.app.outputs import exports_on_template
    from taichi_ndf.app.simulation import RUN_FILES, SimulationError, simulate
    from taichi_ndf.discretise import of_scene
    from taichi_ndf.io import incomplete_path, staged_run
    from taichi_ndf.io.memory import check_export_memory
    from taichi_ndf.io.progress_log import PROGRESS_FILE, logged_progress
    from taichi_ndf.scene.overrides import parse_assignment
    from taichi_ndf.scene.schema import SceneError

    staging = incomplete_path(args.out)
    shown_result = []

    def show(result: dict) -> None:  # the result before the outputs (they cost seconds)
        for line in summary_lines(scene.name, result):
            print(line, flush=True)
        if on_result is not None:
            on_result(result)
        shown_result.append(True)

    try:
        from taichi_ndf.scene.reader import load_scene
        from taichi_ndf.scene.training import trains_the_field

        scene_keys = dict(parse_assignment(text) for text in args.set)
        scene = load_scene(args.scene, material=args.material, field=args.field,
                           overrides=scene_keys)
        solver = scene.quick_solver if args.quick else scene.solver
        if args.refine is not None and scene.dynamics is not None:
            raise ValueError("--refine: a dynamic run ([dynamics]) solves on one grid, the "
                             "finest of [field] levels")
        if args.tolerance is not None and scene.dynamics is not None:
            raise ValueError("--tolerance: a dynamic run ([dynamics]) solves on one grid, the "
                             "finest of [field] levels")
        if args.refine is not None:
            scene = refined_scene(scene, args.refine)
            solver = dataclasses.replace(solver, max_levels=0)
        adaptive = None
        if args.tolerance is not None:
            from taichi_ndf.discretise.adaptive import adaptive as adaptive_discretisation
            from taichi_ndf.solve.adaptive import AdaptiveConfig

            if args.refine is not None or args.resume:
                raise ValueError("--tolerance chooses the grids itself: drop --refine/--resume")
            adaptive = AdaptiveConfig(args.tolerance, args.max_unknowns, args.indicator)
        if solver.method == "newton" and (args.iterations is not None or args.samples is not None):
            raise ValueError("--iterations and --samples set Adam; this scene is solved by "
                             "projected Newton ([training] method = \"newton\")")
        if args.iterations is not None:
            if args.iterations < 0:
                raise ValueError(f"--iterations must be >= 0, got {args.iterations}")
            solver = solver.with_iterations(args.iterations)
            if not trains_the_field(solver):
                raise ValueError("--iterations 0: nothing would train the field (no L-BFGS or "
                                 "Newton iterations in the scene either)")
        overrides = {} if args.seed is None else {"seed": args.seed}
        if args.samples is not None:
            overrides["samples"] = args.samples
        solver = dataclasses.replace(solver, **overrides)
        sized = of_scene(scene)
        if adaptive is not None:
            sized = adaptive_discretisation(sized, adaptive)
        sized.check_size(solver, itemsize=8 if args.precision == "f64" else 4)
        if not exports_on_template(scene.model):
            frames = scene.output.frames or len(solver.load_steps)
            if scene.dynamics is not None:
                frames = scene.dynamics.frames
            check_export_memory(scene.output.resolution, "output.resolution", frames=frames)
        with shown("ndf-sim"), staged_run(args.out, overwrite=args.overwrite,
                                          resume=args.resume, products=RUN_FILES) as out, \
                logged_progress(out.file(PROGRESS_FILE)):
            runtime = start(args)  # the directory is claimed before the runtime starts
            result = simulate(scene, out, solver=solver, resume=args.resume,
                              machine=machine_description(runtime),
                              report=lambda line: print(line, flush=True),
                              on_result=show, pictures=args.pictures, adaptive=adaptive)
    except (SceneError, SimulationError, FileExistsError, FileNotFoundError, ValueError) as err:
        print(f"ndf-sim: error: {err}", file=sys.stderr)
        return 2
    except MemoryError:
        kept = f"; the previous run in {args.out} is unchanged" if args.out.exists() else ""
        print(f"ndf-sim: error: out of memory; the incomplete attempt is in {staging} (its "
              f"checkpoint can be resumed with --resume){kept}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        where = (f"the last checkpoint is in {staging} (continue with --resume)"
                 if (staging / "checkpoint.pt").is_file() else "no checkpoint was written yet")
        print(f"ndf-sim: interrupted; {where}", file=sys.stderr)
        return 130
    if not shown_result:
        show(result)
    print(f"outputs in {args.out}")
    return 0


def summary_lines(name: str, result: dict) -> list[str]:
    """The final summary of a solve: Π, with several grid levels its Richardson-extrapolated
    value ± the estimated error, and each probe (extrapolated ± error where refined)."""
    refinement = result.get("refinement")
    lines = [f"{name}: Π = {result['energy']:.6g} J after {result['iterations']} iterations "
             f"in {result['wall_time']:.1f} s"]
    if refinement:
        e = refinement["energy"]
        lines.append(f"  refinement over {len(e['values'])} grids: Π → {e['text']} J")
        if e.get("warning"):
            lines.append(f"  warning: {e['warning']}")
        if refinement.get("adaptive"):
            a = refinement["adaptive"]
            lines.append(f"  adaptive (tolerance {a['tolerance']:g}): {a['outcome']}; "
                         f"{a.get('worst', 'no estimate')}")
    for probe, u in result["probes"].items():
        line = f"  probe {probe}: u = ({u[0]:.5g}, {u[1]:.5g}, {u[2]:.5g}) m"
        if refinement:
            parts = refinement["probes"][probe]
            line += "; extrapolated (" + ", ".join(
                f"{c['extrapolated']:.5g} ± {c['estimated_error']:.2g}" for c in parts) + ") m"
            bases = sorted({c.get("order_basis") for c in parts} & {"assumed", "unreliable"})
            within = [str(a) for a, c in enumerate(parts) if c.get("error_bound") == "point"]
            if bases:
                line += f" (order {' / '.join(bases)}" + (
                    f"; component {', '.join(within)} within the point's bar)" if within else ")")
        lines.append(line)
    return lines


if __name__ == "__main__":
    sys.exit(main())
