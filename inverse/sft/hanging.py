"""A sheet held at two corners hanging under gravity: the shell model of one frame.

The sheet is flat at rest, W × H [m], with surface coordinates ξ = (ξ¹, ξ²) ∈ [0, W] × [0, H]
(arclengths of the flat sheet). The two held corners are ξ_a = (0, 0) and ξ_b = (W, 0): the held
edge is ξ² = 0. A frame's model (`hanging_model`) places the flat reference sheet rigidly
where the held corners are — its edge ξ² = 0 along the line from corner a to corner b, centred
between them, its ξ² axis along `across` (a unit vector perpendicular to that line, pointing
into the sheet) — and holds each corner with a `Handle` that moves the reference corner to its
observed position. A handle holds the slope too (`boundary.constraints.Handle`): the sheet's
tangent plane at a held corner is the reference plane, spanned by the corner line and
`across`. Gravity acts through the material's areal density.

`SheetGrid` relates a template mesh to these coordinates: a template whose vertices form a
regular grid (row-major in either index order, as ndf-sim's meshes and the φ-SfT / PGSfT
templates), with the two held vertices at the two ends of one grid edge. Its ξ are the grid
indices times the mean lengths of the template's grid lines along each direction (the flat
sheet that the template bends isometrically).

Everything here is in one frame of reference, e.g. camera coordinates [m] (OpenCV axes), with
gravity given in that frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from taichi_ndf.boundary import BoundaryConditions
from taichi_ndf.boundary.constraints import Handle
from taichi_ndf.geometry.analytic import Plane
from taichi_ndf.problem.loads import Loads
from taichi_ndf.problem.model import ShellModel

STANDARD_GRAVITY = 9.81  # m/s²


@dataclass(frozen=True)
class SheetGrid:
    """A grid template's surface coordinates.

    xi: (V, 2) [m] per template vertex; size: (W, H) [m] of the flat sheet; held: the two held
    vertex indices (ξ = (0, 0) and (W, 0)); shape: grid vertices along (ξ¹, ξ²); index:
    (n1, n2) the vertex at grid position (i, j)."""

    xi: np.ndarray
    size: tuple[float, float]
    held: tuple[int, int]
    shape: tuple[int, int]
    index: np.ndarray

    @classmethod
    def from_template(cls, vertices: np.ndarray, faces: np.ndarray,
                      held: tuple[int, int]) -> SheetGrid:
        """The grid of a template mesh (module docstring); raises ValueError when the mesh is
        not a regular grid or the held vertices are not the two ends of one grid edge."""
        vertices = np.asarray(vertices, dtype=np.float64)
        n = len(vertices)
        held = tuple(int(h) for h in held)
        if len(held) != 2 or held[0] == held[1] or not all(0 <= h < n for h in held):
            raise ValueError(f"held corners must be two distinct vertex indices below {n}, got "
                             f"{held}")
        columns = _grid_columns(np.asarray(faces), n)
        rows = n // columns
        index = np.arange(n).reshape(rows, columns)
        (ra, ca), (rb, cb) = divmod(held[0], columns), divmod(held[1], columns)
        corners = {(0, 0), (0, columns - 1), (rows - 1, 0), (rows - 1, columns - 1)}
        if (ra, ca) not in corners or (rb, cb) not in corners or (ra != rb and ca != cb):
            raise ValueError(f"held vertices {held} are not the two ends of one edge of the "
                             f"{rows} x {columns} vertex grid")
        if ra == rb:  # the held edge is a row: ξ¹ runs along columns
            grid = index if ra == 0 else index[::-1]
            grid = grid.T  # (along ξ¹, along ξ²)
            if ca > cb:
                grid = grid[::-1]
        else:
            grid = index if ca == 0 else index[:, ::-1]
            if ra > rb:
                grid = grid[::-1]
        grid = np.ascontiguousarray(grid)  # grid[i, j]: vertex at ξ¹ index i, ξ² index j
        points = vertices[grid]
        width = float(np.linalg.norm(np.diff(points, axis=0), axis=2).sum(axis=0).mean())
        height = float(np.linalg.norm(np.diff(points, axis=1), axis=2).sum(axis=1).mean())
        n1, n2 = grid.shape
        xi = np.empty((n, 2))
        i, j = np.meshgrid(np.arange(n1), np.arange(n2), indexing="ij")
        xi[grid.ravel(), 0] = (i.ravel() / (n1 - 1)) * width
        xi[grid.ravel(), 1] = (j.ravel() / (n2 - 1)) * height
        return cls(xi=xi, size=(width, height), held=held, shape=(n1, n2), index=grid)

    def with_size(self, size: tuple[float, float]) -> SheetGrid:
        """The same grid on a flat sheet of the stated size (W, H) [m] (W along the held
        edge): ξ scaled along each direction."""
        scale = np.array([float(size[0]) / self.size[0], float(size[1]) / self.size[1]])
        return SheetGrid(xi=self.xi * scale, size=(float(size[0]), float(size[1])),
                         held=self.held, shape=self.shape, index=self.index)

def _grid_columns(faces: np.ndarray, n: int) -> int:
    """Vertices per row of a row-major grid mesh, from its edges' index differences."""
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    steps = np.abs(edges[:, 0] - edges[:, 1])
    steps = steps[steps > 1]
    if len(steps) == 0:
        raise ValueError("the template is not a regular vertex grid (no row-to-row edges)")
    columns = int(np.bincount(steps).argmax())
    if n % columns or n // columns < 2 or columns < 2:
        raise ValueError(f"the template's {n} vertices are not a regular grid (rows of "
                         f"{columns})")
    return columns


