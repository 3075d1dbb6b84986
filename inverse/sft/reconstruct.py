"""Physics-regularised shape-from-template, frame by frame, on either displacement field: the
one reconstructor (`FrameReconstructor`, a `inverse.sft.sequential.FrameFit`).

Each frame's surface is x(ξ) = X(ξ) + u(ξ) on the template's reference surface (ξ = the
template's UVs; X the template itself, piecewise linear for data and output, its C² spline fit
``MeshSurface`` for the energy), with u the displacement field that the settings name: a cubic
B-spline solved by Gauss–Newton (`SplinePriorConfig`, `inverse.sft.spline_prior`) or a SIREN
trained by Adam (`ReconstructionConfig`, `inverse.sft.siren_prior`), looked up in the inverse
registry (`inverse.material.field_types`, the one place in `inverse` that tells field types
apart). Frame 0 is the template (the input contract gives it). Frame t > 0 starts from frame
t − 1's field (warm start) and minimises

    E(u) = E_data(u) + w_phys · Π_int(u) / E_ref

E_data the least-squares data terms of `inverse.sft.least_squares` (robust reprojection of the
tracked points, silhouette of the template vertices with masks, the outline of the visible
border vertices, smooth motion towards the constant-velocity prediction), with the spline
field optionally the photometric term (`inverse.sft.photometric`) and the cover term
(`inverse.sft.contour`); Π_int the Kirchhoff–Love internal energy of a fixed linear isotropic
material over the template, and E_ref = B / 2 the bending energy of the template bent to
uniform curvature 1/√A (A its area, B the bending stiffness), so Π_int / E_ref is
dimensionless and does not depend on the stiffness scale: the prior is fixed by ν, the
thickness h (D / B = 12 / h²) and the one number w_phys, chosen once on a tuning sequence and
never per sequence. Pinned vertices are exact: u = φ N with ``PinnedPoint`` conditions at
their UVs.

What differs between the fields is the field's (`inverse.sft.sequential.FrameField`): the
field itself, where the prior's energy is evaluated (a SIREN: Monte-Carlo samples redrawn every
Adam step; a spline: the fixed `taichi_ndf.discretise.trimmed.sheet_quadrature`), where the
data terms' rows lie among those points, and the minimiser (Adam on the gradients; projected
Newton on the shell's Hessian blocks and the data terms' Gauss–Newton blocks). This module
holds the rest: the template's surface, the pinned conditions, the prior's material and
E_ref, the frame's data points and terms, the reported loss terms and the vertices.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch

from inverse.material.field_types import of_frame_settings
from inverse.sft.contour import BorderCurve, CoverTerm, mean_border_edge, visible_points
from inverse.sft.inputs import Template, mean_edge_length
from inverse.sft.sequential import DataWeights, FittedFrame, FrameData
from taichi_ndf.boundary import BoundaryConditions
from taichi_ndf.boundary.constraints import PinnedPoint
from taichi_ndf.geometry import MeshSurface
from taichi_ndf.shell.materials import preset

log = logging.getLogger(__name__)


class FrameReconstructor:
    """Holds the template's surface, the frame field that the settings name and the
    per-frame fit (a `inverse.sft.sequential.FrameFit`).

    pinned: template vertex indices held at their template positions (None: none); initial:
    per-frame initial guesses of the vertices [m] (n, 3) (e.g. the baseline's) that each
    frame's field is first fitted to (ValueError on a field without initial guesses);
    config: `SplinePriorConfig` or `ReconstructionConfig`."""

    def __init__(self, template: Template, *, pinned: np.ndarray | None = None,
                 initial: Sequence[np.ndarray] | None = None, config: Any = None):
        kind = of_frame_settings(config)
        if initial is not None and not kind.initial_guesses:
            raise ValueError(f"initial guesses are not for the {kind.field_type.name} field: it "
                             "starts each frame from the previous frame's solution")
        self.config = cfg = config
        self.weights = DataWeights(cfg.huber_px, cfg.temporal_weight, cfg.silhouette_weight,
                                   cfg.outline_weight, cfg.silhouette_border_gap,
                                   cfg.silhouette_allowance, cfg.allowance_reach,
                                   cfg.allowance_fade)
        self.template = template
        self.initial = initial
        self.surface = MeshSurface(template.vertices, template.faces, template.uvs,
                                   name="template")
        self.mean_edge = mean_edge_length(template.vertices, template.faces)
        self.conditions = None
        if pinned is not None and len(pinned):
            points = [PinnedPoint(xi=tuple(float(c) for c in template.uvs[i])) for i in pinned]
            self.conditions = BoundaryConditions(points, self.surface.domain)
        material = preset(cfg.material)
        material = material.with_stiffness(
            membrane_stiffness=cfg.membrane_factor * material.membrane_stiffness)
        self.energy_reference = 0.5 * material.bending_stiffness
        self.frame_field = kind.frame_field(self.surface, self.conditions, cfg,
                                       mean_edge=self.mean_edge, material=material,
                                       energy_reference=self.energy_reference)
        self.field = self.frame_field.field
        self.vertex_xi = torch.from_numpy(template.uvs).to(self.frame_field.dtype)
        self.rest = torch.from_numpy(template.vertices).double()
        # The mask's outline covered by the border (`inverse.sft.contour`; w_cover > 0).
        self.border_curve = self.cover_allowance = None
        if cfg.cover_weight > 0:
            self.border_curve = BorderCurve.of(template.vertices, template.faces, template.uvs,
                                               per_edge=cfg.cover_points)

    def vertices(self) -> np.ndarray:
        """The current surface at the template vertices [m], shape (n, 3), template order."""
        return (self.rest + self.frame_field.displacement(self.vertex_xi).double()).numpy()

    def fit_frame(self, frame: FrameData) -> FittedFrame:
        """One frame's vertices, its final loss terms and the minimiser's iterations; the
        solve starts from the field's current state (the last frame's), fitted first to the
        frame's initial guess where one is given."""
        if self.initial is not None:
            guess = np.asarray(self.initial[frame.index]) - self.template.vertices
            self.frame_field.fit_to(self.vertex_xi, torch.from_numpy(guess))
        dtype = self.frame_field.dtype
        blocks = [frame.track_xi.to(dtype), self.vertex_xi]
        photo = frame.photometric
        if photo is not None:
            blocks.append(photo.xi.to(dtype))
        cover = self.border_curve is not None and frame.distance is not None
        if cover:
            blocks.append(self.border_curve.xi.to(dtype))
        rows = self.frame_field.rows(blocks)
        data = frame.data_term(rows[0], rows[1], slope=self.frame_field.slope)
        terms = [data]
        if photo is not None:
            terms.append(photo.term(frame.camera, rows[2]))
        if cover:
            terms.append(self._cover_term(frame, rows[-1]))
        solved = self.frame_field.solve(terms)
        parts = data.parts(solved.u_jets)
        for term in terms[1:]:
            parts.update(term.parts(solved.u_jets))
        parts.update(solved.parts)
        return FittedFrame(self.vertices(), parts, solved.iterations)

    def _cover_term(self, frame: FrameData, rows: torch.Tensor) -> CoverTerm:
        """The frame's cover term (`inverse.sft.contour`) at rows `rows`, its outline points
        chosen near the border of the field's current shape (the frame's start)."""
        curve, cfg = self.border_curve, self.config
        if self.cover_allowance is None and frame.first_distance is not None:
            self.cover_allowance = curve.allowance(frame.camera, frame.first_distance)
        start = curve.rest + self.frame_field.displacement(curve.xi).double()
        start_pixels = frame.camera.project(start).numpy()
        edge = mean_border_edge(curve, frame.camera.project(torch.from_numpy(self.vertices())
                                                            ).numpy())
        return CoverTerm(frame.camera, rows, curve, frame.distance,
                         visible=visible_points(curve, frame.outline_offset),
                         allowance=self.cover_allowance, start=start_pixels,
                         weight=cfg.cover_weight, reach=cfg.cover_reach * edge,
                         slack=cfg.cover_slack * edge)
