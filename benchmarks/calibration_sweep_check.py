"""The calibration study run by ndf-sweep against benchmarks/material_calibration.py: per case,
noise level and unknown the summary of the sweep's fits (fits and how many determine the
unknown, mean and rms relative error, coverage of 2 s.e., as the script computes them:
`inverse.material.calibration.Calibration`) beside the script's, and the largest relative
difference between the two in any fit's estimate and reported standard error; with --fits,
every fit.

    python benchmarks/material_calibration.py --json S.json        # the whole study, 123 fits
    ndf-sweep benchmarks/material_calibration.toml --out OUT --workers 2
    python benchmarks/calibration_sweep_check.py S.json OUT/results.csv [--fits]

(The strip part alone: `material_calibration.py --cases strip --noise 0.01 --draws 8` against
benchmarks/material_calibration_strip.toml.) Exit code 1 if a sweep run did not finish ok or
a fit of the sweep is not in the script's output; the script's fits that the sweep lacks are
counted (a part of the study, e.g. material_calibration_short.toml, checked against the
whole study's output).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections import defaultdict

import numpy as np

from inverse.material.calibration import Calibration, Draw
from taichi_ndf.sweep.table import read_csv


def _number(text: str) -> float:
    """A table cell as a float; '' is a non-finite value (calibration_draw writes one as null:
    an undetermined unknown's standard error is infinite)."""
    return math.inf if text == "" else float(text)


def relative_difference(a: float, b: float) -> float:
    """|b − a| / |a|; 0 where both are the same (inf and inf, nan and nan too)."""
    if a == b or (math.isnan(a) and math.isnan(b)):
        return 0.0
    return abs(b - a) / abs(a) if a else math.inf


def sweep_calibrations(rows: list[dict]) -> dict[tuple[str, float], tuple[list[str],
                                                                           Calibration]]:
    """The sweep's ok rows as one Calibration per (case, noise), with the unknowns' names."""
    groups = defaultdict(list)
    for row in rows:
        groups[row["case"], float(row["noise"])].append(row)
    out = {}
    for (case, noise), group in groups.items():
        names = [k[len("value_"):] for k in group[0] if k.startswith("value_")
                 and group[0][k] != ""]
        draws = [Draw(int(r["seed"]), *(np.array([_number(r[f"{part}_{n}"]) for n in names])
                                        for part in ("value", "standard_error", "fisher",
                                                     "discretisation")),
                      float(r["fit_s"])) for r in group]
        truth = np.array([float(group[0][f"truth_{n}"]) for n in names])
        out[case, noise] = names, Calibration(case, noise, truth, draws)
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("script_json", help="--json output of benchmarks/material_calibration.py")
    p.add_argument("results_csv", help="results.csv of the ndf-sweep calibration study")
    p.add_argument("--fits", action="store_true", help="also print every fit")
    args = p.parse_args()
    with open(args.script_json) as f:
        summary = {(r["case"], r["unknown"], float(r["noise"])): r for r in json.load(f)}
    script = {(*key, d["seed"]): d for key, r in summary.items() for d in r["draws"]}
    rows = read_csv(args.results_csv)
    bad = [r for r in rows if r["status"] != "ok"]
    for row in bad:
        print(f"{row['point']}: {row['status']}: {row['reason']}")
    calibrations = sweep_calibrations([r for r in rows if r["status"] == "ok"])
    if args.fits:
        print("case | unknown | noise | seed | script estimate | sweep estimate | rel. diff | "
              "script s.e. | sweep s.e. | rel. diff")
    worst: dict[tuple, float] = {}
    seen, extra = set(), 0
    for (case, noise), (names, cal) in calibrations.items():
        for j, name in enumerate(names):
            for d in cal.draws:
                key = (case, name, noise, d.seed)
                theirs = script.get(key)
                if theirs is None:
                    print(f"{key}: in the sweep, not in the script's output")
                    extra += 1
                    continue
                seen.add(key)
                dv = relative_difference(theirs["value"], float(d.values[j]))
                de = relative_difference(theirs["standard_error"], float(d.errors[j]))
                worst[case, name, noise] = max(worst.get((case, name, noise), 0.0), dv, de)
                if args.fits:
                    print(f"{case} | {name} | {noise:g} | {d.seed} | {theirs['value']:.12g} | "
                          f"{d.values[j]:.12g} | {dv:.1e} | {theirs['standard_error']:.6g} | "
                          f"{d.errors[j]:.6g} | {de:.1e}")
    missing = sorted(set(script) - seen)
    print(f"{len(missing)} of the script's {len(script)} (fit, unknown) pairs are not in the "
          "sweep" + (f" (e.g. {missing[0]}): a part of the study" if missing else ""))
    print("case | unknown | noise | fits (determined) | mean error % | rms error % | "
          "coverage of 2 s.e. (determined) | script: mean / rms % , coverage | "
          "largest rel. diff. script vs sweep (estimate, s.e.)")
    for (case, noise), (names, cal) in calibrations.items():
        rel, coverage, determined = cal.relative_errors(), cal.coverage(), cal.determined()
        for j, name in enumerate(names):
            s = summary.get((case, name, noise))
            theirs = ("—" if s is None else f"{s['mean_error_pct']:+.3f} / "
                      f"{s['rms_error_pct']:.3f}, {100 * s['coverage_2se']:.0f} %")
            print(f"{case} | {name} | {100 * noise:g} % | {len(cal.draws)} ({determined[j]}) | "
                  f"{100 * rel[:, j].mean():+.3f} | {100 * np.sqrt((rel[:, j] ** 2).mean()):.3f}"
                  f" | {100 * coverage[j]:.0f} % | {theirs} | "
                  f"{worst.get((case, name, noise), math.nan):.1e}")
    print(f"{len(seen)} (fit, unknown) pairs compared; largest relative difference: "
          f"{max(worst.values(), default=math.nan):.1e}")
    return 1 if bad or extra else 0


if __name__ == "__main__":
    sys.exit(main())
