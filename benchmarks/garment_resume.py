"""A garment run interrupted and resumed through ndf-sim equals the run that went through, and
ndf-export writes it from its checkpoint (issue 30: checkpoints for several patches).

scenes/skirt_panels.toml (two panels, 16 × 8 spans each, load steps 0.5, 1), run as a user runs
it, each in a child process:
- whole: `ndf-sim skirt_panels.toml --out W`;
- interrupted: the same into I, sent SIGINT (Ctrl-C) once I.incomplete/checkpoint.pt exists
  (written after load step 1), then `ndf-sim ... --out I --resume`;
- export: `ndf-export W --out W/export.obj --resolution 64 32` (the scene's output grid).
Prints per process its exit code, CPU (user + sys) and wall seconds; then whether the resumed
run's meshes and probes are byte-identical to the whole run's, Π of both, and the export's
objects against the run's mesh_<panel>.obj (vertex counts, largest position difference [m]);
load average and commit.

    PYTHONPATH=$PWD OMP_NUM_THREADS=1 python benchmarks/garment_resume.py [OUT_DIR]
"""

from __future__ import annotations

import json
import os
import resource
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from provenance import commit  # noqa: E402

SCENE = ROOT / "scenes" / "skirt_panels.toml"
COMPARED = ("mesh.obj", "mesh.ply", "mesh_front.obj", "mesh_front.ply", "mesh_back.obj",
            "mesh_back.ply", "reference.obj", "probes.json")


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _run(args: list[str], *, interrupt_when: Path | None = None) -> tuple[int, float, float]:
    """Run `python -m <args>`; with interrupt_when, SIGINT once that file exists. Returns the
    exit code, CPU and wall seconds."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    cpu, wall = _children_cpu(), time.perf_counter()
    process = subprocess.Popen([sys.executable, "-m", *args], env=env,
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    if interrupt_when is not None:
        while process.poll() is None and not interrupt_when.exists():
            time.sleep(0.05)
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
    _, err = process.communicate()
    if process.returncode not in (0, 130):
        raise RuntimeError(f"{args}: exit {process.returncode}: {err.strip()[-500:]}")
    return process.returncode, _children_cpu() - cpu, time.perf_counter() - wall


def _vertices(path: Path) -> list[np.ndarray]:
    """The vertex blocks of an OBJ's objects (`o name` then its `v` lines), in order."""
    blocks: list[list[list[float]]] = []
    for line in path.read_text().splitlines():
        if line.startswith("o "):
            blocks.append([])
        elif line.startswith("v "):
            if not blocks:
                blocks.append([])
            blocks[-1].append([float(v) for v in line.split()[1:4]])
    return [np.array(b) for b in blocks]


def main() -> None:
    base = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(tempfile.mkdtemp(prefix="resume_"))
    whole, interrupted = base / "whole", base / "interrupted"
    sim = ["taichi_ndf.cli.sim", str(SCENE)]
    rows = [("ndf-sim (whole)", *_run([*sim, "--out", str(whole)]))]
    staged = interrupted.with_name(interrupted.name + ".incomplete") / "checkpoint.pt"
    rows.append(("ndf-sim, Ctrl-C after load step 1",
                 *_run([*sim, "--out", str(interrupted)], interrupt_when=staged)))
    rows.append(("ndf-sim --resume", *_run([*sim, "--out", str(interrupted), "--resume"])))
    export = whole / "export.obj"
    rows.append(("ndf-export W --out export.obj",
                 *_run(["taichi_ndf.cli.export", str(whole), "--out", str(export),
                        "--resolution", "64", "32"])))
    print("| process | exit | CPU [s] | wall [s] |\n|---|---|---|---|")
    for name, code, cpu, wall in rows:
        print(f"| {name} | {code} | {cpu:.1f} | {wall:.1f} |")
    same = {n: (whole / n).read_bytes() == (interrupted / n).read_bytes() for n in COMPARED}
    energy = [json.loads((d / "result.json").read_text())["energy"]
              for d in (whole, interrupted)]
    print(f"\nresumed run's files byte-identical to the whole run's: {same}")
    print(f"Π whole {energy[0]!r} J, resumed {energy[1]!r} J, equal: {energy[0] == energy[1]}")
    for name, block in zip(("front", "back"), _vertices(export), strict=True):
        run = _vertices(whole / f"mesh_{name}.obj")[0]
        difference = float(np.abs(block - run).max()) if block.shape == run.shape else None
        print(f"export object {name}: {len(block)} vertices (run's mesh_{name}.obj: "
              f"{len(run)}), largest position difference {difference} m")
    print(f"\nload average {os.getloadavg()[0]:.2f}, commit {commit()}")


if __name__ == "__main__":
    main()
