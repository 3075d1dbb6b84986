"""The README's first demo: a napkin pinned at one corner, hanging under gravity.

    python demos/napkin.py            # full run into runs/napkin (a minute or two on a laptop CPU)
    python demos/napkin.py --quick    # a few iterations, to check the installation

Any further option goes to `ndf-sim` (e.g. --material canvas, --overwrite, --arch cuda).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from taichi_ndf.cli import sim

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "napkin.toml"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=ROOT / "runs" / "napkin",
                        help="output directory (default: runs/napkin in the repository)")
    parser.add_argument("--quick", action="store_true", help="a short smoke-test run")
    args, rest = parser.parse_known_args(argv)
    cli_args = [str(SCENE), "--out", str(args.out), *(["--quick"] if args.quick else []), *rest]
    status = sim.main(cli_args)
    if status == 0:
        print(f"open {args.out / 'render.png'} (render), {args.out / 'energy.png'} (energy), "
              f"{args.out / 'mesh.ply'} (mesh with strains) and {args.out / 'result.json'}")
    return status


if __name__ == "__main__":
    sys.exit(main())
