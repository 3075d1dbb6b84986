"""The shell's material from a reconstructed video of a sheet held at two corners.

Input: the per-frame reconstructions (vertex positions, template order, camera coordinates
[m], e.g. `ndf-sft`'s meshes) of a grid template held at two corner vertices, and gravity in
camera coordinates. Each used frame becomes one observation of `inverse.material`: its model is
`hanging.hanging_model` — the flat sheet of the template's grid-line lengths, the held corners
where the reconstruction puts them in that frame, the reference plane hanging vertically from
the corner line (`hanging.hanging_across`), gravity — and its points are the reconstructed
vertices with their surface coordinates (correspondence). With `corners="fitted"` (default)
the held corners of every frame whose corners are not the template's (SfT's frame 0 is the
template) are unknowns too, 3 coordinates each (`Observation.free_handles`,
`inverse.material.handles`; docs/sft.md §8). The
unknown bending stiffness B (and optionally the membrane stiffness D) is then fitted to all
frames at once by the Newton method of `ndf-fit-material` (`newton_fit.newton_estimate`): each
frame's shape is the cloth's own equilibrium (spline field + projected Newton) under gravity
with its corners held where the video puts them, B is found by Levenberg–Marquardt with
implicit-function Jacobians over the frames' equilibria, on two grids; its standard error
combines the noise part — the larger of the Fisher error and the cluster-robust (sandwich)
error with one cluster per frame, since a reconstruction's error is smooth and its held
corners are shared by the whole frame, so residuals are not independent — and the two grids'
difference; the identifiability statement is that method's (eigen-analysis of the Fisher
matrix).

Identifiability: under gravity alone the shape fixes the stiffness only relative to the weight:
B / (ρ_A g), i.e. the bending length c = (B / (ρ_A g))^(1/3). B itself follows from a stated
areal density ρ_A (`areal_density`). D enters as D / (ρ_A g): it is estimated beside B unless
a `membrane_stiffness` is stated (then held there). Measured on a synthetic hanging sheet
(benchmarks/RESULTS.md, Material from video): at D = 100 N/m the sheet stretches 0.4 % under
its weight, and the shape between the held corners depends on it enough that a held D of
300 N/m put B 87 % low; estimated, D came out 101.7 ± 4.3 N/m and B within 1.5 %.

The flat sheet's size: `sheet_size` when stated; else from the template's grid-line lengths
(the template file's own vertices, `rest`): a planar template is the flat sheet; a template
that is frame 0's hanging shape (as SfT templates are) carries that frame's stretch under
gravity, which `unstretched_grid` removes with the fitted frame-0 equilibrium
(`sheet_size_from="equilibrium"`, default; measured: +15 % in B taken as it is, −0.55 %
unstretched, benchmarks/RESULTS.md).

What is compared (`observed`): all three coordinates of each vertex ("3d", default), or the
two directions across its camera ray ("ray", the camera centre at the origin of the camera
coordinates) — measured worse on a sheet facing the camera, whose bending is seen along the
rays (benchmarks/RESULTS.md, Material from video, 2026-12-06).

Frame weights (`frame_weights`): "equal" counts every vertex of every frame alike; "misfit"
counts each frame by the inverse of its own misfit variance (`misfit_weights`: the rms misfit
of the coarse-grid fit that precedes the final one — the flat-size passes' last or the
coarse estimate's), i.e. weighted least squares with one variance per frame, the same
clusters as the robust error. A frame that the model explains worse — a reconstruction further
from the truth, a frame that is not an equilibrium — counts less; the template (frame 0 of an
SfT sequence, the given shape) typically counts most. Measured in benchmarks/RESULTS.md
(Material from video, 2026-12-06 09:20).

Quasi-static check: the held corners' accelerations (second differences of the reconstructed
corner positions at the frame rate) over g; a frame whose corners accelerate by more than
`QUASI_STATIC_LIMIT` g is not an equilibrium, and the report says how many there are. The
used frames: `frames` evenly spread, among those whose whole sheet accelerates by at most
`quasi_static_limit` g when that is stated (`material_frames`; the report's "frame_choice").
"""

from __future__ import annotations

import logging
import math
import time

import numpy as np
import torch

