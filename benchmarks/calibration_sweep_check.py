"""The calibration study run by ndf-sweep against benchmarks/material_calibration.py: per fit
(case, noise, seed) the estimate and reported standard error of both and their relative
difference.

    python benchmarks/material_calibration.py --cases strip --noise 0.01 --draws 8 --json S.json
    ndf-sweep benchmarks/material_calibration_strip.toml --out OUT --workers 2
    python benchmarks/calibration_sweep_check.py S.json OUT/results.csv
"""

from __future__ import annotations

import argparse
import json

from taichi_ndf.sweep.table import read_csv


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("script_json", help="--json output of benchmarks/material_calibration.py")
    p.add_argument("results_csv", help="results.csv of the ndf-sweep calibration study")
    args = p.parse_args()
    with open(args.script_json) as f:
        script = {(r["case"], r["unknown"], float(r["noise"]), d["seed"]): d
                  for r in json.load(f) for d in r["draws"]}
    print("case | unknown | noise | seed | script estimate | sweep estimate | rel. diff | "
          "script s.e. | sweep s.e. | rel. diff")
    worst = 0.0
    for row in read_csv(args.results_csv):
        if row["status"] != "ok":
            print(f"{row['point']}: {row['status']}: {row['reason']}")
            continue
        for key in row:
            if not key.startswith("value_"):
                continue
            unknown = key[len("value_"):]
            draw = script.get((row["case"], unknown, float(row["noise"]), int(row["seed"])))
            if draw is None:
                continue
            value, error = float(row[key]), float(row[f"standard_error_{unknown}"])
            dv = abs(value - draw["value"]) / abs(draw["value"])
            de = abs(error - draw["standard_error"]) / abs(draw["standard_error"])
            worst = max(worst, dv, de)
            print(f"{row['case']} | {unknown} | {float(row['noise']):g} | {row['seed']} | "
                  f"{draw['value']:.12g} | {value:.12g} | {dv:.1e} | "
                  f"{draw['standard_error']:.6g} | {error:.6g} | {de:.1e}")
    print(f"largest relative difference: {worst:.1e}")


if __name__ == "__main__":
    main()
