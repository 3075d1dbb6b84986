"""`ndf-export CHECKPOINT --resolution R --out MESH.obj|.ply`: evaluate a trained field anywhere.

The checkpoint carries its scene, so the boundary conditions and reference surface are rebuilt
exactly; the field is continuous, so any resolution can be exported. A garment's checkpoint
(its panels' fields) is written with one object per panel, named by it (OBJ: `o <panel>`;
PLY: a `panel` vertex property and a header comment `panel <index> <name>` per panel).
`ndf-export RUN_DIR --format usd [--out FILE.usdc]` converts a finished run (its meshes, strains,
trajectory, probes) into one USD stage (needs the [usd] extra).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from taichi_ndf.cli.common import (
    ArgumentParser,
    add_runtime_options,
    description,
    finite_float,
    interruptible,
    start,
)

USD_SUFFIXES = (".usdc", ".usda", ".usd")


def build_parser() -> argparse.ArgumentParser:
    p = ArgumentParser(prog="ndf-export", description=description(__doc__))
    p.add_argument("checkpoint", type=Path, metavar="RUN",
                   help="a run directory written by ndf-sim, or its checkpoint.pt")
    p.add_argument("--format", choices=("obj", "ply", "usd"),
                   help="output format (default: from the --out suffix: .obj, .ply, "
                   ".usdc/.usda/.usd)")
    p.add_argument("--resolution", type=int, nargs="+", default=[128],
                   help="grid cells per surface coordinate: R or R1 R2 (default 128)")
    p.add_argument("--out", type=Path,
                   help="output mesh file (.obj or .ply, or .usdc/.usda/.usd with --format usd: "
                   "default RUN_DIR/result.usdc); refused if it exists without --overwrite")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    p.add_argument("--time", type=finite_float, default=1.0,
                   help="load factor t in [0, 1] of a pseudo-time field's path (default 1)")
    add_runtime_options(p)
    return p


@interruptible("ndf-export")
def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    usd = args.out is not None and args.out.suffix.lower() in USD_SUFFIXES
    if args.format == "usd" or (args.format is None and usd):
        return _export_usd(args)
    if args.checkpoint.is_dir():  # a run directory: its checkpoint
        args.checkpoint = args.checkpoint / "checkpoint.pt"
    try:
        if args.out is None:
            raise ValueError("--out is required (a .obj or .ply file)")
        if args.format is not None and args.out.suffix.lower() != f".{args.format}":
            raise ValueError(f"--format {args.format} needs --out ending in .{args.format}, "
                             f"got {args.out}")
        if args.out.suffix.lower() not in (".obj", ".ply"):
            raise ValueError(f"--out must end in .obj or .ply, got {args.out}")
        if args.out.exists() and not args.overwrite:
            raise FileExistsError(f"{args.out} exists; pass --overwrite to replace it")
        if len(args.resolution) not in (1, 2) or min(args.resolution) < 1:
            raise ValueError(f"--resolution takes one or two positive integers, got "
                             f"{args.resolution}")
        res = tuple(args.resolution) * (2 if len(args.resolution) == 1 else 1)
        if not 0.0 <= args.time <= 1.0:
            raise ValueError(f"--time must be in [0, 1], got {args.time}")
        _refuse_a_garment(args.checkpoint)
        start(args)
        from taichi_ndf.app.outputs import deformed_mesh, exports_on_template
        from taichi_ndf.app.panels import part_meshes, write_panels_file
        from taichi_ndf.app.simulation import checkpoint_scene
        from taichi_ndf.discretise import of_scene
        from taichi_ndf.io import write_obj, write_ply
        from taichi_ndf.io.memory import check_export_memory
        from taichi_ndf.minimise.checkpoint import load_checkpoint

        checkpoint = load_checkpoint(args.checkpoint)
        scene = checkpoint_scene(args.checkpoint, checkpoint.extra)
        if not exports_on_template(scene.model):
            check_export_memory(res, "--resolution")
        # the surfaces of the run: its one field's, or a garment's panels (named)
        parts = of_scene(scene).result_parts(checkpoint.field)
        if args.time != 1.0 and not scene.solver.pseudo_time:
            raise ValueError("--time needs a checkpoint of a pseudo-time field "
                             "([training] pseudo_time = true)")
        from taichi_ndf import progress

        with progress.stage(f"export {res[0]} × {res[1]} mesh to {args.out.name}", 2):
            if any(p.name for p in parts):  # one object per panel, named by it
                meshes = part_meshes(parts, res)
                progress.report(1)
                write_panels_file(args.out, parts, meshes)
                progress.report(2)
                print(f"wrote {args.out}: {len(parts)} panels ("
                      + ", ".join(f"{p.name} {len(m.deformed)} vertices"
                                  for p, m in zip(parts, meshes, strict=True)) + ")")
                return 0
            (part,) = parts
            mesh = deformed_mesh(part.model, part.field, res, load_factor=args.time,
                                 pseudo_time=scene.solver.pseudo_time)
            progress.report(1)
            if args.out.suffix.lower() == ".obj":
                write_obj(args.out, mesh.deformed, mesh.faces, uvs=mesh.uv)
            else:
                write_ply(args.out, mesh.deformed, mesh.faces, uvs=mesh.uv,
                          vertex_scalars=mesh.scalars())
            progress.report(2)
    except (ValueError, FileExistsError, FileNotFoundError) as err:
        print(f"ndf-export: error: {err}", file=sys.stderr)
        return 2
    print(f"wrote {args.out}: {len(mesh.deformed)} vertices, {len(mesh.faces)} faces")
    return 0


def _refuse_a_garment(checkpoint: Path) -> None:
    """ValueError in one line where `checkpoint` is missing from a garment run's directory."""
    from taichi_ndf.io.run_files import garment_panels

    panels = None if checkpoint.is_file() else garment_panels(checkpoint.parent)
    if panels:
        raise ValueError(f"{checkpoint.parent} is a garment run ({len(panels)} panels: "
                         f"{', '.join(panels)}) and has no checkpoint.pt to evaluate at another "
                         "resolution (written before garment runs were checkpointed); its "
                         "meshes are mesh.obj/.ply (all panels) and mesh_<panel>.obj/.ply, or "
                         "use --format usd")


def _export_usd(args) -> int:
    """The run directory (no field evaluation: the run's own files) as one USD stage."""
    from taichi_ndf.export.usd import require_usd, write_run_usd
    from taichi_ndf.extras import MissingExtra
    from taichi_ndf.io.run_files import read_run

    run_dir = args.checkpoint.parent if args.checkpoint.is_file() else args.checkpoint
    out = args.out if args.out is not None else run_dir / "result.usdc"
    try:
        require_usd()
        if out.suffix not in USD_SUFFIXES:
            raise ValueError(f"--out must end in .usdc, .usda or .usd with --format usd, got {out}")
        if out.exists() and not args.overwrite:
            raise FileExistsError(f"{out} exists; pass --overwrite to replace it")
        run = read_run(run_dir)
        write_run_usd(run, out)
    except (MissingExtra, ValueError, FileExistsError, FileNotFoundError) as err:
        print(f"ndf-export: error: {err}", file=sys.stderr)
        return 2
    print(f"wrote {out}: {len(run.deformed)} vertices, {len(run.faces)} faces, "
          f"{len(run.frames)} trajectory frames")
    return 0


if __name__ == "__main__":
    sys.exit(main())
