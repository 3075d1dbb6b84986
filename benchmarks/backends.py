"""The two Taichi backends back to back: taichi 1.7.4 and its maintained fork quadrants
(issue 32, `taichi_ndf.runtime`).

Each measurement runs in a fresh process per backend (TAICHI_NDF_BACKEND=...), the backends
interleaved, so a busy neighbour slows both alike; wall and CPU time (user + sys of the
process and its threads) side by side, with the load average before and after.

    steps       compile time: the first SIREN Adam step and the first projected-Newton step
                (napkin) less a steady step, in a process with an empty kernel cache (cold)
                and again with that cache (warm); the steady SIREN step (napkin scene's field,
                128 x 3, 4096 samples) and Newton step (napkin, 16 x 16 cubic spans)
    napkin      the README demo (demos/napkin.py: spline, 8² and 16² spans, Richardson) in f64
    energies    Π in f64 of the napkin (spline, 8² spans; and its SIREN after the steps' Adam
                iterations) and of every validation case (spline path, one grid) on both
                backends, and their relative difference (acceptance: 1e-12)

    OMP_NUM_THREADS=1 nice -n 10 python benchmarks/backends.py [--quick] [--fast-math]
        [--tasks steps napkin energies] [--cases square_plate ...]

Needs both backends in one environment: pip install -e '.[quadrants]' (quadrants 1.3.3 and
taichi 1.7.4 import side by side). --quick: fewer steps, two validation cases, no demo.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
NAPKIN = ROOT / "scenes" / "napkin.toml"
BACKENDS = ("taichi", "quadrants")
TASKS = ("steps", "napkin", "energies")
QUICK_CASES = ("square_plate", "scordelis_lo_roof")


def cpu_seconds() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


class Clock:
    """Wall and CPU seconds since the last `lap`."""

    def __init__(self):
        self.wall, self.cpu = time.perf_counter(), cpu_seconds()

    def lap(self) -> tuple[float, float]:
        wall, cpu = time.perf_counter(), cpu_seconds()
        out = (wall - self.wall, cpu - self.cpu)
        self.wall, self.cpu = wall, cpu
        return out


def _init(precision: str = "f64", fast_math: bool = False) -> dict:
    import torch

    import taichi_ndf

    torch.set_num_threads(1)
    clock = Clock()
    runtime = taichi_ndf.init(arch="cpu", precision=precision, seed=0, fast_math=fast_math)
    wall, cpu = clock.lap()
    return {"backend": taichi_ndf.runtime.machine_description(runtime)["backend"],
            "init_s": wall, "init_cpu_s": cpu}


def napkin_siren(count: int, callbacks=()):
    """`count` Adam iterations of the napkin scene's SIREN (its field and samples) from the
    scene's seed; the `SolveResult` (Π on the monitor samples at the end)."""
    import dataclasses

    from taichi_ndf.field import NeuralField
    from taichi_ndf.scene.reader import load_scene
    from taichi_ndf.solve.output_scale import field_for_run
    from taichi_ndf.solve.solver import Solver

    scene = load_scene(NAPKIN)
    config = dataclasses.replace(scene.solver, iterations=count, progress=False,
                                 monitor_every=count, checkpoint_every=0)
    field = NeuralField(field_for_run(scene.field, scene.output_scale_estimate, scene.model,
                                      config), seed=config.seed)
    return Solver(scene.model, field, config).run(callbacks=callbacks)


def siren_steps(count: int) -> dict:
    """Times of the napkin scene's Adam iterations: the first (compilation included), the
    median of the others."""
    laps = []

    class Timer:
        def on_start(self, solver):
            self.clock = Clock()

        def on_step(self, solver, energy, grad_norm):
            laps.append(self.clock.lap())

    napkin_siren(count, [Timer()])
    return _first_and_steady("siren", laps)


