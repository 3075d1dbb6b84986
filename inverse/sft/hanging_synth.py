"""A synthetic hanging-sheet sequence with known material, for material-from-video checks.

A textured W × H sheet is held at its two top corners and hangs under gravity; the corners move
slowly (closer together, the corner line turning and rolling, the held tangent plane tilting,
the sheet moving away from the camera), so every frame is a quasi-static equilibrium. Each
frame's shape is the project's own forward solve of `hanging.hanging_model`: the equilibrium
of a spline displacement field by projected Newton (`SplineEquilibrium`, from the flat
reference through its load steps for frame 0, from the previous frame's shape for the others:
a quasi-static continuation along the motion), on a grid finer than and of another degree than the
estimator's (no inverse crime). Frames are rendered by `synth.render_sequence` (camera,
texture, clutter, degradations) and written by `synth.write_sequence` in the input layout of
`ndf-sft`, plus ``hanging.json``: the true material, the held vertex indices, gravity in
camera coordinates and the settings.

Camera coordinates (OpenCV: x right, y down, z forward); gravity (0, 9.81, 0) m/s², down the
image. Command line: ``python -m inverse.sft.hanging_synth --out DIR --frames 12``.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
import time
from dataclasses import asdict, dataclass, field

import numpy as np
import torch

from inverse.material.spline_equilibrium import SplineEquilibrium, SplineModelConfig
from inverse.material.unknowns import parse_unknowns
from inverse.sft.degradations import Degradations
from inverse.sft.hanging import STANDARD_GRAVITY, hanging_model
from inverse.sft.synth import SyntheticSequence, default_camera, render_sequence, write_sequence
from inverse.sft.texture import cluttered_background, sheet_texture
from taichi_ndf.io import grid_mesh
from taichi_ndf.shell.materials import LinearIsotropic

log = logging.getLogger(__name__)

GRAVITY = (0.0, STANDARD_GRAVITY, 0.0)  # camera coordinates: down the image


@dataclass(frozen=True)
class HangingMotion:
    """The held corners over t ∈ [0, 1] (camera coordinates [m], angles [deg]).

    depth: z of the corners' midpoint at t = 0, moving by `recede` over the sequence; height: y
    of the midpoint; sway: x amplitude of the midpoint (one period); separation: corner
    distance over W at t = 0 and t = 1 (linear); yaw: turn of the corner line about the
    vertical (0 → yaw); roll: height of corner b over corner a at t = 1 [m]; tilt: angle of
    the held tangent plane about the corner line at t = 0 and t = 1 (0: vertical, the
    estimator's model, `hanging.hanging_across`)."""

    depth: float = 0.6
    recede: float = 0.04
    height: float = -0.14
    sway: float = 0.02
    separation: tuple[float, float] = (0.95, 0.85)
    yaw: float = 20.0
    roll: float = 0.01
    tilt: tuple[float, float] = (0.0, 0.0)

    def corners(self, t: float, width: float) -> tuple[np.ndarray, np.ndarray]:
        """Held corner positions (2, 3) and the held plane's `across` direction at t."""
        yaw = math.radians(self.yaw * t)
        line = np.array([math.cos(yaw), 0.0, math.sin(yaw)])
        half = 0.5 * width * (self.separation[0] + (self.separation[1] - self.separation[0]) * t)
        middle = np.array([self.sway * math.sin(2 * math.pi * t), self.height,
                           self.depth + self.recede * t])
        a = middle - half * line - np.array([0.0, 0.5 * self.roll * t, 0.0])
        b = middle + half * line + np.array([0.0, -0.5 * self.roll * t, 0.0])
        e1 = (b - a) / np.linalg.norm(b - a)
        down = np.array(GRAVITY) - (np.array(GRAVITY) @ e1) * e1
        down /= np.linalg.norm(down)
        tilt = math.radians(self.tilt[0] + (self.tilt[1] - self.tilt[0]) * t)
        across = math.cos(tilt) * down + math.sin(tilt) * np.cross(e1, down)
        return np.stack([a, b]), across


@dataclass(frozen=True)
class HangingConfig:
    """A synthetic hanging-sheet sequence.

    frames: number of frames (t = 0 … 1); sheet_size: (W, H) [m]; cells: template grid cells;
    bending_length: c = (B / (ρ_A g))^(1/3) [m] of the true material; areal_density ρ_A
    [kg/m²]; membrane_stiffness D [N/m]; poisson_ratio ν; band: the handles' band (fraction
    of the domain); spans, degree: the truth's spline grid; the rest as `synth.SynthConfig`."""

    frames: int = 12
    seed: int = 0
    image_size: tuple[int, int] = (640, 480)
    focal: float = 600.0
    sheet_size: tuple[float, float] = (0.3, 0.3)
    cells: tuple[int, int] = (24, 24)
    bending_length: float = 0.02
    areal_density: float = 0.2
    membrane_stiffness: float = 100.0
    poisson_ratio: float = 0.25
    band: float = 0.1
    spans: tuple[int, int] = (12, 12)
    degree: int = 4
    texture_size: tuple[int, int] = (1024, 1024)
    supersample: int = 3
    clutter: bool = True
    motion: HangingMotion = field(default_factory=HangingMotion)
    degradations: Degradations = field(default_factory=Degradations)

    def __post_init__(self):
        if self.frames < 1:
            raise ValueError(f"frames must be >= 1, got {self.frames}")
        if min(self.sheet_size) <= 0 or min(self.cells) < 2:
            raise ValueError(f"sheet_size must be positive and cells >= 2, got "
                             f"{self.sheet_size}, {self.cells}")
        for name in ("bending_length", "areal_density", "membrane_stiffness"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)!r}")

    @property
    def material(self) -> LinearIsotropic:
        """The true material: B = ρ_A g c³."""
        b = self.areal_density * STANDARD_GRAVITY * self.bending_length ** 3
        return LinearIsotropic(membrane_stiffness=self.membrane_stiffness,
                               bending_stiffness=b, poisson_ratio=self.poisson_ratio,
                               areal_density=self.areal_density)


