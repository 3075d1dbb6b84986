"""Run any scene of scenes/ by name or path, headless, into runs/NAME[_MATERIAL].

    python demos/run_scene.py sleeve_twist
    python demos/run_scene.py skirt --material canvas --quick
    python demos/run_scene.py --list

Any further option goes to `ndf-sim` (e.g. --iterations 500, --overwrite, --precision f64).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from taichi_ndf.cli import sim

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "scenes"


def scene_path(name: str) -> Path:
    """A scene file given as a path or as the name of a file in scenes/ (without .toml)."""
    path = Path(name)
    if path.suffix == ".toml" and path.is_file():
        return path
    candidate = SCENES / f"{name}.toml"
    if candidate.is_file():
        return candidate
    known = ", ".join(sorted(p.stem for p in SCENES.glob("*.toml")))
    raise SystemExit(f"run_scene: no scene {name!r}; shipped scenes: {known}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("scene", nargs="?", help="scene name in scenes/ or path to a .toml file")
    parser.add_argument("--list", action="store_true", help="list the shipped scenes")
    parser.add_argument("--out", type=Path,
                        help="output directory (default: runs/NAME or runs/NAME_MATERIAL)")
    parser.add_argument("--material", help="replace the scene's material by a preset")
    parser.add_argument("--quick", action="store_true", help="a short smoke-test run")
    args, rest = parser.parse_known_args(argv)
    if args.list or args.scene is None:
        for path in sorted(SCENES.glob("*.toml")):
            print(path.stem)
        return 0
    path = scene_path(args.scene)
    out = args.out or ROOT / "runs" / (path.stem + (f"_{args.material}" if args.material else ""))
    cli_args = [str(path), "--out", str(out), *(["--quick"] if args.quick else []),
                *(["--material", args.material] if args.material else []), *rest]
    return sim.main(cli_args)


if __name__ == "__main__":
    sys.exit(main())