from inverse.material.handles import offset_report
from inverse.material.newton_fit import NewtonEstimateConfig, newton_estimate
from inverse.material.observations import Observation, ray_rows
from inverse.material.outer_fit import OuterConfig
from inverse.material.report import estimate_document
from inverse.material.spline_equilibrium import SplineModelConfig
from inverse.material.unknowns import parse_unknowns
from inverse.sft.hanging import SheetGrid, hanging_across, hanging_model
from inverse.sft.material_frames import QUASI_STATIC_LIMIT, corner_accelerations, used_frames
from inverse.sft.material_grid import GridChoice
from inverse.sft.settings import FABRIC_BENDING_LENGTH, MaterialFromVideoConfig

log = logging.getLogger(__name__)

# The flat size from a frame-0 template (`unstretched_grid`): most passes, stop below this change
SIZE_PASSES, SIZE_TOLERANCE = 3, 2e-5
PLANAR_TOLERANCE = 1e-4  # a template within this fraction of its diagonal of a plane is flat
MISFIT_FLOOR = 1e-6  # [m] smallest per-frame misfit a frame weight is computed from
HELD_HANDLES = (0, 1)  # the held corners' handles among a frame model's constraints

def frame_observations(vertices: list[np.ndarray], grid: SheetGrid,
                       config: MaterialFromVideoConfig, frames: list[int],
                       weights: np.ndarray | None = None, *,
                       given_corners: np.ndarray | None = None) -> list[Observation]:
    """One observation per used frame (module docstring); `weights` (one per used frame)
    scale each frame's residuals (`Observation.rows`); corners "fitted": a frame's held
    corners are unknowns unless they are the `given_corners` (2, 3) [m] (the template's)."""
    material = config.start_material
    xi = torch.from_numpy(grid.xi)
    observations = []
    for k, f in enumerate(frames):
        points = np.asarray(vertices[f], dtype=np.float64)
        gravity = np.asarray(config.gravity, dtype=np.float64)
        corners = points[list(grid.held)]
        across = hanging_across(corners, gravity)
        model = hanging_model(grid.size, material, corners, across, gravity, band=config.band)
        observed = torch.from_numpy(points)
        rows = ray_rows(observed) if config.observed == "ray" else None
        if weights is not None:
            if rows is None:
                rows = torch.eye(3, dtype=observed.dtype).expand(len(observed), 3, 3)
            rows = float(weights[k]) * rows.clone()
        given = given_corners is not None and np.abs(corners - given_corners).max() <= 1e-6
        free = HELD_HANDLES if config.corners == "fitted" and not given else ()
        observations.append(Observation(model, observed, xi, rows, free))
    return observations


def misfit_weights(per_frame_rms: np.ndarray) -> np.ndarray:
    """Per-frame weights w_f = σ̄ / σ_f from each frame's rms misfit σ_f [m] of a first fit
    (σ̄ their rms, so the weighted residuals keep the scale of metres; σ_f floored at
    `MISFIT_FLOOR`): a frame's vertices counted with the inverse of its own misfit variance —
    weighted least squares with one variance per frame, as the cluster-robust error's one
    cluster per frame."""
    sigma = np.maximum(np.asarray(per_frame_rms, dtype=np.float64), MISFIT_FLOOR)
    return float(np.sqrt(np.mean(sigma ** 2))) / sigma


