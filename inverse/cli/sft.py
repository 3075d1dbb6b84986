"""`ndf-sft`: monocular shape-from-template reconstruction with the Kirchhoff–Love prior.

    ndf-sft --frames F --camera C.json --template T.obj --texture X.png [--masks M]
            [--pinned P] [--gt G] [--method prior|no-prior|baseline] [--field spline|siren]
            --out DIR
    ndf-sft --capture DIR [--pinned 0,992] [--gt G] ... --out OUT

Methods: ``prior`` (default) fits a displacement field per frame with the Kirchhoff–Love prior,
``no-prior`` the same field without it (w_phys = 0), ``baseline`` the per-frame baseline alone
(``inverse.sft.baseline``). Fields: ``spline`` (default; Gauss–Newton over a B-spline,
``inverse.sft.spline_prior``, needs ``--precision f64``) or ``siren`` (a neural field trained
with Adam, ``inverse.sft.siren_prior``, initialised per frame from the baseline unless
``--init previous``). Stages (each timed in ``result.json``): load inputs, tracking
(``inverse.sft.tracking``), baseline (when the method or the SIREN's initialisation needs it),
reconstruction, output. Writes ``DIR/meshes/000000.obj`` … (the
template's connectivity, vertex order and UVs), ``DIR/overlay.mp4`` (the reconstructed mesh's
projected wireframe drawn over the frames) and ``DIR/result.json``; with ``--gt`` (a folder of
ground-truth meshes, template vertex order, or of point clouds) also the metrics of
``inverse.sft.metrics`` (meshes) or the field's chamfer protocol of ``inverse.sft.chamfer``
(clouds). ``--capture DIR`` reads a φ-SfT / PGSfT capture folder (``inverse.sft.capture``) and
prints the conventions it applied (also in result.json); its ground truth is used by default.
Input conventions: ``docs/sft.md``. The work itself is ``inverse.cli.sft_run``, imported
once the command line is read (``--help`` imports neither torch nor Taichi).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from inverse.cli.sft_material import add_material_options
from inverse.cli.sft_options import add_border_options, add_input_options, add_motion_options
from inverse.sft.settings import ReconstructionConfig, SplinePriorConfig
from taichi_ndf.cli.common import (
    ArgumentParser,
    add_runtime_options,
    description,
    finite_float,
    interruptible,
)

METHODS = ("prior", "no-prior", "baseline")


def build_parser() -> argparse.ArgumentParser:
    p = ArgumentParser(prog="ndf-sft", description=description(__doc__))
    add_input_options(p)
    p.add_argument("--out", type=Path, required=True, help="output directory (new or empty "
                   "unless --overwrite)")
    p.add_argument("--method", choices=METHODS, default="prior",
                   help="prior: field + Kirchhoff–Love prior; no-prior: the same field without "
                   "it; baseline: the per-frame baseline alone (default: %(default)s)")
    p.add_argument("--field", choices=("spline", "siren"), default="spline",
                   help="displacement field of prior/no-prior: spline (Gauss–Newton) or siren "
                   "(Adam) (default: %(default)s)")
    p.add_argument("--physics-weight", type=finite_float, default=None,
                   help="w_phys of the Kirchhoff–Love prior (default: the field's, "
                   f"{SplinePriorConfig.physics_weight:g} spline, "
                   f"{ReconstructionConfig.physics_weight:g} siren); --method no-prior sets 0")
    p.add_argument("--iterations", "--steps", dest="iterations", type=int,
                   default=ReconstructionConfig.steps,
                   help="siren: Adam iterations per frame (default: %(default)s; --steps: the "
                   "same)")
    p.add_argument("--init", choices=("baseline", "previous"), default="baseline",
                   help="siren: initial guess of each frame, the baseline's mesh or the "
                   "previous frame (default: %(default)s)")
    p.add_argument("--flow", action="store_true",
                   help="add dense optical-flow correspondences (inverse.sft.flow) to "
                   "the sparse tracks (slower; not better on R1, docs/sft_results.md)")
    p.add_argument("--guided", action="store_true",
                   help="re-find lost texture points near where the reconstruction of the frames "
                   "before predicts them (inverse.sft.guided) and add them to the tracks")
    p.add_argument("--photometric-weight", type=finite_float, default=None,
                   help="spline: w_photo of the photometric term, the texture compared with "
                   "each frame at every textured point (inverse.sft.photometric; default "
                   f"{SplinePriorConfig.photometric_weight:g}, 0: off)")
    p.add_argument("--silhouette-border-gap", type=float, default=None, metavar="EDGES",
                   help="spline: the silhouette acts on a border vertex only where no tracked "
                   "point lies within EDGES template mean edge lengths (default "
                   f"{SplinePriorConfig.silhouette_border_gap:g}: every vertex; inf: interior "
                   "vertices only; not better on R1, benchmarks/RESULTS.md)")
    p.add_argument("--silhouette-allowance", action="store_true",
                   help="spline: the silhouette tolerates each border vertex as far outside the "
                   "mask as the template lies outside mask 0 (default: off)")
    p.add_argument("--allowance-reach", type=float, default=None, metavar="EDGES",
                   help="spline: that allowance only where a tracked point lies within EDGES "
                   "template mean edge lengths of the vertex (default: everywhere)")
    p.add_argument("--extrapolate", action="store_true",
                   help="spline: start each frame from the constant-velocity extrapolation of "
                   "the two frames before (default: from the frame before)")
    add_motion_options(p)
    p.add_argument("--fps", type=finite_float, default=30.0, help="overlay video frame rate")
    p.add_argument("--overwrite", action="store_true",
                   help="allow writing into a non-empty output directory")
    add_border_options(p)
    add_material_options(p)
    add_runtime_options(p)
    return p


def confidence_line(confidence: dict, vertices: int) -> str:
    """One printed line: which frames have parts no tracked point observes."""
    frames = confidence["frames_with_unobserved_parts"]
    if not frames:
        return (f"confidence: every vertex within {confidence['reach_mean_edges']:g} mean edge "
                "lengths of a tracked point in every frame")
    most = max(confidence["unobserved_vertices"])
    return (f"confidence: {len(frames)} frame(s) ({frames[0]}–{frames[-1]}) have vertices farther "
            f"than {confidence['reach_mean_edges']:g} mean edge lengths from every tracked point "
            f"(up to {most} of {vertices}): their shape there is the prior's, not measured "
            "(result.json 'confidence')")


@interruptible("ndf-sft")
def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from inverse.cli.sft_inputs import metrics_line
    from inverse.cli.sft_run import run
    from inverse.sft.errors import InputError
    from inverse.sft.material_from_video import summary_line

    try:
        summary = run(args)
    except (InputError, FileExistsError, ValueError, RuntimeError) as err:
        print(f"ndf-sft: error: {err}", file=sys.stderr)
        return 2
    timings = summary["timings"]
    print(f"reconstructed {summary['frames']} frames; seconds per frame: " + ", ".join(
        f"{name} {value:.2f}" for name, value in timings["per_frame"].items()))
    if "metrics" in summary:
        print(metrics_line(summary["metrics"]))
    if "material" in summary:
        print(summary_line(summary["material"]))
    print(confidence_line(summary["confidence"], summary["vertices"]))
    print(f"outputs in {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
