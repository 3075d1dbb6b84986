"""The data terms of the SfT fit, for either field, as one objective term with Gauss–Newton
Hessian blocks: Newton minimises them on the spline field (`inverse.sft.spline_prior`), Adam
takes their value and gradient on the SIREN (`inverse.sft.siren_prior`).

Every data term is a (robust) least-squares function of the displacement value u at its own
points, so it enters the objective's term interface (`taichi_ndf.objective.Term`): its value
[px²], its gradient with respect to the jets (value channel only) and its per-point Hessian
blocks (N, 6, 3, 6, 3), nonzero only in the value–value 3 × 3 block, the Gauss–Newton
JᵀWJ of its residuals. The points are rows of one sample set: the tracked surface points and
the template vertices follow the shell's quadrature points (weight 0 there, so the shell
energy ignores them):

    E_data(u) = Σ_i w_i ρ(‖π(X_i + u_i) − p_i‖)                 reprojection [px²]
              + w_sil / n · Σ_v D(π(X_v + u_v))²                silhouette [px²] (with a mask)
              + w_temp / (n h²) · Σ_v ‖X_v + u_v − x̂_v‖²        smooth motion [px²-equivalent]
              + w_out / n · Σ_{v ∈ ∂} min(0, D(π(X_v + u_v)) − o_v)²   outline [px²] (with a mask)

with w_i the confidences normalised to sum 1, ρ the Huber penalty (quadratic up to huber_px,
linearised for Gauss–Newton by iteratively reweighted least squares as in the baseline), π the
pinhole projection, D the distance [px] outside the silhouette's outline (0 inside;
`inverse.sft.silhouette.silhouette_residual`), x̂_v = 2 x_{t−1} − x_{t−2} the
constant-velocity prediction of vertex v and h the template's mean edge length. The outline
term acts on the template's border vertices ∂ only: D signed (negative inside the mask), o_v ≤ 0
the depth inside the mask that vertex v is allowed (`outline_offsets`: its own depth in frame
0), so a border vertex that has slid deeper into the silhouette than the template's own
outline lay in frame 0 is pulled back out to it, while inside the allowance it is free. The
silhouette term alone is one-sided (it only pulls vertices in), so a sheet whose outline
retreats inside the mask is not told. With `VertexTerms.silhouette_rows` the silhouette sum
runs over the chosen vertices only (`SplinePriorConfig.silhouette_border_gap`: border vertices
far from every track, and the interior ones); n stays the number of vertices. With
`VertexTerms.silhouette_allowance` a_v ≥ 0 the silhouette residual is max(0, D − a_v): a border
vertex that lay a_v outside mask 0 in frame 0 (the template, right by construction) is not
pulled further in than that.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from inverse.sft.camera import Camera
from inverse.sft.silhouette import bilinear_differentiable, silhouette_residual
from taichi_ndf import jets
from taichi_ndf.problem.sampling import SurfaceSamples

COMPONENTS = 3
# Depth [m] below which projected points are clamped (a bad step must not divide by ~0).
MIN_DEPTH = 1e-6


@dataclass(frozen=True)
class Reprojection:
    """Tracked points: rest positions X_i (n, 3) [m], pixels p_i (n, 2), confidences (n,)."""

    rest: torch.Tensor
    target: torch.Tensor
    confidence: torch.Tensor
    huber_px: float


@dataclass(frozen=True)
class VertexTerms:
    """Template vertices X_v (n, 3) [m]: motion towards `predicted` (n, 3) [m] with weight
    w_temp over the squared mean edge length h² [m²]; silhouette distance image (h, w) [px]
    (None: no silhouette term) with weight w_sil: `inverse.sft.silhouette.silhouette_distance`;
    outline_offset: (n,) [px], the signed distance o_v ≤ 0 a border vertex may reach inside the
    mask, −inf for the other vertices (None: no outline term), with weight w_out;
    silhouette_rows: bool (n,), the vertices the silhouette term acts on (None: all);
    silhouette_allowance: (n,) [px] ≥ 0, the distance outside the mask each vertex may lie
    unpenalised (`inverse.sft.silhouette.silhouette_allowance`; None: 0)."""

    rest: torch.Tensor
    predicted: torch.Tensor
    motion_weight: float
    mean_edge: float
    distance: torch.Tensor | None = None
    silhouette_weight: float = 0.0
    outline_offset: torch.Tensor | None = None
    outline_weight: float = 0.0
    silhouette_rows: torch.Tensor | None = None
    silhouette_allowance: torch.Tensor | None = None


class LeastSquaresData:
    """Reprojection at rows `tracks`, motion and silhouette at rows `vertices` of the samples
    (int64 index tensors, one row per track / vertex, in their order); the `Term` protocol plus
    Gauss–Newton `hessian_blocks`. Float64 throughout.

    slope: the distance image's slope dD/dpx in the silhouette and outline rows. "image" (for
    Newton): the bilinear sample of the image's central differences, smooth across pixel
    edges, so the Gauss–Newton rows do not jump from one pixel to the next. "interpolant" (for
    a first-order minimiser, Adam): the exact derivative of the bilinear interpolant that the
    value samples, so the gradient is the value's own (piecewise constant per pixel)."""

    SLOPES = ("image", "interpolant")

    def __init__(self, camera: Camera, tracks: torch.Tensor, reprojection: Reprojection,
                 vertices: torch.Tensor, vertex_terms: VertexTerms, *, slope: str = "image"):
        if slope not in self.SLOPES:
            raise ValueError(f"slope must be one of {self.SLOPES}, not {slope!r}")
        self.slope = slope
        self.camera = camera
        self.tracks, self.vertices = tracks, vertices
        self.reprojection = reprojection
        c = reprojection.confidence.double()
        self.track_weight = c / c.sum().clamp_min(1e-300)
        self.vertex = vertex_terms
        self.motion_scale = vertex_terms.motion_weight / (
            len(vertex_terms.rest) * vertex_terms.mean_edge**2)
        self.silhouette_scale = vertex_terms.silhouette_weight / len(vertex_terms.rest)
        self.outline_scale = 0.0
        if vertex_terms.outline_offset is not None and vertex_terms.distance is not None:
            self.outline_scale = vertex_terms.outline_weight / len(vertex_terms.rest)
        self.silhouette_on = (None if vertex_terms.silhouette_rows is None
                              else vertex_terms.silhouette_rows.to(torch.float64))
        if vertex_terms.distance is not None:
            gy, gx = np.gradient(vertex_terms.distance.numpy())
            self.distance_gradient = (torch.from_numpy(gx), torch.from_numpy(gy))

    def parts(self, u_jets: torch.Tensor) -> dict[str, float]:
        """Each term's unweighted value: reprojection [px²], motion [m²/h² per vertex],
        silhouette [px² per vertex]."""
        u = u_jets[:, jets.VALUE].double()
        rep = self.reprojection
        residual = self._track_pixels(u) - rep.target
        out = {"reprojection": float((self.track_weight * huber(residual, rep.huber_px)).sum())}
        x = self.vertex.rest + u[self.vertices]
        out["motion"] = float(((x - self.vertex.predicted) ** 2).sum(1).mean()
                              / self.vertex.mean_edge**2)
        if self.vertex.distance is not None:
            d = self._silhouette_residual(self._vertex_pixels(u))
            out["silhouette"] = float((d**2).mean())
        if self.outline_scale > 0:
            d = self._outline_residual(self._vertex_pixels(u))
            out["outline"] = float((d**2).mean())
        return out

    def evaluate(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                 load_factor: float = 1.0, *, grad: bool = True
                 ) -> tuple[float, torch.Tensor | None]:
        """E_data [px²] and dE_data/du_jets (N, 6, 3) (value channel only)."""
        value, gradient, _ = self._evaluate(u_jets, grad=grad, blocks=False)
        return value, gradient

    def hessian_blocks(self, samples: SurfaceSamples, u_jets: torch.Tensor,
                       load_factor: float = 1.0, *, steps: torch.Tensor) -> torch.Tensor:
        """Gauss–Newton blocks (N, 6, 3, 6, 3): JᵀWJ of the residuals at each point in the
        value–value block (positive semi-definite), 0 elsewhere. steps: unused (analytic)."""
        return self._evaluate(u_jets, grad=False, blocks=True)[2]

    # -- the three terms --------------------------------------------------------------------

    def _track_pixels(self, u: torch.Tensor) -> torch.Tensor:
        return self.camera.project(self.reprojection.rest + u[self.tracks], min_depth=MIN_DEPTH)

    def _vertex_pixels(self, u: torch.Tensor) -> torch.Tensor:
        return self.camera.project(self.vertex.rest + u[self.vertices], min_depth=MIN_DEPTH)

    def _silhouette_residual(self, pixels: torch.Tensor) -> torch.Tensor:
        """D [px] (n,) outside the mask, 0 inside and at the vertices the term leaves out."""
        d = silhouette_residual(self.vertex.distance, pixels, self.vertex.silhouette_allowance)
        return d if self.silhouette_on is None else d * self.silhouette_on

    def _outline_residual(self, pixels: torch.Tensor) -> torch.Tensor:
        """min(0, D − o) [px] (n,): how much deeper inside the mask than allowed."""
        depth = bilinear_differentiable(self.vertex.distance, pixels)
        return (depth - self.vertex.outline_offset).clamp_max(0.0)

    def _distance_rows(self, points: torch.Tensor, active: torch.Tensor) -> torch.Tensor:
        """d D(π(x)) / dx (n, 3) at the vertices where `active` (n,) is set, 0 elsewhere."""
        pixels = self.camera.project(points, min_depth=MIN_DEPTH)
        if self.slope == "interpolant":
            pixels = pixels.detach().requires_grad_(True)
            with torch.enable_grad():
                bilinear_differentiable(self.vertex.distance, pixels).sum().backward()
            image_slope = pixels.grad
        else:
            image_slope = torch.stack(
                [bilinear_differentiable(g, pixels) for g in self.distance_gradient], 1)
        slope = active.to(points.dtype)[:, None] * image_slope  # dD/dpx
        return torch.einsum("nr,nri->ni", slope,
                            self.camera.projection_jacobian(points, min_depth=MIN_DEPTH))

    def _evaluate(self, u_jets: torch.Tensor, *, grad: bool, blocks: bool):
        dtype = u_jets.dtype
        u = u_jets[:, jets.VALUE].double()
        n = u.shape[0]
        gradient = torch.zeros(n, COMPONENTS, dtype=torch.float64) if grad else None
        hessian = torch.zeros(n, COMPONENTS, COMPONENTS, dtype=torch.float64) if blocks else None

        # Reprojection, Huber by IRLS: ρ'(r) r̂ = 2 s r with s = 1 or δ/|r|.
        rep = self.reprojection
        points = rep.rest + u[self.tracks]
        residual = self.camera.project(points, min_depth=MIN_DEPTH) - rep.target
        value = (self.track_weight * huber(residual, rep.huber_px)).sum()
        r = residual.norm(dim=1)
        irls = 2.0 * self.track_weight * torch.where(
            r <= rep.huber_px, torch.ones_like(r), rep.huber_px / r.clamp_min(1e-300))
        jac = self.camera.projection_jacobian(points, min_depth=MIN_DEPTH)  # (m, 2, 3)
        if grad:
            gradient[self.tracks] += torch.einsum("m,mri,mr->mi", irls, jac, residual)
        if blocks:
            hessian[self.tracks] += torch.einsum("m,mri,mrj->mij", irls, jac, jac)

        # Smooth motion: quadratic, exact Hessian 2 s I.
        vt = self.vertex
        difference = vt.rest + u[self.vertices] - vt.predicted
        value = value + self.motion_scale * (difference**2).sum()
        if grad:
            gradient[self.vertices] += 2.0 * self.motion_scale * difference
        if blocks:
            eye = torch.eye(COMPONENTS, dtype=torch.float64)
            hessian[self.vertices] += 2.0 * self.motion_scale * eye

        # Silhouette: D(π(x))², Gauss–Newton on the residual D.
        if vt.distance is not None and self.silhouette_scale > 0:
            points = vt.rest + u[self.vertices]
            pixels = self.camera.project(points, min_depth=MIN_DEPTH)
            d = self._silhouette_residual(pixels)
            value = value + self.silhouette_scale * (d**2).sum()
            row = self._distance_rows(points, d > 0)  # inside, D = 0 is flat
            if grad:
                gradient[self.vertices] += 2.0 * self.silhouette_scale * d[:, None] * row
            if blocks:
                hessian[self.vertices] += 2.0 * self.silhouette_scale * (
                    row[:, :, None] * row[:, None, :])

        # Outline: border vertices no deeper inside the mask than allowed, Gauss–Newton.
        if self.outline_scale > 0:
            points = vt.rest + u[self.vertices]
            d = self._outline_residual(self.camera.project(points, min_depth=MIN_DEPTH))
            value = value + self.outline_scale * (d**2).sum()
            row = self._distance_rows(points, d < 0)
            if grad:
                gradient[self.vertices] += 2.0 * self.outline_scale * d[:, None] * row
            if blocks:
                hessian[self.vertices] += 2.0 * self.outline_scale * (
                    row[:, :, None] * row[:, None, :])

        full_grad = full_blocks = None
        if grad:
            full_grad = torch.zeros(n, jets.CHANNELS, COMPONENTS, dtype=dtype)
            full_grad[:, jets.VALUE] = gradient.to(dtype)
        if blocks:
            full_blocks = torch.zeros(n, jets.CHANNELS, COMPONENTS, jets.CHANNELS, COMPONENTS,
                                      dtype=dtype)
            full_blocks[:, jets.VALUE, :, jets.VALUE, :] = hessian.to(dtype)
        return float(value), full_grad, full_blocks


def huber(residual: torch.Tensor, delta: float) -> torch.Tensor:
    """Huber penalty (n,) [px²] of residuals (n, 2) [px]: r² up to δ, 2δr − δ² beyond."""
    r = torch.sqrt((residual**2).sum(dim=1) + 1e-24)
    return torch.where(r <= delta, r**2, 2.0 * delta * r - delta**2)