def newton_steps(count: int, spans: int = 16) -> dict:
    """Times of projected-Newton iterations on the napkin (spans × spans cubic, Gauss points,
    from the flat sheet): the first (compilation included), the median of the others."""
    from taichi_ndf.field.spline import SplineConfig, SplineField
    from taichi_ndf.minimise.assembly import Assembly, gauge_unknowns, local_basis_at
    from taichi_ndf.minimise.linearisation import SplineLinearisation
    from taichi_ndf.minimise.newton import NewtonConfig, minimise
    from taichi_ndf.objective import Objective
    from taichi_ndf.problem.operator import DisplacementOperator
    from taichi_ndf.problem.quadrature import span_quadrature
    from taichi_ndf.scene.reader import load_scene

    model = load_scene(NAPKIN).model
    surface = model.surface
    laps = []
    clock = Clock()
    field = SplineField(SplineConfig(spans=(spans, spans), degree=3,
                                     domain=surface.domain.bounds))
    samples = span_quadrature(surface, field.config, model.loads)
    operator = DisplacementOperator(field, model.boundary)
    basis = local_basis_at(operator, samples.xi)
    assembly = Assembly(samples, basis, field.coefficients.shape[0]).at_load(operator, 1.0)

    def on_step(_coefficients) -> bool:
        laps.append(clock.lap())
        return False

    linearisation = SplineLinearisation(assembly, fixed=gauge_unknowns(model.boundary, basis),
                                        length=math.sqrt(surface.domain.rectangle_area))
    minimise(linearisation, Objective.of_model(model).potential(1.0), field.coefficients,
             NewtonConfig(max_iterations=count), on_step=on_step)
    return _first_and_steady("newton", laps)


def _first_and_steady(name: str, laps: list[tuple[float, float]]) -> dict:
    steady = laps[1:]
    return {f"{name}_first_s": laps[0][0], f"{name}_first_cpu_s": laps[0][1],
            f"{name}_step_s": statistics.median(w for w, _ in steady),
            f"{name}_step_cpu_s": statistics.median(c for _, c in steady),
            f"{name}_steps": len(laps)}


def napkin_demo(out: Path) -> dict:
    sys.path.insert(0, str(ROOT / "demos"))
    import napkin

    clock = Clock()
    status = napkin.main(["--out", str(out), "--precision", "f64", "--overwrite"])
    wall, cpu = clock.lap()
    if status != 0:
        raise RuntimeError(f"demos/napkin.py exited {status}")
    result = json.loads((out / "result.json").read_text())
    return {"demo_s": wall, "demo_cpu_s": cpu, "energy": {"napkin demo": result["energy"]}}


def energies(cases: list[str], siren_steps: int) -> dict:
    """Π [J] in f64: the napkin's spline solve on one grid (8² spans), `siren_steps` Adam
    iterations of its SIREN, and each validation case's spline solve on one grid."""
    import dataclasses

    from taichi_ndf.scene.reader import load_scene
    from taichi_ndf.solve.spline_solver import solve_spline
    from taichi_ndf.validation import CASES, load_case_scene
    from taichi_ndf.validation.runner import _objective

    out = {}
    scene = load_scene(NAPKIN, field="spline")
    plan = dataclasses.replace(scene.field, levels=1)
    config = dataclasses.replace(scene.solver, progress=False)
    out["napkin 8x8"] = solve_spline(scene.model, plan, config).levels[-1].energy
    out[f"napkin SIREN, {siren_steps} Adam steps"] = napkin_siren(siren_steps).energy
    for name in cases:
        case = CASES[name]
        case_scene, model, plan = load_case_scene(case, field="spline")
        config = dataclasses.replace(case_scene.solver, progress=False)
        run = solve_spline(model, dataclasses.replace(plan, levels=1), config,
                           objective=_objective(case, model))
        out[name] = run.levels[-1].energy
    return {"energy": out}


def child(args: argparse.Namespace) -> None:
    result = _init(fast_math=args.fast_math)
    if args.child == "steps":
        result |= siren_steps(args.siren_steps)
        result |= newton_steps(args.newton_steps)
    elif args.child == "napkin":
        with tempfile.TemporaryDirectory() as work:
            result |= napkin_demo(Path(work) / "napkin")
    else:
        result |= energies(args.cases, args.siren_steps)
    print(json.dumps(result))


