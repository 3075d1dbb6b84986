"""Time to solution of the forward solver: wall time until Π is within 1 % of its converged
value, and peak memory, for the napkin (scenes/napkin.toml: pinned corner, gravity, default
cloth) and the sleeve (scenes/sleeve_compression.toml).

    python benchmarks/time_to_solution.py [--cases napkin sleeve] [--reference-factor 3]
                                          [--threads 2]

"Converged" is a reference run of the same scene with `reference-factor` times as many
iterations per load step. Both runs monitor Π on the same fixed sample set (the solver seeds
it from the scene's seed), so their energies are comparable. Each run is a fresh subprocess,
so the peak resident memory (getrusage) is that run's own; `--threads` sets its torch CPU
threads (the scene run and the reference alike). Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import platform
import resource
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CASES = {
    "napkin": ROOT / "scenes" / "napkin.toml",
    "sleeve": ROOT / "scenes" / "sleeve_compression.toml",
}
TOLERANCE = 0.01  # relative distance to the converged Π


def solve(scene_path: Path, iteration_factor: float, precision: str, monitor_every: int,
          threads: int) -> dict:
    """One run in this process with `threads` torch threads; returns its monitor history and
    peak memory."""
    import torch

    import taichi_ndf

    torch.set_num_threads(threads)

    taichi_ndf.init(arch="cpu", precision=precision, seed=0)
    from taichi_ndf.field import NeuralField
    from taichi_ndf.minimise.callbacks import DivergenceGuard
    from taichi_ndf.scene.reader import load_scene
    from taichi_ndf.solve.solver import Solver

    scene = load_scene(scene_path)
    config = scene.solver.with_iterations(round(scene.solver.iterations * iteration_factor))
    config = dataclasses.replace(
        config, monitor_every=monitor_every, progress=False, checkpoint_every=0
    )
    field = NeuralField(scene.field, seed=config.seed)
    result = Solver(scene.model, field, config).run(callbacks=[DivergenceGuard()])
    return {
        "energy": result.energy,
        "iterations": result.iterations,
        "wall_time": result.wall_time,
        "history": [(h.iteration, h.load_factor, h.energy, h.wall_time) for h in result.history],
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }


def run_subprocess(case: str, factor: float, precision: str, monitor_every: int,
                   threads: int) -> dict:
    command = [
        sys.executable,
        __file__,
        "--one",
        case,
        "--factor",
        str(factor),
        "--precision",
        precision,
        "--monitor-every",
        str(monitor_every),
        "--threads",
        str(threads),
    ]
    out = subprocess.run(command, check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def time_to_tolerance(history, reference: float) -> tuple[float | None, int | None]:
    """First monitor point of the last load step from which Π stays within the tolerance."""
    last = [h for h in history if h[1] == history[-1][1]]
    hit = None
    for iteration, _, energy, wall in last:
        if abs(energy - reference) <= TOLERANCE * abs(reference):
            hit = hit or (wall, iteration)
        else:
            hit = None
    return hit if hit else (None, None)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    p.add_argument(
        "--reference-factor",
        type=float,
        default=3.0,
        help="iterations of the reference run / the scene's (default 3)",
    )
    p.add_argument("--precision", default="f32", choices=("f32", "f64"))
    p.add_argument("--monitor-every", type=int, default=25)
    p.add_argument("--threads", type=int, default=1,
                   help="torch CPU threads of each run (default 1)")
    p.add_argument("--one", choices=list(CASES), help=argparse.SUPPRESS)
    p.add_argument("--factor", type=float, default=1.0, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.one:
        print(json.dumps(solve(CASES[args.one], args.factor, args.precision, args.monitor_every,
                               args.threads)))
        return 0

    print(
        f"machine: {platform.processor() or platform.machine()}, "
        f"{args.threads} torch thread(s), precision {args.precision}"
    )
    print(
        "| scene | iterations (scene) | Π converged [J] | Π at end of scene run [J] | "
        "time to 1 % [s] | scene run [s] | peak memory [MB] |"
    )
    print("|---|---|---|---|---|---|---|")
    for case in args.cases:
        run = run_subprocess(case, 1.0, args.precision, args.monitor_every, args.threads)
        reference = run_subprocess(case, args.reference_factor, args.precision,
                                   args.monitor_every, args.threads)
        wall, iteration = time_to_tolerance(run["history"], reference["energy"])
        reached = f"{wall:.1f} (iteration {iteration})" if wall is not None else "not reached"
        print(
            f"| {case} | {run['iterations']} | {reference['energy']:.6g} "
            f"({reference['iterations']} it.) | {run['energy']:.6g} | {reached} | "
            f"{run['wall_time']:.1f} | {run['peak_rss_mb']:.0f} |",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
