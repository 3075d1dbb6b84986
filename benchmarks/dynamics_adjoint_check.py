"""Issue 29's adjoint acceptance re-measured (benchmarks/RESULTS.md, "Issue 29 acceptance
audit"): the cases of tests/test_dynamics_adjoint.py (its `check`, and the tip's z at T),
printed as a table: dJ/dB by the adjoint against central differences of whole runs
(δ = 0.01 N·m), float64, with the CPU (user + sys) and wall of the whole script.

    PYTHONPATH=$PWD OMP_NUM_THREADS=1 python benchmarks/dynamics_adjoint_check.py
"""

from __future__ import annotations

import os
import resource
import sys
import time
from pathlib import Path

import torch

import taichi_ndf

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import test_dynamics_adjoint as cases  # noqa: E402  (the test's strip, start and check)

from taichi_ndf import jets  # noqa: E402
from taichi_ndf.minimise.assembly import displacement_at  # noqa: E402
from taichi_ndf.problem.operator import DisplacementOperator  # noqa: E402

TIP = (4.0, 0.5)  # ξ of the strip's tip probe [m]


def cpu_seconds() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def tip_case(integrator: str, bending: float = 100.0, delta: float = 1e-2
             ) -> tuple[float, float]:
    """dw/dB of the tip's z displacement at T: (adjoint, central difference) [m/(N·m)]."""
    tip = torch.tensor([TIP], dtype=torch.float64)

    def probe(stepper, coefficients):
        operator = DisplacementOperator(stepper.field, stepper.model.boundary)
        return displacement_at(operator, tip, coefficients, 1.0)[0, jets.VALUE, 2]

    stepper = cases.stepper(integrator, bending)
    c0, v0 = cases.start(stepper)
    states = cases.record(stepper, c0, v0)
    end = states[-1].displacement.clone().requires_grad_(True)
    (weight,) = torch.autograd.grad(probe(stepper, end), end)
    adjoint = cases.gradient(stepper, states, "bending_stiffness", {len(states) - 1: weight})
    values = [float(probe(other, cases.record(other, c0, v0)[-1].displacement))
              for other in (cases.stepper(integrator, bending + delta),
                            cases.stepper(integrator, bending - delta))]
    return adjoint, (values[0] - values[1]) / (2 * delta)


def main() -> int:
    taichi_ndf.init(arch="cpu", precision="f64", seed=0)
    torch.set_num_threads(1)
    load = os.getloadavg()
    print(f"load average {load[0]:.1f} {load[1]:.1f} {load[2]:.1f}\n")
    cpu0, wall0 = cpu_seconds(), time.perf_counter()
    print("| quantity | integrator | α [1/s] | adjoint dJ/dB | central difference | "
          "adjoint/CD − 1 |")
    print("|---|---|---|---|---|---|")
    for integrator, alpha in (("newmark", 0.0), ("newmark", 0.5), ("implicit_euler", 0.5)):
        adjoint, central = cases.check(integrator, alpha)
        print(f"| Σ⟨W_k, C_k⟩ | {integrator} | {alpha:g} | {adjoint:.12g} | {central:.12g} | "
              f"{adjoint / central - 1:.1e} |", flush=True)
    for integrator in ("newmark", "implicit_euler"):
        adjoint, central = tip_case(integrator)
        print(f"| tip z at T = 0.2 s | {integrator} | 0 | {adjoint:.12g} | {central:.12g} | "
              f"{adjoint / central - 1:.1e} |", flush=True)
    load = os.getloadavg()
    print(f"\nCPU {cpu_seconds() - cpu0:.1f} s, wall {time.perf_counter() - wall0:.1f} s, "
          f"load average at the end {load[0]:.1f} {load[1]:.1f} {load[2]:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
