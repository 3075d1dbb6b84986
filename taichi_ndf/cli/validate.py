"""`ndf-validate [CASE ...] [--quick] --out DIR`: run the published shell benchmarks (built-in
case names or case files CASE.toml) and write the results table (results.md, results.json)
and one convergence plot per case."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from taichi_ndf.cli.common import (
    ArgumentParser,
    add_runtime_options,
    description,
    interruptible,
    nonnegative_int,
    start,
)
from taichi_ndf.io import OutputDir
from taichi_ndf.scene.schema import SceneError


def build_parser() -> argparse.ArgumentParser:
    from taichi_ndf.validation import CASES, SCENES_DIR

    p = ArgumentParser(prog="ndf-validate", description=description(__doc__))
    p.add_argument("cases", nargs="*", metavar="CASE",
                   help=f"built-in cases (default: all): {', '.join(CASES)}; or case files "
                   "CASE.toml (docs/validation.md)")
    p.add_argument("--out", type=Path, required=True, help="output directory (new or empty "
                   "unless --overwrite)")
    p.add_argument("--quick", action="store_true",
                   help="short runs with each scene's [training.quick] settings (smoke test)")
    p.add_argument("--iterations", "--iters", dest="iterations", type=nonnegative_int,
                   help="Adam iterations per load step (overrides the scenes)")
    p.add_argument("--field", choices=("siren", "spline"), default=None,
                   help="default: the field each case's scene names ([field] type, as in "
                   "ndf-sim); spline: solved by projected Newton on three grids (the scene's "
                   "own spline keys, or the grid rule's grid; then refined twice; --quick: "
                   "one), read on the finest; siren: trained by Adam")
    p.add_argument("--scenes", type=Path, default=SCENES_DIR,
                   help=f"folder of the case scene files (default: {SCENES_DIR})")
    p.add_argument("--overwrite", action="store_true",
                   help="allow writing into a non-empty output directory")
    add_runtime_options(p, seed=None,
                        seed_help="random seed (default: each scene's)")
    return p


@interruptible("ndf-validate")
def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from taichi_ndf.minimise.callbacks import DivergenceError
    from taichi_ndf.validation import CASES, load_case, run_case, write_report

    unknown = [c for c in args.cases if c not in CASES and not c.endswith(".toml")]
    if unknown:
        print(f"ndf-validate: error: unknown case(s) {', '.join(unknown)}; choose from "
              f"{', '.join(CASES)} or give a case file CASE.toml", file=sys.stderr)
        return 2
    try:
        cases = [load_case(c) if c.endswith(".toml") else CASES[c]
                 for c in args.cases or list(CASES)]
        names = [case.name for case in cases]
        if len(set(names)) != len(names):
            raise ValueError(f"two cases share a name: {', '.join(names)}")
        out = OutputDir(args.out, overwrite=args.overwrite)
        start(args)
        results = []
        for case in cases:
            name = case.name
            result = run_case(case, quick=args.quick, iterations=args.iterations,
                              scenes_dir=args.scenes, seed=args.seed,
                              field=args.field)
            results.append(result)
            for row in result.rows:
                value = "not run" if row.computed is None else f"{row.computed:.5g}"
                error = ("" if row.relative_error is None
                         else f" ({100 * row.relative_error:.2f} % off)")
                print(f"{name} {row.quantity} @ {row.level:g}: {value} vs {row.reference:.5g}"
                      f"{error}", flush=True)
            write_report(results, out, quick=args.quick)
    except (SceneError, DivergenceError, FileExistsError, ValueError) as err:
        print(f"ndf-validate: error: {err}", file=sys.stderr)
        return 2
    print(f"table in {out.path / 'results.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
