"""Shape-from-template frame by frame, for either displacement field: the one per-frame driver.

Frame 0 is the template (the input contract gives it). For every frame t > 0 the driver
gathers what the frame tells about the sheet (`FrameData`): the tracked surface points with
their pixels and confidences (with `flow`, the dense-flow correspondences carried from frame
t − 1's reconstruction added: `inverse.sft.flow`), the constant-velocity prediction
x̂ = 2 x_{t−1} − x_{t−2} of the vertices for the motion term, with a mask the silhouette's
distance image, and with the outline term the allowance of the border vertices that frame
t − 1's reconstruction shows (`inverse.sft.outline`). A `FrameFit` (the one reconstructor,
`inverse.sft.reconstruct.FrameReconstructor`) then minimises its field's prior plus the one
data term of `inverse.sft.least_squares` (`FrameData.data_term`) from its own last state, the
previous frame (warm start): the spline field by Newton (`inverse.sft.spline_prior`) or the
SIREN by Adam (`inverse.sft.siren_prior`), each a `FrameField`. The frames run
through the one continuation loop (`taichi_ndf.minimise.continuation.solve_over`, a frame per
step), which calls the solve callbacks and reports progress per frame; the driver times each
frame (wall and process CPU).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
import torch

from inverse.sft.camera import Camera
from inverse.sft.correspondences import FrameCorrespondences, track_gaps
from inverse.sft.flow import DenseFlow, merged
from inverse.sft.guided import GuidedSearch
from inverse.sft.inputs import Template, mean_edge_length
from inverse.sft.least_squares import LeastSquaresData, Reprojection, VertexTerms
from inverse.sft.outline import border_vertices, outline_allowance, outline_offsets
from inverse.sft.photometric import PhotometricEvidence, PhotometricFrame
from inverse.sft.silhouette import (
    faded_allowance,
    silhouette_allowance,
    silhouette_distance,
)
from taichi_ndf.minimise.continuation import Stages, Step, solve_over

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class DataWeights:
    """The data term's settings: huber_px [px], the reprojection error beyond which its penalty
    grows linearly; the weights w_temp (motion), w_sil (silhouette, with masks) and w_out
    (outline; needs masks and w_sil > 0; 0: no outline term); silhouette_border_gap: the
    silhouette term acts on a border vertex of the template only where the frame has no
    tracked point within this many mean edge lengths of it (0: on every border vertex; inf:
    on none), and on every interior vertex; silhouette_allowance: the silhouette term
    tolerates each border vertex as far outside the mask as the template lay outside mask 0
    (`inverse.sft.silhouette.silhouette_allowance`), only where a tracked point lies within
    allowance_reach mean edge lengths of it (None: everywhere)."""

    huber_px: float
    temporal_weight: float
    silhouette_weight: float
    outline_weight: float = 0.0
    silhouette_border_gap: float = 0.0
    silhouette_allowance: bool = False
    allowance_reach: float | None = None
    allowance_fade: float | None = None  # mean edges (`silhouette.faded_allowance`)


@dataclass(frozen=True)
class FrameData:
    """What frame `index` tells about the sheet, on the template (n vertices X (n, 3) [m],
    `rest`, float64; mean edge length h [m]): the m tracked surface points' UVs ξ (m, 2) and
    template positions (m, 3) [m], their pixels (m, 2) [px] and confidences (m,); the vertices'
    predicted positions x̂ (n, 3) [m]; the mask's `silhouette_distance` (h, w) [px] or None;
    the outline offsets (n,) [px] (`outline_offsets`) or None; the photometric term's data
    (`inverse.sft.photometric`) or None; the vertices the silhouette term acts on, bool (n,),
    or None for all; the silhouette allowance (n,) [px] or None."""

    index: int
    camera: Camera
    rest: torch.Tensor
    mean_edge: float
    weights: DataWeights
    track_xi: torch.Tensor
    track_rest: torch.Tensor
    pixels: torch.Tensor
    confidence: torch.Tensor
    predicted: torch.Tensor
    distance: torch.Tensor | None
    outline_offset: torch.Tensor | None
    photometric: PhotometricFrame | None = None
    silhouette_rows: torch.Tensor | None = None
    silhouette_allowance: torch.Tensor | None = None
    first_distance: torch.Tensor | None = None  # mask 0's `silhouette_distance` (the cover term)

    def data_term(self, tracks: torch.Tensor, vertices: torch.Tensor, *,
                  slope: str = "image") -> LeastSquaresData:
        """The frame's data term on a batch of points where rows `tracks` (m,) are the tracked
        points and rows `vertices` (n,) the template vertices (int64); slope: the distance
        image's slope, "image" for Newton, "interpolant" for Adam (`LeastSquaresData`)."""
        w = self.weights
        return LeastSquaresData(
            self.camera, tracks,
            Reprojection(self.track_rest, self.pixels, self.confidence, w.huber_px),
            vertices,
            VertexTerms(self.rest, self.predicted, w.temporal_weight, self.mean_edge,
                        self.distance, w.silhouette_weight, self.outline_offset,
                        w.outline_weight, self.silhouette_rows, self.silhouette_allowance),
            slope=slope)


