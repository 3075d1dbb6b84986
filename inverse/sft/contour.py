"""The mask's outline covered by the sheet's projected border: the direction of the silhouette
that the silhouette and outline terms of `inverse.sft.least_squares` lack.

Those terms act on the sheet's own points: each border vertex is pulled inside the mask (the
silhouette) and no deeper than frame 0 allowed (the outline). Neither asks whether every part
of the mask's outline has a border of the sheet beside it: a free corner projected out at the
wrong pixel leaves the outline where the real corner is uncovered, and nothing pulls it there.
The cover term measures, for each point c_j of the mask's outline near the sheet's border, how
far it is from the sheet's projected border curve:

    E_cover(u) = w_cover / m · Σ_j ρ(max(0, min_k ‖c_j − π(x_k)‖ − a_k(j) − s))      [px²]

over the m outline points within the reach τ of the border at the start of the frame (the
previous frame's shape; an outline that no border comes near — a hand, a fold's silhouette —
is not the border's), x_k = X_k + u(ξ_k) points along the template's border edges
(`BorderCurve`: several per edge, so the curve and not only its vertices is compared; each a
surface point of its own, so every residual depends on one point and its Gauss–Newton block is
exact), k(j) the nearest visible one, a_k the allowance: how far from mask 0's outline the
template's own border lay at that point in frame 0 (the template is right by construction;
where the mask and the template disagree, that much is not charged), s a slack
(`SplinePriorConfig.cover_slack` mean projected border edges: an outline uncovered by less is
left to the silhouette and outline terms), and ρ Tukey's biweight with reach τ,
ρ(r) = τ²/3 · (1 − (1 − (r/τ)²)³) for r < τ and τ²/3 beyond (quadratic for small r; a point
that leaves the reach stops pulling). τ is `SplinePriorConfig.cover_reach` mean projected
border edges of the start. Gauss–Newton on the scalar residual r: its row is (e/‖e‖)ᵀ dπ/dx
with e = π(x_k) − c_j, Tukey by iteratively reweighted least squares (weight (1 − (r/τ)²)²).

The outline points are the mask's outline itself at sub-pixel positions: half-way between each
mask pixel and its non-mask 4-neighbour (where the `silhouette_distance` image is 0); a mask
cut by the image's edge has none along it.

Measured on φ-SfT's R1 and the synthetic study: not better than without it (benchmarks/
RESULTS.md, R1 section, wip-sft11): where the mask is a few pixels wider than the cloth it
pulls the border out, which an inextensible sheet does by bending. Off by default.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy.spatial import cKDTree

from inverse.sft.camera import Camera
from inverse.sft.least_squares import COMPONENTS, MIN_DEPTH
from inverse.sft.outline import border_edges
from inverse.sft.silhouette import bilinear_differentiable
from taichi_ndf import jets


@dataclass(frozen=True)
class BorderCurve:
    """Points along the template's border edges: UVs ξ (K, 2), template positions X (K, 3) [m]
    (float64), the edge's two vertices (K, 2) int64; `per_edge` points on each border edge at
    parameters (i + ½) / per_edge (an edge's ends are shared with its neighbours, so none
    lies on a vertex)."""

    xi: torch.Tensor
    rest: torch.Tensor
    ends: np.ndarray
    per_edge: int

    @classmethod
    def of(cls, vertices: np.ndarray, faces: np.ndarray, uvs: np.ndarray, *,
           per_edge: int) -> BorderCurve:
        """The border of a template (vertices [m] (n, 3), faces (F, 3), uvs (n, 2))."""
        if per_edge < 1:
            raise ValueError(f"per_edge must be >= 1, got {per_edge}")
        edges = border_edges(faces)
        t = (np.arange(per_edge) + 0.5) / per_edge
        ends = np.repeat(edges, per_edge, axis=0)
        t = np.tile(t, len(edges))[:, None]
        xi = (1 - t) * uvs[ends[:, 0]] + t * uvs[ends[:, 1]]
        rest = (1 - t) * vertices[ends[:, 0]] + t * vertices[ends[:, 1]]
        return cls(torch.from_numpy(xi.astype(np.float64)),
                   torch.from_numpy(rest.astype(np.float64)), ends.astype(np.int64), per_edge)

    def allowance(self, camera: Camera, distance: torch.Tensor) -> torch.Tensor:
        """(K,) [px]: how far each point of the template (frame 0's shape) lies from the
        outline of frame 0's mask (`distance` D₀ (h, w), its `silhouette_distance`),
        |D₀(π(X_k))|."""
        pixels = camera.project(self.rest, min_depth=MIN_DEPTH)
        return bilinear_differentiable(distance, pixels).abs()


def outline_points(distance: torch.Tensor) -> np.ndarray:
    """(m, 2) [px]: the mask's outline, half-way between every mask pixel and each of its
    non-mask 4-neighbours, from a `silhouette_distance` image (h, w) (negative on the mask).
    A mask cut by the image's edge has none there (nothing lies beyond to compare)."""
    mask = distance.numpy() < 0
    rows, cols = np.nonzero(mask[:, :-1] != mask[:, 1:])
    across = np.stack([cols + 0.5, rows], 1)
    rows, cols = np.nonzero(mask[:-1] != mask[1:])
    down = np.stack([cols, rows + 0.5], 1)
    return np.concatenate([across, down]).astype(np.float64)


def tukey(r: torch.Tensor, reach: float) -> torch.Tensor:
    """Tukey's biweight (n,) [px²] of residuals r (n,) ≥ 0 [px]: τ²/3 (1 − (1 − (r/τ)²)³)
    below τ = reach, τ²/3 beyond."""
    s = (1 - (r / reach) ** 2).clamp_min(0.0)
    return reach**2 / 3 * (1 - s**3)


class CoverTerm:
    """E_cover at rows `rows` (K,) of a sample set, the points of a `BorderCurve` (the `Term`
    protocol plus Gauss–Newton `hessian_blocks`), float64. visible: bool (K,), the points that
    may cover the outline; allowance: (K,) [px] (`BorderCurve.allowance`) or None; start: the
    points' pixels (K, 2) at the start of the frame, which choose the outline points within
    `reach` [px] of a visible point; slack [px]: added to every point's allowance (an outline
    left uncovered by less is not charged)."""

    def __init__(self, camera: Camera, rows: torch.Tensor, curve: BorderCurve,
                 distance: torch.Tensor, *, visible: np.ndarray, allowance: torch.Tensor | None,
                 start: np.ndarray, weight: float, reach: float, slack: float = 0.0):
        self.camera, self.rows, self.curve = camera, rows, curve
        self.visible = np.flatnonzero(visible)
        self.allowance = (torch.zeros(len(curve.xi), dtype=torch.float64) if allowance is None
                          else allowance)
        self.reach = float(reach)
        self.allowance = self.allowance + float(slack)
        outline = outline_points(distance)
        if len(self.visible) and len(outline):
            near, _ = cKDTree(start[self.visible]).query(outline, distance_upper_bound=reach)
            outline = outline[np.isfinite(near)]
        else:
            outline = outline[:0]
        self.outline = torch.from_numpy(outline)
        self.scale = weight / max(len(outline), 1)

    def _residual(self, u: torch.Tensor):
        """Points (m, 3) [m] and pixels (m, 2) of each outline point's nearest visible border
        point, the unit directions (m, 2) from the outline point to it, the residuals r (m,)
        [px] and the nearest point's index (m,) among all K."""
        points = self.curve.rest + u[self.rows]
        pixels = self.camera.project(points, min_depth=MIN_DEPTH)
        visible = pixels[self.visible]
        if not len(self.outline) or not len(visible):
            empty = torch.zeros(0, dtype=torch.float64)
            return points[:0], pixels[:0], pixels[:0], empty, torch.zeros(0, dtype=torch.long)
        _, nearest = cKDTree(visible.detach().numpy()).query(self.outline.numpy())
        k = torch.from_numpy(self.visible[nearest])
        offset = pixels[k] - self.outline
        length = offset.norm(dim=1)
        r = (length - self.allowance[k]).clamp_min(0.0)
        return points[k], pixels[k], offset / length.clamp_min(1e-12)[:, None], r, k

    def parts(self, u_jets: torch.Tensor) -> dict[str, float]:
        """The mean residual penalty [px²] and the number of outline points."""
        _, _, _, r, _ = self._residual(u_jets[:, jets.VALUE].double())
        return {"cover": float(tukey(r, self.reach).mean()) if len(r) else 0.0,
                "cover_points": float(len(r))}

    def evaluate(self, samples, u_jets: torch.Tensor, load_factor: float = 1.0, *,
                 grad: bool = True):
        value, gradient, _ = self._evaluate(u_jets, grad=grad, blocks=False)
        return value, gradient

    def hessian_blocks(self, samples, u_jets: torch.Tensor, load_factor: float = 1.0, *,
                       steps: torch.Tensor) -> torch.Tensor:
        return self._evaluate(u_jets, grad=False, blocks=True)[2]

    def _evaluate(self, u_jets: torch.Tensor, *, grad: bool, blocks: bool):
        dtype, n = u_jets.dtype, u_jets.shape[0]
        points, _, direction, r, k = self._residual(u_jets[:, jets.VALUE].double())
        value = self.scale * tukey(r, self.reach).sum()
        full_grad = full_blocks = None
        if grad or blocks:
            row = torch.einsum("mr,mri->mi", direction,
                               self.camera.projection_jacobian(points, min_depth=MIN_DEPTH))
            s = (1 - (r / self.reach) ** 2).clamp_min(0.0)
            irls = 2.0 * self.scale * s**2 * (r > 0)
            target = self.rows[k]
        if grad:
            gradient = torch.zeros(n, COMPONENTS, dtype=torch.float64)
            gradient.index_add_(0, target, irls[:, None] * r[:, None] * row)
            full_grad = torch.zeros(n, jets.CHANNELS, COMPONENTS, dtype=dtype)
            full_grad[:, jets.VALUE] = gradient.to(dtype)
        if blocks:
            hessian = torch.zeros(n, COMPONENTS, COMPONENTS, dtype=torch.float64)
            hessian.index_add_(0, target, irls[:, None, None] * row[:, :, None] * row[:, None, :])
            full_blocks = torch.zeros(n, jets.CHANNELS, COMPONENTS, jets.CHANNELS, COMPONENTS,
                                      dtype=dtype)
            full_blocks[:, jets.VALUE, :, jets.VALUE, :] = hessian.to(dtype)
        return float(value), full_grad, full_blocks


def visible_points(curve: BorderCurve, outline_offset: torch.Tensor | None) -> np.ndarray:
    """Bool (K,): the border points both of whose edge's vertices the outline term counts as
    seen (a finite `outline_offset`, `inverse.sft.outline.outline_offsets`); all without it."""
    if outline_offset is None:
        return np.ones(len(curve.xi), dtype=bool)
    seen = np.isfinite(outline_offset.numpy())
    return seen[curve.ends[:, 0]] & seen[curve.ends[:, 1]]


def mean_border_edge(curve: BorderCurve, pixels: np.ndarray) -> float:
    """Mean length [px] of the border edges of `curve` on a mesh whose vertices project to
    `pixels` (n, 2)."""
    ends = curve.ends[::curve.per_edge]
    return float(np.linalg.norm(pixels[ends[:, 0]] - pixels[ends[:, 1]], axis=1).mean())
