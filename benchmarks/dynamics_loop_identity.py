"""Before/after of `TimeStepper.run` on the shipped dynamic scenes at a short duration: the
final coefficients' SHA-256 (16 hex digits), the steps, Newton iterations and substeps per
step, T + Π per step and the frame times, with the CPU (user + sys) and wall seconds of each
run, written as JSON to argv[1]; argv[2] "adaptive" (AdaptiveStep(2 dt, 6, 1)) or "halve"
(Newton capped at 4 iterations per step, so steps are halved) varies the run. Run it with
PYTHONPATH at each commit to compare (benchmarks/RESULTS.md, "One solve stack: the dynamics
time loop in the continuation loop")."""

import dataclasses
import hashlib
import json
import resource
import sys
import time

import taichi_ndf

taichi_ndf.init(arch="cpu", precision="f64", seed=0)
from pathlib import Path  # noqa: E402

from taichi_ndf.app.dynamics import _dtype  # noqa: E402
from taichi_ndf.problem.dynamics import AdaptiveStep  # noqa: E402
from taichi_ndf.scene.reader import load_scene  # noqa: E402
from taichi_ndf.solve.dynamics import DynamicsError, TimeStepper  # noqa: E402
from taichi_ndf.solve.spline_solver import newton_config  # noqa: E402

SCENES = Path(__file__).resolve().parents[1] / "scenes"
MODE = sys.argv[2] if len(sys.argv) > 2 else ""
DUR = {"napkin_drop_sphere": 0.2, "cloth_pendulum": 0.08, "sheet_slide_box": 0.08,
       "flag_wind": 0.08}
out = {}
for name, d in DUR.items():
    scene = load_scene(SCENES / f"{name}.toml")
    cfg = dataclasses.replace(scene.dynamics, duration=d, adaptive=AdaptiveStep(
        2 * scene.dynamics.dt, 6, 1) if MODE == "adaptive" else scene.dynamics.adaptive)
    newton = newton_config(scene.solver, _dtype())
    if MODE == "halve":
        newton = dataclasses.replace(newton, max_iterations=4)
    r0, w0 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
    try:
        tr = TimeStepper(scene.model, scene.field, cfg, newton=newton).run()
    except DynamicsError as err:  # the same error before and after is the same behaviour
        out[name] = {"error": str(err)}
        print(name, err, flush=True)
        continue
    r1 = resource.getrusage(resource.RUSAGE_SELF)
    c = tr.field.coefficients.detach().contiguous().cpu().numpy()
    out[name] = {"sizes": [r.size for r in tr.records], "steps": len(tr.records),
                 "sha": hashlib.sha256(c.tobytes()).hexdigest()[:16],
                 "iterations": [r.newton_iterations for r in tr.records],
                 "substeps": [r.substeps for r in tr.records],
                 "totals": [r.total for r in tr.records], "frames": [t for t, _ in tr.frames],
                 "cpu": r1.ru_utime + r1.ru_stime - r0.ru_utime - r0.ru_stime,
                 "wall": time.perf_counter() - w0}
    print(name, out[name]["sha"], out[name]["steps"], sum(out[name]["iterations"]),
          out[name]["substeps"], f'{out[name]["cpu"]:.1f} {out[name]["wall"]:.1f}', flush=True)
json.dump(out, open(sys.argv[1], "w"))