@dataclass(frozen=True)
class FittedFrame:
    """One frame's vertices [m] (n, 3), template order; its final loss terms; the
    minimiser's iterations (Newton iterations or Adam steps)."""

    vertices: np.ndarray
    losses: dict[str, float]
    iterations: int


class FrameFit(Protocol):
    """The field-specific minimisation of one frame, from the field's last state."""

    weights: DataWeights

    def fit_frame(self, frame: FrameData) -> FittedFrame: ...


@dataclass(frozen=True)
class FrameSolve:
    """A field's minimisation of one frame: u_jets (N, 6, 3) [m] at the rows the frame's
    terms index (`FrameField.rows`) where its loss terms are reported; parts: the field's own
    loss terms ("inertia", "energy" = Π_int / E_ref); iterations: Newton iterations or Adam
    steps."""

    u_jets: torch.Tensor
    parts: dict[str, float]
    iterations: int


class FrameField(Protocol):
    """One field type's part of the frame fit (`inverse.material.field_types` names the class
    per settings class), built as `frame_field(surface, conditions, config, mean_edge=,
    material=, energy_reference=)` on the template's surface (`MeshSurface`), the pinned
    conditions (or None), the settings, the template's mean edge length [m], the prior's
    material and E_ref [J].

    field: the displacement field (under the conditions through its `DisplacementOperator`);
    dtype: of its evaluation points; slope: the distance image's slope its minimiser follows
    (`LeastSquaresData`: "image" for Newton, "interpolant" for Adam)."""

    field: Any
    dtype: torch.dtype
    slope: str

    def displacement(self, xi: torch.Tensor) -> torch.Tensor:
        """u (N, 3) [m] at ξ (N, 2) of the current state (no tape kept for a solve)."""

    def rows(self, blocks: Sequence[torch.Tensor]) -> list[torch.Tensor]:
        """Start a frame on the data points `blocks` (each (n_k, 2) of ξ, in order): the row
        of each block's points (int64 (n_k,)) in the u_jets the frame's terms see."""

    def solve(self, terms: Sequence[Any]) -> FrameSolve:
        """Minimise the prior plus `terms` (built on the rows `rows` gave) from the field's
        current state, which it leaves at the solution."""

    def fit_to(self, xi: torch.Tensor, target: torch.Tensor) -> None:
        """Fit u at ξ (n, 2) to `target` (n, 3) [m] (a per-frame initial guess; a field
        whose `InverseFieldType.initial_guesses` is false need not have it)."""


@dataclass
class ReconstructionResult:
    """Vertices per frame [m] (n, 3), template order; wall and process CPU seconds (all
    threads) and iterations per frame; final loss terms per frame (frame 0: the template,
    0 s, no terms)."""

    vertices: list[np.ndarray]
    seconds: list[float]
    cpu_seconds: list[float]
    iterations: list[int]
    losses: list[dict[str, float]] = field(default_factory=list)


