"""`ndf-render RUN_DIR --view iso --colour QUANTITY --size WxH`: re-render a finished run.

Reads the run's own files (no field evaluation, no Taichi): the final deformed mesh coloured by
one per-vertex quantity, from one or more named views side by side, with its ground shadow, the
scene's obstacles and a colour bar with units.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from taichi_ndf.cli.common import description, finite_float
from taichi_ndf.io.run_files import QUANTITIES
from taichi_ndf.render.figure import VIEWS


def image_size(text: str) -> tuple[int, int]:
    """'800x600' -> (800, 600)."""
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected WIDTHxHEIGHT, e.g. 800x600, got {text!r}") from None
    if not (16 <= width <= 8192 and 16 <= height <= 8192):
        raise argparse.ArgumentTypeError(f"width and height must be in [16, 8192], got {text!r}")
    return width, height


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="ndf-render", description=description(__doc__))
    p.add_argument("run", type=Path, help="run directory written by ndf-sim")
    p.add_argument("--view", nargs="+", choices=tuple(VIEWS), default=["iso"],
                   help="one or more views, drawn side by side (default: iso, a three-quarter "
                   "view)")
    p.add_argument("--colour", choices=tuple(QUANTITIES), default="bending_strain",
                   help="per-vertex quantity shown (default: bending_strain)")
    p.add_argument("--size", type=image_size, default=None,
                   help="image size WIDTHxHEIGHT in pixels (default: 600 pixels high, each "
                   "view as wide as its framed shape needs, 300 to 800 pixels, as render.png)")
    p.add_argument("--time", type=finite_float, default=None, metavar="T",
                   help="the trajectory frame at load factor (or pseudo-time) T instead of the "
                   "final state (coloured by displacement: the other quantities are stored for "
                   "the final state only)")
    p.add_argument("--no-shadow", action="store_true", help="leave out the ground shadow")
    p.add_argument("--out", type=Path,
                   help="PNG file (default: RUN/render_<views>_<colour>.png)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    at = "" if args.time is None else f"_t{args.time:g}"
    out = args.out or args.run / f"render_{'_'.join(args.view)}_{args.colour}{at}.png"
    try:
        from taichi_ndf.io.run_files import read_run
        from taichi_ndf.render import save_png
        from taichi_ndf.render.figure import Obstacle, render_figure

        if out.suffix.lower() != ".png":
            raise ValueError(f"--out must end in .png, got {out}")
        if out.exists() and not args.overwrite:
            raise FileExistsError(f"{out} exists; pass --overwrite to replace it")
        run = read_run(args.run)
        deformed, scalars = frame_at(run, args.time, args.colour)
        width, height = args.size or (None, 600)
        image = render_figure(
            deformed, run.faces, scalars=scalars,
            scalar_label=QUANTITIES[args.colour], views=tuple(args.view), up=run.up,
            obstacles=tuple(Obstacle(o.vertices, o.faces) for o in run.obstacles),
            width=width, height=height, shadow=not args.no_shadow)
        save_png(out, image)
    except (ValueError, FileExistsError, FileNotFoundError) as err:
        print(f"ndf-render: error: {err}", file=sys.stderr)
        return 2
    print(f"wrote {out} ({image.shape[1]}x{image.shape[0]}, {', '.join(args.view)}, "
          f"{args.colour})")
    return 0


def frame_at(run, time: float | None, colour: str):
    """Positions (V, 3) and per-vertex values (V,) of the run's final state (time None) or of
    its trajectory frame at load factor `time` (displacement only: the strains and energy
    density are stored for the final state)."""
    import numpy as np

    if time is None:
        return run.deformed, run.quantity(colour)
    factors = [f.load_factor for f in run.frames]
    matches = [f for f in run.frames if abs(f.load_factor - time) <= 1e-9]
    if not matches:
        have = ", ".join(f"{t:g}" for t in factors) if factors else "none (one load step)"
        raise ValueError(f"--time {time:g}: the run has trajectory frames at {have}")
    if colour != "displacement":
        raise ValueError(f"--time: {colour} is stored for the final state only; use "
                         "--colour displacement")
    if run.reference is None:
        raise ValueError(f"{run.path} has no reference.obj, so no displacement")
    vertices = matches[0].vertices
    return vertices, np.linalg.norm(vertices - run.reference, axis=1)


if __name__ == "__main__":
    sys.exit(main())