def estimate_material(vertices: list[np.ndarray], faces: np.ndarray, held: tuple[int, int],
                      config: MaterialFromVideoConfig | None = None, *,
                      rest: np.ndarray | None = None) -> dict:
    """Estimate the material from per-frame vertex positions (module docstring).

    vertices: per frame (V, 3) [m], template order, camera coordinates; faces: (F, 3)
    template faces; held: the two held corner vertices; rest: (V, 3) [m] the template's own
    vertices, whose grid-line lengths give the flat sheet's size unless `config.sheet_size`
    states it (exact for a flat template; a template that is a hanging frame carries that
    frame's stretch; None: the reconstructed frame 0, which gravity has stretched).
    Returns the report (`report`'s keys)."""
    config = config or MaterialFromVideoConfig()
    t0, cpu = time.perf_counter(), time.process_time()
    template = np.asarray(vertices[0] if rest is None else rest, dtype=np.float64)
    grid = SheetGrid.from_template(template, faces, held)
    if config.sheet_size is not None:
        grid = grid.with_size(config.sheet_size)
    g = float(np.linalg.norm(config.gravity))
    frames, frame_choice = used_frames(vertices, config.frames, config.fps, g,
                                       config.quasi_static_limit)
    given = template[list(grid.held)]  # held where a frame's corners are the template's
    observations = frame_observations(vertices, grid, config, frames, given_corners=given)
    spec = "bending,stretch" if config.estimate_membrane else "bending"
    _, unknowns = parse_unknowns(spec, observations[0].model)
    material = config.start_material
    start = [material.bending_stiffness] + (
        [material.membrane_stiffness] if config.estimate_membrane else [])
    size_from = "stated" if config.sheet_size is not None else config.sheet_size_from
    if size_from == "equilibrium" and planar(template):
        size_from = "template"  # a flat template is the flat sheet: nothing to unstretch
    choice = GridChoice(config, g)
    spans = choice.first(grid.size)
    passes, coarse_rms, weights = [], None, None
    if size_from == "equilibrium":
        grid, start, passes = unstretched_grid(vertices, faces, grid, config, frames,
                                               unknowns, start, spans, given)
        observations = frame_observations(vertices, grid, config, frames, given_corners=given)
        coarse_rms = np.array(passes[-1]["per_frame_rms_m"])
    elif choice.chosen or config.frame_weights == "misfit":  # a coarse first estimate
        coarse = newton_estimate(observations, unknowns, _newton(config, spans, 1),
                                 start=start)
        start = [float(v) for v in coarse.fits[-1].values]
        coarse_rms = _per_frame_rms(coarse.fits[-1].residuals, observations)
    if config.frame_weights == "misfit":
        weights = misfit_weights(coarse_rms)
        observations = frame_observations(vertices, grid, config, frames, weights,
                                          given_corners=given)
    spans = choice.next(grid.size, start[0], "coarse estimate") or spans
    result = newton_estimate(observations, unknowns, _newton(config, spans, 2), start=start)
    finer_spans = choice.next(grid.size, float(result.fits[-1].values[0]), "estimate",
                              only_finer=spans)
    if finer_spans and result.fits[-1].converged:  # refine once: the estimate's c asks
        result = newton_estimate(observations, unknowns, _newton(config, finer_spans, 2),
                                 start=[float(v) for v in result.fits[-1].values])
    document = estimate_document(result.estimate, observations[0].model, ratios=result.ratios,
                                 notes=result.notes + choice.notes)
    fit = result.fits[-1]
    unit = np.ones(len(frames)) if weights is None else weights
    per_frame = _per_frame_rms(fit.residuals, observations) / unit
    accelerations = corner_accelerations(vertices, grid.held, config.fps)
    grids = [{"spans": list(f.label["spans"]), "degree": config.degree,
              "bending_stiffness": float(f.values[0]),
              **({"membrane_stiffness": float(f.values[1])} if config.estimate_membrane
                 else {}),
              "rms_m": _rms(_per_frame_rms(f.residuals, observations) / unit, observations)}
             for f in result.fits]
    document["misfit"] = _rms(per_frame, observations)  # unweighted [m]
    out = report(document, grid, frames, per_frame, accelerations / g, config,
                 (time.perf_counter() - t0, time.process_time() - cpu), grids,
                 stable=all(f.stable for f in result.fits),
                 converged=all(f.converged for f in result.fits))
    out["bending_stiffness"]["standard_error_parts"] = error_parts(result, 0)
    out["sheet_size_from"] = size_from
    out["sheet_size_passes"] = passes
    out["grid_choice"] = choice.steps
    out["frame_choice"] = frame_choice
    out["frame_weights"] = {"kind": config.frame_weights, "weights": unit.tolist(),
                            "coarse_per_frame_rms_m": None if coarse_rms is None
                            else coarse_rms.tolist()}
    check = result.coarse_at_fine_handles  # the grid difference's coarse fit, corners held
    out["corners"] = {"kind": config.corners, "frames": offset_report(fit, observations, frames),
                      "coarse_grid_at_fitted_corners": None if check is None else {
                          "spans": list(check.label["spans"]), "values": check.values.tolist()}}
    return out


def _newton(config: MaterialFromVideoConfig, spans: tuple[int, int],
            levels: int) -> NewtonEstimateConfig:
    return NewtonEstimateConfig(
        model=SplineModelConfig(spans=tuple(int(s) for s in spans),
                                degree=config.degree, boundary_length=None),
        outer=OuterConfig(max_iterations=config.max_iterations, max_step=1.0),
        levels=levels, start_from_observations=True, clustered=True)