def run_child(task: str, backend: str, cache: str, args: argparse.Namespace) -> dict:
    command = [sys.executable, __file__, "--child", task, "--siren-steps", str(args.siren_steps),
               "--newton-steps", str(args.newton_steps), "--cases", *args.cases,
               *(["--fast-math"] if args.fast_math else [])]
    env = {**os.environ, "TAICHI_NDF_BACKEND": backend, "TAICHI_NDF_CACHE": cache,
           "OMP_NUM_THREADS": "1",
           "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    load = os.getloadavg()[0]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise RuntimeError(f"{task} on {backend} failed:\n{done.stderr[-3000:]}")
    result = json.loads(done.stdout.strip().splitlines()[-1])
    result |= {"process_s": wall, "process_cpu_s": (after.ru_utime - before.ru_utime)
               + (after.ru_stime - before.ru_stime),
               "load": (load, os.getloadavg()[0])}
    return result


def row(*cells) -> str:
    return "| " + " | ".join(str(c) for c in cells) + " |"


def pair(r: dict, key: str) -> str:
    return f"{r[key + '_s']:.2f} / {r[key + '_cpu_s']:.2f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", choices=TASKS, default=list(TASKS))
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--backends", nargs=2, choices=BACKENDS, default=list(BACKENDS),
                        help="the order in which each measurement runs them (default: %(default)s)")
    parser.add_argument("--cases", nargs="*", default=None,
                        help="validation cases of the energies task (default: all; --quick: "
                        f"{', '.join(QUICK_CASES)})")
    parser.add_argument("--fast-math", action="store_true",
                        help="both backends with the compiler's fast math on (taichi_ndf.init's "
                        "fast_math; off by default)")
    parser.add_argument("--siren-steps", type=int, default=None)
    parser.add_argument("--newton-steps", type=int, default=None)
    parser.add_argument("--child", choices=TASKS, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.cases is None:
        from taichi_ndf.validation import CASES  # no Taichi import

        args.cases = list(QUICK_CASES if args.quick else CASES)
    args.siren_steps = args.siren_steps or (4 if args.quick else 11)
    args.newton_steps = args.newton_steps or (3 if args.quick else 6)
    if args.child:
        child(args)
        return
    if args.quick:
        args.tasks = [t for t in args.tasks if t != "napkin"]
    print(f"machine: {os.cpu_count()} CPUs, Python {sys.version.split()[0]}; fast math "
          f"{'on' if args.fast_math else 'off'}; wall / CPU seconds; load = 1-minute load "
          "average before / after each process\n")
    with tempfile.TemporaryDirectory() as work:
        backends = args.backends
        caches = {b: str(Path(work) / b) for b in backends}
        if "steps" in args.tasks:
            runs = {(b, state): run_child("steps", b, caches[b], args)
                    for state in ("cold", "warm") for b in backends}
            print(row("backend", "cache", "init", "first SIREN step", "SIREN step",
                      "first Newton step", "Newton step", "compile (first − steady)",
                      "process", "load"))
            print(row(*["---"] * 10))
            for (_, state), r in runs.items():
                compile_s, compile_cpu_s = (
                    r[f"siren_first{k}"] - r[f"siren_step{k}"]
                    + r[f"newton_first{k}"] - r[f"newton_step{k}"] for k in ("_s", "_cpu_s"))
                print(row(r["backend"], state, pair(r, "init"), pair(r, "siren_first"),
                          pair(r, "siren_step"), pair(r, "newton_first"),
                          pair(r, "newton_step"), f"{compile_s:.2f} / {compile_cpu_s:.2f}",
                          pair(r, "process"),
                          "{:.1f} / {:.1f}".format(*r["load"])))
            print()
        results = {}
        for task in [t for t in ("napkin", "energies") if t in args.tasks]:
            for b in backends:  # warm caches from the steps task where it ran
                results.setdefault(b, {}).setdefault("energy", {})
                r = run_child(task, b, caches[b], args)
                results[b]["energy"] |= r.pop("energy")
                results[b][task] = r
        if "napkin" in args.tasks:
            print(row("backend", "napkin demo (f64)", "process", "load"))
            print(row(*["---"] * 4))
            for b in backends:
                r = results[b]["napkin"]
                print(row(r["backend"], pair(r, "demo"), pair(r, "process"),
                          "{:.1f} / {:.1f}".format(*r["load"])))
            print()
        if results:
            print(row("Π [J], f64", *BACKENDS, "relative difference"))
            print(row(*["---"] * 4))
            worst = 0.0
            for name, a in results[BACKENDS[0]]["energy"].items():
                b = results[BACKENDS[1]]["energy"][name]
                difference = abs(a - b) / abs(a)
                worst = max(worst, difference)
                print(row(name, f"{a:.16g}", f"{b:.16g}", f"{difference:.1e}"))
            print(f"\nlargest relative difference of Π: {worst:.1e} (acceptance 1e-12)")


if __name__ == "__main__":
    main()
