"""`ndf-sim SCENE.toml --out DIR`: run a scene to equilibrium and write what it produced."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

from taichi_ndf.cli.common import add_runtime_options, machine_description, start
from taichi_ndf.io import OutputDir
from taichi_ndf.scene_schema import SceneError
from taichi_ndf.simulation import SimulationError, simulate


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="ndf-sim", description=__doc__.split("\n")[0].strip("`"))
    p.add_argument("scene", type=Path, help="scene file (TOML); see docs/scenes.md")
    p.add_argument("--out", type=Path, required=True, help="output directory (must be new or "
                   "empty unless --overwrite or --resume)")
    p.add_argument("--iters", type=int, help="Adam iterations per load step (overrides scene)")
    p.add_argument("--samples", type=int, help="samples per iteration (overrides scene)")
    p.add_argument("--material", help="replace the scene's material by a preset "
                   "(cloth, canvas, cotton, silk)")
    p.add_argument("--quick", action="store_true",
                   help="a short run with the scene's [training.quick] settings (smoke test)")
    p.add_argument("--resume", action="store_true",
                   help="continue an interrupted run from DIR/checkpoint.pt")
    p.add_argument("--overwrite", action="store_true",
                   help="allow writing into a non-empty output directory")
    add_runtime_options(p)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        from taichi_ndf.scene import load_scene

        scene = load_scene(args.scene, material=args.material)
        runtime = start(args)
        if args.resume and not (args.out / "checkpoint.pt").is_file():
            raise SimulationError(f"--resume: no checkpoint at {args.out / 'checkpoint.pt'}")
        out = OutputDir(args.out, overwrite=args.overwrite or args.resume)
        solver = scene.quick_solver if args.quick else scene.solver
        if args.iters is not None:
            solver = solver.with_iterations(args.iters)
        overrides = {"seed": args.seed}
        if args.samples is not None:
            overrides["samples"] = args.samples
        solver = dataclasses.replace(solver, **overrides)
        result = simulate(scene, out, solver=solver, resume=args.resume,
                          machine=machine_description(runtime))
    except (SceneError, SimulationError, FileExistsError, ValueError) as err:
        print(f"ndf-sim: error: {err}", file=sys.stderr)
        return 2
    print(f"{scene.name}: Π = {result['energy']:.6g} J after {result['iterations']} iterations "
          f"in {result['wall_time']:.1f} s")
    for name, u in result["probes"].items():
        print(f"  probe {name}: u = ({u[0]:.5g}, {u[1]:.5g}, {u[2]:.5g}) m")
    print(f"outputs in {out.path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
