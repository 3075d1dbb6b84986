"""Is a wrong-model material fit flagged? (issue 35)

The cantilever strip (scenes/inverse/cantilever_strip.toml, a known tip load, B unknown)
observed from the right model's equilibrium (quartic 20 × 4 grid, 41 × 9 points, noise
0.2 % of its size per coordinate), fitted by `newton_estimate` on the right scene and on three
deliberately wrong ones: the clamp tilted 15°, a 1.5× thickness (E and ρ known), gravity with
a sideways 0.5 g. Prints per scene the goodness-of-fit statement (residual rms against the
estimated noise and the forward model's error, χ²/dof, p-value) and what the estimate says of
B. The scenes and the fit are the slow tests' (tests/test_inverse_material_goodness.py), run
here for their figures. About 5 minutes of CPU.

    nice python benchmarks/wrong_model_fits.py [--json benchmarks/wrong_model_fits.json]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch

import taichi_ndf
from tests.test_inverse_material_goodness import B_TRUE, fit_strip, observed_strip

SCENES = {"right model": {}, "clamp tilted 15°": {"tilt_degrees": 15.0},
          "1.5× thickness": {"thickness_factor": 1.5}, "sideways 0.5 g": {"sideways_g": 0.5}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    torch.set_num_threads(1)
    taichi_ndf.init(arch="cpu", precision="f64", seed=0)  # as the tests (conftest.py)
    observed = observed_strip()
    rows = []
    for name, wrong in SCENES.items():
        started, cpu = time.perf_counter(), time.process_time()
        result, fit, document = fit_strip(observed, **wrong)
        entry = document["parameters"]["bending_stiffness"]
        rows.append({"scene": name, "wrong": wrong, **fit.to_dict(),
                     "status": entry.get("status"), "determined": entry.get("determined"),
                     "value": entry.get("value"), "standard_error": entry.get("standard_error"),
                     "true_value": B_TRUE,
                     "solves_converged": all(f.solves_converged for f in result.fits),
                     "wall": time.perf_counter() - started, "cpu": time.process_time() - cpu})
        print(json.dumps(rows[-1], default=float), flush=True)
        if args.json:
            args.json.write_text(json.dumps(rows, indent=1, default=float))
    print("| scene | residual rms [mm] | noise [mm] | forward-model error [mm] | χ²/dof (dof) | "
          f"p | verdict | B [N·m] (true {B_TRUE:.6g}) | wall / CPU [s] |")
    print("|" + "---|" * 9)
    for r in rows:
        b = (f"{r['value']:.6g} ± {r['standard_error']:.2g}" if r["value"] is not None
             else f"not given ({r['status']})")
        print(f"| {r['scene']} | {1e3 * r['residual_rms_m']:.3g} | {1e3 * r['noise_m']:.3g} | "
              f"{1e3 * r['forward_model_error_m']:.2g} | {r['chi2_per_dof']:.3g} ({r['dof']}) | "
              f"{r['p_value']:.2g} | {'explains' if r['explains_data'] else 'does not explain'}"
              f" | {b} | {r['wall']:.0f} / {r['cpu']:.0f} |")


if __name__ == "__main__":
    main()
