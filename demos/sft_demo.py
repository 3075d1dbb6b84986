"""Shape-from-template demo: a synthetic sequence reconstructed with and without the physics prior.

Renders a textured sheet sequence with exact ground truth (``inverse.sft.synth``), tracks it,
and reconstructs it three ways: the per-frame baseline, a displacement field without the
Kirchhoff–Love prior (w_phys = 0) and the same field with it; prints the metrics (protocol of
``inverse.sft.metrics``) and the seconds per frame of every stage.

    python demos/sft_demo.py [--sequence fold|roll|corner|wave] [--frames 30] [--seed 0]
        [--field spline|siren] [--quick]

``--field spline`` (default): the B-spline field solved per frame by Gauss–Newton
(``inverse.sft.spline_prior``, float64, as ``ndf-sft``). ``--field siren``: the older SIREN
field trained with Adam (``inverse.sft.siren_prior``, initialised from the baseline).
``--quick``: 3 frames at 320x240 (and few Adam steps for the SIREN), a smoke test.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time

import numpy as np
import torch

import taichi_ndf
from inverse.sft.baseline import reconstruct_baseline
from inverse.sft.frame_fits import reconstruct_sequence
from inverse.sft.metrics import PROTOCOL, evaluate_sequence
from inverse.sft.settings import ReconstructionConfig, SplinePriorConfig
from inverse.sft.synth import SEQUENCES, SynthConfig, generate
from inverse.sft.tracking import track_sequence


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--sequence", choices=SEQUENCES, default="fold")
    p.add_argument("--frames", type=int, default=30)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--field", choices=("spline", "siren"), default="spline",
                   help="spline: Gauss-Newton on a B-spline (default, float64); siren: the "
                        "older SIREN + Adam path")
    p.add_argument("--quick", action="store_true", help="tiny smoke-test version")
    p.add_argument("--precision", choices=("f32", "f64"), default=None,
                   help="Taichi precision (default: f64 for spline, which needs it; f32 siren)")
    return p


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    precision = args.precision or ("f64" if args.field == "spline" else "f32")
    if args.field == "spline" and precision != "f64":
        parser.error("--field spline needs --precision f64 (its Hessian blocks are central "
                     "differences)")
    if args.frames < 2:
        parser.error(f"--frames must be at least 2, got {args.frames}")
    taichi_ndf.init(precision=precision, seed=args.seed)
    torch.set_num_threads(1)  # see ndf-sft --threads
    synth = SynthConfig(sequence=args.sequence, frames=args.frames, seed=args.seed)
    config = (SplinePriorConfig() if args.field == "spline"
              else ReconstructionConfig(seed=args.seed))
    if args.quick:
        synth = dataclasses.replace(synth, frames=3, image_size=(320, 240), focal=300.0,
                                    cells=(10, 8), texture_size=(512, 384), supersample=1)
        if args.field == "siren":
            config = dataclasses.replace(config, width=16, energy_samples=128, steps=10,
                                         init_steps=10)
    rows = run(synth, config)
    print(f"{args.sequence}, {synth.frames} frames {synth.image_size[0]}x{synth.image_size[1]}, "
          f"noise {synth.degradations.noise_sigma * 255:.0f}/255, {args.field} field")
    print(format_table(rows))
    print(f"protocol: {PROTOCOL}")
    return 0


def run(synth: SynthConfig, config: SplinePriorConfig | ReconstructionConfig) -> list[dict]:
    """Metrics and seconds per frame of the baseline and the field with and without the prior
    (the spline field if `config` is a `SplinePriorConfig`, else the SIREN)."""
    sequence = generate(synth)
    n = len(sequence.frames)
    clock = time.perf_counter()
    correspondences, _ = track_sequence(sequence.frames, sequence.template, sequence.texture,
                                        sequence.camera, masks=sequence.masks)
    tracking = (time.perf_counter() - clock) / n
    clock = time.perf_counter()
    baseline = reconstruct_baseline(sequence.template, sequence.camera, correspondences).vertices
    baseline_time = (time.perf_counter() - clock) / n

    def row(name: str, vertices: list[np.ndarray], stages: dict[str, float]) -> dict:
        metrics = evaluate_sequence(vertices, sequence.vertices, sequence.faces,
                                    camera=sequence.camera).summary()
        return {"method": name, **metrics, "seconds": stages}

    rows = [row("baseline", baseline, {"tracking": tracking, "baseline": baseline_time})]
    for name, weight in (("field, no prior", 0.0), ("field + KL prior", config.physics_weight)):
        settings = dataclasses.replace(config, physics_weight=weight)
        clock = time.perf_counter()
        siren = isinstance(settings, ReconstructionConfig)  # fitted to the baseline first
        vertices = reconstruct_sequence(sequence.template, sequence.camera, correspondences,
                                        settings, masks=sequence.masks,
                                        initial=baseline if siren else None).vertices
        stages = {"tracking": tracking, **({"baseline": baseline_time} if siren else {})}
        stages["reconstruction"] = (time.perf_counter() - clock) / n
        rows.append(row(name, vertices, stages))
    return rows


def format_table(rows: list[dict]) -> str:
    header = (f"{'method':<18} {'e3D':>7} {'e3D-P':>7} {'chamfer':>8} {'normal°':>8} "
              f"{'reproj px':>9}  seconds per frame (tracking / baseline / reconstruction)")
    lines = [header]
    for r in rows:
        s = r["seconds"]
        stages = " / ".join(f"{s[k]:.2f}" if k in s else "-"
                            for k in ("tracking", "baseline", "reconstruction"))
        lines.append(f"{r['method']:<18} {r['e3d']:7.4f} {r['e3d_procrustes']:7.4f} "
                     f"{r['chamfer_x1e4']:8.3f} {r['normal_deg']:8.2f} "
                     f"{r['reprojection_px']:9.3f}  {stages}")
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
