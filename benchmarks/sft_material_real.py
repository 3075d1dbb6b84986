"""The material of a real captured sheet (φ-SfT's R1) from its reconstructed video.

    python benchmarks/sft_material_real.py --data /path/to/phi_sft_r1 --run DIR
        [--held 0 992] [--quasi-static G] [--frames 8] [--spans N1 N2] [--json OUT]

DIR holds an `ndf-sft --capture DATA --out DIR` run (its meshes/); without DIR/meshes the
reconstruction is run first as a child process (default settings) and timed. The estimate is
`material_from_video.estimate_material` on those meshes with every default of
`ndf-sft --estimate-material` but the options given (frame 0's mesh, the template, as `rest`,
as `ndf-sft` passes it). The data stays outside the repository.

Printed (benchmarks/RESULTS.md, Material from video): B ± s.e. at the stated areal density
(R1's is not stated in its README: the default, the median of measured fabrics, and B for the
5th–95th percentile of measured areal densities, B ∝ ρ_A), the bending length
c = (B / (ρ_A g))^(1/3) (independent of ρ_A: what the shapes determine) and where it falls
among measured fabrics, D and whether it is determined, and per used frame the sheet's
acceleration, the fit's rms misfit and the reconstruction's own error — the rms distance of its
vertices to the nearest point of that frame's Kinect cloud — so that the misfit can be judged
against what the reconstruction itself is off by. CPU s (user + sys of this process, the
estimate alone) and wall s, the load average before and after.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch

import taichi_ndf
from inverse.sft.material_from_video import MaterialFromVideoConfig, estimate_material
from inverse.sft.settings import FABRIC_AREAL_DENSITY
from taichi_ndf.io import read_mesh


def cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def reconstruct(data: Path, run: Path) -> str:
    """Run the default `ndf-sft --capture` into `run`; its CPU and wall seconds as text."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "inverse.cli.sft", "--capture", str(data),
                    "--out", str(run)], check=True)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    seconds = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return f"reconstruction: {seconds:.0f} s CPU, {time.perf_counter() - t0:.0f} s wall"


def cloud_error(vertices: np.ndarray, cloud: np.ndarray) -> float:
    """rms distance [m] of the vertices to their nearest cloud point."""
    from scipy.spatial import cKDTree

    distance, _ = cKDTree(cloud).query(vertices)
    return float(np.sqrt(np.mean(distance ** 2)))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--data", type=Path, required=True)
    p.add_argument("--run", type=Path, required=True)
    p.add_argument("--held", type=int, nargs=2, default=(0, 992))
    p.add_argument("--quasi-static", type=float, default=None)
    p.add_argument("--frames", type=int, default=None)
    p.add_argument("--spans", type=int, nargs=2, default=None)
    p.add_argument("--json", type=Path, default=None)
    args = p.parse_args()
    if not (args.data / "ground_truth").is_dir():
        sys.exit(f"--data {args.data}: no ground_truth/ folder (the R1 layout)")
    print(f"load average before: {os.getloadavg()}")
    if not (args.run / "meshes").is_dir():
        print(reconstruct(args.data, args.run))
    torch.set_num_threads(1)
    taichi_ndf.init(arch="cpu", precision="f64")
    files = sorted((args.run / "meshes").glob("*.obj"))
    vertices = [np.asarray(read_mesh(f).vertices, dtype=np.float64) for f in files]
    faces = np.asarray(read_mesh(files[0]).faces)
    options = {"quasi_static_limit": args.quasi_static}
    if args.frames is not None:
        options["frames"] = args.frames
    if args.spans is not None:
        options["spans"] = tuple(args.spans)
    config = MaterialFromVideoConfig(**options)
    print(f"{len(vertices)} frames of {len(vertices[0])} vertices; {config}")
    t0, c0 = time.perf_counter(), cpu()
    material = estimate_material(vertices, faces, tuple(args.held), config, rest=vertices[0])
    seconds, cpu_seconds = time.perf_counter() - t0, cpu() - c0
    if args.json:
        args.json.write_text(json.dumps(material, indent=1, default=str))
    print(table(material, vertices, args.data, config))
    print(f"estimate: {cpu_seconds:.0f} s CPU (user + sys), {seconds:.0f} s wall; load average "
          f"after: {os.getloadavg()}")


def table(material: dict, vertices: list[np.ndarray], data: Path,
          config: MaterialFromVideoConfig) -> str:
    b, c = material["bending_stiffness"], material["bending_length"]
    d = material["membrane_stiffness"]
    fit = material["goodness_of_fit"]
    choice = material["frame_choice"]
    accel = choice["sheet_acceleration_over_g"]
    lines = [f"frames used: {material['frames_used']} ({choice['note']})",
             f"sheet size {material['sheet_size_m']} m (from: {material['sheet_size_from']}); "
             f"grids {[g['spans'] for g in material['grids']]}: B "
             f"{[round(g['bending_stiffness'], 9) for g in material['grids']]}",
             "", "| frame | sheet acceleration / g | fit's rms misfit [mm] | reconstruction's "
             "rms distance to the cloud [mm] | misfit / reconstruction error |",
             "|---|---|---|---|---|"]
    for frame, misfit in zip(material["frames_used"], fit["per_frame_rms_m"], strict=True):
        cloud = np.load(data / "ground_truth" / f"point_cloud_{frame:03d}.npy")
        error = cloud_error(vertices[frame], cloud.astype(np.float64))
        a = "" if accel is None else f"{accel[frame]:.3f}"
        lines.append(f"| {frame} | {a} | {1e3 * misfit:.2f} | {1e3 * error:.2f} | "
                     f"{misfit / error:.1f} |")
    lines.append("")
    if b["value"] is None or c is None:
        lines.append(f"B undetermined (rms misfit {1e3 * fit['rms_m']:.2f} mm); grids: "
                     f"{[g['bending_stiffness'] for g in material['grids']]}")
    else:
        low, _, high = FABRIC_AREAL_DENSITY
        scale = b["value"] / b["at_areal_density"]
        lines += [
            f"B = {b['value']:.4g} ± {b['standard_error']:.2g} N·m at the stated ρ_A = "
            f"{b['at_areal_density']:g} kg/m² (R1's areal density is not stated; B ∝ ρ_A: "
            f"{scale * low:.3g} – {scale * high:.3g} N·m for ρ_A = {low:g} – {high:g} kg/m², "
            f"the 5th–95th percentile of measured fabrics)",
            f"bending length c = {100 * c['value']:.3f} ± {100 * c['standard_error']:.3f} cm "
            f"(independent of ρ_A): {material['fabric_percentile']}",
            f"s.e. parts of B: {material['bending_stiffness'].get('standard_error_parts')}"]
    dd = ("held" if d["held"] else f"{d['value']} ± {d['standard_error']} N/m, determined: "
          f"{d.get('determined')}")
    lines += [f"D: {dd}", f"identifiability: {material['identifiability']}",
              f"identifiability (Fisher): {material['estimate'].get('identifiability')}",
              f"rms misfit {1e3 * fit['rms_m']:.2f} mm; corners' largest acceleration "
              f"{material['quasi_static']['largest_corner_acceleration_over_g']:.3f} g; "
              f"converged {material['converged']}, stable {material['stable']}",
              f"notes: {material['estimate'].get('notes')}"]
    return "\n".join(lines)


if __name__ == "__main__":
    main()