def planar(vertices: np.ndarray) -> bool:
    """Whether the vertices lie in one plane (within PLANAR_TOLERANCE of their diagonal)."""
    centred = vertices - vertices.mean(axis=0)
    normal = np.linalg.svd(centred, full_matrices=False)[2][-1]
    diagonal = float(np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0)))
    return float(np.abs(centred @ normal).max()) <= PLANAR_TOLERANCE * diagonal


def unstretched_grid(vertices, faces, grid: SheetGrid, config: MaterialFromVideoConfig,
                     frames: list[int], unknowns, start: list[float],
                     spans: tuple[int, int], given: np.ndarray | None = None):
    """The flat sheet's size when the template is the sheet's shape in frame 0 (as SfT
    templates are): the template's grid-line lengths are the flat sheet's stretched by that
    frame's equilibrium, so the size is updated by the fixed point
    size ← size · (template's lengths / the fitted frame-0 equilibrium's lengths), each pass
    a fit on the coarse grid `spans` from the previous pass's values, until the size changes by less
    than SIZE_TOLERANCE (at most SIZE_PASSES). Returns the grid, the last values (the start
    of the final fit) and per pass the size and the fitted values."""
    measured = np.array(grid.size)
    passes = []
    for _ in range(SIZE_PASSES):
        observations = frame_observations(vertices, grid, config, frames, given_corners=given)
        coarse = newton_estimate(observations, unknowns, _newton(config, spans, 1),
                                 start=start)
        start = [float(v) for v in coarse.fits[-1].values]
        shape = coarse.fitted_positions(frames.index(0), torch.from_numpy(grid.xi))
        lengths = np.array(SheetGrid.from_template(shape.detach().numpy(), faces,
                                                   grid.held).size)
        size = np.array(grid.size) * measured / lengths
        change = float(np.abs(size / np.array(grid.size) - 1).max())
        passes.append({"size_m": size.tolist(), "values": start, "change": change,
                       "per_frame_rms_m": _per_frame_rms(coarse.fits[-1].residuals,
                                                         observations).tolist()})
        log.info("flat size from the template: %s (change %.2g)", size.tolist(), change)
        grid = grid.with_size(tuple(float(v) for v in size))
        if change < SIZE_TOLERANCE:
            break
    return grid, start, passes


def error_parts(result, index: int) -> dict:
    """Unknown `index`'s standard error parts [its unit]: the Fisher error (independent
    residuals), the noise part used (the larger of it and the cluster-robust error over the
    frames) and the discretisation part (the two grids' difference)."""
    fit = result.fits[-1]
    value = float(fit.values[index])
    jacobian = fit.jacobian  # in z = ln θ: relative errors (the corners profiled out)
    dof = max(len(fit.residuals) - jacobian.shape[1] - fit.nuisance, 1)
    sigma2 = float(fit.residuals @ fit.residuals) / dof
    try:
        fisher = math.sqrt(sigma2 * float(np.linalg.inv(jacobian.T @ jacobian)[index, index]))
    except np.linalg.LinAlgError:
        fisher = math.inf
    return {"fisher": fisher * value, "noise": float(result.fisher_errors[index]),
            "discretisation": float(result.model_errors[index])}


def _per_frame_rms(residuals: np.ndarray, observations: list[Observation]) -> np.ndarray:
    """Per observation: rms distance [m] per point (the residuals as they are, weighted)."""
    sizes = [o.components * len(o.points) for o in observations]
    parts = np.split(residuals, np.cumsum(sizes)[:-1])
    return np.array([math.sqrt(float(p @ p) / len(o.points))
                     for p, o in zip(parts, observations, strict=True)])


def _rms(per_frame: np.ndarray, observations: list[Observation]) -> float:
    """The rms over all points [m] of per-observation rms values."""
    counts = np.array([len(o.points) for o in observations], dtype=np.float64)
    return math.sqrt(float(counts @ np.asarray(per_frame) ** 2) / float(counts.sum()))


