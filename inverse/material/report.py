"""Reports of a material/force estimate: the JSON document and the observed-vs-fitted overlay."""

from __future__ import annotations

import cv2
import numpy as np

from inverse.material.goodness import GoodnessOfFit
from inverse.material.identifiability import finite_or_none
from inverse.material.residual import Estimate, bending_length
from taichi_ndf.render import frame_mesh, render_shaded, widest_azimuth

OBSERVED_BGR = (40, 40, 220)


REJECTED = "the model does not explain the data"


def estimate_document(estimate: Estimate, model, *, ratios: dict | None = None,
                      notes: list[str] | None = None,
                      goodness: GoodnessOfFit | None = None) -> dict:
    """Plain-data report: a value and standard error only for determined unknowns, and the
    goodness of fit (`goodness.goodness_of_fit`; None: the residual method, which fits no
    shape). Where the fit fails that test nothing is "determined": each unknown's entry says
    the model does not explain the data and gives the best-fit value without an error."""
    parameters = {}
    explains = goodness is None or goodness.explains
    for j, u in enumerate(estimate.unknowns):
        determined = bool(estimate.identifiability.determined[j]) and explains
        entry = {"unit": u.unit, "determined": determined,
                 "relative_std": finite_or_none(float(estimate.identifiability.std[j]))}
        if determined:
            entry["value"] = float(estimate.values[j])
            entry["standard_error"] = finite_or_none(float(estimate.standard_errors[j]))
        elif not explains:
            entry["status"] = REJECTED
            entry["best_fit_value"] = float(estimate.values[j])
        parameters[u.name] = entry
    identifiability = estimate.identifiability.to_dict()
    if not explains:
        identifiability["determined"] = [False] * len(estimate.unknowns)
        identifiability["combinations"] = [
            {**c, "determined": False, "status": REJECTED}
            for c in identifiability["combinations"]]
    document = {"method": estimate.method, "parameters": parameters,
                "goodness_of_fit": None if goodness is None else goodness.to_dict(),
                "identifiability": identifiability,
                "misfit": estimate.misfit,
                "misfit_meaning": ("relative equilibrium residual |Aθ − b| / |b|"
                                   if estimate.method == "residual" else
                                   "rms point distance [m]"),
                "iterations": estimate.iterations, "time_s": estimate.time}
    if estimate.gauge is not None:
        document["gauge"] = estimate.gauge
    length = bending_length(estimate, model)
    if length is not None:
        document["bending_length_m"] = {"value": length[0], "standard_error": length[1]}
    if ratios:
        document["ratios"] = {k: {"value": v, "relative_std": s} for k, (v, s) in ratios.items()}
    if notes:
        document["notes"] = list(notes)
    return document


def overlay_image(fitted_vertices: np.ndarray, faces: np.ndarray, observed: np.ndarray, *,
                  width: int = 800, height: int = 600) -> np.ndarray:
    """The fitted surface shaded, the observed points drawn over it as red dots (BGR uint8).

    fitted_vertices: (V, 3) [m]; faces: (F, 3); observed: (M, 3) [m]."""
    both = np.concatenate([fitted_vertices, observed])
    camera = frame_mesh(both, width=width, height=height,
                        azimuth_deg=widest_azimuth(fitted_vertices, faces))
    image = np.ascontiguousarray(render_shaded(fitted_vertices, faces, camera=camera,
                                               width=width, height=height))
    cam = camera.to_camera(observed)
    k = camera.intrinsics(width, height)
    front = cam[:, 2] > 0
    pixels = (cam[front] @ k.T)[:, :2] / cam[front, 2:3]
    for x, y in np.rint(pixels).astype(int):
        cv2.circle(image, (int(x), int(y)), 2, OBSERVED_BGR, -1, lineType=cv2.LINE_AA)
    cv2.putText(image, "surface: fitted equilibrium   dots: observed", (10, 22),
                cv2.FONT_HERSHEY_SIMPLEX, 0.55, (30, 30, 30), 1, cv2.LINE_AA)
    return image
