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
        [--noise 0.005 0.02] [--draws 20] [--flap-spans 40 40] [--json out.json]

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
from inverse.material.calibration import CASES, Calibration, calibrate, newton_fit


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
                       "standard_error": float(d.errors[j]), "fisher": float(d.fisher[j]),
                       "discretisation": float(d.model_part[j]), "seconds": d.seconds,
                       "cpu_seconds": d.cpu_seconds} for d in cal.draws],
            "mean_s": float(np.mean(seconds)), "max_s": float(np.max(seconds)),
            "mean_cpu_s": float(np.mean(cpu)), "max_cpu_s": float(np.max(cpu))})
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--cases", default="strip,flap,point_load")
    p.add_argument("--noise", type=float, nargs="+", default=[0.005, 0.02])
    p.add_argument("--draws", type=int, default=20)
    p.add_argument("--json", default=None)
    p.add_argument("--flap-spans", type=int, nargs=2, default=[40, 40], metavar=("N1", "N2"),
                   help="spans of the flap observation's quartic grid (each divisible by 4: "
                        "the Richardson check solves 1/4 and 1/2 of them too)")
    args = p.parse_args()
    unknown = [n for n in args.cases.split(",") if n not in CASES]
    if unknown:
        p.error(f"unknown case(s) {unknown}; choose from {', '.join(CASES)}")
    if any(n < 4 or n % 4 for n in args.flap_spans):
        p.error(f"--flap-spans must be positive multiples of 4, got {args.flap_spans}")
    torch.set_num_threads(1)
    taichi_ndf.init(arch="cpu", precision="f64", seed=0)
    logging.basicConfig(level=logging.WARNING)
    logging.getLogger("inverse.material.calibration").setLevel(logging.INFO)  # one line a fit
    results = []
    print(f"load average at start: {os.getloadavg()}")
    header = ("case", "unknown", "noise", "fits (determined)", "truth", "mean est.",
              "mean err %", "rms err %", "mean s.e. (determined)", "(Fisher; disc.)",
              "coverage (of determined)", "wall s/fit (max)",
              "CPU s/fit (max)")
    print(" | ".join(header))
    for name in args.cases.split(","):
        started = time.perf_counter()
        case = CASES[name](tuple(args.flap_spans)) if name == "flap" else CASES[name]()
        accuracy = "" if case.observation_error is None else (
            f"; Richardson: order {case.observation_order:.2f}, largest position error "
            f"{case.observation_error:.3g} m")
        print(f"# {name}: observation from {case.source} ({time.perf_counter() - started:.1f} s"
              f"{accuracy})")
        names = [u.name for u in case.unknowns]
        for noise in [0.0, *args.noise]:
            cal = calibrate(case, newton_fit, noise, args.draws)
            for r in rows(cal, names):
                r["observation_error_m"] = case.observation_error
                r["observation_order"] = case.observation_order
                results.append(r)
                print(f"{r['case']} | {r['unknown']} | {100 * r['noise']:g} % | {r['fits']} "
                      f"({r['determined']}) | "
                      f"{r['truth']:.5g} | {r['mean_estimate']:.6g} | "
                      f"{r['mean_error_pct']:+.3f} | {r['rms_error_pct']:.3f} | "
                      f"{r['mean_se']:.3g} | ({r['mean_fisher']:.2g}; "
                      f"{r['mean_discretisation']:.2g}) | {100 * r['coverage_2se']:.0f} % | "
                      f"{r['mean_s']:.1f} ({r['max_s']:.1f}) | "
                      f"{r['mean_cpu_s']:.1f} ({r['max_cpu_s']:.1f})", flush=True)
            if args.json:  # after every noise level: a long study keeps what it finished
                with open(args.json, "w") as f:
                    json.dump(results, f, indent=2)
    print(f"load average at end: {os.getloadavg()}")


if __name__ == "__main__":
    main()