def report(document: dict, grid: SheetGrid, frames: list[int], per_frame: np.ndarray,
           acceleration_over_g: np.ndarray, config: MaterialFromVideoConfig,
           seconds: tuple[float, float],
           grids: list[dict], *, stable: bool, converged: bool) -> dict:
    """The "material" entry of result.json: value, s.e., bending length, identifiability,
    goodness of fit, where it falls among measured fabrics, and the quasi-static check."""
    bending = document["parameters"]["bending_stiffness"]
    length = document.get("bending_length_m")
    rms = float(document["misfit"])
    moving = int(np.sum(acceleration_over_g > QUASI_STATIC_LIMIT))
    out = {
        "bending_stiffness": {"value": bending.get("value"),
                              "standard_error": bending.get("standard_error"),
                              "unit": "N·m", "determined": bending["determined"],
                              "at_areal_density": config.areal_density},
        "bending_length": None if length is None else {
            "value": length["value"], "standard_error": length["standard_error"],
            "unit": "m"},
        "membrane_stiffness": _membrane(document, config),
        "identifiability": (
            "gravity is the only load: the shape determines B / (ρ_A g), i.e. the bending "
            "length c = (B / (ρ_A g))^(1/3); B is given at the stated areal density "
            f"ρ_A = {config.areal_density:g} kg/m² (B scales with it)"
            + ("; the membrane stiffness D was estimated beside B (it enters as "
               "D / (ρ_A g), so it too is given at the stated ρ_A)"
               if config.estimate_membrane else
               f"; the membrane stiffness is held at the stated D = "
               f"{config.membrane_stiffness:g} N/m (a wrong held D biases B: "
               "benchmarks/RESULTS.md, Material from video)")),
        "goodness_of_fit": {
            "rms_m": rms, "rms_over_sheet_size": rms / math.hypot(*grid.size),
            "per_frame_rms_m": per_frame.tolist(),
            "worst_frame": int(frames[int(np.argmax(per_frame))]),
            "worst_frame_rms_m": float(per_frame.max()),
            "observed": config.observed,
            "meaning": ("rms 3-D distance between each used frame's fitted equilibrium and "
                        "its reconstructed vertices" if config.observed == "3d" else
                        "rms distance, perpendicular to each vertex's camera ray (what the "
                        "image observed; depth left out), between each used frame's fitted "
                        "equilibrium and its reconstructed vertices")},
        "fabric_percentile": None if length is None else fabric_position(length["value"]),
        "quasi_static": {
            "largest_corner_acceleration_over_g": float(acceleration_over_g.max(initial=0.0)),
            "frames_above_limit": moving, "limit_over_g": QUASI_STATIC_LIMIT,
            "fps": config.fps},
        "grids": grids,
        "frames_used": frames, "sheet_size_m": list(grid.size),
        "stable": stable, "converged": converged, "seconds": seconds[0],
        "cpu_seconds": seconds[1],
        "estimate": document,
    }
    return out


def _membrane(document: dict, config: MaterialFromVideoConfig) -> dict:
    """D's entry: the estimate (value and s.e. when determined) or the stated, held value."""
    if not config.estimate_membrane:
        return {"value": config.membrane_stiffness, "standard_error": None, "unit": "N/m",
                "held": True}
    entry = document["parameters"]["membrane_stiffness"]
    return {"value": entry.get("value"), "standard_error": entry.get("standard_error"),
            "unit": "N/m", "held": False, "determined": entry["determined"],
            "at_areal_density": config.areal_density}


def fabric_position(length: float) -> str:
    """Where a bending length [m] falls among the 251 measured fabrics of Feng et al. 2022."""
    p5, p50, p95 = FABRIC_BENDING_LENGTH
    if length < p5:
        return "below the 5th percentile (softer than 95 % of measured fabrics)"
    if length > p95:
        return "above the 95th percentile (stiffer than 95 % of measured fabrics)"
    return ("between the 5th and the 50th percentile" if length < p50 else
            "between the 50th and the 95th percentile")


def summary_line(material: dict) -> str:
    """One line for the command line."""
    b, c = material["bending_stiffness"], material["bending_length"]
    fit = material["goodness_of_fit"]
    if c is None or b["value"] is None:
        return (f"material: bending stiffness undetermined (rms misfit "
                f"{1e3 * fit['rms_m']:.2f} mm)")
    d = material["membrane_stiffness"]
    if d["held"]:
        membrane = f"D held at {d['value']:g} N/m"
    elif d["value"] is None:
        membrane = "D undetermined"
    else:
        membrane = f"D = {d['value']:.4g} ± {d['standard_error']:.2g} N/m"
    return (f"material: bending length {100 * c['value']:.3f} ± {100 * c['standard_error']:.3f}"
            f" cm ({material['fabric_percentile']}); B = {b['value']:.4g} ± "
            f"{b['standard_error']:.2g} N·m at ρ_A = {b['at_areal_density']:g} kg/m²; "
            f"{membrane}; rms misfit {1e3 * fit['rms_m']:.2f} mm")