def hanging_across(corners: np.ndarray, gravity: np.ndarray) -> np.ndarray:
    """The `across` direction of a sheet hanging from its corner line: gravity made
    perpendicular to the line (the reference plane vertical through the corners). Measured on
    equilibria whose held plane was tilted by 15° (`hanging_synth`, tilt): the sheet leaves its
    corners within 1° of this direction, in a boundary layer of the handle's band, so the
    held plane's tilt is not observable from the shape and this is the model's choice."""
    line = corners[1] - corners[0]
    line = line / np.linalg.norm(line)
    down = np.asarray(gravity, dtype=np.float64)
    down = down - (down @ line) * line
    if not np.linalg.norm(down) > 1e-9 * np.linalg.norm(gravity):
        raise ValueError("the held corners lie on a vertical line: no plane hangs from them")
    return down / np.linalg.norm(down)


def hanging_model(size: tuple[float, float], material, corners: np.ndarray,
                  across: np.ndarray, gravity: np.ndarray, *,
                  band: float = 0.1, grip: float = 0.0) -> ShellModel:
    """The model of one frame (module docstring).

    size: (W, H) [m]; material: a `LinearIsotropic` (or any material); corners: (2, 3) held
    corner positions [m]; across: unit vector ⊥ the corner line into the sheet; gravity: (3,)
    [m/s²]; band: the handles' band (fraction of the domain) over which the slope is held;
    grip: 0 holds each corner at its point; > 0 [m] holds the corner's patch of that radius
    along the held edge (`Handle.radius`: a quarter disc of the flat sheet, an ellipse of
    semi-axes grip and grip·H/W where H ≠ W), moved rigidly (translated, its plane kept).
    Which describes a capture is the capture's (a pinch or a clip); measured on the
    synthetic swing (benchmarks/RESULTS.md, "a held patch (grip) and the grid"), a 2 cm grip
    removed the point's static singularity at the corners but neither made the moving sheet
    converge in the grid nor lowered B's grid bias (−24 % at 24² against 28², the point's
    −7 %) — with the rim integrated by the spans' Gauss points, first order and erratic. With
    the rim integrated exactly (`discretise.held_patches`) and knots graded towards the
    corners, the rest converges in the grid (2 cm: B's steps −9.0, −3.4, −0.5 % from 16² to
    40², the observed rest's 0.40, 0.070, 0.014 mm rms; dP/dB by central differences),
    where the point's B drifts at order ≈ 1. (Until wip-sftmat13 a grip's sensitivities were
    wrong — the stepper's points, a trimmed quadrature's, paired with displacements in the
    assembly's other order: `rest_start`'s dP/dB 46 % rms off a central difference on graded
    32², the dynamics' tangent growing ≈ 4.5 × per frame; `solve.dynamics.TimeStepper` now
    takes the assembly's order.) The default stays the point (0)."""
    corners = np.asarray(corners, dtype=np.float64)
    width, height = (float(s) for s in size)
    line = corners[1] - corners[0]
    e1 = line / np.linalg.norm(line)
    e2 = np.asarray(across, dtype=np.float64)
    e2 = e2 - (e2 @ e1) * e1
    e2 = e2 / np.linalg.norm(e2)
    e3 = np.cross(e1, e2)
    origin = corners.mean(axis=0) - 0.5 * width * e1
    surface = Plane(bounds=((0.0, width), (0.0, height)), origin=tuple(origin),
                    frame=(tuple(e1), tuple(e2), tuple(e3)))
    radius = float(grip) / width
    handles = [Handle((0.0, 0.0), tuple(corners[0] - origin), radius=radius),
               Handle((width, 0.0), tuple(corners[1] - origin - width * e1), radius=radius)]
    boundary = BoundaryConditions(handles, surface.domain, surface=surface, length=band)
    return ShellModel(surface, material, Loads(gravity=tuple(float(g) for g in gravity)),
                      boundary)

