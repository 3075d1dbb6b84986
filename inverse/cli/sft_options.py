"""The input options of ``ndf-sft`` (the contract's files or one capture folder), apart from
the loading (``inverse.cli.sft_inputs``) so that ``--help`` imports neither torch nor Taichi."""

from __future__ import annotations

import argparse
import re
from pathlib import Path

CONTRACT_OPTIONS = ("frames", "camera", "template", "texture")


def pinned_option(text: str) -> list[int] | Path:
    """``--pinned``: a comma-separated list of vertex indices (``0,992``) or a file."""
    if re.fullmatch(r"\s*\d+(\s*,\s*\d+)*\s*", text):
        return [int(v) for v in text.split(",")]
    return Path(text)


def add_input_options(p: argparse.ArgumentParser) -> None:
    """The input options of ``ndf-sft``: the contract's files or one capture folder."""
    p.add_argument("--capture", type=Path,
                   help="a capture folder in the φ-SfT / PGSfT layout (frames/, masks/, "
                   "template/*.obj, camera.json, ground_truth/, pinned file): axes, UVs and "
                   "texture found by the tool and stated (docs/sft.md §7); replaces --frames, "
                   "--camera, --template, --texture, --masks")
    p.add_argument("--frames", type=Path, help="video file or folder of images")
    p.add_argument("--camera", type=Path, help="camera JSON (docs/sft.md)")
    p.add_argument("--template", type=Path,
                   help="template mesh with UVs, camera coordinates of frame 0 (OBJ or PLY)")
    p.add_argument("--texture", type=Path, help="texture image of the template")
    p.add_argument("--masks", type=Path, help="folder of per-frame masks (white = sheet)")
    p.add_argument("--pinned", type=pinned_option,
                   help="held vertex indices: a list like 0,992 or a file (JSON list or text); "
                   "with --capture it overrides the capture's pinned file")
    p.add_argument("--gt", type=Path, help="ground truth for metrics: a folder of meshes (the "
                   "template's vertex order) or of point clouds (.npy / .ply, the field's "
                   "chamfer protocol); with --capture its ground_truth/ by default")


# The mask's outline covered by the border and the fading allowance (`SplinePriorConfig`'s
# cover_weight, cover_reach, cover_slack, allowance_fade; spline field only).
BORDER_OPTIONS = ("cover_weight", "cover_reach", "cover_slack", "allowance_fade")


def add_border_options(p: argparse.ArgumentParser) -> None:
    """``--cover-weight``, ``--cover-reach``, ``--cover-slack``, ``--allowance-fade``: the
    cover term (`inverse.sft.contour`) and the fading silhouette allowance; default: the
    settings' (off)."""
    p.add_argument("--cover-weight", type=float, default=None, metavar="W",
                   help="spline: w_cover, the mask's outline covered by the sheet's projected "
                   "border (inverse.sft.contour; default 0: off)")
    p.add_argument("--cover-reach", type=float, default=None, metavar="EDGES",
                   help="spline: the cover term's reach in mean projected border edges "
                   "(default 3)")
    p.add_argument("--cover-slack", type=float, default=None, metavar="EDGES",
                   help="spline: outline uncovered by less than EDGES mean projected border "
                   "edges is not charged by the cover term (default 0)")
    p.add_argument("--allowance-fade", type=float, default=None, metavar="EDGES",
                   help="spline: with --silhouette-allowance, the allowance fades as a vertex "
                   "moves from its frame-0 pixel, to none at EDGES mean projected edges "
                   "(default: no fading)")


# -- the spline prior's inertia (wip-sft12) ------------------------------------------------------

def positive_seconds(text: str) -> float:
    """``--frame-interval``: a positive, finite number of seconds."""
    value = float(text)
    if not 0 < value < float("inf"):
        raise argparse.ArgumentTypeError(f"must be positive and finite [s], got {text!r}")
    return value


def add_motion_options(p: argparse.ArgumentParser) -> None:
    """The spline prior's inertia: ``--frame-interval S`` (`SplinePriorConfig.frame_interval`)."""
    p.add_argument("--frame-interval", type=positive_seconds, default=None, metavar="S",
                   help="spline: the time between frames [s] (1/fps of the capture); adds the "
                   "inertia ½ ρ_A/Δt² ‖u − û‖²_M of a time step towards the constant-velocity "
                   "prediction, scaled like the prior (default: off; not better on R1, "
                   "benchmarks/RESULTS.md)")
