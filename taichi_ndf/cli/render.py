"""`ndf-render RUN_DIR --view iso --colour QUANTITY --size WxH`: re-render a finished run.

Reads the run's own files (no field evaluation, no Taichi): the final deformed mesh coloured by
one per-vertex quantity, from one or more named views side by side, with its ground shadow, the
scene's obstacles and a colour bar with units.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

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
    p = argparse.ArgumentParser(prog="ndf-render", description=__doc__.split("\n")[0].strip("`"))
    p.add_argument("run", type=Path, help="run directory written by ndf-sim")
    p.add_argument("--view", nargs="+", choices=tuple(VIEWS), default=["iso"],
                   help="one or more views, drawn side by side (default: iso, a three-quarter "
                   "view)")
    p.add_argument("--colour", choices=tuple(QUANTITIES), default="bending_strain",
                   help="per-vertex quantity shown (default: bending_strain)")
    p.add_argument("--size", type=image_size, default=(800, 600),
                   help="image size WIDTHxHEIGHT in pixels (default: 800x600)")
    p.add_argument("--no-shadow", action="store_true", help="leave out the ground shadow")
    p.add_argument("--out", type=Path,
                   help="PNG file (default: RUN/render_<views>_<colour>.png)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    out = args.out or args.run / f"render_{'_'.join(args.view)}_{args.colour}.png"
    try:
        from taichi_ndf.io.run_files import read_run
        from taichi_ndf.render import save_png
        from taichi_ndf.render.figure import Obstacle, render_figure

        if out.suffix.lower() != ".png":
            raise ValueError(f"--out must end in .png, got {out}")
        if out.exists() and not args.overwrite:
            raise FileExistsError(f"{out} exists; pass --overwrite to replace it")
        run = read_run(args.run)
        width, height = args.size
        image = render_figure(
            run.deformed, run.faces, scalars=run.quantity(args.colour),
            scalar_label=QUANTITIES[args.colour], views=tuple(args.view), up=run.up,
            obstacles=tuple(Obstacle(o.vertices, o.faces) for o in run.obstacles),
            width=width, height=height, shadow=not args.no_shadow)
        save_png(out, image)
    except (ValueError, FileExistsError, FileNotFoundError) as err:
        print(f"ndf-render: error: {err}", file=sys.stderr)
        return 2
    print(f"wrote {out} ({width}x{height}, {', '.join(args.view)}, {args.colour})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
