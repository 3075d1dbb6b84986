"""Calibration of the Newton material estimate's standard errors (issue 18).

For every case of `inverse.material.calibration` (strip: heavy elastica at a tilted clamp;
flap: orthotropic flap; point_load: tip load on the cantilever strip) one noise-free fit and
`--draws` fits per noise level (seeds 1..draws), each by `newton_estimate` with its defaults
(grid rule, cubic, band 2, grids h and h/2). Prints per case, noise level and unknown: the
truth, how many fits determine the unknown, the mean estimate, the mean and rms relative
error, the mean reported standard error of the determined fits (and the mean Fisher and
discretisation parts), the coverage (fraction of the determined fits with
|estimate − truth| ≤ 2 s.e.; target ≥ 90 %), and the mean / largest wall and CPU time per fit.

    python benchmarks/material_calibration.py [--cases strip,flap,point_load]
        [--noise 0.005 0.02] [--draws 20] [--json out.json]

Single-threaded (torch and OpenMP); the machine load (`os.getloadavg`) is printed.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import time

import numpy as np
import torch

import taichi_ndf
from inverse.material.calibration import CASES, Calibration, calibrate
from inverse.material.newton_fit import newton_estimate


def newton(observations, unknowns):
    result = newton_estimate(observations, unknowns)
    e = result.estimate
    return e.values, e.standard_errors, result.fisher_errors, result.discretisation


def rows(cal: Calibration, names: list[str]) -> list[dict]:
    rel = cal.relative_errors()
    coverage, determined = cal.coverage(), cal.determined()
    seconds = [d.seconds for d in cal.draws]
    cpu = [d.cpu_seconds for d in cal.draws]
    out = []
    for j, name in enumerate(names):
        out.append({
            "case": cal.case, "unknown": name, "noise": cal.noise, "fits": len(cal.draws),
            "truth": float(cal.truth[j]),
            "mean_estimate": float(np.mean([d.values[j] for d in cal.draws])),
            "mean_error_pct": 100 * float(rel[:, j].mean()),
            "rms_error_pct": 100 * float(np.sqrt((rel[:, j] ** 2).mean())),
            "determined": int(determined[j]),
            "mean_se": float(np.mean([d.errors[j] for d in cal.draws
                                      if np.isfinite(d.errors[j])] or [np.inf])),
            "mean_fisher": float(np.mean([d.fisher[j] for d in cal.draws])),
            "mean_discretisation": float(np.mean([d.model_part[j] for d in cal.draws])),
            "coverage_2se": float(coverage[j]),
            "draws": [{"seed": d.seed, "value": float(d.values[j]),
                       "standard_error": float(d.errors[j])} for d in cal.draws],
            "mean_s": float(np.mean(seconds)), "max_s": float(np.max(seconds)),
            "mean_cpu_s": float(np.mean(cpu)), "max_cpu_s": float(np.max(cpu))})
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--cases", default="strip,flap,point_load")
    p.add_argument("--noise", type=float, nargs="+", default=[0.005, 0.02])
    p.add_argument("--draws", type=int, default=20)
    p.add_argument("--json", default=None)
    args = p.parse_args()
    torch.set_num_threads(1)
    taichi_ndf.init(arch="cpu", precision="f64", seed=0)
    logging.basicConfig(level=logging.WARNING)
    results = []
    print(f"load average at start: {os.getloadavg()}")
    header = ("case", "unknown", "noise", "fits (determined)", "truth", "mean est.",
              "mean err %", "rms err %", "mean s.e. (determined)", "(Fisher; disc.)",
              "coverage (of determined)", "wall s/fit (max)",
              "CPU s/fit (max)")
    print(" | ".join(header))
    for name in args.cases.split(","):
        started = time.perf_counter()
        case = CASES[name]()
        print(f"# {name}: observation from {case.source} ({time.perf_counter() - started:.1f} s)")
        names = [u.name for u in case.unknowns]
        for noise in [0.0, *args.noise]:
            cal = calibrate(case, newton, noise, args.draws)
            for r in rows(cal, names):
                results.append(r)
                print(f"{r['case']} | {r['unknown']} | {100 * r['noise']:g} % | {r['fits']} "
                      f"({r['determined']}) | "
                      f"{r['truth']:.5g} | {r['mean_estimate']:.6g} | "
                      f"{r['mean_error_pct']:+.3f} | {r['rms_error_pct']:.3f} | "
                      f"{r['mean_se']:.3g} | ({r['mean_fisher']:.2g}; "
                      f"{r['mean_discretisation']:.2g}) | {100 * r['coverage_2se']:.0f} % | "
                      f"{r['mean_s']:.1f} ({r['max_s']:.1f}) | "
                      f"{r['mean_cpu_s']:.1f} ({r['max_cpu_s']:.1f})", flush=True)
    print(f"load average at end: {os.getloadavg()}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(results, f, indent=2)


if __name__ == "__main__":
    main()
