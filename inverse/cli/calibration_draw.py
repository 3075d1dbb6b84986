"""One fit of the material-estimate calibration (a study's ``job = "calibration"``).

    python -m inverse.cli.calibration_draw --case strip --noise 0.01 --seed 3 --out DIR
        [--flap-spans 40 40] [--case-cache FOLDER]

Builds the case of `inverse.material.calibration` (CASES), fits the observation with noise
`--noise` drawn with `--seed` (seed 0: the noise-free observation, with --noise 0) by
`newton_fit`, single-threaded, f64, like benchmarks/material_calibration.py does for each of
its draws, and writes DIR/draw.json: the unknowns, truth, estimate, reported standard error
and its Fisher and discretisation parts, wall and CPU time of the fit [s], the case's
observation error.

With --case-cache (`ndf-sweep` passes OUT/cache) the case's solved observation is taken from
the study's cache (`taichi_ndf.sweep.cache`) where an earlier run stored it, else solved and
stored: the flap and point-load observations are projected-Newton solves with their
Richardson check, minutes each, and the same for every fit of the case. The key is the case,
its flap spans, the code (`code_version`) and the versions of numpy, scipy, torch and taichi.
"""

from __future__ import annotations

import argparse
import functools
import logging
import sys
from importlib.metadata import version
from pathlib import Path

import numpy as np
import torch

import taichi_ndf
from inverse.material.calibration import CASES, Case, fit_draw, newton_fit
from inverse.material.identifiability import finite_or_none
from taichi_ndf.cli.common import ArgumentParser, finite_float, interruptible, nonnegative_int
from taichi_ndf.io import staged_run
from taichi_ndf.sweep import cache
from taichi_ndf.sweep.provenance import code_version


def build_parser() -> argparse.ArgumentParser:
    p = ArgumentParser(prog="calibration_draw", description=__doc__.split("\n\n")[0])
    p.add_argument("--case", required=True, choices=tuple(CASES))
    p.add_argument("--noise", type=finite_float, required=True,
                   help="σ of the Gaussian noise per coordinate, a fraction of the "
                   "observation's bounding-box diagonal")
    p.add_argument("--seed", type=nonnegative_int, required=True,
                   help="noise seed (0: the noise-free observation; needs --noise 0)")
    p.add_argument("--flap-spans", type=int, nargs=2, default=[40, 40], metavar=("N1", "N2"),
                   help="spans of the flap observation's grid (multiples of 4)")
    p.add_argument("--case-cache", type=Path, default=None, metavar="FOLDER",
                   help="take the case's solved observation from FOLDER where an earlier "
                   "run stored it, else store it there (a study's OUT/cache)")
    p.add_argument("--out", required=True, help="output directory (new or empty)")
    return p


def case_key(name: str, flap_spans: tuple[int, int]) -> dict:
    """Everything a built case depends on (the module docstring): its cache key."""
    key = {"case": name, "code": code_version(), "precision": "f64",
           "versions": {p: version(p) for p in ("numpy", "scipy", "torch", "taichi")}}
    if name == "flap":
        key["flap_spans"] = list(flap_spans)
    return key


def _optional(value: float | None) -> np.ndarray:
    """A float or None as an array (shape () or (0,))."""
    return np.array([] if value is None else value, dtype=np.float64)


def _from_optional(array: np.ndarray) -> float | None:
    return None if array.size == 0 else float(array)


def build_case(name: str, flap_spans: tuple[int, int], folder: Path | None = None) -> Case:
    """The case `name` (flap on `flap_spans`); with `folder`, its solved observation from
    the cache there if stored, else solved and stored."""
    builder = functools.partial(CASES[name], flap_spans) if name == "flap" else CASES[name]
    if folder is None:
        return builder()
    key = case_key(name, flap_spans)
    stored = cache.load(folder, name, key)
    if stored is not None:
        return builder(solved=(torch.from_numpy(stored["points"]),
                               _from_optional(stored["order"]),
                               _from_optional(stored["error"])))
    case = builder()
    points, order, error = case.solved()
    cache.store(folder, name, key, {"points": points.detach().numpy(),
                                    "order": _optional(order), "error": _optional(error)})
    return case


def _finite(values) -> list:
    """Numbers for JSON: a non-finite one (an undetermined unknown's error) as null."""
    return [finite_or_none(float(v)) for v in values]


@interruptible("calibration_draw")
def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if (args.seed == 0) != (args.noise == 0):
        print("calibration_draw: error: --seed 0 is the noise-free fit and needs --noise 0; "
              "a noisy fit needs --seed >= 1", file=sys.stderr)
        return 2
    if any(n < 4 or n % 4 for n in args.flap_spans):
        print(f"calibration_draw: error: --flap-spans must be positive multiples of 4, got "
              f"{args.flap_spans}", file=sys.stderr)
        return 2
    if args.noise < 0:
        print(f"calibration_draw: error: --noise must be >= 0, got {args.noise}",
              file=sys.stderr)
        return 2
    torch.set_num_threads(1)
    taichi_ndf.init(arch="cpu", precision="f64", seed=0)
    logging.basicConfig(level=logging.WARNING)
    case = build_case(args.case, tuple(args.flap_spans), args.case_cache)
    draw = fit_draw(case, newton_fit, args.noise, args.seed)
    with staged_run(args.out) as out:
        out.write_json("draw.json", {
            "case": case.name, "noise": args.noise, "seed": draw.seed,
            "unknowns": [u.name for u in case.unknowns], "truth": case.truth.tolist(),
            "value": _finite(draw.values), "standard_error": _finite(draw.errors),
            "fisher": _finite(draw.fisher), "discretisation": _finite(draw.model_part),
            "seconds": draw.seconds, "cpu_seconds": draw.cpu_seconds,
            "observation_error_m": case.observation_error,
            "observation_order": case.observation_order})
    print(f"{case.name} noise {args.noise:g} seed {args.seed}: {draw.values.tolist()} ± "
          f"{draw.errors.tolist()} ({draw.seconds:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