def template_grid(config: HangingConfig):
    """The template grid (`io.grid_mesh` over [0, W] × [0, H]) and its UVs (texture upright
    with ξ² down the image); the held corners are vertices 0 and cells[0]."""
    grid = grid_mesh(((0.0, config.sheet_size[0]), (0.0, config.sheet_size[1])), config.cells)
    uvs = np.column_stack([grid.uv[:, 0], 1.0 - grid.uv[:, 1]])
    return grid, uvs, (0, config.cells[0])


def equilibrium_shapes(config: HangingConfig) -> list[np.ndarray]:
    """The true vertex positions (V, 3) per frame [m]: each frame's equilibrium (module
    docstring)."""
    grid, _, _ = template_grid(config)
    xi = torch.from_numpy(grid.xi)
    material = config.material
    spline = SplineModelConfig(spans=config.spans, degree=config.degree, boundary_length=None)
    times = np.linspace(0.0, 1.0, config.frames) if config.frames > 1 else np.zeros(1)
    shapes = []
    for i, t in enumerate(times):
        t0 = time.perf_counter()
        corners, across = config.motion.corners(float(t), config.sheet_size[0])
        model = hanging_model(config.sheet_size, material, corners, across, np.array(GRAVITY),
                              band=config.band)
        model, unknowns = parse_unknowns("bending", model)
        equilibrium = SplineEquilibrium(model, unknowns, spline, spline.grid(model))
        # frame 0 from the flat sheet through the load steps; later frames from the previous
        # frame's shape (quasi-static continuation along the motion)
        start = None if not shapes else equilibrium.fitted_state(
            xi, torch.from_numpy(shapes[-1]))
        equilibrium.solve([material.bending_stiffness], start=start)
        shapes.append(equilibrium.positions(xi).numpy())
        log.info("hanging frame %d: equilibrium in %d Newton steps, %.1f s", i,
                 equilibrium.newton_steps, time.perf_counter() - t0)
    return shapes


def generate(config: HangingConfig) -> SyntheticSequence:
    """Solve and render the sequence (deterministic by config.seed)."""
    camera = default_camera(*config.image_size, focal=config.focal)
    grid, uvs, _ = template_grid(config)
    vertices = equilibrium_shapes(config)
    texture = sheet_texture(*config.texture_size, seed=config.seed)
    background = (cluttered_background(*config.image_size, seed=config.seed + 1)
                  if config.clutter else None)
    frames, masks, encoded = render_sequence(
        vertices, grid.faces, uvs, texture, camera, background=background,
        degradations=config.degradations, supersample=config.supersample, seed=config.seed)
    return SyntheticSequence(camera=camera, faces=grid.faces, uvs=uvs, texture=texture,
                             vertices=vertices, frames=frames, masks=masks, encoded=encoded)


def truth_document(config: HangingConfig) -> dict:
    """What `hanging.json` records: the true material and the conditions of the sequence."""
    material = config.material
    _, _, held = template_grid(config)
    return {"bending_stiffness": material.bending_stiffness,
            "bending_length_m": config.bending_length,
            "areal_density": config.areal_density,
            "membrane_stiffness": config.membrane_stiffness,
            "poisson_ratio": config.poisson_ratio,
            "held_vertices": list(held), "gravity": list(GRAVITY),
            "config": asdict(config)}


def write(config: HangingConfig, out, *, frame_format: str = "jpg",
          overwrite: bool = False, command: str = ""):
    """Generate and write the sequence (module docstring); returns the folder."""
    sequence = generate(config)
    path = write_sequence(sequence, out, frame_format=frame_format, overwrite=overwrite,
                          settings={"command": command, "config": asdict(config)})
    (path / "hanging.json").write_text(json.dumps(truth_document(config), indent=2))
    (path / "held.json").write_text(json.dumps(list(template_grid(config)[2])))
    return path


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    p = argparse.ArgumentParser(prog="python -m inverse.sft.hanging_synth",
                                description="Render a hanging-sheet sequence of known material.")
    p.add_argument("--out", required=True)
    p.add_argument("--frames", type=int, default=12)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--bending-length", type=float, default=0.02, help="c [m]")
    p.add_argument("--cells", type=int, nargs=2, default=(24, 24))
    p.add_argument("--image-size", type=int, nargs=2, default=(640, 480))
    p.add_argument("--spans", type=int, nargs=2, default=(12, 12), help="truth's grid")
    p.add_argument("--format", choices=("jpg", "png"), default="jpg")
    p.add_argument("--overwrite", action="store_true")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    import taichi_ndf
    torch.set_num_threads(1)
    taichi_ndf.init(arch="cpu", precision="f64")
    config = HangingConfig(frames=args.frames, seed=args.seed,
                           bending_length=args.bending_length, cells=tuple(args.cells),
                           image_size=tuple(args.image_size), spans=tuple(args.spans),
                           degradations=Degradations(jpeg_quality=80))
    write(config, args.out, frame_format=args.format, overwrite=args.overwrite,
          command="python -m inverse.sft.hanging_synth " + " ".join(argv))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
