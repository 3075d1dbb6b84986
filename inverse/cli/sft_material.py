"""`ndf-sft --estimate-material`: the options of the material estimate and their checks.

Defaults (`MaterialFromVideoConfig`): quartic splines on a grid and its refinement chosen from
the bending length (`inverse.sft.material_grid`; 7 × 7 / 14 × 14 for c ≥ 2.9 cm on a 0.3 m
sheet), the membrane
stiffness D estimated beside B unless `--membrane-stiffness` states it, the flat sheet's size
from the template unless `--sheet-size` states it, each frame weighted by the inverse of its
coarse-grid misfit (`--material-frame-weights`), the held corners of the frames after the
first fitted beside the material (`--material-corners`). The held corners are `--held-corners A B`
(default: the two `--pinned` vertices, when the corners do not move); the template must be a
regular vertex grid with them at the two ends of one grid edge
(`inverse.sft.hanging.SheetGrid`). Everything is checked before tracking; a bad option is an
`InputError` (exit 2). The estimate itself is
`inverse.sft.material_from_video.estimate_material` on the reconstructed meshes.
"""

from __future__ import annotations

import argparse

import numpy as np

from inverse.sft.errors import InputError
from inverse.sft.settings import (
    CORNERS,
    FRAME_WEIGHTS,
    OBSERVED,
    SHEET_SIZE_FROM,
    MaterialFromVideoConfig,
)
from taichi_ndf.cli.common import finite_float

DEFAULTS = MaterialFromVideoConfig()


def _text(values) -> str:
    return " ".join(f"{v:g}" for v in values)


def add_material_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("material from the video (--estimate-material)")
    g.add_argument("--estimate-material", action="store_true",
                   help="estimate the bending stiffness of a sheet held at two corners from "
                   "its equilibria in the reconstructed frames (docs/sft.md)")
    g.add_argument("--held-corners", type=int, nargs=2, metavar=("A", "B"),
                   help="template vertices of the two held corners, which may move (default: "
                   "the two --pinned vertices)")
    g.add_argument("--areal-density", type=finite_float,
                   help="stated areal density [kg/m²] that turns B/(ρ g) into B (default: "
                   f"{DEFAULTS.areal_density:g}, the median of measured fabrics)")
    g.add_argument("--gravity", type=finite_float, nargs=3, metavar=("GX", "GY", "GZ"),
                   help="gravity [m/s²] in camera coordinates (default: "
                   f"{_text(DEFAULTS.gravity)}, down the image)")
    g.add_argument("--material-frames", type=int,
                   help=f"frames used, evenly spread (0: all; default: {DEFAULTS.frames})")
    g.add_argument("--material-spans", type=int, nargs=2, metavar=("N1", "N2"),
                   help="coarse spline grid of the equilibria; the fine grid has twice its "
                   "spans (default: chosen from the bending length, spans of at most 1.5 c, "
                   "7 to 16 per side; inverse.sft.material_grid)")
    g.add_argument("--material-degree", type=int,
                   help="spline degree of the equilibria, 3 or 4 (default: "
                   f"{DEFAULTS.degree}; cubic measured undetermined on the same grids)")
    g.add_argument("--membrane-stiffness", type=finite_float, metavar="D",
                   help="hold the membrane stiffness at this stated D [N/m] (default: D is "
                   "estimated beside B; a wrong held D biases B, docs/sft.md)")
    g.add_argument("--material-observed", choices=OBSERVED,
                   help="what of each reconstructed vertex the fit compares: 3d (all three "
                   "coordinates) or ray (the two directions across its camera ray, the depth "
                   f"left to the physics; default: {DEFAULTS.observed})")
    g.add_argument("--material-frame-weights", choices=FRAME_WEIGHTS,
                   help="how the frames count in the fit: misfit (each frame by the inverse "
                   "of its coarse-grid rms misfit) or equal (every vertex alike; default: "
                   f"{DEFAULTS.frame_weights})")
    g.add_argument("--material-corners", choices=CORNERS,
                   help="the held corners of the frames after the first: fitted (unknowns of "
                   "the fit beside the material, 3 coordinates each: a reconstruction's corner "
                   "error is not imposed) or held where the reconstruction puts them (default: "
                   f"{DEFAULTS.corners})")
    g.add_argument("--material-quasi-static", type=finite_float, metavar="G",
                   help="use only frames whose sheet accelerates by at most G times g "
                   "(second differences of the reconstruction at --fps; frame 0 always "
                   "kept; default: every frame taken as an equilibrium)")
    g.add_argument("--sheet-size-from", choices=SHEET_SIZE_FROM,
                   help="without --sheet-size: the flat size from the template's grid-line "
                   "lengths as they are (template) or unstretched by the fitted equilibrium of "
                   "frame 0, whose shape the template is (equilibrium; a planar template is "
                   f"taken as it is; default: {DEFAULTS.sheet_size_from})")
    g.add_argument("--sheet-size", type=finite_float, nargs=2, metavar=("W", "H"),
                   help="size of the flat sheet [m], W along the held edge, when known "
                   "(default: the template's grid-line lengths; a template that is a hanging "
                   "frame carries its stretch)")


def material_config(args: argparse.Namespace) -> MaterialFromVideoConfig | None:
    """The estimate's settings (None without --estimate-material); InputError when an option
    is invalid or given without --estimate-material."""
    given = [name for name in _FIELD if getattr(args, name) is not None]
    if args.held_corners is not None:
        given.insert(0, "held_corners")
    if not args.estimate_material:
        if given:
            raise InputError(f"--{given[0].replace('_', '-')} needs --estimate-material")
        return None
    try:
        return MaterialFromVideoConfig(fps=args.fps, **{
            field: _value(args, name) for name, field in _FIELD.items()
            if getattr(args, name) is not None})
    except ValueError as err:
        raise InputError(f"--estimate-material: {err}") from None


# command-line option (argparse dest) -> MaterialFromVideoConfig field
_FIELD = {"areal_density": "areal_density", "gravity": "gravity",
          "material_frames": "frames", "material_spans": "spans",
          "material_degree": "degree", "membrane_stiffness": "membrane_stiffness",
          "sheet_size": "sheet_size", "material_observed": "observed",
          "sheet_size_from": "sheet_size_from", "material_frame_weights": "frame_weights",
          "material_corners": "corners", "material_quasi_static": "quasi_static_limit"}


def _value(args: argparse.Namespace, name: str):
    value = getattr(args, name)
    return tuple(value) if isinstance(value, list) else value


def check_held_corners(args: argparse.Namespace, template, pinned) -> tuple[int, int]:
    """The two held corners (--held-corners, else the --pinned vertices) after checking that
    the template is a grid with them at the ends of one edge; InputError otherwise."""
    if args.held_corners is not None:
        held = tuple(args.held_corners)
    elif pinned is not None and len(pinned) == 2:
        held = (int(pinned[0]), int(pinned[1]))
    else:
        raise InputError("--estimate-material needs the two held corners: --held-corners A B "
                         f"or exactly two --pinned vertices (got "
                         f"{0 if pinned is None else len(pinned)})")
    from inverse.sft.hanging import SheetGrid

    try:
        SheetGrid.from_template(np.asarray(template.vertices), np.asarray(template.faces), held)
    except ValueError as err:
        raise InputError(f"--estimate-material: {err}") from None
    return held