def reconstruct_frames(template: Template, camera: Camera,
                       correspondences: Sequence[FrameCorrespondences], fit: FrameFit, *,
                       masks: Sequence[np.ndarray] | None = None,
                       flow: DenseFlow | None = None,
                       guided: GuidedSearch | None = None,
                       photometric: PhotometricEvidence | None = None,
                       callbacks: Sequence[Any] = ()) -> ReconstructionResult:
    """Vertices for every frame (frame 0 = template), fitted frame by frame by `fit`.

    The frames are the steps of the one continuation loop
    (`taichi_ndf.minimise.continuation.solve_over`, step value: the frame index): a frame
    starts from the vertices of the frames before it, its fit is the step's solve and its
    timing and result the bookkeeping after it. masks: per-frame silhouettes (bool (h, w)) or
    None; flow: dense flow correspondences added to each frame's tracks, carried from the frame
    before's reconstruction; guided: texture points re-found near where the frames before
    predict them (`inverse.sft.guided`), added to each frame's tracks; photometric: the
    texture compared with the frame at the points visible from frame t − 1's surface
    (`inverse.sft.photometric`; a fit that takes it adds the term); callbacks: the loop's
    callbacks (`taichi_ndf.minimise.callbacks`: on_start, on_load_step(fit, frame index) after
    each frame, on_end), called with `fit`.
    """
    weights = fit.weights
    rest = torch.from_numpy(template.vertices).double()
    mean_edge = mean_edge_length(template.vertices, template.faces)
    # Frame 0's mask as a distance image: the allowances below and the cover term's.
    first_distance = None
    if masks is not None and weights.silhouette_weight > 0:
        first_distance = silhouette_distance(masks[0])
    # How deep inside the mask each visible border vertex may lie (frame 0's outline).
    allowance = None
    if first_distance is not None and weights.outline_weight > 0:
        allowance = outline_allowance(template.vertices, template.faces, camera,
                                      first_distance, tolerance=mean_edge)
    border = border_vertices(template.faces, len(template.vertices))
    # How far outside the mask each border vertex may lie unpenalised (frame 0's disagreement).
    tolerated = None
    if first_distance is not None and weights.silhouette_allowance:
        tolerated = torch.from_numpy(silhouette_allowance(
            first_distance, camera.project(rest).numpy(), border))
        log.info("silhouette allowance: %d border vertices outside mask 0, up to %.2f px",
                 int((tolerated > 0).sum()), float(tolerated.max()))
    result = ReconstructionResult([template.vertices.copy()], [0.0], [0.0], [0], [{}])
    first_pixels = camera.project(template.vertices)  # frame 0's, for a fading allowance
    fade_px = (weights.allowance_fade or 0.0) * float(np.mean(np.linalg.norm(
        first_pixels[template.faces] - first_pixels[np.roll(template.faces, 1, 1)], axis=2)))

    def solve(step: Step, history: list[np.ndarray]) -> tuple[FittedFrame, float, float]:
        """Frame `step.value` fitted from `history`, the vertices of the (at most two) frames
        before it; with its wall and process CPU seconds."""
        i = int(step.value)
        start, cpu = time.perf_counter(), time.process_time()
        seen = correspondences[i]
        if guided is not None:
            seen = merged(seen, guided.correspondences(i, history, seen))
        if flow is not None:
            seen = merged(seen, flow.correspondences(i, history[-1]))
        distance = offsets = None
        if masks is not None and weights.silhouette_weight > 0:
            distance = silhouette_distance(masks[i])
            if allowance is not None:
                offsets = outline_offsets(allowance, history[-1], template.faces,
                                          tolerance=mean_edge)
        silhouette_rows = None  # every vertex
        allowed = tolerated
        if weights.silhouette_border_gap > 0 or (
                tolerated is not None and weights.allowance_reach is not None):
            gaps = track_gaps(template.vertices, template.faces, seen, mean_edge)
            if weights.silhouette_border_gap > 0:
                silhouette_rows = torch.from_numpy(
                    ~border | (gaps > weights.silhouette_border_gap))
            if tolerated is not None and weights.allowance_reach is not None:
                allowed = tolerated * torch.from_numpy(gaps <= weights.allowance_reach)
        if allowed is not None and weights.allowance_fade is not None:
            allowed = torch.from_numpy(faded_allowance(
                allowed.numpy(), first_pixels, camera.project(history[-1]), fade_px))
        faces = template.faces[seen.face]
        bary = torch.from_numpy(seen.bary)
        previous = torch.from_numpy(history[-1])
        before = torch.from_numpy(history[-2]) if len(history) > 1 else previous
        frame = FrameData(
            index=i, camera=camera, rest=rest, mean_edge=mean_edge, weights=weights,
            track_xi=(bary[:, :, None] * torch.from_numpy(template.uvs[faces])).sum(1),
            track_rest=(bary[:, :, None] * rest[torch.from_numpy(faces)]).sum(1),
            pixels=torch.from_numpy(seen.xy), confidence=torch.from_numpy(seen.confidence),
            predicted=2.0 * previous - before, distance=distance, outline_offset=offsets,
            photometric=None if photometric is None else photometric.frame(i, history[-1]),
            silhouette_rows=silhouette_rows, silhouette_allowance=allowed,
            first_distance=first_distance)
        fitted = fit.fit_frame(frame)
        return fitted, time.perf_counter() - start, time.process_time() - cpu

    def keep(step: Step, solved: tuple[FittedFrame, float, float]) -> None:
        fitted, seconds, cpu_seconds = solved
        result.seconds.append(seconds)
        result.cpu_seconds.append(cpu_seconds)
        result.vertices.append(fitted.vertices)
        result.iterations.append(fitted.iterations)
        result.losses.append(fitted.losses)
        log.debug("frame %d: %.2f s, %d iterations, %s", step.value, seconds,
                  fitted.iterations, fitted.losses)

    if len(correspondences) > 1:
        solve_over(Stages(solve, lambda _step, _previous, _coarser: result.vertices[-2:],
                          after_step=keep),
                   range(1, len(correspondences)), callbacks=callbacks, subject=fit,
                   stage="SfT reconstruction, frames")
    log.info("SfT reconstruction: %d frames, %.2f s per frame", len(result.vertices),
             np.mean(result.seconds[1:]) if len(result.seconds) > 1 else 0.0)
    return result
